"""Full time histories of a few runs: the closed-loop plant in one jitted, vmapped scan.

Random numbers: run ``i`` of a batch has the key ``fold_in(key(seed), i)``, and step ``k`` draws
counter-based normals keyed by that key and k (:mod:`mcfdd.analysis.noise`), so a run's signals
do not depend on the batch it is simulated in.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis import noise
from mcfdd.fdd import system
from mcfdd.plant import closed_loop


def run_keys(seed: int, indices):
    """Per-run random keys, ``fold_in(key(seed), index)``: one compiled program per seed and batch size."""
    return _run_keys(np.asarray(indices, dtype=np.uint32), seed=seed)


@partial(jax.jit, static_argnames="seed")
def _run_keys(indices, seed: int):
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(indices)


def sample_time(k, dt_s: float):
    """Time (s) of step index ``k`` (an integer array): k dt_s in JAX's default float type."""
    return k.astype(jnp.result_type(float)) * dt_s


def scan_steps(body, carry, key, n_steps: int, dim: int, unroll: int = 1):
    """``lax.scan`` of ``body(carry, k, noise) -> (carry, y)`` over steps k = 0 .. n_steps - 1.

    The ``dim`` standard normals of step k are :func:`mcfdd.analysis.noise.normals` of the run
    key's words and k: counter-based, drawn inside the step, independent of the horizon and of
    the batch. Returns (final carry, stacked y with leading axis n_steps).
    """
    words = noise.key_words(key)
    dtype = jnp.result_type(float)

    def one(c, k):
        return body(c, k, noise.normals(words, k, dim, dtype))

    return jax.lax.scan(one, carry, jnp.arange(n_steps), unroll=unroll)


def plant_history(model: closed_loop.PlantModel, scenario: closed_loop.Scenario, key, n_steps: int,
                  dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Time history of one run: :class:`~mcfdd.plant.closed_loop.PlantOutputs` with leading axis n_steps."""
    params = closed_loop.prepare(model, scenario, dt_s)
    init_dim, step_dim = closed_loop.noise_dims(model)
    state = closed_loop.init(params, jax.random.normal(key, (init_dim,)))

    def body(state, k, noise):
        return closed_loop.step(params, state, sample_time(k, dt_s), noise, dt_s, substeps, kinds)

    return scan_steps(body, state, key, n_steps, step_dim)[1]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def plant_batch(model, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`plant_history`: scenarios and keys carry a leading batch axis."""
    return jax.vmap(lambda s, k: plant_history(model, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)


def fdd_history(model: closed_loop.PlantModel, fdd_params: system.FddParams, scenario: closed_loop.Scenario, key,
                n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Plant and FDD together over one run: (PlantOutputs, FddOutputs), leading axis n_steps."""
    params = closed_loop.prepare(model, scenario, dt_s)
    init_dim, step_dim = closed_loop.noise_dims(model)
    plant_state = closed_loop.init(params, jax.random.normal(key, (init_dim,)))
    zero = jnp.zeros_like(params.qbar_pa)
    fdd_state = system.init(fdd_params, zero)

    def body(carry, k, noise):
        plant_state, fdd_state = carry
        t = sample_time(k, dt_s)
        plant_state, out = closed_loop.step(params, plant_state, t, noise, dt_s, substeps, kinds)
        fdd_state, fdd_out = system.step(fdd_params, fdd_state, out.u_c_m, out.u_m, out.vcas_m_s, out.altitude_m,
                                         t, dt_s)
        return (plant_state, fdd_state), (out, fdd_out)

    return scan_steps(body, (plant_state, fdd_state), key, n_steps, step_dim)[1]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def fdd_batch(model, fdd_params, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`fdd_history`."""
    return jax.vmap(lambda s, k: fdd_history(model, fdd_params, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)

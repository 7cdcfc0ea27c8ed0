"""Full time histories of a few runs: the closed-loop plant in one jitted, vmapped scan.

Random numbers: run ``i`` of a batch draws from ``fold_in(key(seed), i)`` and step ``k`` from
``fold_in(run_key, k)``, so a run's signals do not depend on the batch it is simulated in.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from mcfdd.fdd import system
from mcfdd.plant import closed_loop


def run_keys(seed: int, indices):
    """Per-run random keys, ``fold_in(key(seed), index)``."""
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(indices, dtype=jnp.uint32))


def step_noise(key, k, dim: int):
    """Standard normals of step ``k`` of the run with key ``key``."""
    return jax.random.normal(jax.random.fold_in(key, k), (dim,))


def plant_history(model: closed_loop.PlantModel, scenario: closed_loop.Scenario, key, n_steps: int,
                  dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Time history of one run: :class:`~mcfdd.plant.closed_loop.PlantOutputs` with leading axis n_steps."""
    params = closed_loop.prepare(model, scenario, dt_s)
    state = closed_loop.init(params, jax.random.normal(key, (3,)))

    def body(state, k):
        noise = step_noise(key, k + 1, closed_loop.NOISE_DIM)
        return closed_loop.step(params, state, k * dt_s, noise, dt_s, substeps, kinds)

    return jax.lax.scan(body, state, jnp.arange(n_steps))[1]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def plant_batch(model, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`plant_history`: scenarios and keys carry a leading batch axis."""
    return jax.vmap(lambda s, k: plant_history(model, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)


def fdd_history(model: closed_loop.PlantModel, fdd_params: system.FddParams, scenario: closed_loop.Scenario, key,
                n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Plant and FDD together over one run: (PlantOutputs, FddOutputs), leading axis n_steps."""
    params = closed_loop.prepare(model, scenario, dt_s)
    plant_state = closed_loop.init(params, jax.random.normal(key, (3,)))
    zero = jnp.zeros_like(params.qbar_pa)
    fdd_state = system.init(fdd_params, zero, zero)

    def body(carry, k):
        plant_state, fdd_state = carry
        noise = step_noise(key, k + 1, closed_loop.NOISE_DIM)
        t = k * dt_s
        plant_state, out = closed_loop.step(params, plant_state, t, noise, dt_s, substeps, kinds)
        fdd_state, fdd_out = system.step(fdd_params, fdd_state, out.u_c_m, out.u_m, scenario.vcas_m_s,
                                         scenario.altitude_m, t, dt_s)
        return (plant_state, fdd_state), (out, fdd_out)

    return jax.lax.scan(body, (plant_state, fdd_state), jnp.arange(n_steps))[1]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def fdd_batch(model, fdd_params, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`fdd_history`."""
    return jax.vmap(lambda s, k: fdd_history(model, fdd_params, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)

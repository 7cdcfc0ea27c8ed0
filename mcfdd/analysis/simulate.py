"""Plant and FDD composed: the one closed-loop run every tool scans (DESIGN.md section 2).

A run is the plant of its model (:func:`mcfdd.plant.closed_loop.loop`: roll axis or full
aircraft) with, optionally, the FDD fed by what the aircraft measures of each plant sample
(:func:`fdd_step`: u_c, u and the measured Vcas and altitude); what the run keeps per step is an
:class:`Observer` (diffrax's ``SubSaveAt(fn=...)``): the full signals (:data:`HISTORY`, for
``simulate`` of a few runs), or the scoring monitors' running state and nothing per step (a
campaign, the worst-case search). The FDD does not act on the plant, so it can also run alone over
stored plant histories (:func:`fdd_over`, the tuner) with the same step and the same observers.

Random numbers: run ``i`` of a batch has the key ``fold_in(key(seed), i)``, and step ``k`` draws
counter-based normals keyed by that key and k (:mod:`mcfdd.analysis.noise`), so a run's signals
do not depend on the batch it is simulated in.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

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


def scan_steps(body, carry, key, n_steps: int, dim: int, unroll: int = 1, method: str = "inverse_cdf"):
    """``lax.scan`` of ``body(carry, k, noise) -> (carry, y)`` over steps k = 0 .. n_steps - 1.

    The ``dim`` standard normals of step k are :func:`mcfdd.analysis.noise.normals` of the run
    key's words and k (by ``method``, the plant's ``Loop.normals``): counter-based, drawn inside the
    step, independent of the horizon and of the batch. Returns (final carry, stacked y with leading
    axis n_steps).
    """
    words = noise.key_words(key)
    dtype = jnp.result_type(float)

    def one(c, k):
        return body(c, k, noise.normals(words, k, dim, dtype, method))

    return jax.lax.scan(one, carry, jnp.arange(n_steps), unroll=unroll)


class Observer(NamedTuple):
    """What a run keeps: ``init(dtype) -> state``; ``update(state, t_s, plant, fdd) -> (state, y)`` at
    every sample (``fdd`` None for the plant alone). A run returns the final state and the y of every
    step stacked along a leading time axis."""

    init: Callable
    update: Callable


HISTORY = Observer(lambda dtype: None, lambda state, t_s, plant, fdd: (None, (plant, fdd)))
"""Keeps every sample's plant outputs (and FDD outputs, None without the FDD)."""


def fdd_step(fdd_params: system.FddParams, state: system.FddState, plant, t_s, dt_s: float):
    """The FDD on what the aircraft measures of a plant sample: command u_c, measured position u,
    measured Vcas and altitude. Returns (new state, :class:`~mcfdd.fdd.system.FddOutputs`)."""
    return system.step(fdd_params, state, plant.u_c_m, plant.u_m, plant.vcas_m_s, plant.altitude_m, t_s, dt_s)


def start(model: closed_loop.PlantModel, fdd_params: system.FddParams | None, scenario: closed_loop.Scenario, key,
          dt_s: float, observer: Observer = HISTORY):
    """A run at t = 0: (plant parameters, carry (plant state, FDD state or None, observer state)).

    ``key`` draws the normals that start the plant's noise filters (:func:`start_from` takes them given).
    """
    return start_from(model, fdd_params, scenario, jax.random.normal(key, (closed_loop.loop(model).init_noise_dim,)),
                      dt_s, observer)


def start_from(model: closed_loop.PlantModel, fdd_params: system.FddParams | None, scenario: closed_loop.Scenario,
               init_normals, dt_s: float, observer: Observer = HISTORY):
    """:func:`start` from given initial normals (``init_noise_dim`` of them)."""
    plant = closed_loop.loop(model)
    params = plant.prepare(model, scenario, dt_s)
    plant_state = plant.init(params, init_normals)
    zero = jnp.zeros_like(params.qbar_pa)
    fdd_state = None if fdd_params is None else system.init(fdd_params, zero)
    return params, (plant_state, fdd_state, observer.init(zero.dtype))


def advance(model: closed_loop.PlantModel, params, fdd_params: system.FddParams | None, carry, k, normals,
            dt_s: float, substeps: int, kinds: tuple[int, ...], observer: Observer = HISTORY):
    """Sample k of a run (``normals``: the plant's ``noise_dim`` standard normals). Returns (new carry, the
    observer's y)."""
    plant_state, fdd_state, seen = carry
    t = sample_time(k, dt_s)
    plant_state, out = closed_loop.loop(model).step(params, plant_state, t, normals, dt_s, substeps, kinds)
    fo = None
    if fdd_params is not None:
        fdd_state, fo = fdd_step(fdd_params, fdd_state, out, t, dt_s)
    seen, y = observer.update(seen, t, out, fo)
    return (plant_state, fdd_state, seen), y


def run(model: closed_loop.PlantModel, fdd_params: system.FddParams | None, scenario: closed_loop.Scenario, key,
        n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...], observer: Observer = HISTORY):
    """One run of n_steps samples of the plant of ``model`` with the FDD (None: the plant alone).

    Returns (the observer's final state, its stacked per-step y).
    """
    params, carry = start(model, fdd_params, scenario, key, dt_s, observer)

    def body(carry, k, normals):
        return advance(model, params, fdd_params, carry, k, normals, dt_s, substeps, kinds, observer)

    plant = closed_loop.loop(model)
    (_, _, seen), ys = scan_steps(body, carry, key, n_steps, plant.noise_dim, method=plant.normals)
    return seen, ys


def run_normals(model: closed_loop.PlantModel, fdd_params: system.FddParams | None, scenario: closed_loop.Scenario,
                init_normals, normals, dt_s: float, substeps: int, kinds: tuple[int, ...],
                observer: Observer = HISTORY):
    """:func:`run` driven by given normals, so that a caller can move them (:mod:`mcfdd.analysis.probability`).

    ``init_normals`` (``init_noise_dim``,) start the plant's noise filters and ``normals``
    (n_steps, ``noise_dim``) are the scan's input, step k's row for sample k; with a campaign run's
    normals it is that run. Returns (the observer's final state, its stacked per-step y).
    """
    params, carry = start_from(model, fdd_params, scenario, init_normals, dt_s, observer)

    def body(carry, xs):
        k, z = xs
        return advance(model, params, fdd_params, carry, k, z, dt_s, substeps, kinds, observer)

    (_, _, seen), ys = jax.lax.scan(body, carry, (jnp.arange(normals.shape[0]), normals))
    return seen, ys


def fdd_over(fdd_params: system.FddParams, plant, observer: Observer, dt_s: float, remat: bool = False):
    """The FDD alone over one stored plant history (PlantOutputs with leaves (T,)), observed as a run.

    ``remat`` rematerialises the step in a gradient (memory of one carry per step). Returns (the
    observer's final state, its stacked per-step y).
    """
    zero = jnp.zeros_like(plant.u_m[0])

    def body(carry, xs):
        fdd_state, seen = carry
        k, out = xs
        t = sample_time(k, dt_s)
        fdd_state, fo = fdd_step(fdd_params, fdd_state, out, t, dt_s)
        seen, y = observer.update(seen, t, out, fo)
        return (fdd_state, seen), y

    (_, seen), ys = jax.lax.scan(jax.checkpoint(body) if remat else body,
                                 (system.init(fdd_params, zero), observer.init(zero.dtype)),
                                 (jnp.arange(plant.u_m.shape[0]), plant))
    return seen, ys


def plant_history(model: closed_loop.PlantModel, scenario: closed_loop.Scenario, key, n_steps: int,
                  dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Time history of one run: :class:`~mcfdd.plant.closed_loop.PlantOutputs` with leading axis n_steps."""
    return run(model, None, scenario, key, n_steps, dt_s, substeps, kinds)[1][0]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def plant_batch(model, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`plant_history`: scenarios and keys carry a leading batch axis."""
    return jax.vmap(lambda s, k: plant_history(model, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)


def fdd_history(model: closed_loop.PlantModel, fdd_params: system.FddParams, scenario: closed_loop.Scenario, key,
                n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Plant and FDD together over one run: (PlantOutputs, FddOutputs), leading axis n_steps."""
    return run(model, fdd_params, scenario, key, n_steps, dt_s, substeps, kinds)[1]


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def fdd_batch(model, fdd_params, scenarios, keys, n_steps: int, dt_s: float, substeps: int, kinds: tuple[int, ...]):
    """Batched :func:`fdd_history`."""
    return jax.vmap(lambda s, k: fdd_history(model, fdd_params, s, k, n_steps, dt_s, substeps, kinds))(scenarios, keys)

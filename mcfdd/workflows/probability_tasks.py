"""The estimator runs of ``mcfdd probability`` as tasks: the same result in this process, on an executor or on Dask.

A task is (stratum, run, point): run ``run`` of the configured estimator on stratum ``stratum``'s
space (point -1), or with the per-airframe parameters fixed at airframe point ``point``
(:class:`mcfdd.analysis.rare.exposure.Conditional`). Its key derives from the seed and the task
alone (``fold_in``), and the task rebuilds its limit state from the config, so a task gives the
same estimate to the last bit wherever and in whatever order it runs. Each process keeps the
limit state of the last config it saw (:func:`prepared`), so its tasks compile once.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from mcfdd import config
from mcfdd.analysis import build, probability as normal_space, rare
from mcfdd.workflows.common import dtype_of, is_dask, load_bank, precision

AIRFRAME_STREAM = 2 ** 31 - 1  # keys of the airframe runs: fold_in(key(seed), AIRFRAME_STREAM), stratum, point, run


def problem_of(cfg: config.CampaignConfig) -> tuple[normal_space.Problem, tuple]:
    """The limit state's problem of a campaign config, and the bank's model names."""
    c, p = cfg.campaign, cfg.probability
    dtype = dtype_of(c.precision)
    model = build.plant_model(cfg.plant)
    bank, names = load_bank(cfg.fdd, dtype)
    r_arm = model.actuator.r_arm_m
    space = normal_space.Space.of(cfg.space.axes, cfg.plant.aircraft.max_mach,
                                   normal_space.noise_dims(model), c.n_steps)
    # the limit state closes over plant and FDD: their NumPy leaves become JAX arrays (traced indexing)
    model, fdd_params = jax.tree.map(lambda x: jnp.asarray(x) if isinstance(x, np.ndarray) else x,
                                     (model, build.fdd_params(cfg.fdd, bank, r_arm)))
    problem = normal_space.Problem(model, fdd_params, build.settings(cfg.evaluation, r_arm),
                                    np.asarray(bank.nu), space, normal_space.EVENTS[p.event][1], c.dt_s, c.substeps,
                                    normal_space.manoeuvre_codes(cfg.space.axes))
    return problem, names


def airframe_axes(cfg: config.CampaignConfig, space: normal_space.Space) -> tuple[str, ...]:
    """The per-airframe axes the space varies (``probability.airframe.axes``), none when the view is off."""
    a = cfg.probability.airframe
    return () if a.view == "none" else tuple(n for n in a.axes if n in space.names)


def airframe_points(cfg: config.CampaignConfig, k: int) -> np.ndarray:
    """(m, k) standard-normal coordinates of the airframes: the 2^k corners at Phi^-1(corner), or
    ``points`` draws of N(0, I_k) from the seed (the quantile view)."""
    a = cfg.probability.airframe
    if a.view == "corner":
        return rare.corners(k, float(norm.ppf(a.corner)))
    key = jax.random.fold_in(jax.random.key(seed_of(cfg)), AIRFRAME_STREAM)
    return np.asarray(jax.random.normal(key, (a.points, k)), float)


def seed_of(cfg: config.CampaignConfig) -> int:
    p = cfg.probability
    return cfg.campaign.seed if p.seed is None else p.seed


class Prepared(NamedTuple):
    """A config's limit state and what its tasks need (built once per process and config)."""

    problem: normal_space.Problem
    names: tuple
    strata: list
    args: list  # StratumArgs per stratum
    g: object  # the batched limit state
    axes: tuple[str, ...]  # per-airframe axes
    conditional: object  # g with the airframe coordinates fixed, or None
    points: np.ndarray  # (m, k) airframe points


_PREPARED: dict = {}


def prepared(cfg: config.CampaignConfig) -> Prepared:
    """The :class:`Prepared` of ``cfg``, kept for the process's next task of the same config.

    Call under ``precision(cfg.campaign.precision)``.
    """
    text = config.to_json(cfg)
    if text not in _PREPARED:
        _PREPARED.clear()
        problem, names = problem_of(cfg)
        strata = normal_space.strata(cfg.space.axes, normal_space.EVENTS[cfg.probability.event][2])
        dtype = dtype_of(cfg.campaign.precision)
        args = [normal_space.stratum_args(cfg.space.axes, s, dtype) for s in strata]
        g = normal_space.limit_state(problem)
        axes = airframe_axes(cfg, problem.space)
        index = tuple(problem.space.names.index(n) for n in axes)
        conditional = rare.exposure.Conditional(g, index) if axes else None
        points = airframe_points(cfg, len(axes)) if axes else np.zeros((0, 0))
        _PREPARED[text] = Prepared(problem, names, strata, args, g, axes, conditional, points)
    return _PREPARED[text]


def _divisor(n: int, most: int) -> int:
    """The largest divisor of n not above ``most``."""
    return max(b for b in range(1, min(n, most) + 1) if n % b == 0)


def run_estimator(g, d: int, key, p, args: tuple) -> rare.Estimate:
    """One run of ``p.method`` (``[probability]``) on the limit state g of dimension d."""
    common = {"keep": p.keep, "confidence": p.confidence, "args": args}
    if p.method == "subset":
        return rare.subset_simulation(g, d, key, n=p.samples, p0=p.p0, max_levels=p.max_levels, chunk=p.chunk,
                                      **common)
    batch = _divisor(p.samples, p.chunk)
    if p.method == "importance":
        return importance_run(g, d, key, p, batch, common)
    return rare.monte_carlo(g, d, key, n=p.samples, batch=batch, **common)


def importance_run(g, d: int, key, p, batch: int, common: dict) -> rare.Estimate:
    """Importance sampling around design points (``[probability]``): the searches start from screened draws or,
    with ``starts_from = "subset"``, from the failure points (smallest ||u|| first, repeated cyclically up to
    ``starts``: duplicates converge to one design point) of a subset simulation run with the first half of the
    key, whose simulations are added; with none found, from screened draws."""
    options = dict(n=p.samples, batch=batch, iterations=p.iterations, spread=p.spread, screening=p.screening,
                   **common)
    if p.starts_from == "screening":
        return rare.importance_sampling(g, d, key, starts=p.starts, **options)
    k_subset, k_sample = jax.random.split(key)
    found = rare.subset_simulation(g, d, k_subset, n=p.start_samples, p0=p.p0, max_levels=p.max_levels,
                                   chunk=p.chunk, keep=p.starts, args=common["args"])
    points = found.failure_points  # repeated cyclically to ``starts`` rows: one shape, one program
    starts = np.resize(points, (p.starts, d)) if len(points) else min(p.starts, p.screening)
    est = rare.importance_sampling(g, d, k_sample, starts=starts, **options)
    return dataclasses.replace(est, n_simulations=est.n_simulations + found.n_simulations)


def estimator_task(cfg: config.CampaignConfig, stratum: int, run: int, point: int = -1) -> rare.Estimate:
    """Estimator run ``run`` of stratum ``stratum``: on its space (``point`` -1) or at airframe ``point``.

    Keys: ``fold_in(fold_in(key(seed), stratum), run)`` on the space, ``fold_in(key(seed),
    AIRFRAME_STREAM)`` folded with stratum, point and run at an airframe.
    """
    with precision(cfg.campaign.precision):
        prep = prepared(cfg)
        base, d = jax.random.key(seed_of(cfg)), prep.problem.space.d
        if point < 0:
            key = jax.random.fold_in(jax.random.fold_in(base, stratum), run)
            return run_estimator(prep.g, d, key, cfg.probability, (prep.args[stratum],))
        key = jax.random.fold_in(base, AIRFRAME_STREAM)
        for i in (stratum, point, run):
            key = jax.random.fold_in(key, i)
        theta = np.asarray(prep.points[point], dtype_of(cfg.campaign.precision))
        return run_estimator(prep.conditional, d - len(prep.axes), key, cfg.probability, (theta, prep.args[stratum]))


def run_tasks(cfg: config.CampaignConfig, tasks, executor=None, compile_cache=None) -> list[rare.Estimate]:
    """The estimates of ``tasks`` [(stratum, run, point)], in their order: in this process (``executor``
    None), on a ``concurrent.futures.Executor`` or on a Dask client (workers set up as for a campaign, with
    ``compile_cache``)."""
    tasks = list(tasks)
    if executor is None:
        return [estimator_task(cfg, *t) for t in tasks]
    options = {}
    if is_dask(executor):
        from mcfdd.workflows import cluster

        cluster.set_up(executor, compile_cache)
        cfg = executor.scatter(cfg, broadcast=True, hash=False)
        options = {"pure": False, "retries": 2}
    futures = [executor.submit(estimator_task, cfg, *t, **options) for t in tasks]
    return [f.result() for f in futures]

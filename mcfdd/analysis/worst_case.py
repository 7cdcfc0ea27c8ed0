"""Worst-case search for the detection bounds of Section 5.3 by gradient through the simulation.

The false-alarm bound (26) is ``tau_f = sup theta`` over fault-free operation, the detection bound
(27) ``tau_d = inf theta`` over the detection window of the relevant faulty situations; the paper
names global worst-case optimisation as the adequate way to compute both and gridding or Monte
Carlo as the cheap approximations. Here the closed loop and the FDD are differentiable, so the
worst case is searched by multi-start projected gradient ascent (Adam, optax) over the continuous
scenario parameters, from the best points of a Sobol screening.

Statistics are the scoring monitors' columns (:func:`statistic`), run in the same scan as plant
and FDD, so a witness's hard value is what a campaign of its scenario scores: the theta bounds of
:data:`mcfdd.analysis.scoring.BOUNDS` (the stall detector's theta at the quiet samples, less the
evaluator's memory of stall loads, and its least peak over relevant stall events; the LOE bank's
fault-free ratio at the excited quiet samples and, over the detection window, the peak of the
smallest ratio among the filters that must fire) and, as detector 'loe_detection', the LOE
detection level's signed statistic (:data:`mcfdd.analysis.scoring.DETECTION`: the confirmed
rejection with contrast, excitation floor, gates and confirmation, whose sign is the verdict). The
search ascends their smooth versions, which the same monitors give with a temperature (a
log-sum-exp, on the logarithm of a theta statistic, :mod:`mcfdd.analysis.scoring.smooth`: T is
relative there, 0.05 about 5 %; on the detection statistic in its own units); as T -> 0 they tend
to the hard ones.

Design decisions (DESIGN.md section 5):

- The stall detector's tau_f is scored as the campaign scores it (one monitor), and that
  definition leaves out the evaluator's memory of stall loads (:mod:`mcfdd.analysis.scoring.stall`):
  a stall that happened is the detector's fault, not fault-free operation, and its residual stays
  in theta for about 1 / gamma (10 s) after it ends, far beyond the 0.5-s grace. Without that, the
  search's tau_f on ``configs/worst_case_stall.toml`` was the memory of a 9-s stall (34 deg).
- Events: a run whose bound does not exist (no relevant stall load for the stall detector's tau_d,
  a run that need not be detected, a peak hinge-load fraction below ``min_load_fraction``) scores
  -inf. A start that reaches such a point ``patience`` evaluations in a row is replaced by the
  screening's next best point that has the event (:func:`pool_from`,
  :class:`mcfdd.analysis.optimise.Restarts`); before that, and once the pool is used up, it
  backtracks to its best point with half steps (the weakest stall load lies at the edge of the set
  of runs that have one). Where the event is rare, :func:`screen` screens on along the Sobol
  sequence until enough runs have it.
- Temperature: the smooth statistic's temperature may fall over the steps (:func:`temperatures`);
  on a detected run's plateau this isolates the deciding sample's gradient, it does not create one.
- Time: the onset of a fault and the start of a manoeuvre are continuous axes where the space
  gives them a range (``fault_onset_s``, ``t_start_s``); the extreme's timing is searched with
  the rest.

Search space: :mod:`mcfdd.analysis.search_space` (the campaign's continuous axes as a unit cube,
categorical ones fixed per start, the traced scenario affine in the columns).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mcfdd.analysis import optimise, scenarios, scoring, simulate
from mcfdd.analysis.search_space import Anchor, Box, SearchSpace, scenario_at, to_columns
from mcfdd.analysis.simulate import run_keys
from mcfdd.fdd import system
from mcfdd.plant import closed_loop

# --------------------------------------------------------------------------------------------
# One point: plant, FDD and the scoring monitors (hard and smooth) in one scan


def run_point(model: closed_loop.PlantModel, fdd_params: system.FddParams, settings: scoring.Settings, box: Box,
              anchor: Anchor, u, key, temperature, n_steps: int, dt_s: float, substeps: int,
              kinds: tuple[int, ...]):
    """Simulate the scenario at u (d,). Returns (the monitors' columns with their smooth versions, columns (d,))."""
    x = to_columns(box, anchor.altitude_m, u)
    scenario, onset = scenario_at(anchor, x)
    truth = scoring.Truth(onset, anchor.accept, anchor.nearest)
    monitor = scoring.monitors(settings, truth, fdd_params, dt_s, temperature)
    state, _ = simulate.run(model, fdd_params, scenario, key, n_steps, dt_s, substeps, kinds,
                            scoring.observer(settings, truth, monitor))
    return scoring.finalize(settings, monitor, state, n_steps * dt_s), x


STATIC = ("n_steps", "dt_s", "substeps", "kinds")


@partial(jax.jit, static_argnames=STATIC)
def evaluate(model, fdd_params, settings, box, anchors, u, keys, temperature, n_steps: int, dt_s: float,
             substeps: int, kinds: tuple[int, ...]):
    """:func:`run_point` over points (leading axis of anchors, u (P, d) and keys), one jit."""
    def one(anchor, u, key):
        return run_point(model, fdd_params, settings, box, anchor, u, key, temperature, n_steps, dt_s, substeps, kinds)

    return jax.vmap(one)(anchors, u, keys)


class Statistic(NamedTuple):
    """A bound read from the monitors' columns: ``sign * columns[hard]`` (``smooth``: its smooth version,
    a logarithm where ``log``)."""

    hard: str
    smooth: str
    sign: float
    log: bool


def statistic(detector: str, bound: str) -> Statistic:
    """The statistic of a bound: the detectors' theta statistics (:data:`scoring.BOUNDS`, smoothed on their
    logarithm) or, for 'loe_detection', the LOE detection level's signed statistic (:data:`scoring.DETECTION`)."""
    if detector == "loe_detection":
        name, sign = scoring.DETECTION[bound]
        return Statistic(name, f"{name}_smooth", sign, False)
    name = scoring.BOUNDS[(detector, bound)]
    return Statistic(name, f"smooth_log_{name}", 1.0, True)


def sense(bound: str) -> float:
    """+1 where the bound is a supremum (searched by ascent), -1 where it is an infimum."""
    return 1.0 if bound == "free" else -1.0


def admissible(columns: dict, min_load_fraction):
    """Runs whose bound counts: those reaching a peak hinge-load fraction of ``min_load_fraction`` (0: all)."""
    return (min_load_fraction <= 0.0) | (columns["peak_load_fraction"] >= min_load_fraction)


@partial(jax.jit, static_argnames=STATIC + ("detector", "bound"))
def score_and_grad(model, fdd_params, settings, box, anchors, u, keys, temperature, n_steps: int, dt_s: float,
                   substeps: int, kinds: tuple[int, ...], detector: str, bound: str, min_load_fraction=0.0):
    """Score (the smooth bound, in log units for theta statistics, sign flipped for an infimum; -inf where
    the run does not count) and its gradient in u, per point.

    Returns (score (P,), (columns, x), gradient (P, d)).
    """
    stat = statistic(detector, bound)

    def one(anchor, u, key):
        def score(u):
            columns, x = run_point(model, fdd_params, settings, box, anchor, u, key, temperature, n_steps, dt_s,
                                   substeps, kinds)
            value = sense(bound) * stat.sign * columns[stat.smooth]
            keep = jnp.isfinite(value) & admissible(columns, min_load_fraction)
            return jnp.where(keep, value, -jnp.inf), (columns, x)

        (value, aux), grad = jax.value_and_grad(score, has_aux=True)(u)
        return value, aux, jnp.where(jnp.isfinite(grad), grad, 0.0)

    return jax.vmap(one)(anchors, u, keys)


def ascend(score_and_grad_fn, u0, iterations: int, learning_rate: float, callback=None,
           restarts: optimise.Restarts | None = None) -> optimise.Trace:
    """Multi-start projected Adam ascent on [0, 1]^d with backtracking (:func:`mcfdd.analysis.optimise.backtracking`).

    ``score_and_grad_fn(u)`` returns (score (S,), aux, gradient (S, d)) for the S starts u (S, d);
    a score of -inf marks an infeasible point: the start backtracks or, with ``restarts``, moves to
    the next point of its pool. ``callback(i, score, aux)`` sees every evaluation. Evaluations: S
    (iterations + 1).
    """
    return optimise.run(score_and_grad_fn, jnp.asarray(u0), optimise.backtracking(learning_rate), iterations,
                        maximize=True, project=lambda u: optax.projections.projection_box(u, 0.0, 1.0),
                        callback=callback, restarts=restarts)


def unit_points(space: SearchSpace, design: str, n: int, seed: int):
    """n points of the whole space by a design: (u (n, d) continuous part, categorical columns)."""
    u = scenarios.unit_sample(design, space.dim + len(space.categorical), n, seed)
    return u[:, :space.dim], space.categories(u[:, space.dim:])


def best_points(values, n: int, bound: str) -> np.ndarray:
    """Indices of the n most extreme finite values (largest for 'free', smallest for 'detect')."""
    v = sense(bound) * np.asarray(values, dtype=float)
    v = np.where(np.isfinite(v), v, -np.inf)
    return np.argsort(-v, kind="stable")[:n]


def extreme(values, bound: str):
    """Index and value of the worst case (max for 'free', min for 'detect') among finite values; (-1, nan) if none."""
    v = np.asarray(values, dtype=float)
    if not np.isfinite(v).any():
        return -1, math.nan
    idx = best_points(v, 1, bound)[0]
    return int(idx), float(v[idx])


# --------------------------------------------------------------------------------------------
# Searches of a problem


class Problem(NamedTuple):
    """A bound to search: simulation, FDD, scoring and space. ``temperature`` in log units (theta
    statistics) or in the statistic's units ('loe_detection'); runs below ``min_load_fraction`` of peak
    hinge load do not count."""

    model: closed_loop.PlantModel
    fdd_params: system.FddParams
    settings: scoring.Settings
    space: SearchSpace
    nu_bank: np.ndarray
    detector: str
    bound: str
    temperature: float
    n_steps: int
    dt_s: float
    substeps: int
    dtype: type
    min_load_fraction: float = 0.0

    def static(self) -> dict:
        return {"n_steps": self.n_steps, "dt_s": self.dt_s, "substeps": self.substeps, "kinds": self.space.kinds()}


class Points(NamedTuple):
    """Evaluated points: u (P, d), categorical columns, column values x (P, d), the smooth and hard
    bound (P,) in the statistic's units (rod m for the stall detector; nan where the run does not
    count), the monitors' columns and, for a gradient search, the pool index each point started from."""

    u: np.ndarray
    categories: dict
    x: np.ndarray
    soft: np.ndarray
    hard: np.ndarray
    outcomes: dict
    start: np.ndarray | None = None


def anchors_at(problem: Problem, box: Box, u, categories: dict) -> Anchor:
    """Anchors of points u (P, d) with categorical columns, taken at their own column values."""
    space = problem.space
    n = np.shape(u)[0]
    cols = space.table(categories, np.zeros((n, space.dim)))
    altitude = np.asarray(cols.get("altitude_m", np.full(n, scenarios.DEFAULTS["altitude_m"])), dtype=problem.dtype)
    x0 = np.asarray(jax.vmap(to_columns, in_axes=(None, 0, 0))(box, jnp.asarray(altitude),
                                                                jnp.asarray(u, problem.dtype)))
    at_x0 = space.table(categories, x0)
    nearest, _ = scenarios.true_model(problem.nu_bank, np.asarray(at_x0.get("fault_kind", np.full(n, "none"))),
                                      np.asarray(at_x0.get("fault_size", np.zeros(n))))
    return space.anchors(categories, x0, problem.nu_bank, problem.dtype)._replace(nearest=jnp.asarray(nearest))


def _points(problem: Problem, u, categories, columns, x) -> Points:
    columns = {k: np.asarray(v) for k, v in columns.items()}
    stat = statistic(problem.detector, problem.bound)
    keep = np.asarray(admissible(columns, problem.min_load_fraction))
    smooth = np.asarray(columns[stat.smooth], dtype=float)
    return Points(np.asarray(u), categories, np.asarray(x),
                  np.where(keep, np.exp(smooth) if stat.log else stat.sign * smooth, np.nan),
                  np.where(keep, stat.sign * np.asarray(columns[stat.hard], dtype=float), np.nan), columns)


def evaluate_points(problem: Problem, u, categories: dict, keys, batch: int) -> Points:
    """Simulate points u (P, d) in batches of ``batch`` (padded, so one compilation serves all)."""
    box = problem.space.box(problem.dtype)
    u = np.asarray(u)
    parts = []
    for start in range(0, u.shape[0], batch):
        idx = np.arange(start, min(start + batch, u.shape[0]))
        padded = np.concatenate([idx, np.repeat(idx[-1:], batch - len(idx))])
        cats = {k: np.asarray(v)[padded] for k, v in categories.items()}
        anchors = anchors_at(problem, box, u[padded], cats)
        columns, x = evaluate(problem.model, problem.fdd_params, problem.settings, box, anchors,
                              jnp.asarray(u[padded], problem.dtype), keys[padded], problem.temperature,
                              **problem.static())
        parts.append(jax.tree.map(lambda a: np.asarray(a)[:len(idx)], (columns, x)))
    columns, x = jax.tree.map(lambda *a: np.concatenate(a), *parts)
    return _points(problem, u, categories, columns, x)


class Pool(NamedTuple):
    """Points a gradient search starts from, in order: u (P, d), categorical columns, keys and their
    ``index`` (P,) (screening rows). The first S are the starts, the rest replace a start that loses the
    event (:class:`mcfdd.analysis.optimise.Restarts`)."""

    u: np.ndarray
    categories: dict
    keys: object
    index: np.ndarray


def temperatures(first: float, last: float, iterations: int) -> np.ndarray:
    """The temperature of each of the iterations + 1 gradient evaluations: geometric from ``first`` to
    ``last`` (``first (last / first)^(i / iterations)``), constant ``first`` where ``last`` is 0."""
    if last <= 0.0 or iterations == 0:
        return np.full(iterations + 1, first)
    return first * (last / first) ** (np.arange(iterations + 1) / iterations)


def gradient_search(problem: Problem, u0, categories: dict, keys, iterations: int, learning_rate: float,
                    callback=None, pool: Pool | None = None, final_temperature: float = 0.0,
                    patience: int = 1) -> list[Points]:
    """Projected gradient search (:func:`ascend`) from the starts u0 (S, d) with their categorical
    columns and keys or, given a ``pool``, from its first S points (u0, categories and keys are then its
    first S), a start infeasible ``patience`` evaluations in a row moving to the pool's next point (before,
    it backtracks). The smooth statistic's temperature
    falls from the problem's to ``final_temperature`` (:func:`temperatures`; 0: constant). Returns the
    evaluated points of every iteration (iterations + 1 of them; ``start``: the pool index of each);
    ``callback(i, points)`` sees each."""
    box = problem.space.box(problem.dtype)
    starts = np.shape(u0)[0]
    if pool is None:
        pool = Pool(np.asarray(u0), categories, keys, np.arange(starts))
    restarts = optimise.Restarts(pool.u, starts, patience)
    schedule = iter(temperatures(problem.temperature, final_temperature, iterations))

    def score_and_grad_fn(u):
        slots = restarts.slots.copy()
        cats = {k: np.asarray(v)[slots] for k, v in pool.categories.items()}
        anchors = anchors_at(problem, box, np.asarray(u), cats)
        score, (columns, x), grad = score_and_grad(
            problem.model, problem.fdd_params, problem.settings, box, anchors, jnp.asarray(u, problem.dtype),
            pool.keys[slots], float(next(schedule)), detector=problem.detector,
            bound=problem.bound, min_load_fraction=problem.min_load_fraction, **problem.static())
        return score, _points(problem, u, cats, columns, x)._replace(start=pool.index[slots]), grad

    report = None if callback is None else (lambda i, score, points: callback(i, points))
    return ascend(score_and_grad_fn, pool.u[:starts], iterations, learning_rate, report, restarts).aux


def sample(problem: Problem, design: str, n: int, seed: int, batch: int, first: int = 0) -> Points:
    """Points ``first`` .. n - 1 of n drawn from the whole space by a design ('sobol' for the
    screening, 'random' for Monte Carlo), point i with key ``run_keys(seed, i)``."""
    u, categories = unit_points(problem.space, design, n, seed)
    return evaluate_points(problem, u[first:], {k: np.asarray(v)[first:] for k, v in categories.items()},
                           run_keys(seed, np.arange(first, n)), batch)


def screen(evaluate_rows, batch: int, wanted: int, most: int) -> tuple[Points, int]:
    """A screening refilled until it holds ``wanted`` runs with the bound's event: rows 0 .. batch - 1 of the
    design, then the next ``batch`` while fewer than ``wanted`` have a finite bound and fewer than ``most``
    rows are screened (``wanted`` 0: one batch). ``evaluate_rows(first, n)`` evaluates rows first .. n - 1
    (:func:`sample`). Returns (the screened points in row order, the number of batches)."""
    parts = [evaluate_rows(0, batch)]
    rows = batch
    while sum(int(np.isfinite(p.hard).sum()) for p in parts) < wanted and rows + batch <= most:
        parts.append(evaluate_rows(rows, rows + batch))
        rows += batch
    return concat(parts), len(parts)


def concat(parts: list[Points]) -> Points:
    """Points of several evaluations, one after the other."""
    return Points(*(jax.tree.map(lambda *a: np.concatenate(a), *(getattr(p, f) for p in parts))
                    for f in ("u", "categories", "x", "soft", "hard", "outcomes")))


def budget(screening: int, starts: int, iterations: int) -> int:
    """Simulations of a search: the screening and every gradient evaluation of every start."""
    return screening + starts * (iterations + 1)


def starts_of(pool: Pool, n: int):
    """The first n points of a pool as starts: (u (n, d), categorical columns, keys)."""
    return pool.u[:n], {k: np.asarray(v)[:n] for k, v in pool.categories.items()}, pool.keys[:n]


def starts_from(screened: Points, n: int, bound: str, seed: int):
    """The n worst screened points as starts: (indices, u (n, d), categorical columns, keys)."""
    pool = pool_from(screened, n, bound, seed)
    return (pool.index[:n], *starts_of(pool, n))


def pool_from(screened: Points, starts: int, bound: str, seed: int) -> Pool:
    """The screened points worst first: the ``starts`` worst, then every other one whose bound counts
    (finite), in order, to replace a start that loses the event."""
    order = best_points(screened.hard, len(screened.hard), bound)
    idx = np.concatenate([order[:starts], [i for i in order[starts:] if np.isfinite(screened.hard[i])]]).astype(int)
    return Pool(screened.u[idx], {k: np.asarray(v)[idx] for k, v in screened.categories.items()},
                run_keys(seed, idx), idx)

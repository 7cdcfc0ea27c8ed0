"""Worst-case search for the detection bounds of Section 5.3 by gradient through the simulation.

The false-alarm bound (26) is ``tau_f = sup theta`` over fault-free operation, the detection bound
(27) ``tau_d = inf theta`` over the detection window of the relevant faulty situations; the paper
names global worst-case optimisation as the adequate way to compute both and gridding or Monte
Carlo as the cheap approximations. Here the closed loop and the FDD are differentiable, so the
worst case is searched by multi-start projected gradient ascent (Adam, optax) over the continuous
scenario parameters, from the best points of a Sobol screening.

Statistics are the scoring monitors' bounds (:data:`mcfdd.analysis.scoring.BOUNDS`: the stall
detector's theta at the quiet samples and its least peak over relevant stall events; the LOE
bank's fault-free ratio at the excited quiet samples and, over the detection window, the peak of
the smallest ratio among the filters that must fire), run in the same scan as plant and FDD. The
hard values are the campaign's columns; the search ascends their smooth versions, which the same
monitors give with a temperature (a log-sum-exp on the logarithm of the statistic,
:mod:`mcfdd.analysis.scoring.smooth`: T is relative, 0.05 about 5 %, and the same for every
detector; as T -> 0 the smooth values tend to the hard ones).

Search space: the ``range`` axes of a campaign's scenario space, mapped from the unit cube as
:func:`mcfdd.analysis.scenarios.design_table` does (Vcas between its lower bound and the smaller of
its upper bound and the Mach-limit speed at the altitude, whose closed form keeps the map
differentiable); the projection is a clip to [0, 1]. Categorical and discrete axes
are held fixed per start, at the values of its screening point. The scenario's random numbers are
fixed by its key, so the objective is deterministic. :func:`mcfdd.analysis.scenarios.to_scenario`
is affine in every continuous column once the categorical ones are fixed, so a point's traced
scenario is ``S(x0) + J (x - x0)`` with S(x0) and J taken from ``to_scenario`` itself: tables and
searches share one conversion.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mcfdd.analysis import optimise, scenarios, scoring, simulate
from mcfdd.analysis.simulate import run_keys
from mcfdd.fdd import system
from mcfdd.plant import atmosphere, closed_loop, manoeuvres

# --------------------------------------------------------------------------------------------
# Search space


class Box(NamedTuple):
    """Unit cube to column values: arrays over the d continuous axes and the Mach limit."""

    lo: jnp.ndarray
    hi: jnp.ndarray
    vcas: jnp.ndarray  # (d,) true for the vcas_kt axis
    altitude: jnp.ndarray  # (d,) one-hot of the altitude_m axis (zeros if it is not continuous)
    max_mach: jnp.ndarray


class Anchor(NamedTuple):
    """One point's fixed part: its categorical values, as the affine map x -> (scenario, onset)."""

    x0: jnp.ndarray  # (d,) column values the map is taken at
    scenario: closed_loop.Scenario  # at x0
    jacobian: closed_loop.Scenario  # leaves with a trailing (d,) axis: change per unit of each column
    onset_s: jnp.ndarray  # fault onset at x0 (inf without a fault)
    onset_jacobian: jnp.ndarray  # (d,)
    accept: jnp.ndarray  # (N,) acceptable identifications at x0
    altitude_m: jnp.ndarray  # altitude if it is not a continuous axis
    nearest: jnp.ndarray | None = None  # nearest model at x0 (set by :func:`anchors_at`)


def to_columns(box: Box, altitude_m, u):
    """Column values (d,) of a point u in [0, 1]^d, as :func:`scenarios.design_table` maps them.

    ``altitude_m`` is the point's altitude when altitude is not a continuous axis.
    """
    span = box.hi - box.lo
    plain = box.lo + u * span
    altitude = jnp.where(jnp.any(box.altitude > 0), jnp.sum(box.altitude * plain), altitude_m)
    vmax = atmosphere.calibrated_airspeed(box.max_mach, altitude) / atmosphere.KT_TO_M_S
    return jnp.where(box.vcas, box.lo + u * (jnp.minimum(box.hi, vmax) - box.lo), plain)


def scenario_at(anchor: Anchor, x):
    """Traced (Scenario, onset) at column values x (d,): ``S(x0) + J (x - x0)``."""
    dx = x - anchor.x0

    def leaf(base, jac):
        if not jnp.issubdtype(base.dtype, jnp.floating):
            return base
        return base + jnp.dot(jac, dx.astype(jac.dtype))

    return jax.tree.map(leaf, anchor.scenario, anchor.jacobian), anchor.onset_s + jnp.dot(anchor.onset_jacobian, dx)


@dataclasses.dataclass(frozen=True)
class SearchSpace:
    """A campaign's scenario space split for the search.

    ``continuous``: the 'range' axes (the unit cube searched); ``categorical``: the other varying
    axes (choices and discrete values), held fixed per point; ``constants``: const axes.
    """

    continuous: tuple
    categorical: tuple
    constants: dict
    max_mach: float

    @classmethod
    def from_axes(cls, axes, max_mach: float) -> SearchSpace:
        """Split the axes (:class:`mcfdd.config.Axis`) of a scenario space."""
        return cls(tuple(a for a in axes if a.kind == "range"),
                   tuple(a for a in axes if a.kind in ("choices", "values")),
                   {a.name: a.values[0] for a in axes if a.kind == "const"}, max_mach)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.continuous)

    @property
    def dim(self) -> int:
        return len(self.continuous)

    def box(self, dtype) -> Box:
        """The :class:`Box` of the continuous axes (column units, e.g. kt, m) in ``dtype``."""
        f = np.dtype(dtype)
        return Box(lo=jnp.asarray([a.lo for a in self.continuous], f),
                   hi=jnp.asarray([a.hi for a in self.continuous], f),
                   vcas=jnp.asarray([n == "vcas_kt" for n in self.names]),
                   altitude=jnp.asarray([float(n == "altitude_m") for n in self.names], f),
                   max_mach=jnp.asarray(self.max_mach, f))

    def categories(self, u_cat) -> dict:
        """Categorical columns of points drawn as u_cat (P, k) in [0, 1)^k (:func:`scenarios.from_unit`)."""
        u_cat = np.asarray(u_cat)
        return {a.name: scenarios.from_unit(a, u_cat[:, j]) for j, a in enumerate(self.categorical)}

    def table(self, categories: dict, x) -> dict:
        """Scenario-table columns (P rows) of points with categorical values and column values x (P, d).

        Fault sizes are merged per kind into ``fault_size`` as in the campaign design.
        """
        x = np.asarray(x, dtype=float).reshape(-1, self.dim)
        n = x.shape[0]
        cols = {name: np.full(n, value) for name, value in self.constants.items()}
        cols.update({k: np.asarray(v) for k, v in categories.items()})
        cols.update({name: x[:, j] for j, name in enumerate(self.names)})
        return scenarios.merge_fault_sizes(cols)

    def anchors(self, categories: dict, x0, nu_bank, dtype) -> Anchor:
        """Anchors (leading axis P) of points with categorical values and column values x0 (P, d)."""
        x0 = np.asarray(x0, dtype=float).reshape(-1, self.dim)
        n, d = x0.shape
        steps = np.concatenate([np.zeros((1, d)), np.eye(d)])  # (d + 1, d)
        x_all = (x0[:, None, :] + steps[None]).reshape(n * (d + 1), d)
        cats = {k: np.repeat(np.asarray(v), d + 1) for k, v in categories.items()}
        cols = self.table(cats, x_all)
        rows = n * (d + 1)
        scen = scenarios.to_scenario(cols, np.float64)
        onset = scenarios.fault_onsets(cols, rows)

        def split(leaf):
            leaf = np.asarray(leaf).reshape(n, d + 1)
            base = leaf[:, 0]
            if not np.issubdtype(leaf.dtype, np.floating):
                return base, np.zeros((n, d), dtype=dtype)
            with np.errstate(invalid="ignore"):
                jac = leaf[:, 1:] - base[:, None]
            return base.astype(dtype), np.nan_to_num(jac, nan=0.0).astype(dtype)

        base = jax.tree.map(lambda leaf: split(leaf)[0], scen)
        jac = jax.tree.map(lambda leaf: split(leaf)[1], scen)
        onset_base, onset_jac = split(onset)
        first = {k: np.asarray(v)[:: d + 1] for k, v in cols.items()}
        _, accept = scenarios.true_model(np.asarray(nu_bank), np.asarray(first.get("fault_kind", np.full(n, "none"))),
                                         np.asarray(first.get("fault_size", np.zeros(n))))
        altitude = np.asarray(first.get("altitude_m", np.full(n, scenarios.DEFAULTS["altitude_m"])), dtype=dtype)
        return Anchor(jnp.asarray(x0, dtype), jax.tree.map(jnp.asarray, base), jax.tree.map(jnp.asarray, jac),
                      jnp.asarray(onset_base), jnp.asarray(onset_jac), jnp.asarray(accept), jnp.asarray(altitude))

    def kinds(self) -> tuple[int, ...]:
        """Static manoeuvre family codes the space can produce."""
        axis = next((a for a in self.categorical if a.name == "manoeuvre_kind"), None)
        names = axis.values if axis else (self.constants.get("manoeuvre_kind", scenarios.DEFAULTS["manoeuvre_kind"]),)
        return tuple(sorted(manoeuvres.KIND_CODE[k] for k in set(names)))


# --------------------------------------------------------------------------------------------
# One point: plant, FDD and the scoring monitors (hard and smooth) in one scan


def run_point(model: closed_loop.PlantModel, fdd_params: system.FddParams, settings: scoring.Settings, box: Box,
              anchor: Anchor, u, key, temperature, n_steps: int, dt_s: float, substeps: int,
              kinds: tuple[int, ...]):
    """Simulate the scenario at u (d,). Returns (the monitors' columns with their smooth versions, columns (d,))."""
    x = to_columns(box, anchor.altitude_m, u)
    scenario, onset = scenario_at(anchor, x)
    truth = scoring.Truth(onset, anchor.accept, anchor.nearest)
    monitor = scoring.monitors(settings, truth, fdd_params, temperature)
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


def smooth_column(detector: str, bound: str) -> str:
    """The column of a bound's smooth logarithm."""
    return f"smooth_log_{scoring.BOUNDS[(detector, bound)]}"


def sense(bound: str) -> float:
    """+1 where the bound is a supremum (searched by ascent), -1 where it is an infimum."""
    return 1.0 if bound == "free" else -1.0


@partial(jax.jit, static_argnames=STATIC + ("detector", "bound"))
def score_and_grad(model, fdd_params, settings, box, anchors, u, keys, temperature, n_steps: int, dt_s: float,
                   substeps: int, kinds: tuple[int, ...], detector: str, bound: str):
    """Score (smooth bound in log units, sign flipped for an infimum) and its gradient in u, per point.

    Returns (score (P,), (columns, x), gradient (P, d)).
    """
    def one(anchor, u, key):
        def score(u):
            columns, x = run_point(model, fdd_params, settings, box, anchor, u, key, temperature, n_steps, dt_s,
                                   substeps, kinds)
            value = sense(bound) * columns[smooth_column(detector, bound)]
            return jnp.where(jnp.isfinite(value), value, -jnp.inf), (columns, x)

        (value, aux), grad = jax.value_and_grad(score, has_aux=True)(u)
        return value, aux, jnp.where(jnp.isfinite(grad), grad, 0.0)

    return jax.vmap(one)(anchors, u, keys)


def ascend(score_and_grad_fn, u0, iterations: int, learning_rate: float, callback=None) -> optimise.Trace:
    """Multi-start projected Adam ascent on [0, 1]^d with backtracking (:func:`mcfdd.analysis.optimise.backtracking`).

    ``score_and_grad_fn(u)`` returns (score (S,), aux, gradient (S, d)) for the S starts u (S, d);
    a score of -inf marks an infeasible point. ``callback(i, score, aux)`` sees every evaluation.
    Evaluations: S (iterations + 1).
    """
    return optimise.run(score_and_grad_fn, jnp.asarray(u0), optimise.backtracking(learning_rate), iterations,
                        maximize=True, project=lambda u: optax.projections.projection_box(u, 0.0, 1.0),
                        callback=callback)


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
    """A bound to search: simulation, FDD, scoring and space. ``temperature`` in log units."""

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

    def static(self) -> dict:
        return {"n_steps": self.n_steps, "dt_s": self.dt_s, "substeps": self.substeps, "kinds": self.space.kinds()}


class Points(NamedTuple):
    """Evaluated points: u (P, d), categorical columns, column values x (P, d), the smooth and hard
    bound (P,) in the statistic's units (rod m for the stall detector) and the monitors' columns."""

    u: np.ndarray
    categories: dict
    x: np.ndarray
    soft: np.ndarray
    hard: np.ndarray
    outcomes: dict


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
    return Points(np.asarray(u), categories, np.asarray(x),
                  np.exp(np.asarray(columns[smooth_column(problem.detector, problem.bound)], dtype=float)),
                  np.asarray(columns[scoring.BOUNDS[(problem.detector, problem.bound)]], dtype=float), columns)


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


def gradient_search(problem: Problem, u0, categories: dict, keys, iterations: int, learning_rate: float,
                    callback=None) -> list[Points]:
    """Projected gradient search (:func:`ascend`) from the starts u0 (S, d) with their categorical
    columns and keys. Returns the evaluated points of every iteration (iterations + 1 of them);
    ``callback(i, points)`` sees each."""
    box = problem.space.box(problem.dtype)

    def score_and_grad_fn(u):
        anchors = anchors_at(problem, box, np.asarray(u), categories)
        score, (columns, x), grad = score_and_grad(
            problem.model, problem.fdd_params, problem.settings, box, anchors, jnp.asarray(u, problem.dtype), keys,
            problem.temperature, detector=problem.detector, bound=problem.bound, **problem.static())
        return score, _points(problem, u, categories, columns, x), grad

    report = None if callback is None else (lambda i, score, points: callback(i, points))
    return ascend(score_and_grad_fn, u0, iterations, learning_rate, report).aux


def sample(problem: Problem, design: str, n: int, seed: int, batch: int, first: int = 0) -> Points:
    """Points ``first`` .. n - 1 of n drawn from the whole space by a design ('sobol' for the
    screening, 'random' for Monte Carlo), point i with key ``run_keys(seed, i)``."""
    u, categories = unit_points(problem.space, design, n, seed)
    return evaluate_points(problem, u[first:], {k: np.asarray(v)[first:] for k, v in categories.items()},
                           run_keys(seed, np.arange(first, n)), batch)


def budget(screening: int, starts: int, iterations: int) -> int:
    """Simulations of a search: the screening and every gradient evaluation of every start."""
    return screening + starts * (iterations + 1)


def starts_from(screened: Points, n: int, bound: str, seed: int):
    """The n worst screened points as starts: (indices, u (n, d), categorical columns, keys)."""
    idx = best_points(screened.hard, n, bound)
    return idx, screened.u[idx], {k: np.asarray(v)[idx] for k, v in screened.categories.items()}, \
        run_keys(seed, idx)

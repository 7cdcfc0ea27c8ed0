"""A campaign's scenarios as points of a standard-normal space, and the margin of an event there (DESIGN.md 5c).

Every random input of a run of a campaign is a deterministic, differentiable function of
standard-normal coordinates u ~ N(0, I_d), d = k + d0 + T m:

- u[:k], one per continuous axis of the space (a ``[lo, hi]`` range, in the space's order):
  x = lo + Phi(u) (hi - lo), the uniform draw of the campaign's design (Vcas up to the smaller of
  its upper bound and the Mach-limit speed at the run's altitude, as the design does);
- u[k:k + d0], the normals that start the turbulence filters (d0 of the plant model);
- u[k + d0:], T steps of m normals each (turbulence forcing and position-sensor noise), the
  scan input of the run (:func:`mcfdd.analysis.simulate.run_normals`).

The categorical axes (choices and discrete values: manoeuvre family, turbulence level, fault
kind) are strata: a stratum fixes them, and its values reach the one compiled limit state as
traced arguments (:class:`StratumArgs`), so every stratum of a run uses one program. A
campaign's own draws are unchanged: its runs draw their noise from counter-based hashes
(:mod:`mcfdd.analysis.noise`); a campaign run is replayed here by giving its columns and its
normals (:func:`margins_at`), which gives the campaign's own margins.

The event's margin g is the campaign's signed margin column (:data:`EVENTS`, from
:func:`mcfdd.analysis.scoring.monitors`, the code the campaign scores with): g > 0 exactly where
the campaign's flag is set. A void run (numbers not finite) has no margin and is outside every
event (g = -inf), as its flags are false.
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtr, ndtri

from mcfdd import columns
from mcfdd.analysis import noise, scenarios, scoring, simulate
from mcfdd.plant import atmosphere, closed_loop, manoeuvres

# event -> (the campaign's flag column, its signed margin column, the fault kinds of its strata)
EVENTS = {
    "false_alarm": ("false_alarm", "false_alarm_margin", ("none",)),
    "missed_detection": ("missed", "missed_margin", columns.PARAMETRIC),
    "stall_false_detection": ("stall_false_detection", "stall_false_detection_margin", ("none",)),
    "false_stall_identification_signal": ("eta_false_signal", "eta_false_signal_margin", ("none",)),
    "false_stall_identification_model": ("eta_false_model", "eta_false_model_margin", ("none",)),
}
_FAULT_FLAGS = ("leakage", "surface_damage", "disconnection", "jamming")  # the order of StratumArgs.kind


@dataclasses.dataclass(frozen=True)
class Space:
    """The coordinates of a campaign's runs (module docstring).

    Attributes:
        names: the continuous axes, one coordinate each (column names, in the space's order).
        lo, hi: (k,) their bounds (column units).
        max_mach: the Mach limit of the Vcas axis (the design's envelope).
        init_dim, step_dim: normals at the start and per step of the plant model.
        n_steps: steps of a run.
    """

    names: tuple[str, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    max_mach: float
    init_dim: int
    step_dim: int
    n_steps: int

    @classmethod
    def of(cls, axes, max_mach: float, noise_dims: tuple[int, int], n_steps: int) -> Space:
        ranges = [a for a in axes if a.kind == "range"]
        return cls(tuple(a.name for a in ranges), tuple(float(a.lo) for a in ranges),
                   tuple(float(a.hi) for a in ranges), max_mach, *noise_dims, n_steps)

    @property
    def k(self) -> int:
        return len(self.names)

    @property
    def d(self) -> int:
        """Dimension of u."""
        return self.k + self.init_dim + self.n_steps * self.step_dim

    def split(self, u):
        """(parameters (k,), initial normals (d0,), step normals (T, m)) of one point u (d,)."""
        k, d0 = self.k, self.init_dim
        return u[:k], u[k:k + d0], u[k + d0:].reshape(self.n_steps, self.step_dim)


class StratumArgs(NamedTuple):
    """A stratum's fixed values, traced: the scenario with its categorical and constant columns set
    (continuous ones at their defaults), the fault kind as flags (leakage, surface damage,
    disconnection, jamming), and the fault size and onset (s) the stratum gives."""

    base: closed_loop.Scenario
    kind: jnp.ndarray
    size: jnp.ndarray
    onset_s: jnp.ndarray


def strata(axes, fault_kinds) -> list[dict]:
    """The strata of a space: each combination of its categorical axes' values, whose fault kind is
    one of ``fault_kinds`` (C order over the axes, as the space lists them). Returns [{column: value}]."""
    discrete = [a for a in axes if a.kind in ("values", "choices")]
    out = []
    for combo in itertools.product(*(a.values for a in discrete)):
        values = dict(zip((a.name for a in discrete), combo))
        kind = values.get("fault_kind", next((a.values[0] for a in axes if a.name == "fault_kind"),
                                             columns.DEFAULTS["fault_kind"]))
        if kind in fault_kinds:
            out.append(values)
    return out


def stratum_columns(axes, stratum: dict) -> dict:
    """Scenario columns (one row, NumPy) of a stratum: constants, the stratum's values, the range axes
    at their lower bound (replaced by the coordinates) and defaults; per-kind sizes merged."""
    cols = {a.name: np.asarray([a.values[0] if a.kind == "const" else a.lo]) for a in axes
            if a.kind in ("const", "range")}
    cols.update({name: np.asarray([value]) for name, value in stratum.items()})
    for name, value in columns.DEFAULTS.items():
        cols.setdefault(name, np.asarray([value]))
    return scenarios.merge_fault_sizes(cols)


def stratum_args(axes, stratum: dict, dtype) -> StratumArgs:
    """The traced arguments of a stratum (:class:`StratumArgs`), leaves of shape ()."""
    cols = stratum_columns(axes, stratum)
    base = jax.tree.map(lambda x: x[0], scenarios.to_scenario(cols, dtype))
    kind = str(cols["fault_kind"][0])
    return StratumArgs(base, np.asarray([kind == f for f in _FAULT_FLAGS], dtype),
                       np.asarray(cols["fault_size"][0], dtype), np.asarray(cols["fault_onset_s"][0], dtype))


def values_at(space: Space, z, args: StratumArgs) -> dict:
    """Column values (column units) of the continuous axes at parameter coordinates z (k,)."""
    unit = ndtr(z)
    values = {}
    for j, name in enumerate(space.names):
        if name != "vcas_kt":
            values[name] = space.lo[j] + unit[j] * (space.hi[j] - space.lo[j])
    altitude = values.get("altitude_m", args.base.altitude_m)
    if "vcas_kt" in space.names:
        j = space.names.index("vcas_kt")
        v_max = atmosphere.calibrated_airspeed(space.max_mach, altitude) / atmosphere.KT_TO_M_S
        values["vcas_kt"] = space.lo[j] + unit[j] * (jnp.minimum(space.hi[j], v_max) - space.lo[j])
    return values


def unit_of(space: Space, cols: dict, row: int = 0) -> np.ndarray:
    """The uniform numbers (k,) that give row ``row`` of scenario columns (the inverse of the design's map).

    A per-kind size axis of another fault kind than the row's does not act on the run: 0.5.
    """
    out = []
    for j, name in enumerate(space.names):
        lo, hi = space.lo[j], space.hi[j]
        of = columns.COLUMN[name].size_of
        if of:
            size = float(np.asarray(cols["fault_size"])[row])
            out.append((size - lo) / (hi - lo) if np.asarray(cols["fault_kind"])[row] == of else 0.5)
            continue
        if name == "vcas_kt":
            altitude = float(np.asarray(cols.get("altitude_m", [columns.DEFAULTS["altitude_m"]]))[row])
            hi = min(hi, float(scenarios.mach_limit_speed_kt(altitude, space.max_mach)))
        out.append((float(np.asarray(cols[name])[row]) - lo) / (hi - lo))
    return np.asarray(out)


def coordinates_of(space: Space, cols: dict, row: int = 0) -> np.ndarray:
    """Parameter coordinates z (k,) of row ``row`` of scenario columns: Phi^-1 of :func:`unit_of`."""
    return np.asarray(ndtri(jnp.asarray(unit_of(space, cols, row))))


def scenario_at(space: Space, values: dict, args: StratumArgs) -> tuple[closed_loop.Scenario, jnp.ndarray]:
    """The stratum's scenario with the continuous columns set to ``values``, and the time (s) its
    fault starts, inf without one (:func:`mcfdd.analysis.scenarios.fault_onsets`)."""
    leaves = {}
    for name, value in values.items():
        column = columns.COLUMN[name]
        if column.leaf not in ("fault", "") and not column.size_of:
            leaves[column.leaf] = value * column.si if column.si != 1.0 else value
    flags = args.kind
    size = args.size
    for name, value in values.items():
        of = columns.COLUMN[name].size_of
        if of:
            size = jnp.where(flags[_FAULT_FLAGS.index(of)] > 0, value, size)
    onset = values.get("fault_onset_s", args.onset_s)
    leak, surface, disconnection, jam = flags[0], flags[1], flags[2], flags[3]
    parametric = leak + surface + disconnection > 0
    inf = jnp.asarray(jnp.inf, args.onset_s.dtype)
    fault = args.base.fault._replace(nu1=1.0 - size * leak, nu2=(1.0 - size * surface) * (1.0 - disconnection),
                                     onset_s=jnp.where(parametric, onset, inf), jam_onset_s=jnp.where(jam > 0, onset,
                                                                                                      inf))
    manoeuvre = args.base.manoeuvre._replace(**{k.partition(".")[2]: v for k, v in leaves.items()
                                                if k.startswith("manoeuvre.")})
    scenario = args.base._replace(**{k: v for k, v in leaves.items() if "." not in k}, fault=fault,
                                  manoeuvre=manoeuvre)
    return scenario, jnp.where(parametric | (jam > 0), onset, inf)


def truth_at(nu_bank: np.ndarray, fault, onset_s, args: StratumArgs) -> scoring.Truth:
    """The scoring truth of a traced fault: :func:`mcfdd.analysis.scenarios.true_model` in JAX.

    The nearest bank model on nu2 among those with nu1 = 1 (surface damage, disconnection) or on
    nu1 among those with nu2 = 1 (leakage), and the two models that bracket the fault; fault-free
    rows accept none (nearest 0), jammed ones none (nearest -1). ``onset_s``: of any fault (s).
    """
    leak, surface, disconnection, jam = (args.kind[i] > 0 for i in range(4))
    parametric = leak | surface | disconnection
    value = jnp.where(leak, fault.nu1, fault.nu2)
    bank = np.asarray(nu_bank, value.dtype)
    members = jnp.where(leak, np.isclose(bank[:, 1], 1.0), np.isclose(bank[:, 0], 1.0))
    grid = jnp.where(leak, bank[:, 0], bank[:, 1])
    near = jnp.argmin(jnp.where(members, jnp.abs(grid - value), jnp.inf))
    below = members & (grid <= value + 1e-12)
    above = members & (grid >= value - 1e-12)
    ids = jnp.arange(len(bank))
    accept = ((ids == near) | (below.any() & (ids == jnp.argmax(jnp.where(below, grid, -jnp.inf))))
              | (above.any() & (ids == jnp.argmin(jnp.where(above, grid, jnp.inf)))))
    nearest = jnp.where(parametric, near, jnp.where(jam, -1, 0)).astype(jnp.int32)
    return scoring.Truth(onset_s, accept & parametric, nearest)


class Problem(NamedTuple):
    """What the limit state closes over: plant, FDD, scoring settings, bank, space and run settings."""

    model: closed_loop.PlantModel
    fdd_params: object
    settings: scoring.Settings
    nu_bank: np.ndarray
    space: Space
    margin: str  # the margin column of the event
    dt_s: float
    substeps: int
    kinds: tuple[int, ...]  # manoeuvre family codes of the whole space (static)


def run_columns(problem: Problem, scenario, truth, init_normals, normals) -> dict:
    """The scoring columns of one run driven by the given normals."""
    monitor = scoring.monitors(problem.settings, truth, problem.fdd_params, problem.dt_s)
    observer = scoring.observer(problem.settings, truth, monitor)
    state, _ = simulate.run_normals(problem.model, problem.fdd_params, scenario, init_normals, normals, problem.dt_s,
                                    problem.substeps, problem.kinds, observer)
    return scoring.finalize(problem.settings, monitor, state, problem.space.n_steps * problem.dt_s)


def margin_of(problem: Problem, u, args: StratumArgs):
    """g at one point u (d,): the event's signed margin, -inf for a void run."""
    z, init_normals, normals = problem.space.split(u)
    scenario, onset = scenario_at(problem.space, values_at(problem.space, z, args), args)
    truth = truth_at(problem.nu_bank, scenario.fault, onset, args)
    m = run_columns(problem, scenario, truth, init_normals, normals)[problem.margin]
    return jnp.where(jnp.isnan(m), -jnp.inf, m)


def limit_state(problem: Problem):
    """The batched limit state ``g(u, args)``, (n, d) -> (n,), of :mod:`mcfdd.analysis.rare`.

    Build it once per problem: the estimators key their compiled programs on g.
    """
    def g(u, args):
        return jax.vmap(lambda row: margin_of(problem, row, args))(u)

    return g


def columns_at(space: Space, points, args: StratumArgs) -> dict:
    """Scenario columns (NumPy, column units) of the continuous axes at points u (n, d)."""
    z = jnp.asarray(points)[:, :space.k]
    values = jax.vmap(lambda row: values_at(space, row, args))(z)
    return {name: np.asarray(values[name], float) for name in space.names}


def campaign_normals(key, n_steps: int, dims: tuple[int, int], method: str = "inverse_cdf"):
    """The normals a campaign run keyed ``key`` draws (:mod:`mcfdd.analysis.noise`, by the plant's ``method``,
    ``closed_loop.loop(model).normals``): (initial (d0,), steps (T, m))."""
    words = noise.key_words(key)
    dtype = jnp.result_type(float)
    steps = jax.vmap(lambda k: noise.normals(words, k, dims[1], dtype, method))(jnp.arange(n_steps))
    return jax.random.normal(key, (dims[0],)), steps


def must_fraction(nu_bank: np.ndarray, kind: str, lo: float, hi: float, points: int = 20_001) -> float:
    """The share of fault sizes uniform on [lo, hi] that must be detected (nearest model not the
    nominal one), on ``points`` equally spaced sizes (exact for lo = hi)."""
    sizes = np.linspace(lo, hi, points if hi > lo else 1)
    nearest, _ = scenarios.true_model(np.asarray(nu_bank), np.full(len(sizes), kind), sizes)
    return float(np.mean(nearest >= 1))


def manoeuvre_codes(axes) -> tuple[int, ...]:
    """The static manoeuvre family codes of a space."""
    axis = next((a for a in axes if a.name == "manoeuvre_kind"), None)
    names = axis.values if axis is not None else (columns.DEFAULTS["manoeuvre_kind"],)
    return tuple(sorted(manoeuvres.KIND_CODE[n] for n in names))


def noise_dims(model) -> tuple[int, int]:
    """(normals at the start, normals per step) of the plant model's runs."""
    plant = closed_loop.loop(model)
    return plant.init_noise_dim, plant.noise_dim


def histories(problem: Problem, u, args: StratumArgs):
    """Time histories of the run at one point u (d,): (PlantOutputs, FddOutputs), leading axis steps."""
    z, init_normals, normals = problem.space.split(jnp.asarray(u))
    scenario, _ = scenario_at(problem.space, values_at(problem.space, z, args), args)
    return simulate.run_normals(problem.model, problem.fdd_params, scenario, init_normals, normals, problem.dt_s,
                                problem.substeps, problem.kinds)[1]

"""Scenario spaces, sampling designs and the conversion of scenario tables to traced scenarios.

A scenario is one row of a table whose columns carry their unit in the name (``vcas_kt``,
``fault_onset_s``); the columns are declared once, in :mod:`mcfdd.columns`. :func:`to_scenario`
turns columns (scalars or arrays) into the traced :class:`~mcfdd.plant.closed_loop.Scenario`
pytree, so single runs, campaigns and searches share one conversion.

A space has one :class:`mcfdd.config.Axis` per column: a constant, a continuous range, discrete values or
named choices (:func:`grid_values` and :func:`from_unit` sample it). A design maps the unit hypercube
to the axes: full grid, random, Latin hypercube or Sobol (``scipy.stats.qmc``), or a grid over some
axes crossed with samples over the others. The flight envelope is respected by construction: Vcas
is drawn between its lower bound and the smaller of its upper bound and the Mach-limit speed at
the drawn altitude (grid points above the limit are dropped), which keeps the stratification of
the design in the unit cube.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import qmc

from mcfdd import columns
from mcfdd.columns import DEFAULTS, PARAMETRIC, SIZE_COLUMNS
from mcfdd.config import DESIGNS, Axis
from mcfdd.plant import actuator, atmosphere, closed_loop, manoeuvres


def grid_values(axis: Axis) -> tuple:
    """The axis's values on a grid: ``n`` points over a range, else its values."""
    if axis.kind == "range":
        return tuple(np.linspace(axis.lo, axis.hi, axis.n)) if axis.n > 1 else (axis.lo,)
    return axis.values


def from_unit(axis: Axis, u):
    """Map uniform numbers in [0, 1) to the axis's values (uniform over a range, equal shares of the values)."""
    if axis.kind == "range":
        return axis.lo + u * (axis.hi - axis.lo)
    options = np.asarray(axis.values)
    return options[np.minimum((u * len(options)).astype(int), len(options) - 1)]


def fault_nu(kind, size):
    """(nu1, nu2) once the fault is in; broadcasts over arrays of kind names and sizes."""
    kind = np.asarray(kind)
    size = np.asarray(size, dtype=float)
    nu1 = np.where(kind == "leakage", 1.0 - size, 1.0)
    nu2 = np.where(kind == "surface_damage", 1.0 - size, np.where(kind == "disconnection", 0.0, 1.0))
    return nu1, nu2


def fault_leaves(kind, size, onset, dtype) -> actuator.ActuatorFault:
    """The fault of rows of kind names, sizes and onsets (s): (nu1, nu2), the parametric and the jam onset."""
    kind = np.asarray(kind)
    nu1, nu2 = fault_nu(kind, size)
    onset = np.asarray(onset).astype(float)
    return actuator.ActuatorFault(
        nu1=nu1.astype(dtype), nu2=nu2.astype(dtype),
        onset_s=np.where(np.isin(kind, PARAMETRIC), onset, np.inf).astype(dtype),
        jam_onset_s=np.where(kind == "jamming", onset, np.inf).astype(dtype))


def _leaf(column: columns.Column, value, dtype):
    """A column's values as its leaf: the code of each name, or the number in SI units."""
    if column.codes:
        code = dict(zip(column.choices, column.codes, strict=True))
        integer = isinstance(column.codes[0], int)
        leaf = np.vectorize(code.__getitem__, otypes=[np.int32 if integer else float])(value)
        return leaf if integer else leaf.astype(dtype)
    return (value if column.si == 1.0 else value * column.si).astype(dtype)


def to_scenario(cols: dict, dtype=np.float32) -> closed_loop.Scenario:
    """Scenario pytree (SI units) from table columns; missing columns take :data:`DEFAULTS`.

    Columns are scalars or arrays of one shape; the leaves of the result have that shape. Each
    column sets its registry leaf (:attr:`mcfdd.columns.Column.leaf`); the fault columns set the
    fault together (:func:`fault_leaves`).
    """
    shape = np.broadcast_shapes(*(np.shape(v) for v in cols.values()))
    c = {k: np.broadcast_to(np.asarray(cols.get(k, v)), shape) for k, v in DEFAULTS.items()}
    f = np.dtype(dtype)
    leaves = {col.leaf: _leaf(col, c[col.name], f) for col in columns.TABLE if col.leaf != "fault"}
    manoeuvre = {k.partition(".")[2]: v for k, v in leaves.items() if k.startswith("manoeuvre.")}
    return closed_loop.Scenario(
        **{k: v for k, v in leaves.items() if "." not in k},
        fault=fault_leaves(c["fault_kind"], c["fault_size"], c["fault_onset_s"], f),
        manoeuvre=manoeuvres.ManoeuvreParams(**manoeuvre))


def merge_fault_sizes(cols: dict) -> dict:
    """``cols`` with its per-kind size columns (``leakage_size``, ...) merged into one ``fault_size``.

    A row takes the size column of its fault kind (0 for the other kinds); ``cols`` is returned
    unchanged when it holds no size column.
    """
    present = [c for c in SIZE_COLUMNS if c in cols]
    if not present:
        return cols
    n = len(np.asarray(cols[present[0]]))
    kind = np.asarray(cols.get("fault_kind", np.full(n, DEFAULTS["fault_kind"])))
    size = np.zeros(len(kind))
    for column in present:
        size = np.where(kind == SIZE_COLUMNS[column], np.asarray(cols.pop(column), dtype=float), size)
    cols["fault_size"] = size
    return cols


def mach_limit_speed_kt(altitude_m, max_mach: float):
    """Calibrated airspeed (kt) at which the Mach limit is reached, per altitude."""
    return np.asarray(atmosphere.calibrated_airspeed(max_mach, np.asarray(altitude_m, float))) / atmosphere.KT_TO_M_S


def unit_sample(design: str, dim: int, n: int, seed: int) -> np.ndarray:
    """n points in [0, 1)^dim by the named design (random, lhs or sobol), deterministic in seed."""
    if dim == 0:
        return np.zeros((n, 0))
    if design == "random":
        return np.random.default_rng(seed).random((n, dim))
    if design == "lhs":
        return qmc.LatinHypercube(d=dim, seed=seed).random(n)
    if design == "sobol":
        return qmc.Sobol(d=dim, scramble=True, seed=seed).random(n)
    raise ValueError(f"unknown sampling design {design!r}; expected one of {', '.join(DESIGNS[1:])}")


def unit_rows(design: str, dim: int, draws, seed: int, whole=None) -> np.ndarray:
    """Points ``draws`` of the sequence :func:`unit_sample` draws, without drawing the ones before.

    Random and Sobol points are generated by index, bit for bit as in the whole sample: the
    generator is advanced (``PCG64.advance``, one 64-bit step per number) or the Sobol sequence
    fast-forwarded to the start of each run of consecutive draws. A Latin hypercube needs the
    whole sample (``whole``, (n, dim)); without it the whole sample is drawn here. A given
    ``whole`` is used for any design: it is the sample (e.g. a sensitivity analysis's pick-freeze
    rows, :mod:`mcfdd.workflows.sensitivity`).

    Args:
        draws: (k,) indices into the sequence, any order, repeats allowed.
        whole: the design's whole unit sample (lhs, or an explicit sample), e.g. generated once and scattered.

    Returns:
        (k, dim) points in [0, 1).
    """
    draws = np.asarray(draws, dtype=np.int64)
    if dim == 0:
        return np.zeros((len(draws), 0))
    if whole is not None or design == "lhs":
        return (unit_sample(design, dim, int(draws.max()) + 1, seed) if whole is None else whole)[draws]
    if design not in ("random", "sobol"):
        raise ValueError(f"unknown sampling design {design!r}; expected one of {', '.join(DESIGNS[1:])}")
    wanted = np.unique(draws)
    starts = np.flatnonzero(np.diff(wanted, prepend=-2) != 1)
    blocks = []
    for first, stop in zip(wanted[starts], np.append(wanted[starts[1:] - 1], wanted[-1]) + 1):
        if design == "random":
            bits = np.random.PCG64(seed)
            bits.advance(int(first) * dim)
            blocks.append(np.random.Generator(bits).random((int(stop - first), dim)))
        else:
            engine = qmc.Sobol(d=dim, scramble=True, seed=seed)
            if first:
                engine.fast_forward(int(first))
            blocks.append(engine.random(int(stop - first)))
    return np.concatenate(blocks)[np.searchsorted(wanted, draws)]


def _split_axes(axes: list[Axis], design: str, grid_axes) -> tuple[list[Axis], list[Axis]]:
    """The gridded and the sampled axes of a design (constants are neither)."""
    varying = [a for a in axes if a.kind != "const"]
    gridded = [a for a in varying if design == "grid" or a.name in grid_axes]
    return gridded, [a for a in varying if a not in gridded]


def design_shape(axes: list[Axis], n_samples: int, design: str, grid_axes=()) -> tuple[int, int]:
    """(grid cells, draws per cell) of a design; raw row r is cell r // draws crossed with draw r % draws."""
    gridded, _ = _split_axes(axes, design, grid_axes)
    return int(np.prod([len(grid_values(a)) for a in gridded], dtype=np.int64)), n_samples


def whole_sample(axes: list[Axis], n_samples: int, design: str, seed: int, grid_axes=()):
    """The unit sample a Latin hypercube design needs whole, (draws, dim); None for the other designs."""
    if design != "lhs":
        return None
    _, sampled = _split_axes(axes, design, grid_axes)
    return unit_sample(design, len(sampled), n_samples, seed)


def design_rows(axes: list[Axis], n_samples: int, design: str, seed: int, rows, grid_axes=(), max_mach: float = 0.82,
                whole=None):
    """Columns of the raw rows ``rows`` of a design, built from their indices alone.

    Raw rows number the grid cells (C order over the gridded axes) crossed with the draws of the
    sampled axes (:func:`design_shape`), before rows above the Mach limit are dropped; the draws
    come from :func:`unit_rows` (``whole``: the whole unit sample of a Latin hypercube or of an
    explicit design). Returns (columns of the k rows, (k,) mask of the rows within the Mach limit).
    """
    gridded, sampled = _split_axes(axes, design, grid_axes)
    _, per_cell = design_shape(axes, n_samples, design, grid_axes)
    cell, draw = np.divmod(np.asarray(rows, dtype=np.int64), per_cell)
    n = len(cell)
    cols: dict[str, np.ndarray] = {a.name: np.repeat(np.asarray([a.values[0]]), n) for a in axes if a.kind == "const"}
    if gridded:
        index = np.unravel_index(cell, [len(grid_values(a)) for a in gridded])
        for a, i in zip(gridded, index):
            cols[a.name] = np.asarray(grid_values(a))[i]
    u = unit_rows("random" if design == "grid" else design, len(sampled), draw, seed, whole)
    for j, a in enumerate(sampled):
        if a.name == "vcas_kt" and a.kind == "range":
            cols["_u_vcas"] = u[:, j]
        else:
            cols[a.name] = from_unit(a, u[:, j])
    altitude = np.asarray(cols.get("altitude_m", np.full(n, DEFAULTS["altitude_m"])), dtype=float)
    v_max = mach_limit_speed_kt(altitude, max_mach)
    if "_u_vcas" in cols:
        a = next(a for a in axes if a.name == "vcas_kt")
        cols["vcas_kt"] = a.lo + cols.pop("_u_vcas") * (np.minimum(a.hi, v_max) - a.lo)
    for name, value in DEFAULTS.items():
        cols.setdefault(name, np.full(n, value))
    return cols, np.asarray(cols["vcas_kt"], dtype=float) <= v_max + 1e-9


def design_table(axes: list[Axis], n_samples: int, design: str, seed: int, grid_axes=(), max_mach: float = 0.82):
    """Columns (dict of arrays) of a design: each cell of the grid axes with ``n_samples`` draws of the rest.

    With ``design == 'grid'`` every non-constant axis is gridded; the ``n_samples`` rows of a cell
    then differ only in the random numbers (turbulence, noise) of their scenario ids.
    Columns not in ``axes`` take their :data:`DEFAULTS`. Rows whose grid flight point lies above the
    Mach limit are dropped. Returns (columns, n_rows); :func:`design_rows` builds any rows alone.
    """
    cells, per_cell = design_shape(axes, n_samples, design, grid_axes)
    cols, keep = design_rows(axes, n_samples, design, seed, np.arange(cells * per_cell), grid_axes, max_mach,
                             whole_sample(axes, n_samples, design, seed, grid_axes))
    return {k: np.asarray(v)[keep] for k, v in cols.items()}, int(keep.sum())


def true_model(nu_bank: np.ndarray, kind, size):
    """Nearest bank model to each fault and the set of acceptable identifications (Fig. 4).

    Surface damage and disconnection are matched among the models with nu1 = 1 on nu2, leakage
    among the models with nu2 = 1 on nu1. A detected model is correct if it is the nearest one or
    one of the two models that bracket the fault. Returns (nearest id (n,), accept mask (n, N));
    fault-free and jamming rows accept no fault model (nearest = 0 for fault-free, -1 for jamming).
    """
    kind = np.asarray(kind)
    nu1, nu2 = fault_nu(kind, size)
    n, n_models = kind.shape[0], nu_bank.shape[0]
    nearest = np.where(kind == "jamming", -1, 0).astype(np.int32)
    accept = np.zeros((n, n_models), dtype=bool)
    families = ((np.isin(kind, ("surface_damage", "disconnection")), 1, nu2, np.isclose(nu_bank[:, 0], 1.0)),
                (kind == "leakage", 0, nu1, np.isclose(nu_bank[:, 1], 1.0)))
    for rows, axis, value, members in families:
        ids = np.flatnonzero(members)
        grid = nu_bank[ids, axis]
        for r in np.flatnonzero(rows):
            dist = np.abs(grid - value[r])
            near = ids[np.argmin(dist)]
            below = ids[grid <= value[r] + 1e-12]
            above = ids[grid >= value[r] - 1e-12]
            nearest[r] = near
            accept[r, near] = True
            if below.size:
                accept[r, below[np.argmax(nu_bank[below, axis])]] = True
            if above.size:
                accept[r, above[np.argmin(nu_bank[above, axis])]] = True
    return nearest, accept


def fault_onsets(cols: dict, n: int):
    """Time (s) a fault of any kind starts, inf for fault-free rows."""
    kind = np.asarray(cols.get("fault_kind", np.full(n, "none")))
    onset = np.asarray(cols.get("fault_onset_s", np.full(n, DEFAULTS["fault_onset_s"])), dtype=float)
    return np.where(kind == "none", math.inf, onset)

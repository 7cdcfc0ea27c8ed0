"""The search space of the worst-case search: a campaign's scenario space as a unit cube and affine maps.

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
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis import scenarios
from mcfdd.plant import atmosphere, closed_loop, manoeuvres


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

"""The scenario columns: one declaration per column of a scenario table (DESIGN.md section 6).

A scenario is one row of a table whose columns carry their unit in the name (``vcas_kt``,
``fault_onset_s``). Each :class:`Column` here says everything the package knows about one: its
default, its allowed range or its names, the single-run key that sets it (``runs[i].fault.onset_s``),
whether a ``[space]`` may vary it, and the leaf of the traced
:class:`~mcfdd.plant.closed_loop.Scenario` it sets with its factor to SI units. Everything else
derives from this list: the configuration's run sections and space axes (:mod:`mcfdd.config`),
the defaults, :func:`mcfdd.analysis.scenarios.to_scenario`, the builders of
:mod:`mcfdd.analysis.build`, the worst-case search space, and the uncertainty application of both
aircraft models (:func:`mcfdd.plant.uncertainty.scaled`).

Adding a column is one entry here (and a leaf of ``Scenario`` if it sets a new one). The module
imports no JAX, so parsing a configuration does not start it.
"""

from __future__ import annotations

import dataclasses
import math

from mcfdd.plant.atmosphere import KT_TO_M_S
from mcfdd.plant.choices import MANOEUVRE_KINDS, TURBULENCE_LEVELS

FAULT_KINDS = ("none", "leakage", "surface_damage", "disconnection", "jamming")
PARAMETRIC = ("leakage", "surface_damage", "disconnection")  # the loss-of-efficiency faults (nu1, nu2)
VCAS_RANGE_KT = (80.0, 420.0)  # the flight envelope of every flight point (the hinge table covers it)
ALTITUDE_RANGE_M = (0.0, 12500.0)
DEG = math.pi / 180.0


@dataclasses.dataclass(frozen=True)
class Column:
    """One column of a scenario table, or one per-kind size axis of a scenario space.

    Attributes:
        name: column name, unit last (``vcas_kt``).
        default: value of a row that does not set it.
        lo, hi: allowed range of a number (None: unbounded on that side); ``lo_open``: lo excluded.
        choices: the allowed names of a named column (empty for a number).
        owner: (section, key) of the single-run configuration that sets it: section 'run'
            (``runs[i]``), 'fault' (``runs[i].fault``) or 'manoeuvre' (``runs[i].manoeuvre``).
        leaf: the leaf of :class:`~mcfdd.plant.closed_loop.Scenario` it sets, ``a.b`` for a
            nested one; 'fault' for the three fault columns, which set the fault's (nu1, nu2) and
            onsets together (:func:`mcfdd.analysis.scenarios.fault_leaves`).
        si: leaf = column value x si (numbers); ``codes``: the leaf value of each choice (names).
        axis: a ``[space]`` may vary it; ``table``: it is a column of scenario tables.
        size_of: a space axis that draws the size of one fault kind, merged into ``fault_size``.
        scales: the nominal plant constants an uncertainty scale multiplies, as (parameter type
            name, field), e.g. ("ActuatorParams", "kci_m_s_a"); applied by
            :func:`mcfdd.plant.uncertainty.scaled`.
        doc: what the value means (configuration docs and JSON Schema).
    """

    name: str
    default: float | str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    owner: tuple[str, str] | None = None
    leaf: str = ""
    si: float = 1.0
    codes: tuple = ()
    axis: bool = True
    table: bool = True
    size_of: str = ""
    scales: tuple[tuple[str, str], ...] = ()
    doc: str = ""


def _run(name, default, lo, hi, **kw) -> Column:
    return Column(name, default, lo, hi, owner=("run", name), leaf=kw.pop("leaf", name), **kw)


def _manoeuvre(name, default, lo=None, hi=None, key=None, leaf=None, **kw) -> Column:
    key = key or name
    return Column(name, default, lo, hi, owner=("manoeuvre", key), leaf=f"manoeuvre.{leaf or key}", **kw)


def _scale(name, lo, hi, scales=(), doc="") -> Column:
    return _run(name, 1.0, lo, hi, scales=scales, doc=doc)


COLUMNS = (
    _run("vcas_kt", 250.0, *VCAS_RANGE_KT, leaf="vcas_m_s", si=KT_TO_M_S, doc="calibrated airspeed"),
    _run("altitude_m", 3000.0, *ALTITUDE_RANGE_M, doc="pressure altitude"),
    _scale("supply_pressure_scale", 0.5, 1.5, (("ActuatorParams", "supply_pressure_pa"),)),
    _scale("kci_scale", 0.5, 1.5, (("ActuatorParams", "kci_m_s_a"),)),
    _scale("kd_scale", 0.0, 3.0, (("ActuatorParams", "kd_n_s2_m2"),)),
    _scale("hinge_scale", 0.0, 3.0, doc="multiplies the hinge load where each aircraft model computes it"),
    _scale("roll_inertia_scale", 0.5, 1.5, (("AircraftParams", "roll_inertia_kg_m2"), ("RcamParams", "ixx_m2"))),
    _scale("mass_scale", 0.7, 1.2, (("RcamParams", "mass_kg"),),
           doc="full aircraft: mass over the nominal 120 t (trim and inertia)"),
    _run("noise_std_mm", 0.05, 0.0, 5.0, leaf="noise_std_m", si=1e-3, doc="position-sensor noise (RMS)"),
    _run("turbulence", "light", None, None, choices=tuple(TURBULENCE_LEVELS), leaf="turbulence_level",
         codes=tuple(TURBULENCE_LEVELS.values()), doc="Dryden turbulence level"),
    Column("fault_kind", "none", choices=FAULT_KINDS, owner=("fault", "kind"), leaf="fault"),
    Column("fault_size", 0.0, 0.0, 1.0, owner=("fault", "size"), leaf="fault", axis=False,
           doc="leakage: pressure loss 1 - nu1; surface_damage: 1 - nu2"),
    Column("fault_onset_s", 10.0, 0.0, owner=("fault", "onset_s"), leaf="fault"),
    _manoeuvre("manoeuvre_kind", "quiet", key="kind", choices=MANOEUVRE_KINDS,
               codes=tuple(range(len(MANOEUVRE_KINDS)))),
    _manoeuvre("amplitude", 0.0, -1.0, 1.0, doc="stick or command fraction; sign gives the direction"),
    _manoeuvre("t_start_s", 5.0, 0.0),
    _manoeuvre("duration_s", 2.0, 0.0, lo_open=True),
    _manoeuvre("hold_s", 2.0, 0.0),
    _manoeuvre("ramp_s", 0.3, 0.0),
    _manoeuvre("freq_lo_hz", 0.1, 0.0, 20.0, lo_open=True),
    _manoeuvre("freq_hi_hz", 2.0, 0.0, 20.0, lo_open=True),
    _manoeuvre("sideslip_deg", 0.0, -15.0, 15.0, leaf="sideslip_rad", si=DEG),
    _manoeuvre("fpa_deg", 0.0, -10.0, 10.0, leaf="fpa_rad", si=DEG,
               doc="fpa_change: flight-path-angle target held for duration_s"),
    _manoeuvre("heading_change_deg", 0.0, -180.0, 180.0, leaf="heading_change_rad", si=DEG,
               doc="heading_change: heading-target step"),
    _manoeuvre("bank_deg", 0.0, -67.0, 67.0, leaf="bank_rad", si=DEG, doc="coordinated_turn: bank target held for "
               "duration_s"),
    _manoeuvre("delta_vcas_kt", 0.0, -100.0, 100.0, leaf="delta_vcas_m_s", si=KT_TO_M_S,
               doc="speed_change: autothrust speed-target step"),
    Column("leakage_size", 0.0, 0.0, 0.95, table=False, size_of="leakage", doc="pressure loss of leakage runs"),
    Column("surface_damage_size", 0.0, 0.0, 1.0, table=False, size_of="surface_damage",
           doc="loss of surface effectiveness of surface-damage runs"),
)
COLUMN = {c.name: c for c in COLUMNS}
TABLE = tuple(c for c in COLUMNS if c.table)  # the columns of a scenario table, in table order
AXES = tuple(c for c in COLUMNS if c.axis)  # what a [space] may vary
DEFAULTS = {c.name: c.default for c in TABLE}
SIZE_COLUMNS = {c.name: c.size_of for c in COLUMNS if c.size_of}  # per-kind size axis -> its fault kind
UNCERTAIN = tuple(c for c in COLUMNS if c.scales)


def owned_by(section: str) -> tuple[Column, ...]:
    """The columns a single-run section ('run', 'fault' or 'manoeuvre') sets, in table order."""
    return tuple(c for c in COLUMNS if c.owner and c.owner[0] == section)

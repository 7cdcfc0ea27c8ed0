"""Configuration: TOML files and dicts validated once into frozen pydantic models (the edge).

Every section is a frozen model that forbids unknown keys; its fields carry their unit in the
name and an allowed range (:func:`spec`) or a ``Literal`` of choices. Types are strict: a string
is not a number and a bool is not an integer, while an integer is a fine number. Every error is a
:class:`ConfigError` of one line naming the key path (``runs[1].fault.size``) and what is allowed.

This module parses and nothing else: the SI pytrees the simulation uses are built from the parsed
models by :mod:`mcfdd.analysis.build`. Adding a key to a section is one line, e.g.::

    window_s: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0, doc="what it sets")
    mode: Literal["a", "b"] = spec("a", doc="what it selects")

and cross-key rules go in the section's :meth:`Section.check`, raising :class:`Invalid`.
"""

import copy
import dataclasses
import json
import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Annotated, Literal

import annotated_types
import numpy as np
import tomli_w
from pydantic import BaseModel, ConfigDict, Field, SkipValidation, TypeAdapter, ValidationError, model_serializer
from pydantic import model_validator
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from mcfdd.fdd import lpv
from mcfdd.plant import atmosphere, manoeuvres, turbulence

FAULT_KINDS = ("none", "leakage", "surface_damage", "disconnection", "jamming")
IDLE_MANOEUVRES = ("quiet", "level_flight")  # no manoeuvre starts: their t_start_s is not used
PARAMETRIC = ("leakage", "surface_damage", "disconnection")
DESIGNS = ("grid", "random", "lhs", "sobol")
PRECISIONS = ("float32", "float64")
TURBULENCE_LEVELS = tuple(turbulence.LEVELS)
VCAS_RANGE_KT = (80.0, 420.0)
ALTITUDE_RANGE_M = (0.0, 12500.0)
SEED_MAX = 2**32 - 1  # seeds are 32-bit: JAX keys, numpy and scipy.stats.qmc take them alike


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range."""


class Invalid(ConfigError):
    """A rule across keys is broken at ``key``, a path relative to the section that checks it."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}" if key else message)
        self.key, self.message = key, message


def _bounds(lo=None, hi=None, lo_open=False) -> dict:
    bounds = {} if lo is None else {"gt" if lo_open else "ge": lo}
    return bounds if hi is None else {**bounds, "le": hi}


def spec(default=PydanticUndefined, *, lo=None, hi=None, lo_open=False, doc=""):
    """A field with an allowed range [lo, hi] (open at lo if ``lo_open``); no default: required."""
    return Field(default, description=doc or None, **_bounds(lo, hi, lo_open))


def bounded(lo=None, hi=None, lo_open=False, tp=float):
    """Type ``tp`` within [lo, hi], for the elements of a fixed-length list."""
    return Annotated[tp, Field(**_bounds(lo, hi, lo_open))]


class Section(BaseModel):
    """A TOML table: frozen, unknown keys forbidden, strict types, lists read as tuples."""

    model_config = ConfigDict(frozen=True, extra="forbid", strict=True)

    @model_validator(mode="before")
    @classmethod
    def _raw_table(cls, data):
        if not isinstance(data, dict):
            return data
        for key, value in data.items():
            if isinstance(value, float) and math.isnan(value):
                raise Invalid(key, "nan is not a number")
        return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}

    @model_validator(mode="after")
    def _checked(self):
        self.check()
        return self

    def check(self):
        """Rules across keys of the section; raise :class:`Invalid` naming the key."""


# --------------------------------------------------------------------------------------------
# One-line messages from pydantic's errors

_EXPECTED = {
    "float_type": "a number", "float_parsing": "a number", "int_type": "an integer", "int_from_float": "an integer",
    "int_parsing": "an integer", "bool_type": "true or false", "bool_parsing": "true or false",
    "string_type": "a string", "model_type": "a table", "model_attributes_type": "a table", "dict_type": "a table",
    "tuple_type": "a list", "list_type": "a list",
}
_RANGE_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal")
_TOML_TYPES = {bool: "boolean", int: "integer", float: "float", str: "string", dict: "table", list: "list",
               tuple: "list"}


def _key_path(loc) -> str:
    path = ""
    for part in loc:
        path = _join(path, f"[{part}]" if isinstance(part, int) else str(part))
    return path


def _join(path: str, key: str) -> str:
    if not (path and key):
        return path or key
    return path + (key if key.startswith("[") else f".{key}")


def _unwrap(tp):
    """(type, constraints) of an annotation without Annotated and Optional."""
    meta = []
    while True:
        if typing.get_origin(tp) is Annotated:
            tp, *extra = typing.get_args(tp)
            for m in extra:
                meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
        elif typing.get_origin(tp) in (typing.Union, types.UnionType):
            tp = next(a for a in typing.get_args(tp) if a is not type(None))
        else:
            return tp, meta


def _is_section(tp) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _target(root, loc):
    """(type, constraints) of the value at ``loc`` below the annotation ``root``; (None, []) if unknown."""
    tp, meta = _unwrap(root)
    for part in loc:
        if isinstance(part, str) and _is_section(tp) and part in tp.model_fields:
            field = tp.model_fields[part]
            tp, extra = _unwrap(field.annotation)
            meta = list(field.metadata) + extra
        elif isinstance(part, int) and typing.get_origin(tp) is tuple:
            args = typing.get_args(tp)
            tp, meta = _unwrap(args[0] if args[1:] == (Ellipsis,) else args[min(part, len(args) - 1)])
        else:
            return None, []
    return tp, meta


def _describe_range(meta) -> str:
    lo = next((m.ge if isinstance(m, annotated_types.Ge) else m.gt for m in meta
               if isinstance(m, (annotated_types.Ge, annotated_types.Gt))), None)
    hi = next((m.le for m in meta if isinstance(m, annotated_types.Le)), None)
    left = "(" if any(isinstance(m, annotated_types.Gt) for m in meta) else "["
    return f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


def _shown(value) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def _describe(root, error) -> tuple[str, str]:
    """(key path, message) of one pydantic error below the annotation ``root``."""
    loc, kind, value = tuple(error["loc"]), error["type"], error.get("input")
    path = _key_path(loc)
    cause = error.get("ctx", {}).get("error")
    if isinstance(cause, Invalid):
        return _join(path, cause.key), cause.message
    if kind == "extra_forbidden":
        parent, _ = _target(root, loc[:-1])
        allowed = ", ".join(sorted(parent.model_fields)) if _is_section(parent) else ""
        return path, f"unknown key; allowed keys are {allowed}"
    if kind == "missing":
        return path, "missing required key"
    tp, meta = _target(root, loc)
    if kind == "literal_error":
        return path, f"{value!r} is not allowed; expected one of {', '.join(repr(c) for c in typing.get_args(tp))}"
    if kind in _RANGE_ERRORS:
        if isinstance(value, float) and math.isnan(value):
            return path, "nan is not a number"
        return path, f"{value!r} is outside the allowed range {_describe_range(meta)}"
    if kind in ("too_short", "too_long"):
        return path, f"expected a list of {len(typing.get_args(tp))} values, got {len(value)}"
    if kind in _EXPECTED:
        got = _TOML_TYPES.get(type(value), type(value).__name__)
        return path, f"expected {_EXPECTED[kind]}, got {got} {_shown(value)}"
    return path, error["msg"]


def _first(errors: list) -> dict:
    """The error to report: the first, unless a table on its path has an unknown key (reported first)."""
    loc = tuple(errors[0]["loc"])
    return next((e for e in errors if e["type"] == "extra_forbidden" and loc[:len(e["loc"]) - 1] == e["loc"][:-1]),
                errors[0])


def _validate(cls, data, prefix: str = ""):
    """``cls.model_validate(data)``; a failure is a :class:`ConfigError` with ``.key`` and one line."""
    try:
        return cls.model_validate(data)
    except ValidationError as err:
        key, message = _describe(cls, _first(err.errors()))
        raise Invalid(_join(prefix, key) or "configuration", message) from None


def parse(cls, data: dict, path: str = ""):
    """Section ``cls`` from a TOML table (a dict); errors name the key below ``path``."""
    return _validate(cls, data, path)


# --------------------------------------------------------------------------------------------
# Plant sections


class ActuatorConfig(Section):
    supply_pressure_pa: float = spec(2.07e7, lo=0.0, lo_open=True, doc="hydraulic supply pressure dP")
    ref_pressure_pa: float | None = spec(None, lo=0.0, lo_open=True, doc="dP_ref; default: equal to dP")
    piston_area_m2: float = spec(2.272e-3, lo=0.0, lo_open=True)
    r_arm_m: float = spec(0.0525, lo=0.0, lo_open=True)
    max_current_ma: float = spec(8.0, lo=0.0, lo_open=True)
    kci_mm_s_per_ma: float = spec(11.46, lo=0.0, lo_open=True)
    kp_ma_per_mm: float = spec(2.18, lo=0.0, lo_open=True)
    kd_n_s2_m2: float = spec(5.6e5, lo=0.0)
    max_deflection_deg: float = spec(25.0, lo=0.0, hi=60.0, lo_open=True)


class HingeConfig(Section):
    area_m2: float = spec(1.93, lo=0.0, lo_open=True)
    chord_m: float = spec(0.58, lo=0.0, lo_open=True)
    ch0: float = spec(0.0, lo=-1.0, hi=1.0)
    ch_alpha_per_rad: float = spec(-0.06, lo=-2.0, hi=2.0)
    ch_delta_per_rad: float = spec(-0.25, lo=-2.0, hi=2.0)



AIRCRAFT_MODELS = ("roll_axis", "rcam")


class AircraftConfig(Section):
    wing_area_m2: float = spec(260.0, lo=0.0, lo_open=True)
    mean_chord_m: float = spec(6.6, lo=0.0, lo_open=True)
    span_m: float = spec(44.8, lo=0.0, lo_open=True)
    mass_kg: float = spec(120000.0, lo=0.0, lo_open=True)
    roll_inertia_kg_m2: float = spec(4.81e6, lo=0.0, lo_open=True)
    monitored_share: float = spec(0.5, lo=0.0, hi=1.0, doc="share of roll power of the monitored aileron")
    max_mach: float = spec(0.82, lo=0.1, hi=0.95, doc="flight points above this Mach number are refused")
    model: Literal[AIRCRAFT_MODELS] = spec("roll_axis", doc="roll_axis: the fast roll axis at a fixed flight "
                                           "point; rcam: the GARTEUR RCAM 6-DoF aircraft in closed loop (Vcas, h "
                                           "and alpha vary in a run)")


class ControlLawConfig(Section):
    max_roll_rate_deg_s: float = spec(15.0, lo=0.0, lo_open=True)
    bank_hold_deg: float = spec(33.0, lo=0.0, hi=90.0)
    bank_protection_deg: float = spec(67.0, lo=0.0, hi=90.0)
    time_constant_s: float = spec(0.5, lo=0.05, hi=10.0)


class PlantConfig(Section):
    actuator: ActuatorConfig = spec(ActuatorConfig())
    hinge: HingeConfig = spec(HingeConfig())
    aircraft: AircraftConfig = spec(AircraftConfig())
    control_law: ControlLawConfig = spec(ControlLawConfig())

    def check_manoeuvres(self, kinds, key: str):
        """Refuse manoeuvre families that the roll axis cannot fly (raises :class:`Invalid` at ``key``)."""
        if self.aircraft.model == "rcam":
            return
        for kind in kinds:
            if kind in manoeuvres.FULL_AIRCRAFT:
                raise Invalid(key, f"{kind!r} needs the full aircraft; set plant.aircraft.model = \"rcam\"")

    def check_flight_point(self, vcas_kt: float, altitude_m: float, key: str):
        """Refuse a flight point above the Mach limit (raises :class:`Invalid` at ``key``)."""
        m = float(atmosphere.mach(vcas_kt * atmosphere.KT_TO_M_S, altitude_m))
        if m > self.aircraft.max_mach:
            raise Invalid(key, f"{vcas_kt} kt at {altitude_m} m is Mach {m:.3f}, above the limit "
                               f"plant.aircraft.max_mach = {self.aircraft.max_mach}")


# --------------------------------------------------------------------------------------------
# Scenario sections

class FaultConfig(Section):
    kind: Literal[FAULT_KINDS] = spec("none")
    size: float = spec(0.0, lo=0.0, hi=1.0, doc="leakage: pressure loss 1 - nu1; surface_damage: 1 - nu2")
    onset_s: float = spec(10.0, lo=0.0)

    def check(self):
        if self.kind == "leakage" and self.size >= 1.0:
            raise Invalid("size", f"{self.size} leaves no pressure (nu1 = 0); leakage size must be below 1")


class ManoeuvreConfig(Section):
    kind: Literal[manoeuvres.KINDS] = spec("quiet")
    amplitude: float = spec(0.0, lo=-1.0, hi=1.0, doc="stick or command fraction; sign gives the direction")
    t_start_s: float = spec(5.0, lo=0.0)
    duration_s: float = spec(2.0, lo=0.0, lo_open=True)
    hold_s: float = spec(2.0, lo=0.0)
    ramp_s: float = spec(0.3, lo=0.0)
    freq_lo_hz: float = spec(0.1, lo=0.0, lo_open=True, hi=20.0)
    freq_hi_hz: float = spec(2.0, lo=0.0, lo_open=True, hi=20.0)
    sideslip_deg: float = spec(0.0, lo=-15.0, hi=15.0)
    fpa_deg: float = spec(0.0, lo=-10.0, hi=10.0, doc="fpa_change: flight-path-angle target held for duration_s")
    heading_change_deg: float = spec(0.0, lo=-180.0, hi=180.0, doc="heading_change: heading-target step")
    bank_deg: float = spec(0.0, lo=-67.0, hi=67.0, doc="coordinated_turn: bank target held for duration_s")
    delta_vcas_kt: float = spec(0.0, lo=-100.0, hi=100.0, doc="speed_change: autothrust speed-target step")


class RunConfig(Section):
    name: str = spec()
    vcas_kt: float = spec(250.0, lo=VCAS_RANGE_KT[0], hi=VCAS_RANGE_KT[1])
    altitude_m: float = spec(3000.0, lo=ALTITUDE_RANGE_M[0], hi=ALTITUDE_RANGE_M[1])
    turbulence: Literal[TURBULENCE_LEVELS] = spec("light")
    noise_std_mm: float = spec(0.05, lo=0.0, hi=5.0)
    supply_pressure_scale: float = spec(1.0, lo=0.5, hi=1.5)
    kci_scale: float = spec(1.0, lo=0.5, hi=1.5)
    kd_scale: float = spec(1.0, lo=0.0, hi=3.0)
    hinge_scale: float = spec(1.0, lo=0.0, hi=3.0)
    roll_inertia_scale: float = spec(1.0, lo=0.5, hi=1.5)
    mass_scale: float = spec(1.0, lo=0.7, hi=1.2, doc="full aircraft: mass over the nominal 120 t (trim and inertia)")
    seed: int | None = spec(None, lo=0, doc="turbulence and sensor noise of this run; unset, every run of the "
                            "config draws the same ones (from simulation.seed), so runs are paired")
    fault: FaultConfig = spec(FaultConfig())
    manoeuvre: ManoeuvreConfig = spec(ManoeuvreConfig())


# --------------------------------------------------------------------------------------------
# FDD sections. Residual thresholds and signal levels are in degrees of surface deflection
# (rod position / r_arm); the FDD itself works on rod positions in m.


class EvaluatorConfig(Section):
    """Narendra evaluator of eq. (14)."""

    alpha: float = spec(0.0, lo=0.0, doc="weight of |r|")
    beta: float = spec(1.0, lo=0.0, doc="weight of the forgetting integral of |r|")
    gamma_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=1000.0, doc="forgetting factor")


class LoeDetectionConfig(Section):
    """Model-detection bank for parametric LOE faults (Section 4).

    Defaults are tuned for 0.05 mm position-sensor noise (see README): the paper's evaluator
    (alpha = 0, beta = 1, gamma = 0.1) averages sensor noise over 10 s against manoeuvre
    transients of a few seconds, so gamma = 1; a slow filter pole keeps the noise band narrow.
    Two levels: detection (``detection_tau``, ``detection_contrast``, ``detection_confirm_s``: the
    fault-free model rejected) and identification (``tau``, ``tau_schedule``, ``confirm_s``: the signature (15)).
    """

    pole_1_s: float = spec(0.5, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of every filter")
    direction_pole_1_s: float = spec(20.0, lo=0.0, lo_open=True, hi=1e4, doc="sgn(xdot) of the LPV gains is the "
                                     "sign of the measured tracking error low-passed with this pole, up to the "
                                     "previous sample (so it does not rectify the current sample's sensor noise)")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=0.0, beta=1.0, gamma_1_s=1.0))
    tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                      doc="threshold on theta_i / ||u||, about the relative gain mismatch |k_j - k_i| / k0_i")
    tau_schedule: float = spec(0.0, lo=0.0, hi=1.0, doc="scheduled thresholds tau_i(rho) = max(tau, tau_schedule "
                               "x distance (16) from model i to its nearest model at the current point, in ratio "
                               "units); 0 keeps tau constant")
    detection_tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0, doc="detection: the fault-free model is "
                                "rejected while theta_0 / ||u|| is above this and ||u|| above the excitation floor")
    detection_confirm_s: float = spec(0.5, lo=0.0, hi=60.0, doc="detection: the rejection must persist this long")
    detection_contrast: float = spec(0.05, lo=0.0, hi=10.0, doc="detection: the fault-free model is rejected only "
                                     "while theta_0 / ||u|| is also this far above the smallest ratio of the fault "
                                     "models (a fault model explains the rod better; sensor noise at the excitation "
                                     "floor raises all ratios alike)")
    excitation_floor_deg: float = spec(0.15, lo=0.0, doc="no decision (detection or identification) while ||u|| "
                                       "(the evaluated low-passed |u_c - u|) is below this: sensor noise alone gives "
                                       "about 0.8 x its RMS (0.06 deg at 0.07 mm)")
    excitation_load_fraction: float = spec(0.0, lo=0.0, hi=1.0, doc="load-weighted excitation: the floor "
                                           "applies to ||u|| with each sample weighted by min(1, estimated hinge-load "
                                           "fraction / this), so decisions are made only where the fault-free and "
                                           "surface-loss models differ; 0 weighs every sample 1")
    confirm_s: float = spec(2.0, lo=0.0, hi=60.0, doc="identification: a decoded model must persist this long")
    max_load_fraction: float = spec(0.5, lo=0.0, hi=1.0, doc="residuals are not evaluated above this estimated "
                                    "hinge-load fraction (1 disables)")
    linear_range_deg: float = spec(3.5, lo=0.0, lo_open=True, doc="residuals are not evaluated while |u_c - u| "
                                   "exceeds this (servo-valve current saturation at i_max / Kp = 4 deg)")
    stall_hold_s: float = spec(3.0, lo=0.0, hi=60.0, doc="no LOE decision while a stall load is identified "
                               "and this long after")


class SignalRulesConfig(Section):
    """Signal-based stall identification, eqs. (32)-(35)."""

    rate_min_deg_s: float = spec(2.0, lo=0.0, lo_open=True, doc="u_dot_min of (33)")
    command_min_deg: float = spec(10.0, lo=0.0, doc="tau_uc,max of (34)")
    position_min_deg: float = spec(10.0, lo=0.0, doc="tau_u,max of (34)")
    window_s: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                           doc="shortest averaging time and re-anchoring window of the mean rate (32)")
    error_min_deg: float = spec(0.5, lo=0.0, doc="smallest |u_c - u| for which (35) counts")


class ModelRuleConfig(Section):
    """Stall identification by model detection with Q_sl, eq. (30).

    The residual left by the motion just before a stall decays at the pole a_sl, so a_sl sets the
    identification latency: on ``configs/stall_campaign.toml`` a_sl = 5 1/s (tau_sl 8 deg)
    identified 242 of 264 stall loads with a median worst latency of 0.52 s, a_sl = 20 1/s
    (tau_sl 15 deg) 262 with 0.24 s (95th percentile 0.36 s), with no identification outside
    stall loads in either. tau_sl grows with a_sl because sensor noise reaches r_sl amplified
    by about a_sl / k_sl.
    """

    k_sl_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=1.0, doc="stall-model gain (paper: 0.01..0.1)")
    pole_1_s: float = spec(20.0, lo=0.0, lo_open=True, hi=1000.0, doc="a_sl")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=0.0, beta=10.0, gamma_1_s=10.0))
    tau_deg: float = spec(15.0, lo=0.0, lo_open=True, doc="tau_sl: stall while theta_sl stays below")


class StallDetectionConfig(Section):
    """Stall-load detector (Section 5; paper evaluator alpha = beta = 1, gamma = 0.1)."""

    pole_1_s: float = spec(10.0, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of eq. (20)")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=1.0, beta=1.0, gamma_1_s=0.1))
    tau_deg: float = spec(1.0, lo=0.0, lo_open=True, doc="threshold tau of eq. (25)")
    identification: Literal["signal", "model"] = spec("signal", doc="which eta is eta_stall")
    signal: SignalRulesConfig = spec(SignalRulesConfig())
    model: ModelRuleConfig = spec(ModelRuleConfig())


class FddConfig(Section):
    bank: str = spec("default", doc="LPV bank JSON file, or 'default' for the bank shipped with mcfdd")
    loe: LoeDetectionConfig = spec(LoeDetectionConfig())
    stall: StallDetectionConfig = spec(StallDetectionConfig())


class SimulationConfig(Section):
    duration_s: float = spec(30.0, lo=0.0, lo_open=True, hi=3600.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1)
    substeps: int = spec(2, lo=1, hi=64, doc="actuator sub-steps per sample in the linear range of the valve")
    seed: int = spec(0, lo=0, hi=SEED_MAX)
    precision: Literal[PRECISIONS] = spec("float32")

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


class SimulateConfig(Section):
    """``mcfdd simulate``: a few named runs simulated in one batch, full time histories."""

    simulation: SimulationConfig = spec(SimulationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    runs: tuple[RunConfig, ...] = spec()

    def check(self):
        if not self.runs:
            raise Invalid("runs", "at least one [[runs]] table is required")
        _check_unique([r.name for r in self.runs], "runs")
        end = self.simulation.duration_s
        for i, run in enumerate(self.runs):
            self.plant.check_flight_point(run.vcas_kt, run.altitude_m, f"runs[{i}]")
            self.plant.check_manoeuvres([run.manoeuvre.kind], f"runs[{i}].manoeuvre.kind")
            for starts, key, what in ((run.manoeuvre.kind not in IDLE_MANOEUVRES, "manoeuvre.t_start_s", "manoeuvre"),
                                      (run.fault.kind != "none", "fault.onset_s", "fault onset")):
                at = run.manoeuvre.t_start_s if key.startswith("manoeuvre") else run.fault.onset_s
                if starts and at >= end:
                    raise Invalid(f"runs[{i}].{key}", f"the {what} at {at} s is at or after the end of the run "
                                                      f"({end} s, simulation.duration_s)")


def _check_unique(names, key):
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise Invalid(f"{key}[{i}].name", f"{name!r} is used by {key}[{names.index(name)}] already")


class SweepConfig(Section):
    """``mcfdd figures`` Fig. 4: fault-size sweeps at one flight point and manoeuvre."""

    simulation: SimulationConfig = spec(SimulationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    run: RunConfig = spec(doc="flight point, manoeuvre and fault onset; the fault kind and size are swept")
    surface_points: int = spec(51, lo=2, hi=1001, doc="surface-effectiveness losses from 0 to 100 %")
    leakage_points: int = spec(31, lo=2, hi=1001, doc="pressure losses from 0 to max_leakage")
    max_leakage: float = spec(0.3, lo=0.0, lo_open=True, hi=0.95)

    def check(self):
        self.plant.check_flight_point(self.run.vcas_kt, self.run.altitude_m, "run")
        self.plant.check_manoeuvres([self.run.manoeuvre.kind], "run.manoeuvre.kind")


# --------------------------------------------------------------------------------------------
# Campaigns


@dataclasses.dataclass(frozen=True)
class Axis:
    """One column of a scenario space.

    kind: 'const' (``values[0]``), 'range' (uniform on [lo, hi]; ``n`` points when gridded),
    'values' (discrete numbers) or 'choices' (names).
    """

    name: str
    kind: str
    values: tuple = ()
    lo: float = 0.0
    hi: float = 0.0
    n: int = 0

    def grid_values(self) -> tuple:
        if self.kind == "range":
            return tuple(np.linspace(self.lo, self.hi, self.n)) if self.n > 1 else (self.lo,)
        return self.values

    def from_unit(self, u):
        """Map uniform numbers in [0, 1) to axis values."""
        if self.kind == "range":
            return self.lo + u * (self.hi - self.lo)
        options = np.asarray(self.values)
        return options[np.minimum((u * len(options)).astype(int), len(options) - 1)]

    def toml(self):
        """The axis as written in a [space] table."""
        if self.kind == "const":
            return self.values[0]
        if self.kind == "choices":
            return list(self.values)
        if self.kind == "values":
            return {"values": list(self.values)}
        return [self.lo, self.hi] if self.n == 2 else {"range": [self.lo, self.hi], "n": self.n}


# Each scenario-table column and the single-run key (section, key) it takes its type, range and default from.
_COLUMN_OWNERS = {**{n: (RunConfig, n) for n in RunConfig.model_fields if n not in ("name", "fault", "manoeuvre")},
                  "fault_kind": (FaultConfig, "kind"), "fault_onset_s": (FaultConfig, "onset_s"),
                  "leakage_size": (FaultConfig, "size"), "surface_damage_size": (FaultConfig, "size"),
                  "manoeuvre_kind": (ManoeuvreConfig, "kind"),
                  **{n: (ManoeuvreConfig, n) for n in ManoeuvreConfig.model_fields if n != "kind"}}


def _column_types() -> dict:
    """Each scenario-table column with the type and range of its single-run key."""
    types = {}
    for column, (owner, key) in _COLUMN_OWNERS.items():
        field = owner.model_fields[key]
        meta = [annotated_types.Ge(0.0), annotated_types.Le(0.95)] if column == "leakage_size" else field.metadata
        types[column] = Annotated[(field.annotation, *meta)] if meta else field.annotation
    return types


_COLUMN_TYPES = _column_types()
_COLUMN_ADAPTERS = {name: TypeAdapter(tp, config=ConfigDict(strict=True)) for name, tp in _COLUMN_TYPES.items()}
SIZE_COLUMNS = {"leakage_size": "leakage", "surface_damage_size": "surface_damage"}


def _adapted(tp, value, key, adapter=None):
    """``value`` validated as type ``tp`` (strict); an error is an :class:`Invalid` at ``key``."""
    try:
        return (adapter or TypeAdapter(tp, config=ConfigDict(strict=True))).validate_python(value)
    except ValidationError as err:
        sub, message = _describe(tp, _first(err.errors()))
        raise Invalid(_join(key, sub), message) from None


def _column_value(name, value, key):
    return _adapted(_COLUMN_TYPES[name], value, key, _COLUMN_ADAPTERS[name])


def field_value(cls, key: str, value):
    """``value`` checked as key ``key`` of section ``cls`` (its type and range), e.g. for a command-line flag.

    >>> field_value(CampaignSettings, "seed", 2**40)
    Traceback (most recent call last):
    mcfdd.config.Invalid: seed: 1099511627776 is outside the allowed range [0, 4294967295]
    """
    field = cls.model_fields[key]
    return _adapted(Annotated[(field.annotation, *field.metadata)] if field.metadata else field.annotation, value, key)


def _axis(name, value, key) -> Axis:
    if name not in _COLUMN_TYPES:
        raise Invalid(key, f"unknown axis; allowed axes are {', '.join(sorted(_COLUMN_TYPES))}")
    names = typing.get_origin(_unwrap(_COLUMN_TYPES[name])[0]) is Literal
    if isinstance(value, dict):
        extra = sorted(set(value) - {"values", "range", "n"})
        if extra:
            raise Invalid(f"{key}.{extra[0]}", "unknown key; an axis table takes values, or range and n")
        if "values" in value:
            vals = value["values"]
            if not isinstance(vals, (list, tuple)) or not vals:
                raise Invalid(f"{key}.values", "expected a non-empty list")
            return Axis(name, "values", tuple(_column_value(name, v, f"{key}.values[{i}]") for i, v in enumerate(vals)))
        if "range" not in value:
            raise Invalid(key, "an axis table needs 'values' or 'range'")
        axis = _axis(name, value["range"], f"{key}.range")
        n = value.get("n", 2)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise Invalid(f"{key}.n", f"expected a positive integer, got {n!r}")
        return dataclasses.replace(axis, n=n)
    if isinstance(value, (list, tuple)):
        if names:
            if not value:
                raise Invalid(key, "expected a non-empty list of names")
            return Axis(name, "choices", tuple(_column_value(name, v, f"{key}[{i}]") for i, v in enumerate(value)))
        if len(value) != 2:
            raise Invalid(key, "a range is [lo, hi]; for discrete values write { values = [...] }")
        lo, hi = _column_value(name, value[0], f"{key}[0]"), _column_value(name, value[1], f"{key}[1]")
        if hi < lo:
            raise Invalid(key, f"range [{lo}, {hi}] is empty")
        return Axis(name, "range", lo=lo, hi=hi, n=2)
    return Axis(name, "const", (_column_value(name, value, key),))


def _axis_schema(tp) -> dict:
    """JSON Schema of the axis syntax of one column."""
    one = TypeAdapter(tp).json_schema()
    if "enum" in one or "const" in one:
        return {"anyOf": [one, {"type": "array", "items": one, "minItems": 1}]}
    pair = {"type": "array", "items": one, "minItems": 2, "maxItems": 2}
    return {"anyOf": [
        one, pair,
        {"type": "object", "properties": {"values": {"type": "array", "items": one, "minItems": 1}},
         "required": ["values"], "additionalProperties": False},
        {"type": "object", "properties": {"range": pair, "n": {"type": "integer", "minimum": 1}},
         "required": ["range"], "additionalProperties": False},
    ]}


class SpaceConfig(Section):
    """Scenario space: one axis per table column, in the order of the TOML table.

    In TOML a key takes a number or a name (constant), ``[lo, hi]`` (uniform range), a list of
    names (choices), ``{ values = [...] }`` (discrete numbers) or ``{ range = [lo, hi], n = 5 }``
    (a range with 5 grid points when gridded). Fault sizes are drawn per kind
    (``leakage_size``, ``surface_damage_size``) and combined into ``fault_size``.
    """

    axes: SkipValidation[tuple[Axis, ...]] = ()

    @model_validator(mode="before")
    @classmethod
    def _from_toml(cls, data):
        if not isinstance(data, dict):
            raise Invalid("", "expected a table of axes")
        return {"axes": tuple(_axis(name, value, name) for name, value in data.items())}

    @model_serializer
    def _to_toml(self) -> dict:
        return {a.name: a.toml() for a in self.axes}

    @classmethod
    def __get_pydantic_json_schema__(cls, core_schema, handler):
        return {"type": "object", "title": cls.__name__, "description": cls.__doc__.splitlines()[0],
                "properties": {name: _axis_schema(tp) for name, tp in _COLUMN_TYPES.items()},
                "additionalProperties": False}

    def axis(self, name):
        return next((a for a in self.axes if a.name == name), None)


class CampaignSettings(Section):
    scenarios: int = spec(1000, lo=1, hi=10_000_000, doc="total number of scenarios, split evenly over the grid "
                          "cells (a multiple of their number)")
    design: Literal[DESIGNS] = spec("sobol")
    grid: tuple[str, ...] = spec((), doc="axes on a full grid, crossed with samples over the others")
    seed: int = spec(0, lo=0, hi=SEED_MAX)
    chunk_size: int = spec(1024, lo=1, hi=1_000_000)
    duration_s: float = spec(60.0, lo=0.0, lo_open=True, hi=3600.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1)
    substeps: int = spec(2, lo=1, hi=64, doc="actuator sub-steps per sample in the linear range of the valve")
    precision: Literal[PRECISIONS] = spec("float32")

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


class EvaluationConfig(Section):
    """How runs are scored (DESIGN.md section 5)."""

    settle_s: float = spec(5.0, lo=0.0, doc="decisions before this are not scored")
    t_detec_s: float = spec(120.0, lo=0.0, lo_open=True, doc="required detection time after the fault onset")
    stall_grace_s: float = spec(0.5, lo=0.0, doc="eta = 1 this soon after a stall load is not a false alarm")
    stall_min_duration_s: float = spec(0.1, lo=0.0, doc="shorter stall intervals are not relevant events")
    stall_min_error_deg: float = spec(1.0, lo=0.0, doc="stall events whose tracking error stays below are not relevant")
    stall_window_s: float = spec(0.5, lo=0.0, lo_open=True, doc="required stall detection/identification time")


def _default(column):
    """Default value of a scenario column: its single-run key's default."""
    owner, key = _COLUMN_OWNERS[column]
    return owner.model_fields[key].default


class CampaignConfig(Section):
    """``mcfdd campaign``: a scenario space sampled, simulated in chunks and scored."""

    campaign: CampaignSettings = spec(CampaignSettings())
    evaluation: EvaluationConfig = spec(EvaluationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def check(self):
        for i, name in enumerate(self.campaign.grid):
            axis = self.space.axis(name)
            if axis is None or axis.kind == "const":
                raise Invalid(f"campaign.grid[{i}]", f"{name!r} is not a varying axis of [space]")
        if not any(a.kind != "const" for a in self.space.axes):
            raise Invalid("space", "nothing varies (no range or list): every scenario would fly one flight point "
                                   "with one plant; give at least one axis a range [lo, hi] or a list")
        names, cells = self.grid_cells()
        if self.campaign.scenarios % cells:
            raise Invalid("campaign.scenarios", f"{self.campaign.scenarios} is not a multiple of the {cells} grid "
                                                f"cells of {' x '.join(names)}; each cell gets scenarios / {cells} "
                                                f"samples")
        self._check_times()
        vcas = self.space.axis("vcas_kt") or Axis("vcas_kt", "const", (_default("vcas_kt"),))
        alt = self.space.axis("altitude_m") or Axis("altitude_m", "const", (_default("altitude_m"),))
        self.plant.check_flight_point(min(vcas.grid_values()), max(alt.grid_values()),
                                      "space: the lowest vcas_kt at the highest altitude_m")
        kinds = self.space.axis("manoeuvre_kind")
        self.plant.check_manoeuvres(kinds.grid_values() if kinds else (), "space.manoeuvre_kind")

    def grid_cells(self) -> tuple[tuple[str, ...], int]:
        """Names of the gridded axes (every varying one with design 'grid') and the number of grid cells."""
        grid = self.campaign.design == "grid"
        axes = [a for a in self.space.axes if a.kind != "const" and (grid or a.name in self.campaign.grid)]
        return tuple(a.name for a in axes), math.prod(len(a.grid_values()) for a in axes)

    def _column_max(self, name: str) -> float:
        axis = self.space.axis(name) or Axis(name, "const", (_default(name),))
        return axis.hi if axis.kind == "range" else max(axis.values)

    def _check_times(self):
        """Settling, fault onsets and manoeuvre starts must all lie within the runs."""
        end = self.campaign.duration_s
        if self.evaluation.settle_s >= end:
            raise Invalid("evaluation.settle_s", f"{self.evaluation.settle_s} s is not below the runs' duration "
                                                 f"({end} s); no decision would be scored")
        windows = (("fault_kind", ("none",), "fault_onset_s", "fault onsets"),
                   ("manoeuvre_kind", IDLE_MANOEUVRES, "t_start_s", "manoeuvres"))
        for kind, idle, column, what in windows:
            axis = self.space.axis(kind)
            if set(axis.grid_values() if axis else (_default(kind),)) <= set(idle):
                continue
            latest = self._column_max(column)
            if latest >= end:
                raise Invalid(f"space.{column}", f"{what} up to {latest} s start at or after the end of the runs "
                                                 f"({end} s)")


# --------------------------------------------------------------------------------------------
# LPV fitting (``mcfdd fit-lpv``)


class LpvModelConfig(Section):
    """One fault model nu = (nu1, nu2) of the bank."""

    name: str = spec()
    nu1: float = spec(1.0, lo=0.0, lo_open=True, hi=1.0, doc="available-pressure share (leakage: nu1 < 1)")
    nu2: float = spec(1.0, lo=0.0, hi=1.0, doc="hinge-load share (surface damage: nu2 < 1, disconnection: 0)")


PAPER_LPV_MODELS = tuple(LpvModelConfig(name=name, nu1=nu1, nu2=nu2) for name, (nu1, nu2) in lpv.PAPER_MODELS)
_VCAS = bounded(*VCAS_RANGE_KT)
_ALTITUDE = bounded(*ALTITUDE_RANGE_M)
_GRID = bounded(2, 100, tp=int)


class LpvEnvelopeConfig(Section):
    """Flight points: a training grid and held-out validation points, all below the Mach limit."""

    vcas_kt: tuple[_VCAS, _VCAS] = spec((100.0, 350.0))
    altitude_m: tuple[_ALTITUDE, _ALTITUDE] = spec((0.0, 12000.0))
    grid: tuple[_GRID, _GRID] = spec((6, 4), doc="training points: Vcas x altitude grid")
    validation_points: int = spec(8, lo=1, hi=10000, doc="validation points drawn in the envelope (Latin hypercube)")

    def check(self):
        for key in ("vcas_kt", "altitude_m"):
            lo, hi = getattr(self, key)
            if not lo < hi:
                raise Invalid(key, f"range [{lo}, {hi}] is empty")


class LpvRunsConfig(Section):
    """Open-loop runs of the nonlinear actuator alone."""

    duration_s: float = spec(15.0, lo=0.0, lo_open=True, hi=600.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1, doc="sample time of the flight computer and of the LPV model")
    substeps: int = spec(4, lo=1, hi=64, doc="actuator integration sub-steps per sample")
    both_directions: bool = spec(True, doc="fly every manoeuvre also with the opposite sign")
    min_pressure: float = spec(0.2, lo=0.0, hi=1.0,
                               doc="runs whose available pressure falls below this share of dP are near a stall load: "
                                   "not fitted, reported apart")

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


class LpvOptimiserConfig(Section):
    """Adam on the output error, step decaying exponentially over the iterations."""

    iterations: int = spec(100, lo=1, hi=100000)
    learning_rate: float = spec(0.1, lo=0.0, lo_open=True, hi=100.0, doc="first step size (1/s)")
    final_learning_rate: float = spec(0.005, lo=0.0, lo_open=True, hi=100.0, doc="last step size (1/s)")


_OPEN_LOOP_KINDS = tuple(k for k in manoeuvres.KINDS if k.startswith("ol_"))


class LpvFitConfig(Section):
    """``mcfdd fit-lpv``: LPV gain models fitted by output error to the nonlinear actuator."""

    seed: int = spec(0, lo=0, hi=SEED_MAX, doc="draws the validation flight points")
    precision: Literal[PRECISIONS] = spec("float64")
    exact_disconnection: bool = spec(False, doc="models with nu2 = 0 take the exact gain of eq. (36), unfitted")
    plant: PlantConfig = spec(PlantConfig())
    models: tuple[LpvModelConfig, ...] = spec(PAPER_LPV_MODELS)
    envelope: LpvEnvelopeConfig = spec(LpvEnvelopeConfig())
    runs: LpvRunsConfig = spec(LpvRunsConfig())
    optimiser: LpvOptimiserConfig = spec(LpvOptimiserConfig())
    training: tuple[ManoeuvreConfig, ...] = spec()
    validation: tuple[ManoeuvreConfig, ...] = spec()

    def check(self):
        if not self.models:
            raise Invalid("models", "at least one [[models]] table is required")
        _check_unique([m.name for m in self.models], "models")
        for key in ("training", "validation"):
            runs = getattr(self, key)
            if not runs:
                raise Invalid(key, f"at least one [[{key}]] manoeuvre is required")
            for i, m in enumerate(runs):
                if m.kind not in _OPEN_LOOP_KINDS:
                    raise Invalid(f"{key}[{i}].kind", f"{m.kind!r} is not an open-loop command; expected one of "
                                                      f"{', '.join(_OPEN_LOOP_KINDS)}")
                if m.amplitude == 0.0:
                    raise Invalid(f"{key}[{i}].amplitude", "must not be 0 (errors are relative to the amplitude)")
                end = m.t_start_s + (2.0 if m.kind == "ol_doublet" else 1.0) * m.duration_s
                if end > self.runs.duration_s:
                    raise Invalid(f"{key}[{i}]", f"ends at {end} s, after runs.duration_s = {self.runs.duration_s}")
        if self.optimiser.final_learning_rate > self.optimiser.learning_rate:
            raise Invalid("optimiser.final_learning_rate", "must not exceed optimiser.learning_rate")
        env, max_mach = self.envelope, self.plant.aircraft.max_mach
        below = atmosphere.below_mach(np.linspace(*env.vcas_kt, env.grid[0]) * atmosphere.KT_TO_M_S,
                                      np.linspace(*env.altitude_m, env.grid[1]), max_mach)
        if below.sum() < 3:
            raise Invalid("envelope", f"only {below.sum()} training grid point(s) are below the Mach limit "
                                      f"plant.aircraft.max_mach = {max_mach}; at least 3 are needed")

    def manoeuvres(self, split: str) -> list[ManoeuvreConfig]:
        """Manoeuvres of ``split`` ('training' or 'validation'), mirrored if runs.both_directions."""
        listed = list(getattr(self, split))
        if self.runs.both_directions:
            listed += [m.model_copy(update={"amplitude": -m.amplitude}) for m in listed]
        return listed


# --------------------------------------------------------------------------------------------
# Worst-case search and tuning of the detection bounds (``mcfdd worst-case``, ``mcfdd tune``)


class SearchSettings(Section):
    """Multi-start projected gradient search of one detection bound, eqs. (26)-(27)."""

    detector: Literal["stall", "loe"] = spec("stall")
    bound: Literal["free", "detect"] = spec(
        "free", doc="free: tau_f of eq. (26), maximised over fault-free runs; detect: tau_d of eq. (27), minimised")
    screening: int = spec(64, lo=1, hi=100_000, doc="Sobol points screened; the worst ones start the gradient search")
    starts: int = spec(4, lo=1, hi=10_000)
    iterations: int = spec(20, lo=1, hi=10_000, doc="gradient steps per start")
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=1.0, doc="Adam step in the unit cube")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum over time, in log units of the statistic (0.05: about 5 %)")


def _fault_kinds(space_cfg: SpaceConfig) -> tuple[str, ...]:
    axis = space_cfg.axis("fault_kind")
    return axis.values if axis else (_default("fault_kind"),)


def _check_as_campaign(cfg: CampaignConfig, section: str):
    """Scenario-space checks of a campaign, with errors naming ``section`` instead of ``campaign``."""
    try:
        cfg.check()
    except Invalid as err:
        raise Invalid(re.sub(r"^campaign\.", f"{section}.", err.key), err.message) from None


class WorstCaseConfig(Section):
    """``mcfdd worst-case``: tau_f or tau_d of one detector by gradient search, against Monte Carlo."""

    simulation: SimulationConfig = spec(SimulationConfig(), doc="horizon, sample time and precision of every run; "
                                                                "seed draws the screening (Monte Carlo: seed + 1)")
    search: SearchSettings = spec(SearchSettings())
    evaluation: EvaluationConfig = spec(EvaluationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def check(self):
        s = self.search
        if s.starts > s.screening:
            raise Invalid("search.starts", f"{s.starts} exceeds search.screening = {s.screening}")
        if not any(a.kind == "range" for a in self.space.axes):
            raise Invalid("space", "no continuous axis ([lo, hi]) to search")
        kinds = _fault_kinds(self.space)
        if s.bound == "free" and set(kinds) != {"none"}:
            raise Invalid("space.fault_kind", f"{list(kinds)}; the false-alarm bound (search.bound = 'free') is "
                                              f"taken over fault-free runs, so fault_kind must be \"none\"")
        if (s.detector, s.bound) == ("loe", "detect") and not set(kinds) <= set(PARAMETRIC):
            raise Invalid("space.fault_kind", f"{list(kinds)}; the LOE detection bound needs parametric faults, "
                                              f"one of {', '.join(PARAMETRIC)}")
        _check_as_campaign(CampaignConfig.model_construct(
            campaign=CampaignSettings(duration_s=self.simulation.duration_s), evaluation=self.evaluation,
            plant=self.plant, fdd=self.fdd, space=self.space), "search")


class TuneSettings(Section):
    """Gradient tuning of one detector's evaluator (and pole) for the largest detection gap."""

    detector: Literal["stall", "loe"] = spec("stall")
    iterations: int = spec(60, lo=1, hi=100_000)
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0, doc="Adam step on the parameters' logarithms")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum/minimum over time and runs, in log units of the statistic")
    margin: float = spec(0.2, lo=0.0, hi=1.0, doc="tau = tau_f + margin (tau_d - tau_f); small: fast detection")
    threshold_candidates: int = spec(32, lo=2, hi=1000,
                                     doc="thresholds compared on the training set when the gap stays negative")
    tune_pole: bool = spec(True, doc="tune the filter pole a besides alpha, beta, gamma")


class TuneConfig(Section):
    """``mcfdd tune``: evaluator tuning on a training campaign, checked on a held-out one.

    Both campaigns draw from the same [space] with their own settings; they must differ in seed.
    """

    tune: TuneSettings = spec(TuneSettings())
    training: CampaignSettings = spec(CampaignSettings(scenarios=256, duration_s=20.0))
    validation: CampaignSettings = spec(CampaignSettings(scenarios=256, seed=1, duration_s=40.0))
    evaluation: EvaluationConfig = spec(EvaluationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def check(self):
        if self.validation.seed == self.training.seed:
            raise Invalid("validation.seed", f"{self.validation.seed} equals training.seed; the held-out campaign "
                                             f"needs its own seed")
        if self.validation.precision != self.training.precision:
            raise Invalid("validation.precision", f"{self.validation.precision!r} differs from training.precision "
                                                  f"{self.training.precision!r}")
        if self.plant.aircraft.model != "roll_axis":
            raise Invalid("plant.aircraft.model", f"{self.plant.aircraft.model!r}; mcfdd tune replays stored "
                                                  f"histories at each run's initial flight point, so it supports "
                                                  f"\"roll_axis\" only")
        for split in ("training", "validation"):
            _check_as_campaign(CampaignConfig.model_construct(
                campaign=getattr(self, split), evaluation=self.evaluation, plant=self.plant, fdd=self.fdd,
                space=self.space), split)

    def campaign(self, split: str, fdd: FddConfig | None = None) -> CampaignConfig:
        """The 'training' or 'validation' campaign, optionally with other FDD settings."""
        return CampaignConfig(campaign=getattr(self, split), evaluation=self.evaluation, plant=self.plant,
                              fdd=fdd or self.fdd, space=self.space)


class FddFragment(Section):
    """A file holding only an [fdd] table (``mcfdd campaign --fdd FILE``, written by ``mcfdd tune``)."""

    fdd: FddConfig = spec()


# --------------------------------------------------------------------------------------------
# Loading, overriding, writing and describing configurations

KINDS = {"simulate": SimulateConfig, "campaign": CampaignConfig, "fit-lpv": LpvFitConfig, "tune": TuneConfig,
         "worst-case": WorstCaseConfig, "sweep": SweepConfig}


def _plain(data):
    if isinstance(data, dict):
        return {k: _plain(v) for k, v in data.items()}
    return [_plain(v) for v in data] if isinstance(data, (list, tuple)) else data


def to_dict(obj) -> dict:
    """The resolved configuration as plain data (tables, lists, scalars); parses back to ``obj``."""
    return _plain(obj.model_dump())


def to_json(obj) -> str:
    return json.dumps(to_dict(obj), sort_keys=True, default=str)


def load_toml(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such configuration file")
    if not path.is_file():
        raise ConfigError(f"{path}: {'a folder' if path.is_dir() else 'not a regular file'}, not a configuration "
                          f"file; give the path of a TOML file")
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (not valid UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a configuration") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read it: {err.strerror or err}") from None


def _in_file(path, fn, *args):
    try:
        return fn(*args)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def load(cls, path):
    """Parse the TOML file at ``path`` into section ``cls``; errors name the file and key."""
    return _in_file(path, parse, cls, load_toml(path))


def infer_kind(data: dict) -> str:
    """The config kind whose top-level sections hold every key of ``data`` (and its required ones)."""
    keys = set(data)
    fits = [k for k, cls in KINDS.items() if keys <= set(cls.model_fields)]
    if not fits:
        known = set().union(*(cls.model_fields for cls in KINDS.values()))
        bad = sorted(keys - known) or sorted(keys)
        raise ConfigError(f"{bad[0]}: unknown key; no configuration kind ({', '.join(KINDS)}) has it")
    complete = [k for k in fits if all(n in keys for n, f in KINDS[k].model_fields.items() if f.is_required())]
    fits = complete or fits
    if len(fits) > 1:
        raise ConfigError(f"kind: the sections {', '.join(sorted(keys)) or '(none)'} fit {', '.join(fits)}; "
                          f"pass kind= one of them")
    return fits[0]


_PATH_PART = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def _split_path(path: str) -> list:
    parts = [int(i) if i else name for name, i in _PATH_PART.findall(path)]
    if not parts or _key_path(parts) != path:
        raise ConfigError(f"{path!r}: not a key path (expected e.g. campaign.scenarios or runs[1].fault.size)")
    return parts


def _with_overrides(cls, data: dict, overrides: dict) -> dict:
    """Copy of raw ``data`` with each dotted key path of ``overrides`` set, sections created as needed."""
    data = copy.deepcopy(data)
    for path, value in overrides.items():
        parts = _split_path(path)
        node, tp = data, cls
        for i, part in enumerate(parts):
            where = _key_path(parts[:i + 1])
            if isinstance(part, str) and _is_section(tp) and tp is not SpaceConfig and part not in tp.model_fields:
                raise ConfigError(f"{where}: unknown key; allowed keys are {', '.join(sorted(tp.model_fields))}")
            tp, _ = _target(tp, [part]) if tp is not None else (None, [])
            last = i == len(parts) - 1
            if isinstance(part, int):
                if not isinstance(node, list) or part >= len(node):
                    raise ConfigError(f"{where}: no such entry ({_key_path(parts[:i])} has "
                                      f"{len(node) if isinstance(node, list) else 'no'} entries)")
            elif not isinstance(node, dict):
                raise ConfigError(f"{_key_path(parts[:i])}: not a table, cannot set {where}")
            if last:
                node[part] = copy.deepcopy(value)
            else:
                if isinstance(part, str) and part not in node:
                    node[part] = {}
                node = node[part]
    return data


def load_config(source, kind: str | None = None, overrides: dict | None = None):
    """A validated configuration from a TOML file or a dict, with dotted-path overrides.

    Args:
        source: path of a TOML file, or its content as a dict (not modified).
        kind: one of :data:`KINDS` ('simulate', 'campaign', 'fit-lpv', 'tune', 'worst-case',
            'sweep'); inferred from the top-level sections when None.
        overrides: {key path: value}, e.g. ``{"campaign.scenarios": 256, "fdd.loe.tau": 0.12,
            "runs[1].fault.size": 0.3}``, applied to the raw data before validation, so a bad
            value gives the same message as in the file.

    Returns:
        The frozen config model of the kind.

    >>> space = {"kci_scale": [0.9, 1.1]}
    >>> cfg = load_config({"campaign": {"scenarios": 8}, "space": space}, overrides={"fdd.loe.tau": 0.12})
    >>> type(cfg).__name__, cfg.campaign.scenarios, cfg.fdd.loe.tau
    ('CampaignConfig', 8, 0.12)
    """
    from_file = not isinstance(source, dict)
    data = load_toml(source) if from_file else source
    if kind is None:
        kind = _in_file(source, infer_kind, data) if from_file else infer_kind(data)
    if kind not in KINDS:
        raise ConfigError(f"kind: {kind!r} is not allowed; expected one of {', '.join(map(repr, KINDS))}")
    overrides = overrides or {}
    merged = _with_overrides(KINDS[kind], data, overrides)
    try:
        return parse(KINDS[kind], merged)
    except Invalid as err:
        if not from_file or any(err.key == o or err.key.startswith((f"{o}.", f"{o}[")) for o in overrides):
            raise
        raise ConfigError(f"{source}: {err}") from None


def differences(old, new, path: str = "") -> list[tuple[str, object, object]]:
    """(key path, old value, new value) wherever two resolved configurations (plain data) differ.

    >>> differences({"campaign": {"seed": 1, "grid": ["a"]}}, {"campaign": {"seed": 2, "grid": ["a"]}})
    [('campaign.seed', 1, 2)]
    """
    if isinstance(old, dict) and isinstance(new, dict):
        return [d for key in sorted(set(old) | set(new), key=str)
                for d in differences(old.get(key), new.get(key), _join(path, str(key)))]
    return [] if old == new else [(path or "configuration", old, new)]


def replace(cfg, changes: dict):
    """A copy of ``cfg`` with the dotted key paths of ``changes`` set, validated like a file.

    >>> cfg = load_config({"campaign": {"scenarios": 8}, "space": {"kci_scale": [0.9, 1.1]}})
    >>> replace(cfg, {"campaign.seed": 3, "fdd.loe.tau": 0.2}).campaign.seed
    3
    """
    return parse(type(cfg), _with_overrides(type(cfg), to_dict(cfg), changes))


def json_schema(kind: str) -> dict:
    """JSON Schema (draft 2020-12) of a configuration kind (one of :data:`KINDS`), for editors and validators.

    >>> schema = json_schema("campaign")
    >>> sorted(schema["properties"]), schema["additionalProperties"]
    (['campaign', 'evaluation', 'fdd', 'plant', 'space'], False)
    """
    if kind not in KINDS:
        raise ConfigError(f"kind: {kind!r} is not allowed; expected one of {', '.join(map(repr, KINDS))}")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **KINDS[kind].model_json_schema()}


def _without_none(data):
    if isinstance(data, dict):
        return {k: _without_none(v) for k, v in data.items() if v is not None}
    if isinstance(data, (list, tuple)):
        return [_without_none(v) for v in data]
    return data


def to_toml(data: dict) -> str:
    """TOML text of nested tables (keys whose value is None are left out: they take their default)."""
    return tomli_w.dumps(_without_none(data))


def fdd_fragment(fdd: FddConfig, comment: str = "") -> str:
    """A config fragment holding only an [fdd] table (``mcfdd campaign --fdd FILE``)."""
    header = "".join(f"# {line}\n" for line in comment.splitlines())
    return header + to_toml({"fdd": to_dict(fdd)})


def load_fdd_fragment(path) -> FddConfig:
    """The [fdd] table of a fragment file, parsed like a config's; errors name the file and key."""
    return load(FddFragment, path).fdd


def set_overrides(pairs) -> dict:
    """``KEY=VALUE`` texts (the ``--set`` flag) as dotted-path overrides; VALUE is read as TOML (a bare word
    as a string)."""
    overrides = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set: {pair!r} is not KEY=VALUE, e.g. fdd.loe.detection_tau=0.12")
        try:
            overrides[key.strip()] = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            overrides[key.strip()] = text
        except RecursionError:
            raise ConfigError(f"--set: the value of {key.strip()} is nested too deeply") from None
    return overrides


def campaign_overrides(set_pairs=(), flags: dict | None = None, fdd_path=None) -> dict:
    """The overrides of a campaign's command line: ``--set`` pairs, then the ``campaign.*`` flags given (each
    checked against its key's range, the flag named in the error), then an FDD fragment replacing [fdd]."""
    overrides = set_overrides(set_pairs)
    for key, value in (flags or {}).items():
        if value is not None:
            try:
                overrides[f"campaign.{key}"] = field_value(CampaignSettings, key, value)
            except Invalid as err:
                raise ConfigError(f"--{key.replace('_', '-')}: {err.message} (campaign.{key})") from None
    if fdd_path:
        overrides["fdd"] = to_dict(load_fdd_fragment(fdd_path))
    return overrides


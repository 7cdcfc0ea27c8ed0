"""Configuration: TOML files parsed once into frozen dataclasses (the edge of the package).

Every section is a frozen dataclass whose fields carry their unit in the name and an allowed
range. Parsing rejects unknown keys, wrong types and out-of-range values with a
:class:`ConfigError` that names the key path (``runs[1].fault.size``) and what is allowed.
Conversion to the SI pytrees the simulation uses happens here and nowhere else.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import types
import typing
from pathlib import Path

import numpy as np

from mcfdd.fdd import evaluator, lpv, stall, system
from mcfdd.analysis import campaign as campaign_sim
from mcfdd.analysis import scenarios as space
from mcfdd.plant import actuator, aircraft, atmosphere, closed_loop, control_law, hinge, manoeuvres, turbulence


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range."""


_NO_META = {"lo": None, "hi": None, "lo_open": False, "choices": None, "doc": ""}


def spec(default=dataclasses.MISSING, *, lo=None, hi=None, lo_open=False, choices=None, doc=""):
    """A dataclass field with an allowed range [lo, hi] (open at lo if ``lo_open``) or choices."""
    meta = {"lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices, "doc": doc}
    if isinstance(default, (list, dict)) or dataclasses.is_dataclass(default):
        value = default
        return dataclasses.field(default_factory=lambda: value, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _describe_range(meta) -> str:
    if meta["choices"] is not None:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    lo, hi = meta["lo"], meta["hi"]
    left = "(" if meta["lo_open"] else "["
    return f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


def _check_range(value, meta, path):
    if meta["choices"] is not None:
        if value not in meta["choices"]:
            raise ConfigError(f"{path}: {value!r} is not allowed; expected {_describe_range(meta)}")
        return
    lo, hi = meta["lo"], meta["hi"]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if math.isnan(value):
            raise ConfigError(f"{path}: nan is not a number")
        below = lo is not None and (value <= lo if meta["lo_open"] else value < lo)
        if below or (hi is not None and value > hi):
            raise ConfigError(f"{path}: {value!r} is outside the allowed range {_describe_range(meta)}")


def _type_name(tp) -> str:
    return getattr(tp, "__name__", str(tp))


def _convert(tp, value, path, meta):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _convert(options[0], value, path, meta)
    if dataclasses.is_dataclass(tp):
        if hasattr(tp, "from_toml"):
            return tp.from_toml(value, path)
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: expected a table, got {type(value).__name__} {value!r}")
        return parse(tp, value, path)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(f"{path}: expected a list, got {type(value).__name__} {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{path}[{i}]", meta) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{path}: expected a list of {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, f"{path}[{i}]", meta) for i, (a, v) in enumerate(zip(args, value)))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {type(value).__name__} {value!r}")
        value = float(value)
    elif tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {type(value).__name__} {value!r}")
    elif tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {value!r}")
    elif tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {type(value).__name__} {value!r}")
    else:
        raise TypeError(f"unsupported configuration type {_type_name(tp)} at {path}")
    _check_range(value, meta, path)
    return value


def parse(cls, data: dict, path: str = ""):
    """Build dataclass ``cls`` from a TOML table, checking keys, types and ranges."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    prefix = f"{path}." if path else ""
    if unknown:
        raise ConfigError(f"{prefix}{unknown[0]}: unknown key; allowed keys are {', '.join(sorted(fields))}")
    values = {}
    for name, field in fields.items():
        key_path = f"{prefix}{name}"
        if name in data:
            values[name] = _convert(hints[name], data[name], key_path, field.metadata or _NO_META)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{key_path}: missing required key")
    obj = cls(**values)
    check = getattr(obj, "check", None)
    if check is not None:
        check(path)
    return obj


def to_dict(obj) -> dict:
    """The resolved configuration as plain data (for metadata and reports)."""
    return dataclasses.asdict(obj)


def to_json(obj) -> str:
    return json.dumps(to_dict(obj), sort_keys=True, default=str)


def load_toml(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such configuration file")
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None


# --------------------------------------------------------------------------------------------
# Plant sections


@dataclasses.dataclass(frozen=True, kw_only=True)
class ActuatorConfig:
    supply_pressure_pa: float = spec(2.07e7, lo=0.0, lo_open=True, doc="hydraulic supply pressure dP")
    ref_pressure_pa: float | None = spec(None, lo=0.0, lo_open=True, doc="dP_ref; default: equal to dP")
    piston_area_m2: float = spec(2.272e-3, lo=0.0, lo_open=True)
    r_arm_m: float = spec(0.0525, lo=0.0, lo_open=True)
    max_current_ma: float = spec(8.0, lo=0.0, lo_open=True)
    kci_mm_s_per_ma: float = spec(11.46, lo=0.0, lo_open=True)
    kp_ma_per_mm: float = spec(2.18, lo=0.0, lo_open=True)
    kd_n_s2_m2: float = spec(5.6e5, lo=0.0)
    max_deflection_deg: float = spec(25.0, lo=0.0, hi=60.0, lo_open=True)

    def params(self) -> actuator.ActuatorParams:
        return actuator.ActuatorParams(
            supply_pressure_pa=self.supply_pressure_pa,
            ref_pressure_pa=self.ref_pressure_pa or self.supply_pressure_pa,
            piston_area_m2=self.piston_area_m2,
            r_arm_m=self.r_arm_m,
            max_current_a=self.max_current_ma * 1e-3,
            kci_m_s_a=self.kci_mm_s_per_ma,
            kp_a_m=self.kp_ma_per_mm,
            kd_n_s2_m2=self.kd_n_s2_m2,
            max_deflection_rad=math.radians(self.max_deflection_deg),
        )


@dataclasses.dataclass(frozen=True, kw_only=True)
class HingeConfig:
    area_m2: float = spec(1.93, lo=0.0, lo_open=True)
    chord_m: float = spec(0.58, lo=0.0, lo_open=True)
    ch0: float = spec(0.0, lo=-1.0, hi=1.0)
    ch_alpha_per_rad: float = spec(-0.06, lo=-2.0, hi=2.0)
    ch_delta_per_rad: float = spec(-0.25, lo=-2.0, hi=2.0)

    def surface(self) -> hinge.HingeSurface:
        return hinge.HingeSurface(self.area_m2, self.chord_m, self.ch0, self.ch_alpha_per_rad, self.ch_delta_per_rad)


AIRCRAFT_MODELS = ("roll_axis", "rcam")


@dataclasses.dataclass(frozen=True, kw_only=True)
class AircraftConfig:
    wing_area_m2: float = spec(260.0, lo=0.0, lo_open=True)
    mean_chord_m: float = spec(6.6, lo=0.0, lo_open=True)
    span_m: float = spec(44.8, lo=0.0, lo_open=True)
    mass_kg: float = spec(120000.0, lo=0.0, lo_open=True)
    roll_inertia_kg_m2: float = spec(4.81e6, lo=0.0, lo_open=True)
    monitored_share: float = spec(0.5, lo=0.0, hi=1.0, doc="share of roll power of the monitored aileron")
    max_mach: float = spec(0.82, lo=0.1, hi=0.95, doc="flight points above this Mach number are refused")
    model: str = spec("roll_axis", choices=AIRCRAFT_MODELS, doc="roll_axis: the fast roll axis at a fixed flight "
                      "point; rcam: the GARTEUR RCAM 6-DoF aircraft in closed loop (Vcas, h and alpha vary in a run)")

    def params(self) -> aircraft.AircraftParams:
        return aircraft.AircraftParams(
            wing_area_m2=self.wing_area_m2, mean_chord_m=self.mean_chord_m, span_m=self.span_m,
            mass_kg=self.mass_kg, roll_inertia_kg_m2=self.roll_inertia_kg_m2,
            monitored_share=self.monitored_share)


@dataclasses.dataclass(frozen=True, kw_only=True)
class ControlLawConfig:
    max_roll_rate_deg_s: float = spec(15.0, lo=0.0, lo_open=True)
    bank_hold_deg: float = spec(33.0, lo=0.0, hi=90.0)
    bank_protection_deg: float = spec(67.0, lo=0.0, hi=90.0)
    time_constant_s: float = spec(0.5, lo=0.05, hi=10.0)

    def params(self) -> control_law.RollLawParams:
        return control_law.RollLawParams(
            max_roll_rate_rad_s=math.radians(self.max_roll_rate_deg_s), bank_hold_rad=math.radians(self.bank_hold_deg),
            bank_protection_rad=math.radians(self.bank_protection_deg), time_constant_s=self.time_constant_s)


VCAS_RANGE_KT = (80.0, 420.0)
ALTITUDE_RANGE_M = (0.0, 12500.0)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PlantConfig:
    actuator: ActuatorConfig = spec(ActuatorConfig())
    hinge: HingeConfig = spec(HingeConfig())
    aircraft: AircraftConfig = spec(AircraftConfig())
    control_law: ControlLawConfig = spec(ControlLawConfig())

    def model(self) -> closed_loop.PlantModel:
        return closed_loop.build_model(
            self.actuator.params(), self.aircraft.params(), self.control_law.params(), self.hinge.surface(),
            vcas_range_m_s=tuple(v * atmosphere.KT_TO_M_S for v in VCAS_RANGE_KT), altitude_range_m=ALTITUDE_RANGE_M,
            aircraft_model=self.aircraft.model)

    def check_manoeuvres(self, kinds, path: str):
        """Refuse manoeuvre families that the roll axis cannot fly."""
        if self.aircraft.model == "rcam":
            return
        for kind in kinds:
            if kind in manoeuvres.FULL_AIRCRAFT:
                raise ConfigError(f"{path}: {kind!r} needs the full aircraft; set plant.aircraft.model = \"rcam\"")

    def check_flight_point(self, vcas_kt: float, altitude_m: float, path: str):
        """Refuse a flight point above the Mach limit."""
        m = float(atmosphere.mach(vcas_kt * atmosphere.KT_TO_M_S, altitude_m))
        if m > self.aircraft.max_mach:
            raise ConfigError(f"{path}: {vcas_kt} kt at {altitude_m} m is Mach {m:.3f}, above the limit "
                              f"plant.aircraft.max_mach = {self.aircraft.max_mach}")


# --------------------------------------------------------------------------------------------
# Scenario sections

@dataclasses.dataclass(frozen=True, kw_only=True)
class FaultConfig:
    kind: str = spec("none", choices=space.FAULT_KINDS)
    size: float = spec(0.0, lo=0.0, hi=1.0, doc="leakage: pressure loss 1 - nu1; surface_damage: 1 - nu2")
    onset_s: float = spec(10.0, lo=0.0)

    def check(self, path):
        if self.kind == "leakage" and self.size >= 1.0:
            raise ConfigError(f"{path}.size: {self.size} leaves no pressure (nu1 = 0); leakage size must be below 1")


@dataclasses.dataclass(frozen=True, kw_only=True)
class ManoeuvreConfig:
    kind: str = spec("quiet", choices=manoeuvres.KINDS)
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


@dataclasses.dataclass(frozen=True, kw_only=True)
class RunConfig:
    name: str = spec()
    vcas_kt: float = spec(250.0, lo=VCAS_RANGE_KT[0], hi=VCAS_RANGE_KT[1])
    altitude_m: float = spec(3000.0, lo=ALTITUDE_RANGE_M[0], hi=ALTITUDE_RANGE_M[1])
    turbulence: str = spec("light", choices=tuple(turbulence.LEVELS))
    noise_std_mm: float = spec(0.05, lo=0.0, hi=5.0)
    supply_pressure_scale: float = spec(1.0, lo=0.5, hi=1.5)
    kci_scale: float = spec(1.0, lo=0.5, hi=1.5)
    kd_scale: float = spec(1.0, lo=0.0, hi=3.0)
    hinge_scale: float = spec(1.0, lo=0.0, hi=3.0)
    roll_inertia_scale: float = spec(1.0, lo=0.5, hi=1.5)
    mass_scale: float = spec(1.0, lo=0.7, hi=1.2, doc="full aircraft: mass over the nominal 120 t (trim and inertia)")
    fault: FaultConfig = spec(FaultConfig())
    manoeuvre: ManoeuvreConfig = spec(ManoeuvreConfig())

    def columns(self) -> dict:
        """The run as a row of a scenario table (see :mod:`mcfdd.analysis.scenarios`)."""
        m = self.manoeuvre
        return {
            "vcas_kt": self.vcas_kt, "altitude_m": self.altitude_m, "supply_pressure_scale": self.supply_pressure_scale,
            "kci_scale": self.kci_scale, "kd_scale": self.kd_scale, "hinge_scale": self.hinge_scale,
            "roll_inertia_scale": self.roll_inertia_scale, "mass_scale": self.mass_scale,
            "noise_std_mm": self.noise_std_mm,
            "turbulence": self.turbulence, "fault_kind": self.fault.kind, "fault_size": self.fault.size,
            "fault_onset_s": self.fault.onset_s, "manoeuvre_kind": m.kind, "amplitude": m.amplitude,
            "t_start_s": m.t_start_s, "duration_s": m.duration_s, "hold_s": m.hold_s, "ramp_s": m.ramp_s,
            "freq_lo_hz": m.freq_lo_hz, "freq_hi_hz": m.freq_hi_hz, "sideslip_deg": m.sideslip_deg,
            "fpa_deg": m.fpa_deg, "heading_change_deg": m.heading_change_deg, "bank_deg": m.bank_deg,
            "delta_vcas_kt": m.delta_vcas_kt,
        }


# --------------------------------------------------------------------------------------------
# FDD sections. Residual thresholds and signal levels are in degrees of surface deflection
# (rod position / r_arm); the FDD itself works on rod positions in m.


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvaluatorConfig:
    """Narendra evaluator of eq. (14)."""

    alpha: float = spec(0.0, lo=0.0, doc="weight of |r|")
    beta: float = spec(1.0, lo=0.0, doc="weight of the forgetting integral of |r|")
    gamma_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=1000.0, doc="forgetting factor")

    def params(self) -> evaluator.NarendraParams:
        return evaluator.NarendraParams(self.alpha, self.beta, self.gamma_1_s)


@dataclasses.dataclass(frozen=True, kw_only=True)
class LoeDetectionConfig:
    """Model-detection bank for parametric LOE faults (Section 4).

    Defaults are tuned for 0.05 mm position-sensor noise (see README): the paper's evaluator
    (alpha = 0, beta = 1, gamma = 0.1) averages sensor noise over 10 s against manoeuvre
    transients of a few seconds, so gamma = 1; a slow filter pole keeps the noise band narrow.
    Two levels: detection (``detection_tau``, ``detection_confirm_s``: the fault-free model
    rejected) and identification (``tau``, ``tau_schedule``, ``confirm_s``: the signature (15)).
    """

    pole_1_s: float = spec(0.5, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of every filter")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=0.0, beta=1.0, gamma_1_s=1.0))
    tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                      doc="threshold on theta_i / ||u||, about the relative gain mismatch |k_j - k_i| / k0_i")
    tau_schedule: float = spec(0.0, lo=0.0, hi=1.0, doc="scheduled thresholds tau_i(rho) = max(tau, tau_schedule "
                               "x distance (16) from model i to its nearest model at the current point, in ratio "
                               "units); 0 keeps tau constant")
    detection_tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0, doc="detection: the fault-free model is "
                                "rejected while theta_0 / ||u|| is above this and ||u|| above the excitation floor")
    detection_confirm_s: float = spec(0.5, lo=0.0, hi=60.0, doc="detection: the rejection must persist this long")
    excitation_floor_deg: float = spec(0.15, lo=0.0, doc="no decision (detection or identification) while ||u|| "
                                       "is below this: theta_0 reaches 0.014 deg from 0.07 mm sensor noise in quiet "
                                       "flight, so noise alone keeps theta_0 / ||u|| below tau = 0.1")
    confirm_s: float = spec(2.0, lo=0.0, hi=60.0, doc="identification: a decoded model must persist this long")
    max_load_fraction: float = spec(0.5, lo=0.0, hi=1.0, doc="residuals are not evaluated above this estimated "
                                    "hinge-load fraction (1 disables)")
    linear_range_deg: float = spec(3.5, lo=0.0, lo_open=True, doc="residuals are not evaluated while |u_c - u| "
                                   "exceeds this (servo-valve current saturation at i_max / Kp = 4 deg)")
    stall_hold_s: float = spec(3.0, lo=0.0, hi=60.0, doc="no LOE decision while a stall load is identified "
                               "and this long after")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SignalRulesConfig:
    """Signal-based stall identification, eqs. (32)-(35)."""

    rate_min_deg_s: float = spec(2.0, lo=0.0, lo_open=True, doc="u_dot_min of (33)")
    command_min_deg: float = spec(10.0, lo=0.0, doc="tau_uc,max of (34)")
    position_min_deg: float = spec(10.0, lo=0.0, doc="tau_u,max of (34)")
    window_s: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                           doc="shortest averaging time and re-anchoring window of the mean rate (32)")
    error_min_deg: float = spec(0.5, lo=0.0, doc="smallest |u_c - u| for which (35) counts")


@dataclasses.dataclass(frozen=True, kw_only=True)
class ModelRuleConfig:
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


@dataclasses.dataclass(frozen=True, kw_only=True)
class StallDetectionConfig:
    """Stall-load detector (Section 5; paper evaluator alpha = beta = 1, gamma = 0.1)."""

    pole_1_s: float = spec(10.0, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of eq. (20)")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=1.0, beta=1.0, gamma_1_s=0.1))
    tau_deg: float = spec(1.0, lo=0.0, lo_open=True, doc="threshold tau of eq. (25)")
    identification: str = spec("signal", choices=("signal", "model"), doc="which eta is eta_stall")
    signal: SignalRulesConfig = spec(SignalRulesConfig())
    model: ModelRuleConfig = spec(ModelRuleConfig())


@dataclasses.dataclass(frozen=True, kw_only=True)
class FddConfig:
    bank: str = spec("default", doc="LPV bank JSON file, or 'default' for the bank shipped with mcfdd")
    loe: LoeDetectionConfig = spec(LoeDetectionConfig())
    stall: StallDetectionConfig = spec(StallDetectionConfig())

    def params(self, bank: lpv.GainBank, r_arm_m: float) -> system.FddParams:
        """FDD parameters in rod units for an actuator with lever arm ``r_arm_m``."""
        deg = math.radians(1.0) * r_arm_m
        loe, stl = self.loe, self.stall
        return system.FddParams(
            loe=system.LoeParams(bank=bank, pole=loe.pole_1_s, evaluator=loe.evaluator.params(), tau=loe.tau,
                                 tau_schedule=loe.tau_schedule, detection_tau=loe.detection_tau,
                                 detection_confirm_s=loe.detection_confirm_s,
                                 excitation_floor=loe.excitation_floor_deg * deg, confirm_s=loe.confirm_s,
                                 max_load_fraction=loe.max_load_fraction,
                                 linear_range_m=loe.linear_range_deg * deg, stall_hold_s=loe.stall_hold_s),
            stall=system.StallParams(
                pole=stl.pole_1_s, evaluator=stl.evaluator.params(), tau=stl.tau_deg * deg,
                signal=stall.SignalRules(stl.signal.rate_min_deg_s * deg, stl.signal.command_min_deg * deg,
                                         stl.signal.position_min_deg * deg, stl.signal.window_s,
                                         stl.signal.error_min_deg * deg),
                model=stall.ModelRule(stl.model.k_sl_1_s, stl.model.pole_1_s, stl.model.evaluator.params(),
                                      stl.model.tau_deg * deg)),
        )


@dataclasses.dataclass(frozen=True, kw_only=True)
class SimulationConfig:
    duration_s: float = spec(30.0, lo=0.0, lo_open=True, hi=3600.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1)
    substeps: int = spec(2, lo=1, hi=64, doc="actuator sub-steps per sample in the linear range of the valve")
    seed: int = spec(0, lo=0)
    precision: str = spec("float32", choices=("float32", "float64"))

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


@dataclasses.dataclass(frozen=True, kw_only=True)
class SimulateConfig:
    """``mcfdd simulate``: a few named runs simulated in one batch, full time histories."""

    simulation: SimulationConfig = spec(SimulationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    runs: tuple[RunConfig, ...] = spec()

    def check(self, path):
        if not self.runs:
            raise ConfigError("runs: at least one [[runs]] table is required")
        names = [r.name for r in self.runs]
        for i, name in enumerate(names):
            if names.index(name) != i:
                raise ConfigError(f"runs[{i}].name: {name!r} is used by runs[{names.index(name)}] already")
        for i, run in enumerate(self.runs):
            self.plant.check_flight_point(run.vcas_kt, run.altitude_m, f"runs[{i}]")
            self.plant.check_manoeuvres([run.manoeuvre.kind], f"runs[{i}].manoeuvre.kind")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SweepConfig:
    """``mcfdd figures`` Fig. 4: fault-size sweeps at one flight point and manoeuvre."""

    simulation: SimulationConfig = spec(SimulationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    run: RunConfig = spec(doc="flight point, manoeuvre and fault onset; the fault kind and size are swept")
    surface_points: int = spec(51, lo=2, hi=1001, doc="surface-effectiveness losses from 0 to 100 %")
    leakage_points: int = spec(31, lo=2, hi=1001, doc="pressure losses from 0 to max_leakage")
    max_leakage: float = spec(0.3, lo=0.0, lo_open=True, hi=0.95)

    def check(self, path):
        self.plant.check_flight_point(self.run.vcas_kt, self.run.altitude_m, "run")
        self.plant.check_manoeuvres([self.run.manoeuvre.kind], "run.manoeuvre.kind")

    def table(self) -> tuple[dict, list[str], np.ndarray, np.ndarray]:
        """Scenario columns of both sweeps, run names, family ('surface'/'leakage') and size per run."""
        surface = np.linspace(0.0, 1.0, self.surface_points)
        leakage = np.linspace(0.0, self.max_leakage, self.leakage_points)
        base = self.run.columns()
        n = len(surface) + len(leakage)
        table = {k: np.full(n, v) for k, v in base.items()}
        table["fault_kind"] = np.array(["surface_damage"] * len(surface) + ["leakage"] * len(leakage))
        table["fault_size"] = np.concatenate([surface, leakage])
        family = np.array(["surface"] * len(surface) + ["leakage"] * len(leakage))
        names = [f"{f}-{100 * v:.1f}pct" for f, v in zip(family, table["fault_size"])]
        return table, names, family, table["fault_size"]


# --------------------------------------------------------------------------------------------
# Campaigns

# Each scenario-table column is checked against the range of the matching single-run key.
_COLUMN_FIELDS = {
    **{f.name: (RunConfig, f.name) for f in dataclasses.fields(RunConfig) if f.name not in ("name", "fault", "manoeuvre")},
    "fault_kind": (FaultConfig, "kind"), "fault_onset_s": (FaultConfig, "onset_s"),
    "leakage_size": (FaultConfig, "size"), "surface_damage_size": (FaultConfig, "size"),
    "manoeuvre_kind": (ManoeuvreConfig, "kind"),
    **{f.name: (ManoeuvreConfig, f.name) for f in dataclasses.fields(ManoeuvreConfig) if f.name != "kind"},
}
_SIZE_COLUMNS = {"leakage_size": "leakage", "surface_damage_size": "surface_damage"}


@dataclasses.dataclass(frozen=True)
class SpaceConfig:
    """Scenario space: one axis per table column.

    In TOML a key takes a number or a name (constant), ``[lo, hi]`` (uniform range), a list of
    names (choices), ``{ values = [...] }`` (discrete numbers) or ``{ range = [lo, hi], n = 5 }``
    (a range with 5 grid points when gridded). Fault sizes are drawn per kind
    (``leakage_size``, ``surface_damage_size``) and combined into ``fault_size``.
    """

    axes: tuple[space.Axis, ...] = ()

    @classmethod
    def from_toml(cls, data, path):
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a table of axes")
        axes = []
        for name, value in data.items():
            key = f"{path}.{name}"
            if name not in _COLUMN_FIELDS:
                raise ConfigError(f"{key}: unknown axis; allowed axes are {', '.join(sorted(_COLUMN_FIELDS))}")
            axes.append(_axis(name, value, key))
        return cls(tuple(axes))

    def axis(self, name):
        return next((a for a in self.axes if a.name == name), None)


def _field_meta(name):
    owner, field_name = _COLUMN_FIELDS[name]
    field = next(f for f in dataclasses.fields(owner) if f.name == field_name)
    return typing.get_type_hints(owner)[field_name], dict(field.metadata)


def _axis(name, value, path) -> space.Axis:
    tp, meta = _field_meta(name)
    if name == "leakage_size":
        meta["hi"] = 0.95
    def one(v, p):
        return _convert(tp, v, p, meta)

    if isinstance(value, dict):
        extra = sorted(set(value) - {"values", "range", "n"})
        if extra:
            raise ConfigError(f"{path}.{extra[0]}: unknown key; an axis table takes values, or range and n")
        if "values" in value:
            vals = value["values"]
            if not isinstance(vals, list) or not vals:
                raise ConfigError(f"{path}.values: expected a non-empty list")
            return space.Axis(name, "values", tuple(one(v, f"{path}.values[{i}]") for i, v in enumerate(vals)))
        if "range" not in value:
            raise ConfigError(f"{path}: an axis table needs 'values' or 'range'")
        axis = _axis(name, value["range"], f"{path}.range")
        n = value.get("n", 2)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ConfigError(f"{path}.n: expected a positive integer, got {n!r}")
        return dataclasses.replace(axis, n=n)
    if isinstance(value, list):
        if tp is str:
            if not value:
                raise ConfigError(f"{path}: expected a non-empty list of names")
            return space.Axis(name, "choices", tuple(one(v, f"{path}[{i}]") for i, v in enumerate(value)))
        if len(value) != 2:
            raise ConfigError(f"{path}: a range is [lo, hi]; for discrete values write {{ values = [...] }}")
        lo, hi = one(value[0], f"{path}[0]"), one(value[1], f"{path}[1]")
        if hi < lo:
            raise ConfigError(f"{path}: range [{lo}, {hi}] is empty")
        return space.Axis(name, "range", lo=lo, hi=hi, n=2)
    return space.Axis(name, "const", (one(value, path),))


@dataclasses.dataclass(frozen=True, kw_only=True)
class CampaignSettings:
    scenarios: int = spec(1000, lo=1, hi=10_000_000, doc="samples (times the grid cells when axes are gridded)")
    design: str = spec("sobol", choices=space.DESIGNS)
    grid: tuple[str, ...] = spec((), doc="axes on a full grid, crossed with samples over the others")
    seed: int = spec(0, lo=0)
    chunk_size: int = spec(1024, lo=1, hi=1_000_000)
    duration_s: float = spec(60.0, lo=0.0, lo_open=True, hi=3600.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1)
    substeps: int = spec(2, lo=1, hi=64)
    precision: str = spec("float32", choices=("float32", "float64"))

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvaluationConfig:
    """How runs are scored (DESIGN.md section 5)."""

    settle_s: float = spec(5.0, lo=0.0, doc="decisions before this are not scored")
    t_detec_s: float = spec(120.0, lo=0.0, lo_open=True, doc="required detection time after the fault onset")
    stall_grace_s: float = spec(0.5, lo=0.0, doc="eta = 1 this soon after a stall load is not a false alarm")
    stall_min_duration_s: float = spec(0.1, lo=0.0, doc="shorter stall intervals are not relevant events")
    stall_min_error_deg: float = spec(1.0, lo=0.0, doc="stall events whose tracking error stays below are not relevant")
    stall_window_s: float = spec(0.5, lo=0.0, lo_open=True, doc="required stall detection/identification time")

    def settings(self, r_arm_m: float) -> campaign_sim.Settings:
        return campaign_sim.Settings(self.settle_s, self.t_detec_s, self.stall_grace_s, self.stall_min_duration_s,
                                 math.radians(self.stall_min_error_deg) * r_arm_m, self.stall_window_s)


@dataclasses.dataclass(frozen=True, kw_only=True)
class CampaignConfig:
    """``mcfdd campaign``: a scenario space sampled, simulated in chunks and scored."""

    campaign: CampaignSettings = spec(CampaignSettings())
    evaluation: EvaluationConfig = spec(EvaluationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def check(self, path):
        for i, name in enumerate(self.campaign.grid):
            axis = self.space.axis(name)
            if axis is None or axis.kind == "const":
                raise ConfigError(f"campaign.grid[{i}]: {name!r} is not a varying axis of [space]")
        vcas = self.space.axis("vcas_kt") or space.Axis("vcas_kt", "const", (space.DEFAULTS["vcas_kt"],))
        alt = self.space.axis("altitude_m") or space.Axis("altitude_m", "const", (space.DEFAULTS["altitude_m"],))
        self.plant.check_flight_point(min(vcas.grid_values()), max(alt.grid_values()),
                                      "space: the lowest vcas_kt at the highest altitude_m")
        kinds = self.space.axis("manoeuvre_kind")
        self.plant.check_manoeuvres(kinds.grid_values() if kinds else (), "space.manoeuvre_kind")

    def design(self):
        """Scenario columns of the design (dict of arrays) and their number of rows."""
        c = self.campaign
        cols, n = space.design_table(list(self.space.axes), c.scenarios, c.design, c.seed, c.grid,
                                         self.plant.aircraft.max_mach)
        kind = np.asarray(cols["fault_kind"])
        size = np.zeros(n)
        for column, fault in _SIZE_COLUMNS.items():
            if column in cols:
                size = np.where(kind == fault, np.asarray(cols.pop(column), dtype=float), size)
        if any(c in {a.name for a in self.space.axes} for c in _SIZE_COLUMNS):
            cols["fault_size"] = size
        return cols, n


def load(cls, path):
    """Parse the TOML file at ``path`` into dataclass ``cls``; errors name the file and key."""
    data = load_toml(path)
    try:
        return parse(cls, data)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


# --------------------------------------------------------------------------------------------
# LPV fitting (``mcfdd fit-lpv``)


@dataclasses.dataclass(frozen=True, kw_only=True)
class LpvModelConfig:
    """One fault model nu = (nu1, nu2) of the bank."""

    name: str = spec()
    nu1: float = spec(1.0, lo=0.0, lo_open=True, hi=1.0, doc="available-pressure share (leakage: nu1 < 1)")
    nu2: float = spec(1.0, lo=0.0, hi=1.0, doc="hinge-load share (surface damage: nu2 < 1, disconnection: 0)")


PAPER_LPV_MODELS = tuple(LpvModelConfig(name=name, nu1=nu1, nu2=nu2) for name, (nu1, nu2) in lpv.PAPER_MODELS)


@dataclasses.dataclass(frozen=True, kw_only=True)
class LpvEnvelopeConfig:
    """Flight points: a training grid and held-out validation points, all below the Mach limit."""

    vcas_kt: tuple[float, float] = spec((100.0, 350.0), lo=VCAS_RANGE_KT[0], hi=VCAS_RANGE_KT[1])
    altitude_m: tuple[float, float] = spec((0.0, 12000.0), lo=ALTITUDE_RANGE_M[0], hi=ALTITUDE_RANGE_M[1])
    grid: tuple[int, int] = spec((6, 4), lo=2, hi=100, doc="training points: Vcas x altitude grid")
    validation_points: int = spec(8, lo=1, hi=10000, doc="validation points drawn in the envelope (Latin hypercube)")

    def check(self, path):
        for key in ("vcas_kt", "altitude_m"):
            lo, hi = getattr(self, key)
            if not lo < hi:
                raise ConfigError(f"{path}.{key}: range [{lo}, {hi}] is empty")

    def training_points(self, max_mach: float):
        """Training flight points (Vcas m/s, h m), two flat arrays."""
        from mcfdd.analysis import lpv_fit

        return lpv_fit.envelope_grid(np.linspace(*self.vcas_kt, self.grid[0]) * atmosphere.KT_TO_M_S,
                                     np.linspace(*self.altitude_m, self.grid[1]), max_mach)

    def validation_flight_points(self, max_mach: float, seed: int):
        """Held-out flight points (Vcas m/s, h m), drawn with ``seed``."""
        axes = [space.Axis("vcas_kt", "range", lo=self.vcas_kt[0], hi=self.vcas_kt[1]),
                space.Axis("altitude_m", "range", lo=self.altitude_m[0], hi=self.altitude_m[1])]
        cols, _ = space.design_table(axes, self.validation_points, "lhs", seed, max_mach=max_mach)
        return cols["vcas_kt"] * atmosphere.KT_TO_M_S, cols["altitude_m"]


@dataclasses.dataclass(frozen=True, kw_only=True)
class LpvRunsConfig:
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


@dataclasses.dataclass(frozen=True, kw_only=True)
class LpvOptimiserConfig:
    """Adam on the output error, step decaying exponentially over the iterations."""

    iterations: int = spec(100, lo=1, hi=100000)
    learning_rate: float = spec(0.1, lo=0.0, lo_open=True, hi=100.0, doc="first step size (1/s)")
    final_learning_rate: float = spec(0.005, lo=0.0, lo_open=True, hi=100.0, doc="last step size (1/s)")


_OPEN_LOOP_KINDS = tuple(k for k in manoeuvres.KINDS if k.startswith("ol_"))


@dataclasses.dataclass(frozen=True, kw_only=True)
class LpvFitConfig:
    """``mcfdd fit-lpv``: LPV gain models fitted by output error to the nonlinear actuator."""

    seed: int = spec(0, lo=0, doc="draws the validation flight points")
    precision: str = spec("float64", choices=("float32", "float64"))
    exact_disconnection: bool = spec(False, doc="models with nu2 = 0 take the exact gain of eq. (36), unfitted")
    plant: PlantConfig = spec(PlantConfig())
    models: tuple[LpvModelConfig, ...] = spec(PAPER_LPV_MODELS)
    envelope: LpvEnvelopeConfig = spec(LpvEnvelopeConfig())
    runs: LpvRunsConfig = spec(LpvRunsConfig())
    optimiser: LpvOptimiserConfig = spec(LpvOptimiserConfig())
    training: tuple[ManoeuvreConfig, ...] = spec()
    validation: tuple[ManoeuvreConfig, ...] = spec()

    def check(self, path):
        if not self.models:
            raise ConfigError("models: at least one [[models]] table is required")
        names = [m.name for m in self.models]
        for i, name in enumerate(names):
            if names.index(name) != i:
                raise ConfigError(f"models[{i}].name: {name!r} is used by models[{names.index(name)}] already")
        for key in ("training", "validation"):
            runs = getattr(self, key)
            if not runs:
                raise ConfigError(f"{key}: at least one [[{key}]] manoeuvre is required")
            for i, m in enumerate(runs):
                if m.kind not in _OPEN_LOOP_KINDS:
                    raise ConfigError(f"{key}[{i}].kind: {m.kind!r} is not an open-loop command; expected one of "
                                      f"{', '.join(_OPEN_LOOP_KINDS)}")
                if m.amplitude == 0.0:
                    raise ConfigError(f"{key}[{i}].amplitude: must not be 0 (errors are relative to the amplitude)")
                end = m.t_start_s + (2.0 if m.kind == "ol_doublet" else 1.0) * m.duration_s
                if end > self.runs.duration_s:
                    raise ConfigError(f"{key}[{i}]: ends at {end} s, after runs.duration_s = {self.runs.duration_s}")
        if self.optimiser.final_learning_rate > self.optimiser.learning_rate:
            raise ConfigError("optimiser.final_learning_rate: must not exceed optimiser.learning_rate")
        v, _ = self.envelope.training_points(self.plant.aircraft.max_mach)
        if len(v) < 3:
            raise ConfigError(f"envelope: only {len(v)} training grid point(s) are below the Mach limit "
                              f"plant.aircraft.max_mach = {self.plant.aircraft.max_mach}; at least 3 are needed")

    def nus(self) -> np.ndarray:
        """Fault parameters (N, 2) of the models."""
        return np.array([(m.nu1, m.nu2) for m in self.models])

    def manoeuvres(self, split: str) -> list[ManoeuvreConfig]:
        """Manoeuvres of ``split`` ('training' or 'validation'), mirrored if runs.both_directions."""
        listed = list(getattr(self, split))
        if self.runs.both_directions:
            listed += [dataclasses.replace(m, amplitude=-m.amplitude) for m in listed]
        return listed

    def manoeuvre_params(self, split: str, dtype=np.float64) -> manoeuvres.ManoeuvreParams:
        """The manoeuvres of :meth:`manoeuvres` as one pytree with a leading axis, SI units."""
        listed = self.manoeuvres(split)
        cols = {"manoeuvre_kind": np.array([m.kind for m in listed])}
        for field in dataclasses.fields(ManoeuvreConfig):
            if field.name != "kind":
                cols[field.name] = np.array([getattr(m, field.name) for m in listed])
        return space.to_scenario(cols, dtype).manoeuvre


# --------------------------------------------------------------------------------------------
# Worst-case search and tuning of the detection bounds (``mcfdd worst-case``, ``mcfdd tune``)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SearchSettings:
    """Multi-start projected gradient search of one detection bound, eqs. (26)-(27)."""

    detector: str = spec("stall", choices=("stall", "loe"))
    bound: str = spec("free", choices=("free", "detect"),
                      doc="free: tau_f of eq. (26), maximised over fault-free runs; detect: tau_d of eq. (27), minimised")
    screening: int = spec(64, lo=1, hi=100_000, doc="Sobol points screened; the worst ones start the gradient search")
    starts: int = spec(4, lo=1, hi=10_000)
    iterations: int = spec(20, lo=1, hi=10_000, doc="gradient steps per start")
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=1.0, doc="Adam step in the unit cube")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum over time, in log units of the statistic (0.05: about 5 %)")


def _fault_kinds(space_cfg: SpaceConfig) -> tuple[str, ...]:
    axis = space_cfg.axis("fault_kind")
    return axis.values if axis else (space.DEFAULTS["fault_kind"],)


def _check_as_campaign(cfg: CampaignConfig, section: str):
    """Scenario-space checks of a campaign, with errors naming ``section`` instead of ``campaign``."""
    try:
        cfg.check("")
    except ConfigError as err:
        raise ConfigError(str(err).replace("campaign.", f"{section}.", 1)) from None


@dataclasses.dataclass(frozen=True, kw_only=True)
class WorstCaseConfig:
    """``mcfdd worst-case``: tau_f or tau_d of one detector by gradient search, against Monte Carlo."""

    simulation: SimulationConfig = spec(SimulationConfig(), doc="horizon, sample time and precision of every run; "
                                                                "seed draws the screening (Monte Carlo: seed + 1)")
    search: SearchSettings = spec(SearchSettings())
    evaluation: EvaluationConfig = spec(EvaluationConfig())
    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def check(self, path):
        s = self.search
        if s.starts > s.screening:
            raise ConfigError(f"search.starts: {s.starts} exceeds search.screening = {s.screening}")
        if not any(a.kind == "range" for a in self.space.axes):
            raise ConfigError("space: no continuous axis ([lo, hi]) to search")
        kinds = _fault_kinds(self.space)
        if s.bound == "free" and set(kinds) != {"none"}:
            raise ConfigError(f"space.fault_kind: {list(kinds)}; the false-alarm bound (search.bound = 'free') is taken "
                              f"over fault-free runs, so fault_kind must be \"none\"")
        if (s.detector, s.bound) == ("loe", "detect") and not set(kinds) <= set(space.PARAMETRIC):
            raise ConfigError(f"space.fault_kind: {list(kinds)}; the LOE detection bound needs parametric faults, one "
                              f"of {', '.join(space.PARAMETRIC)}")
        _check_as_campaign(CampaignConfig(evaluation=self.evaluation, plant=self.plant, fdd=self.fdd, space=self.space),
                           "search")

    def search_space(self):
        """The space split for the search (:class:`mcfdd.analysis.worst_case.SearchSpace`)."""
        from mcfdd.analysis import worst_case

        return worst_case.SearchSpace.from_axes(self.space.axes, self.plant.aircraft.max_mach, _SIZE_COLUMNS)


@dataclasses.dataclass(frozen=True, kw_only=True)
class TuneSettings:
    """Gradient tuning of one detector's evaluator (and pole) for the largest detection gap."""

    detector: str = spec("stall", choices=("stall", "loe"))
    iterations: int = spec(60, lo=1, hi=100_000)
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0, doc="Adam step on the parameters' logarithms")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum/minimum over time and runs, in log units of the statistic")
    margin: float = spec(0.2, lo=0.0, hi=1.0, doc="tau = tau_f + margin (tau_d - tau_f); small: fast detection")
    threshold_candidates: int = spec(32, lo=2, hi=1000,
                                     doc="thresholds compared on the training set when the gap stays negative")
    tune_pole: bool = spec(True, doc="tune the filter pole a besides alpha, beta, gamma")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TuneConfig:
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

    def check(self, path):
        if self.validation.seed == self.training.seed:
            raise ConfigError(f"validation.seed: {self.validation.seed} equals training.seed; the held-out campaign "
                              f"needs its own seed")
        if self.validation.precision != self.training.precision:
            raise ConfigError(f"validation.precision: {self.validation.precision!r} differs from training.precision "
                              f"{self.training.precision!r}")
        if self.plant.aircraft.model != "roll_axis":
            raise ConfigError(f"plant.aircraft.model: {self.plant.aircraft.model!r}; mcfdd tune replays stored "
                              f"histories at each run's initial flight point, so it supports \"roll_axis\" only")
        for split in ("training", "validation"):
            _check_as_campaign(self.campaign(split), split)

    def campaign(self, split: str, fdd: FddConfig | None = None) -> CampaignConfig:
        """The 'training' or 'validation' campaign, optionally with other FDD settings."""
        return CampaignConfig(campaign=getattr(self, split), evaluation=self.evaluation, plant=self.plant,
                              fdd=fdd or self.fdd, space=self.space)


def to_toml(data: dict) -> str:
    """TOML text of nested tables of numbers, strings, booleans and lists (sub-tables after keys)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")

    def table(name, d, lines):
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict) and v is not None}
        if name:
            lines.append(f"[{name}]")
        lines.extend(f"{k} = {value(v)}" for k, v in scalars.items())
        for k, v in d.items():
            if isinstance(v, dict):
                lines.append("")
                table(f"{name}.{k}" if name else k, v, lines)

    lines: list[str] = []
    table("", data, lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def fdd_fragment(fdd: FddConfig, comment: str = "") -> str:
    """A config fragment holding only an [fdd] table (``mcfdd campaign --fdd FILE``)."""
    header = "".join(f"# {line}\n" for line in comment.splitlines())
    return header + to_toml({"fdd": to_dict(fdd)})


def load_fdd_fragment(path) -> FddConfig:
    """The [fdd] table of a fragment file, parsed like a config's; errors name the file and key."""
    data = load_toml(path)
    try:
        extra = sorted(set(data) - {"fdd"})
        if extra:
            raise ConfigError(f"{extra[0]}: unknown key; an FDD fragment holds only an [fdd] table")
        if "fdd" not in data:
            raise ConfigError("fdd: missing required key")
        return _convert(FddConfig, data["fdd"], "fdd", _NO_META)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None

"""Plant sections: the actuator, the hinge load, the aircraft and its roll law (DESIGN.md section 3).

Keys carry their unit in the name; :mod:`mcfdd.analysis.build` turns them into SI parameters.
"""

from __future__ import annotations

from mcfdd.config.base import Invalid, Section, choice, spec
from mcfdd.plant import atmosphere
from mcfdd.plant.choices import FULL_AIRCRAFT


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
    model: choice(AIRCRAFT_MODELS) = spec("roll_axis", doc="roll_axis: the fast roll axis at a fixed flight "
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
            if kind in FULL_AIRCRAFT:
                raise Invalid(key, f"{kind!r} needs the full aircraft; set plant.aircraft.model = \"rcam\"")

    def check_flight_point(self, vcas_kt: float, altitude_m: float, key: str):
        """Refuse a flight point above the Mach limit (raises :class:`Invalid` at ``key``)."""
        m = float(atmosphere.mach(vcas_kt * atmosphere.KT_TO_M_S, altitude_m))
        if m > self.aircraft.max_mach:
            raise Invalid(key, f"{vcas_kt} kt at {altitude_m} m is Mach {m:.3f}, above the limit "
                               f"plant.aircraft.max_mach = {self.aircraft.max_mach}")

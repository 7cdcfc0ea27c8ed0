"""``mcfdd fit-lpv``: LPV gain models (eqs. 3-4) fitted by output error to the nonlinear actuator."""

from __future__ import annotations

import numpy as np

from mcfdd import columns
from mcfdd.config.base import SEED_MAX, Invalid, Section, bounded, choice, spec
from mcfdd.config.kinds import PRECISIONS, check_unique
from mcfdd.config.plant import PlantConfig
from mcfdd.config.scenario import ManoeuvreConfig
from mcfdd.plant import atmosphere
from mcfdd.plant.choices import OPEN_LOOP_KINDS


class LpvModelConfig(Section):
    """One fault model nu = (nu1, nu2) of the bank."""

    name: str = spec()
    nu1: float = spec(1.0, lo=0.0, lo_open=True, hi=1.0, doc="available-pressure share (leakage: nu1 < 1)")
    nu2: float = spec(1.0, lo=0.0, hi=1.0, doc="hinge-load share (surface damage: nu2 < 1, disconnection: 0)")


# Section 6.1: fault-free, 100 / 67 / 34 % loss of surface effectiveness, 15 / 27 % pressure loss.
PAPER_LPV_MODELS = tuple(LpvModelConfig(name=name, nu1=nu1, nu2=nu2) for name, nu1, nu2 in (
    ("fault-free", 1.0, 1.0), ("surface-loss-100", 1.0, 0.0), ("surface-loss-67", 1.0, 0.33),
    ("surface-loss-34", 1.0, 0.66), ("pressure-loss-15", 0.85, 1.0), ("pressure-loss-27", 0.73, 1.0)))
_VCAS = bounded(*columns.VCAS_RANGE_KT)
_ALTITUDE = bounded(*columns.ALTITUDE_RANGE_M)
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


class LpvFitConfig(Section):
    """``mcfdd fit-lpv``: LPV gain models fitted by output error to the nonlinear actuator."""

    seed: int = spec(0, lo=0, hi=SEED_MAX, doc="draws the validation flight points")
    precision: choice(PRECISIONS) = spec("float64")
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
        check_unique([m.name for m in self.models], "models")
        for key in ("training", "validation"):
            runs = getattr(self, key)
            if not runs:
                raise Invalid(key, f"at least one [[{key}]] manoeuvre is required")
            for i, m in enumerate(runs):
                if m.kind not in OPEN_LOOP_KINDS:
                    raise Invalid(f"{key}[{i}].kind", f"{m.kind!r} is not an open-loop command; expected one of "
                                                      f"{', '.join(OPEN_LOOP_KINDS)}")
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

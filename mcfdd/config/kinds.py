"""The configuration kinds of the simulating commands, composed of shared sections.

Every kind that simulates has ``[plant]`` and ``[fdd]`` (:class:`Simulated`); the kinds that score
runs over a scenario space add ``[evaluation]`` and ``[space]`` and share the space's rules
(:class:`Scored`); the horizon, sample time, sub-steps, seed and precision of runs are one section
(:class:`SimulationConfig`), which a campaign's settings extend.

Over 400 lines: one class per kind with the checks that span its sections, kept together so that a
kind's keys and rules are read in one place.
"""

from __future__ import annotations

import math

from mcfdd import columns
from mcfdd.config.base import SEED_MAX, Invalid, Section, choice, spec
from mcfdd.config.fdd import FddConfig
from mcfdd.config.plant import PlantConfig
from mcfdd.config.scenario import RunConfig, SpaceConfig

DESIGNS = ("grid", "random", "lhs", "sobol")
PRECISIONS = ("float32", "float64")
IDLE_MANOEUVRES = ("quiet", "level_flight")  # no manoeuvre starts: their t_start_s is not used


def _duration(default: float):
    return spec(default, lo=0.0, lo_open=True, hi=3600.0)


class SimulationConfig(Section):
    """How runs are simulated: horizon, sample time, sub-steps, seed and precision."""

    duration_s: float = _duration(30.0)
    dt_s: float = spec(0.01, lo=1e-4, hi=0.1)
    substeps: int = spec(2, lo=1, hi=64, doc="actuator sub-steps per sample in the linear range of the valve")
    seed: int = spec(0, lo=0, hi=SEED_MAX)
    precision: choice(PRECISIONS) = spec("float32")

    @property
    def n_steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))


class CampaignSettings(SimulationConfig):
    """A campaign's runs: how many, by which design, in chunks of how many."""

    scenarios: int = spec(1000, lo=1, hi=10_000_000, doc="total number of scenarios, split evenly over the grid "
                          "cells (a multiple of their number)")
    design: choice(DESIGNS) = spec("sobol")
    grid: tuple[str, ...] = spec((), doc="axes on a full grid, crossed with samples over the others")
    chunk_size: int = spec(1024, lo=1, hi=1_000_000)
    duration_s: float = _duration(60.0)


class EvaluationConfig(Section):
    """How runs are scored (DESIGN.md section 5)."""

    settle_s: float = spec(5.0, lo=0.0, doc="decisions before this are not scored")
    t_detec_s: float = spec(120.0, lo=0.0, lo_open=True, doc="required detection time after the fault onset")
    stall_grace_s: float = spec(0.5, lo=0.0, doc="eta = 1 this soon after a stall load is not a false alarm")
    stall_min_duration_s: float = spec(0.1, lo=0.0, doc="shorter stall intervals are not relevant events")
    stall_min_error_deg: float = spec(1.0, lo=0.0, doc="stall events whose tracking error stays below are not relevant")
    stall_window_s: float = spec(0.5, lo=0.0, lo_open=True, doc="required stall detection/identification time")


def check_unique(names, key):
    """Refuse a name used twice in the list at ``key``."""
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise Invalid(f"{key}[{i}].name", f"{name!r} is used by {key}[{names.index(name)}] already")


class Simulated(Section):
    """The plant and the FDD every simulating kind has."""

    plant: PlantConfig = spec(PlantConfig())
    fdd: FddConfig = spec(FddConfig())


class SimulateConfig(Simulated):
    """``mcfdd simulate``: a few named runs simulated in one batch, full time histories."""

    simulation: SimulationConfig = spec(SimulationConfig())
    runs: tuple[RunConfig, ...] = spec()

    def check(self):
        if not self.runs:
            raise Invalid("runs", "at least one [[runs]] table is required")
        check_unique([r.name for r in self.runs], "runs")
        end = self.simulation.duration_s
        for i, run in enumerate(self.runs):
            self.plant.check_flight_point(run.vcas_kt, run.altitude_m, f"runs[{i}]")
            self.plant.check_manoeuvres([run.manoeuvre.kind], f"runs[{i}].manoeuvre.kind")
            for starts, key, what, at in (
                    (run.manoeuvre.kind not in IDLE_MANOEUVRES, "manoeuvre.t_start_s", "manoeuvre",
                     run.manoeuvre.t_start_s),
                    (run.fault.kind != "none", "fault.onset_s", "fault onset", run.fault.onset_s)):
                if starts and at >= end:
                    raise Invalid(f"runs[{i}].{key}", f"the {what} at {at} s is at or after the end of the run "
                                                      f"({end} s, simulation.duration_s)")


class SweepConfig(Simulated):
    """``mcfdd figures`` Fig. 4: fault-size sweeps at one flight point and manoeuvre."""

    simulation: SimulationConfig = spec(SimulationConfig())
    run: RunConfig = spec(doc="flight point, manoeuvre and fault onset; the fault kind and size are swept")
    surface_points: int = spec(51, lo=2, hi=1001, doc="surface-effectiveness losses from 0 to 100 %")
    leakage_points: int = spec(31, lo=2, hi=1001, doc="pressure losses from 0 to max_leakage")
    max_leakage: float = spec(0.3, lo=0.0, lo_open=True, hi=0.95)

    def check(self):
        self.plant.check_flight_point(self.run.vcas_kt, self.run.altitude_m, "run")
        self.plant.check_manoeuvres([self.run.manoeuvre.kind], "run.manoeuvre.kind")


def grid_cells(space: SpaceConfig, settings: CampaignSettings) -> tuple[tuple[str, ...], int]:
    """Names of the gridded axes (every varying one with design 'grid') and the number of grid cells."""
    grid = settings.design == "grid"
    axes = [a for a in space.axes if a.kind != "const" and (grid or a.name in settings.grid)]
    return tuple(a.name for a in axes), math.prod(a.points for a in axes)


class Scored(Simulated):
    """The kinds whose runs are scored over a scenario space."""

    evaluation: EvaluationConfig = spec(EvaluationConfig())
    space: SpaceConfig = spec(SpaceConfig())

    def values(self, column: str) -> tuple:
        """The values the space gives a named column (its default when the space leaves it)."""
        axis = self.space.axis(column)
        return axis.values if axis else (columns.COLUMN[column].default,)

    def extent(self, column: str) -> tuple:
        """(smallest, largest) value the space gives a number column."""
        axis = self.space.axis(column)
        return axis.extent if axis else (columns.COLUMN[column].default,) * 2

    def check_space(self, settings: CampaignSettings, section: str):
        """The space's rules for runs of ``settings``; errors on its keys name them below ``section``."""
        for i, name in enumerate(settings.grid):
            axis = self.space.axis(name)
            if axis is None or axis.kind == "const":
                raise Invalid(f"{section}.grid[{i}]", f"{name!r} is not a varying axis of [space]")
        if not any(a.kind != "const" for a in self.space.axes):
            raise Invalid("space", "nothing varies (no range or list): every scenario would fly one flight point "
                                   "with one plant; give at least one axis a range [lo, hi] or a list")
        names, cells = grid_cells(self.space, settings)
        if settings.scenarios % cells:
            raise Invalid(f"{section}.scenarios", f"{settings.scenarios} is not a multiple of the {cells} grid cells "
                                                  f"of {' x '.join(names)}; each cell gets scenarios / {cells} samples")
        self._check_times(settings.duration_s)
        self.plant.check_flight_point(self.extent("vcas_kt")[0], self.extent("altitude_m")[1],
                                      "space: the lowest vcas_kt at the highest altitude_m")
        kinds = self.space.axis("manoeuvre_kind")
        self.plant.check_manoeuvres(kinds.values if kinds else (), "space.manoeuvre_kind")

    def _check_times(self, end: float):
        """Settling, fault onsets and manoeuvre starts must all lie within runs of ``end`` seconds."""
        if self.evaluation.settle_s >= end:
            raise Invalid("evaluation.settle_s", f"{self.evaluation.settle_s} s is not below the runs' duration "
                                                 f"({end} s); no decision would be scored")
        windows = (("fault_kind", ("none",), "fault_onset_s", "fault onsets"),
                   ("manoeuvre_kind", IDLE_MANOEUVRES, "t_start_s", "manoeuvres"))
        for kind, idle, column, what in windows:
            if set(self.values(kind)) <= set(idle):
                continue
            latest = self.extent(column)[1]
            if latest >= end:
                raise Invalid(f"space.{column}", f"{what} up to {latest} s start at or after the end of the runs "
                                                 f"({end} s)")


class SensitivityConfig(Section):
    """What drives a campaign's verdicts (``mcfdd sensitivity``; its bootstrap and seed also serve the regional
    section of every campaign's summary.md)."""

    outcomes: tuple[str, ...] = spec((), doc="continuous outcomes analysed, e.g. [\"loe_ratio0_max_pre\"]; empty: each "
                                     "of mcfdd.workflows.sensitivity.study.DEFAULT_OUTCOMES the space has runs for")
    method: choice(("pick_freeze", "screen")) = spec(
        "pick_freeze", doc="pick_freeze: variance-based indices (samples x (factors + 2) runs per stratum) and the "
        "gradient screen; screen: the gradient screen (DGSM) alone (samples runs and gradients per stratum)")
    samples: int = spec(256, lo=8, hi=65536, doc="base samples N per stratum, a power of 2")
    bootstrap: int = spec(1000, lo=100, hi=100_000, doc="bootstrap resamples of every interval")
    confidence: float = spec(0.95, lo=0.5, hi=0.999, doc="level of every interval")
    seed: int | None = spec(None, lo=0, hi=SEED_MAX, doc="design, noise paths and bootstraps; default campaign.seed")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0, doc="smooth maximum over time of the gradient "
                              "screen, in log units of the statistic (as in worst-case)")

    def check(self):
        if self.samples & (self.samples - 1):
            raise Invalid("samples", f"{self.samples} is not a power of 2 (Sobol' points are balanced in powers of 2)")


# Fraction of flight time at each turbulence level: MIL-F-8785C section 3.7.2.1 (and MIL-HDBK-1797),
# probability of exceedance of the light, moderate and severe intensities at low altitude (below
# 1,000 ft AGL): 1e-2, 1e-3 and 1e-5; a level's share is the difference of the exceedances.
TURBULENCE_EXPOSURE = {"none": 0.99, "light": 9e-3, "moderate": 9.9e-4, "severe": 1e-5}
EVENTS = ("false_alarm", "missed_detection", "stall_false_detection", "false_stall_identification_signal",
          "false_stall_identification_model")
ESTIMATORS = ("subset", "importance", "mc")
STARTS = ("screening", "subset")  # where importance sampling's design-point searches start


class ExposureConfig(Section):
    """Fraction of flight time per value of a categorical axis (``mcfdd probability``, per flight hour).

    A stratum's weight is the product of its values' fractions over the axes, normalised over the
    strata of the space (independent axes assumed); a value a table leaves out, and an axis without
    a table, take equal shares of what the table leaves.
    """

    turbulence: dict[str, float] = spec(TURBULENCE_EXPOSURE, doc="fraction of flight time per turbulence level; "
                                        "default from MIL-F-8785C 3.7.2.1 (probability of exceedance of light, "
                                        "moderate and severe turbulence at low altitude: 1e-2, 1e-3, 1e-5)")
    manoeuvre_kind: dict[str, float] = spec({}, doc="fraction of flight time per manoeuvre family; default: "
                                            "equal shares (no public source: set it from flight data)")

    def check(self):
        for key, names in (("turbulence", columns.COLUMN["turbulence"].choices),
                           ("manoeuvre_kind", columns.COLUMN["manoeuvre_kind"].choices)):
            for name, value in getattr(self, key).items():
                if name not in names:
                    raise Invalid(f"{key}.{name}", f"not a {key} name; expected one of {', '.join(names)}")
                if not 0.0 <= value <= 1.0:
                    raise Invalid(f"{key}.{name}", f"{value!r} is not a fraction of flight time in [0, 1]")


AIRFRAME_VIEWS = ("corner", "quantile", "none")


class AirframeConfig(Section):
    """The per-airframe view of ``mcfdd probability``: P(event | the parameters an aircraft keeps for life)."""

    axes: tuple[str, ...] = spec(("kci_scale", "kd_scale", "supply_pressure_scale"),
                           doc="range axes fixed per aircraft (those the space varies are used)")
    view: choice(AIRFRAME_VIEWS) = spec("corner", doc="corner: at each of the 2^k corners, the worst reported; "
                                        "quantile: at 'points' airframes drawn from the ranges, the 'quantile' "
                                        "reported; none: not estimated")
    corner: float = spec(0.99, lo=0.5, lo_open=True, hi=0.99999, doc="the corners put each axis at its (1 - corner) "
                         "and corner quantiles of its range")
    quantile: float = spec(0.9, lo=0.0, lo_open=True, hi=1.0, doc="the quantile over airframes reported (view "
                           "quantile)")
    points: int = spec(32, lo=2, hi=10_000, doc="airframes drawn (view quantile)")

    def check(self):
        for name in self.axes:
            if name not in columns.COLUMN:
                raise Invalid(f"axes.{name}", "not a scenario column")


class ProbabilitySettings(Section):
    """How rare an event is (``mcfdd probability``): its per-run probability per stratum and per flight hour."""

    event: choice(EVENTS) = spec("false_alarm", doc="false_alarm and the stall ones over fault-free runs; "
                                 "missed_detection per parametric fault kind over the runs that must be detected")
    method: choice(ESTIMATORS) = spec("subset", doc="subset simulation, importance sampling around design points, "
                                      "or plain Monte Carlo")
    target_cov: float = spec(0.3, lo=0.0, lo_open=True, hi=10.0, doc="repeat independent estimator runs per stratum "
                             "until their pooled coefficient of variation is below this (or the budget is spent)")
    repeats: int = spec(4, lo=1, hi=10_000, doc="independent estimator runs per stratum at least; from 3 on, the "
                        "stated c.o.v. is never below the one the spread of their ln p_hat gives")
    budget: int = spec(100_000, lo=1, hi=10**10, doc="simulations over all strata at most (after the first 'repeats' "
                       "runs of each stratum)")
    samples: int = spec(1000, lo=10, hi=10**7, doc="subset: samples per level; importance: samples; mc: runs of one "
                        "estimator run")
    p0: float = spec(0.1, lo=0.0, lo_open=True, hi=0.5, doc="subset: conditional probability of a level")
    max_levels: int = spec(12, lo=1, hi=50, doc="subset: intermediate levels at most")
    starts_from: choice(STARTS) = spec("screening", doc="importance: the design-point searches start from the runs "
                                       "of largest margin among `screening` standard-normal draws, or from the "
                                       "failure points of a subset simulation run of `start_samples` samples per "
                                       "level (its simulations counted)")
    starts: int = spec(8, lo=1, hi=10_000, doc="importance: design-point searches at once (damped HLRF with "
                       "gradients through the simulation), one start each")
    screening: int = spec(256, lo=1, hi=10**6, doc="importance, starts_from 'screening': draws screened for starts")
    start_samples: int = spec(500, lo=10, hi=10**6, doc="importance, starts_from 'subset': samples per level of "
                              "the subset simulation run whose failure points start the searches")
    iterations: int = spec(20, lo=1, hi=10_000, doc="importance: damped HLRF iterations per start")
    spread: float = spec(1.0, lo=0.0, lo_open=True, hi=10.0, doc="importance: standard deviation of each mixture "
                         "component along its design direction (1: unit covariance; above 1: widened, tempered)")
    chunk: int = spec(250, lo=1, hi=10**6, doc="runs simulated at once (memory, not results)")
    keep: int = spec(16, lo=1, hi=10_000, doc="failure points kept per stratum")
    confidence: float = spec(0.95, lo=0.5, hi=0.999)
    seed: int | None = spec(None, lo=0, hi=SEED_MAX, doc="estimator keys; default campaign.seed")
    exposure: ExposureConfig = spec(ExposureConfig())
    airframe: AirframeConfig = spec(AirframeConfig())

    def check(self):
        if self.method == "importance" and self.starts_from == "screening" and self.starts > self.screening:
            raise Invalid("starts", f"{self.starts} starts are more than the {self.screening} draws screened for them "
                          "(screening)")


class CampaignConfig(Scored):
    """``mcfdd campaign``: a scenario space sampled, simulated in chunks and scored."""

    campaign: CampaignSettings = spec(CampaignSettings())
    sensitivity: SensitivityConfig = spec(SensitivityConfig())
    probability: ProbabilitySettings = spec(ProbabilitySettings())

    def check(self):
        self.check_space(self.campaign, "campaign")

    def grid_cells(self) -> tuple[tuple[str, ...], int]:
        """Names of the gridded axes (every varying one with design 'grid') and the number of grid cells."""
        return grid_cells(self.space, self.campaign)


class SearchSettings(Section):
    """Multi-start projected gradient search of one detection bound, eqs. (26)-(27)."""

    detector: choice(("stall", "loe", "loe_detection")) = spec(
        "stall", doc="stall: the stall detector's theta; loe: the LOE bank's ratios theta_i / ||u|| "
        "(identification); loe_detection: the LOE detection level's signed statistic (its sign is the verdict)")
    bound: choice(("free", "detect")) = spec(
        "free", doc="free: tau_f of eq. (26), maximised over fault-free runs; detect: tau_d of eq. (27), minimised")
    screening: int = spec(64, lo=1, hi=100_000, doc="Sobol points screened; the worst ones start the gradient search")
    starts: int = spec(4, lo=1, hi=10_000)
    iterations: int = spec(20, lo=1, hi=10_000, doc="gradient steps per start")
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=1.0, doc="Adam step in the unit cube")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum over time, in log units of the statistic (0.05: about 5 %); "
                                  "for loe_detection in the statistic's units (theta_0 / ||u||)")
    min_load_fraction: float = spec(0.0, lo=0.0, hi=1.0, doc="only runs whose peak hinge-load fraction "
                                    "(peak_load_fraction) reaches this count (detect: the faults an FDD must see)")
    pool: int = spec(0, lo=0, hi=100_000, doc="screened runs with the bound's event (a relevant stall load, a "
                     "run that must be detected) wanted as starts and their replacements: while fewer have it, the "
                     "Sobol sequence is screened on in batches of `screening` points, up to `screening_max` (0: one "
                     "batch)")
    screening_max: int = spec(0, lo=0, hi=1_000_000, doc="most points screened when refilling to `pool` (0: "
                              "`screening`, no refill)")
    patience: int = spec(1, lo=1, hi=10_000, doc="infeasible evaluations in a row (the run lost the event) after "
                         "which a start is replaced by the pool's next point; before, it backtracks with half steps")
    final_temperature: float = spec(0.0, lo=0.0, hi=10.0, doc="temperature at the last gradient evaluation: a "
                                    "geometric schedule from `temperature` (0: constant `temperature`)")


class WorstCaseConfig(Scored):
    """``mcfdd worst-case``: tau_f or tau_d of one detector by gradient search, against Monte Carlo."""

    simulation: SimulationConfig = spec(SimulationConfig(), doc="horizon, sample time and precision of every run; "
                                                                "seed draws the screening (Monte Carlo: seed + 1)")
    search: SearchSettings = spec(SearchSettings())

    def check(self):
        s = self.search
        if s.starts > s.screening:
            raise Invalid("search.starts", f"{s.starts} exceeds search.screening = {s.screening}")
        if 0 < s.screening_max < s.screening:
            raise Invalid("search.screening_max", f"{s.screening_max} is below search.screening = {s.screening}")
        if not any(a.kind == "range" for a in self.space.axes):
            raise Invalid("space", "no continuous axis ([lo, hi]) to search")
        kinds = self.values("fault_kind")
        if s.bound == "free" and set(kinds) != {"none"}:
            raise Invalid("space.fault_kind", f"{list(kinds)}; the false-alarm bound (search.bound = 'free') is "
                                              f"taken over fault-free runs, so fault_kind must be \"none\"")
        if s.detector != "stall" and s.bound == "detect" and not set(kinds) <= set(columns.PARAMETRIC):
            raise Invalid("space.fault_kind", f"{list(kinds)}; the LOE detection bound needs parametric faults, "
                                              f"one of {', '.join(columns.PARAMETRIC)}")
        self.check_space(CampaignSettings(duration_s=self.simulation.duration_s), "search")


class TuneSettings(Section):
    """Gradient tuning of one detector's evaluator (and pole) for the largest detection gap."""

    detector: choice(("stall", "loe")) = spec("stall")
    iterations: int = spec(60, lo=1, hi=100_000)
    learning_rate: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0, doc="Adam step on the parameters' logarithms")
    temperature: float = spec(0.05, lo=0.0, lo_open=True, hi=10.0,
                              doc="smooth maximum/minimum over time and runs, in log units of the statistic")
    margin: float = spec(0.2, lo=0.0, hi=1.0, doc="tau = tau_f + margin (tau_d - tau_f); small: fast detection")
    threshold_candidates: int = spec(32, lo=2, hi=1000,
                                     doc="thresholds compared on the training set when the gap stays negative")
    tune_pole: bool = spec(True, doc="tune the filter pole a besides alpha, beta, gamma")
    level: choice(("identification", "detection")) = spec(
        "identification", doc="LOE bank: identification tunes the evaluator and pole for the signature's gap and "
        "places tau; detection tunes the detection level (detection_tau, detection_contrast, excitation floor and "
        "noise factor, evaluator, pole) on the detection monitor's margins")
    must_detect: choice(("separable", "all")) = spec(
        "separable", doc="detection level: tau_d over the faulty runs that must be detected and are separable "
        "(the fault's gain distance at the peak load above the uncertainty's), or over all of them")
    must_detect_kinds: tuple[choice(columns.PARAMETRIC), ...] = spec(
        (), doc="detection level: tau_d only over these fault kinds (empty: every parametric kind)")
    min_peak_load_fraction: float = spec(0.0, lo=0.0, hi=1.0, doc="detection level: tau_d only over runs whose "
                                         "peak hinge-load fraction after the onset is at least this")
    tune_confirmation: bool = spec(False, doc="detection level: tune detection_confirm_s too")
    scan_scales: tuple[float, float] = spec((0.5, 2.5), doc="detection level: the detection thresholds are "
                                            "scaled by threshold_candidates factors spaced geometrically over "
                                            "this range, each scored on the training set")
    safety: float = spec(1.1, lo=1.0, hi=10.0, doc="detection level: the chosen factor is the smallest from "
                         "which no candidate alarms on the training set, times this")
    max_missed_fraction: float | None = spec(
        None, lo=0.0, hi=1.0, doc="detection level: a miss limit; when set, the chosen factor is the scanned "
        "candidate with the fewest training false alarms among those that miss at most this fraction of the "
        "must-detect runs (ties to the faster median detection), or the fewest missed if none does; safety is "
        "then not applied")


class TuneConfig(Scored):
    """``mcfdd tune``: evaluator tuning on a training campaign, checked on a held-out one.

    Both campaigns draw from the same [space] with their own settings; they must differ in seed.
    """

    tune: TuneSettings = spec(TuneSettings())
    training: CampaignSettings = spec(CampaignSettings(scenarios=256, duration_s=20.0))
    validation: CampaignSettings = spec(CampaignSettings(scenarios=256, seed=1, duration_s=40.0))

    def check(self):
        if self.validation.seed == self.training.seed:
            raise Invalid("validation.seed", f"{self.validation.seed} equals training.seed; the held-out campaign "
                                             f"needs its own seed")
        if self.validation.precision != self.training.precision:
            raise Invalid("validation.precision", f"{self.validation.precision!r} differs from training.precision "
                                                  f"{self.training.precision!r}")
        t = self.tune
        if t.level == "detection" and t.detector != "loe":
            raise Invalid("tune.level", f"'detection' is the LOE bank's level; tune.detector is {t.detector!r}")
        if t.max_missed_fraction is not None and t.level != "detection":
            raise Invalid("tune.max_missed_fraction", f"{t.max_missed_fraction}; a miss limit applies to tune.level "
                                                      f"= 'detection', not {t.level!r}")
        lo, hi = t.scan_scales
        if not 0.0 < lo < hi:
            raise Invalid("tune.scan_scales", f"{[lo, hi]}; expected 0 < low < high")
        for split in ("training", "validation"):
            self.check_space(getattr(self, split), split)

    def campaign(self, split: str, fdd: FddConfig | None = None) -> CampaignConfig:
        """The 'training' or 'validation' campaign, optionally with other FDD settings."""
        return CampaignConfig(campaign=getattr(self, split), evaluation=self.evaluation, plant=self.plant,
                              fdd=fdd or self.fdd, space=self.space)


class FddFragment(Section):
    """A file holding only an [fdd] table (``mcfdd campaign --fdd FILE``, written by ``mcfdd tune``)."""

    fdd: FddConfig = spec()

"""From parsed configuration (:mod:`mcfdd.config`) to the SI pytrees and tables the analysis runs on.

Configuration keys carry their unit in the name (kt, deg, mA, mm); everything built here is in
SI units (m/s, rad, A, m), and FDD thresholds and signal levels given in degrees of surface
deflection become rod positions through the lever arm r_arm.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mcfdd import columns, config
from mcfdd.analysis import batch, lpv_fit, metrics, scenarios, scoring, worst_case
from mcfdd.fdd import evaluator, lpv, stall, system
from mcfdd.plant import actuator, aircraft, atmosphere, closed_loop, control_law, hinge, manoeuvres


def _actuator_params(c: config.ActuatorConfig) -> actuator.ActuatorParams:
    return actuator.ActuatorParams(
        supply_pressure_pa=c.supply_pressure_pa,
        ref_pressure_pa=c.ref_pressure_pa or c.supply_pressure_pa,
        piston_area_m2=c.piston_area_m2,
        r_arm_m=c.r_arm_m,
        max_current_a=c.max_current_ma * 1e-3,
        kci_m_s_a=c.kci_mm_s_per_ma,
        kp_a_m=c.kp_ma_per_mm,
        kd_n_s2_m2=c.kd_n_s2_m2,
        max_deflection_rad=math.radians(c.max_deflection_deg),
    )


def _aircraft_params(c: config.AircraftConfig) -> aircraft.AircraftParams:
    return aircraft.AircraftParams(wing_area_m2=c.wing_area_m2, mean_chord_m=c.mean_chord_m, span_m=c.span_m,
                                   mass_kg=c.mass_kg, roll_inertia_kg_m2=c.roll_inertia_kg_m2,
                                   monitored_share=c.monitored_share)


def _roll_law_params(c: config.ControlLawConfig) -> control_law.RollLawParams:
    return control_law.RollLawParams(
        max_roll_rate_rad_s=math.radians(c.max_roll_rate_deg_s), bank_hold_rad=math.radians(c.bank_hold_deg),
        bank_protection_rad=math.radians(c.bank_protection_deg), time_constant_s=c.time_constant_s)


def _hinge_surface(c: config.HingeConfig) -> hinge.HingeSurface:
    return hinge.HingeSurface(c.area_m2, c.chord_m, c.ch0, c.ch_alpha_per_rad, c.ch_delta_per_rad)


def plant_model(plant_cfg: config.PlantConfig) -> closed_loop.PlantModel:
    """Plant constants and hinge table over the configurable flight envelope."""
    return closed_loop.build_model(
        _actuator_params(plant_cfg.actuator), _aircraft_params(plant_cfg.aircraft),
        _roll_law_params(plant_cfg.control_law), _hinge_surface(plant_cfg.hinge),
        vcas_range_m_s=tuple(v * atmosphere.KT_TO_M_S for v in columns.VCAS_RANGE_KT),
        altitude_range_m=columns.ALTITUDE_RANGE_M, aircraft_model=plant_cfg.aircraft.model)


def evaluator_params(c: config.EvaluatorConfig) -> evaluator.NarendraParams:
    return evaluator.NarendraParams(c.alpha, c.beta, c.gamma_1_s)


def fdd_params(fdd_cfg: config.FddConfig, bank: lpv.GainBank, r_arm_m: float) -> system.FddParams:
    """FDD parameters in rod units for an actuator with lever arm ``r_arm_m``."""
    deg = math.radians(1.0) * r_arm_m
    loe, stl = fdd_cfg.loe, fdd_cfg.stall
    return system.FddParams(
        loe=system.LoeParams(bank=bank, pole=loe.pole_1_s, direction_pole=loe.direction_pole_1_s,
                             evaluator=evaluator_params(loe.evaluator), tau=loe.tau,
                             tau_schedule=system.switch(loe.tau_schedule), detection_tau=loe.detection_tau,
                             detection_confirm_s=loe.detection_confirm_s, detection_contrast=loe.detection_contrast,
                             excitation_floor=loe.excitation_floor_deg * deg,
                             excitation_load_fraction=system.switch(loe.excitation_load_fraction),
                             excitation_noise_factor=system.switch(loe.excitation_noise_factor),
                             noise_gamma=loe.noise_gamma_1_s, confirm_s=loe.confirm_s,
                             max_load_fraction=None if loe.max_load_fraction >= 1.0 else loe.max_load_fraction,
                             load_scales=np.asarray(bank.nu)[:, 1] if loe.load_gate == "best_fit" else None,
                             linear_range_m=loe.linear_range_deg * deg, stall_hold_s=loe.stall_hold_s),
        stall=system.StallParams(
            pole=stl.pole_1_s, evaluator=evaluator_params(stl.evaluator), tau=stl.tau_deg * deg,
            signal=stall.SignalRules(stl.signal.rate_min_deg_s * deg, stl.signal.command_min_deg * deg,
                                     stl.signal.position_min_deg * deg, stl.signal.window_s,
                                     stl.signal.error_min_deg * deg),
            model=stall.ModelRule(stl.model.k_sl_1_s, stl.model.pole_1_s, evaluator_params(stl.model.evaluator),
                                  stl.model.tau_deg * deg),
            saturation=None if stl.saturation_rate_fraction == 0.0 else stall.SaturationGate(
                stl.saturation_error_deg * deg, stl.saturation_rate_fraction, stl.rate_pole_1_s),
            identification=identification_gate(stl, deg)),
    )


def identification_gate(stl: config.StallDetectionConfig, deg: float) -> stall.IdentificationGate | None:
    """The stall identification gate in rod units (``deg``: m of rod travel per degree); None when both of
    its keys are 0 (not built: the detector's iota opens identification)."""
    if stl.identification_tau_deg == 0.0 and stl.identification_residual_deg == 0.0:
        return None
    return stall.IdentificationGate((stl.identification_tau_deg or stl.tau_deg) * deg,
                                    stl.identification_residual_deg * deg or None)


def settings(eval_cfg: config.EvaluationConfig, r_arm_m: float) -> scoring.Settings:
    """Scoring settings of a campaign (the tracking-error floor in m of rod travel)."""
    return scoring.Settings(eval_cfg.settle_s, eval_cfg.t_detec_s, eval_cfg.stall_grace_s,
                             eval_cfg.stall_min_duration_s, math.radians(eval_cfg.stall_min_error_deg) * r_arm_m,
                             eval_cfg.stall_window_s)


def run_columns(run: config.RunConfig) -> dict:
    """The run as a row of a scenario table: each column from its run key (:attr:`mcfdd.columns.Column.owner`)."""
    sections = {"run": run, "fault": run.fault, "manoeuvre": run.manoeuvre}
    return {c.name: getattr(sections[c.owner[0]], c.owner[1]) for c in columns.TABLE}


def run_entry(row: dict, name: str, seed: int, index: int) -> dict:
    """A ``[[runs]]`` entry of a simulate config (plain values) from a scenario-table row: the inverse of
    :func:`run_columns` (columns the row lacks keep their defaults), with the run key (seed, index)."""
    entry = {"name": name, "seed": int(seed), "index": int(index), "fault": {}, "manoeuvre": {}}
    for c in columns.TABLE:
        if c.name in row:
            value = row[c.name]
            value = value.item() if isinstance(value, np.generic) else value
            (entry if c.owner[0] == "run" else entry[c.owner[0]])[c.owner[1]] = value
    return entry


def sweep_table(sweep: config.SweepConfig) -> tuple[dict, list[str], np.ndarray, np.ndarray]:
    """Scenario columns of both Fig. 4 sweeps, run names, family ('surface'/'leakage') and size per run."""
    surface = np.linspace(0.0, 1.0, sweep.surface_points)
    leakage = np.linspace(0.0, sweep.max_leakage, sweep.leakage_points)
    n = len(surface) + len(leakage)
    table = {k: np.full(n, v) for k, v in run_columns(sweep.run).items()}
    table["fault_kind"] = np.array(["surface_damage"] * len(surface) + ["leakage"] * len(leakage))
    table["fault_size"] = np.concatenate([surface, leakage])
    family = np.array(["surface"] * len(surface) + ["leakage"] * len(leakage))
    names = [f"{f}-{100 * v:.1f}pct" for f, v in zip(family, table["fault_size"])]
    return table, names, family, table["fault_size"]


def _samples(cfg: config.CampaignConfig) -> int:
    """Samples per grid cell: ``campaign.scenarios`` is the total over the cells."""
    return cfg.campaign.scenarios // cfg.grid_cells()[1]


def design(cfg: config.CampaignConfig) -> tuple[dict, int]:
    """Scenario columns of a campaign's design (dict of arrays) and their number of rows."""
    c = cfg.campaign
    cols, n = scenarios.design_table(list(cfg.space.axes), _samples(cfg), c.design, c.seed, c.grid,
                                     cfg.plant.aircraft.max_mach)
    return scenarios.merge_fault_sizes(cols), n


@dataclasses.dataclass(frozen=True)
class DesignPlan:
    """What the chunks of a campaign need of its whole design, computed once (small beside the design).

    Attributes:
        n: number of scenarios.
        rows: (n,) raw design row (:func:`mcfdd.analysis.scenarios.design_rows`) of each scenario
            id, or None when no row was dropped at the Mach limit (scenario id = raw row).
        whole: the Latin hypercube's unit sample (lhs designs only, else None).
        ranges: (lo, hi) of each uncertain scale over the whole design (detectability columns).
        kinds: manoeuvre family codes present in the campaign (static structure of its program).
        keys: (n,) index of each scenario's random key (``fold_in(seed, index)``), or None when it
            is the scenario id (a sensitivity design gives two runs the same noise path).
    """

    n: int
    rows: np.ndarray | None
    whole: np.ndarray | None
    ranges: dict
    kinds: tuple
    keys: np.ndarray | None = None

    def key_index(self, ids):
        """The random-key index of scenario ids (a run's key is ``fold_in(key(seed), index)``)."""
        return ids if self.keys is None else self.keys[ids]


def design_plan(cfg: config.CampaignConfig, whole: np.ndarray | None = None, keys=None) -> DesignPlan:
    """The :class:`DesignPlan` of a campaign (builds the whole design once, then keeps only the plan).

    Args:
        whole: an explicit unit sample of the sampled axes, (draws per grid cell, dim), instead of
            the config's design (the pick-freeze rows of :mod:`mcfdd.workflows.sensitivity`).
        keys: (raw rows,) random-key index of each raw design row; None: the scenario id.
    """
    c = cfg.campaign
    axes = list(cfg.space.axes)
    samples = _samples(cfg)
    cells, per_cell = scenarios.design_shape(axes, samples, c.design, c.grid)
    if whole is None:
        whole = scenarios.whole_sample(axes, samples, c.design, c.seed, c.grid)
    cols, keep = scenarios.design_rows(axes, samples, c.design, c.seed, np.arange(cells * per_cell), c.grid,
                                       cfg.plant.aircraft.max_mach, whole)
    cols = scenarios.merge_fault_sizes({k: np.asarray(v)[keep] for k, v in cols.items()})
    kinds = batch.kinds_in([manoeuvres.KIND_CODE[k] for k in np.unique(cols["manoeuvre_kind"])])
    return DesignPlan(int(keep.sum()), None if keep.all() else np.flatnonzero(keep), whole,
                      metrics.uncertainty_ranges(cols), kinds, None if keys is None else np.asarray(keys)[keep])


def design_chunk(cfg: config.CampaignConfig, plan: DesignPlan, ids) -> dict:
    """Scenario columns of the scenario ids ``ids`` (any order, repeats allowed), built from their indices.

    The same rows as ``design(cfg)[0]`` indexed by ``ids``, to the last bit, without the rest of
    the design.
    """
    c = cfg.campaign
    ids = np.asarray(ids, dtype=np.int64)
    cols, _ = scenarios.design_rows(list(cfg.space.axes), _samples(cfg), c.design, c.seed,
                                    ids if plan.rows is None else plan.rows[ids], c.grid, cfg.plant.aircraft.max_mach,
                                    plan.whole)
    return scenarios.merge_fault_sizes(cols)


def search_space(cfg: config.WorstCaseConfig) -> worst_case.SearchSpace:
    """The scenario space of a worst-case search, split into continuous and categorical axes."""
    return worst_case.SearchSpace.from_axes(cfg.space.axes, cfg.plant.aircraft.max_mach)


def lpv_training_points(envelope: config.LpvEnvelopeConfig, max_mach: float):
    """Training flight points (Vcas m/s, h m) of the LPV fit, two flat arrays."""
    return lpv_fit.envelope_grid(np.linspace(*envelope.vcas_kt, envelope.grid[0]) * atmosphere.KT_TO_M_S,
                                 np.linspace(*envelope.altitude_m, envelope.grid[1]), max_mach)


def lpv_validation_points(envelope: config.LpvEnvelopeConfig, max_mach: float, seed: int):
    """Held-out flight points (Vcas m/s, h m) of the LPV fit, drawn with ``seed``."""
    axes = [config.Axis("vcas_kt", "range", lo=envelope.vcas_kt[0], hi=envelope.vcas_kt[1]),
            config.Axis("altitude_m", "range", lo=envelope.altitude_m[0], hi=envelope.altitude_m[1])]
    cols, _ = scenarios.design_table(axes, envelope.validation_points, "lhs", seed, max_mach=max_mach)
    return cols["vcas_kt"] * atmosphere.KT_TO_M_S, cols["altitude_m"]


def lpv_nus(cfg: config.LpvFitConfig) -> np.ndarray:
    """Fault parameters (N, 2) of the models to fit."""
    return np.array([(m.nu1, m.nu2) for m in cfg.models])


def lpv_manoeuvre_params(cfg: config.LpvFitConfig, split: str, dtype=np.float64) -> manoeuvres.ManoeuvreParams:
    """The manoeuvres of ``cfg.manoeuvres(split)`` as one pytree with a leading axis, SI units."""
    listed = cfg.manoeuvres(split)
    cols = {c.name: np.array([getattr(m, c.owner[1]) for m in listed]) for c in columns.owned_by("manoeuvre")}
    return scenarios.to_scenario(cols, dtype).manoeuvre

"""The sensitivity study of a campaign: its design (factors, strata, pick-freeze runs) and its outcomes.

Factors are the campaign space's sampled axes (ranges: continuous; lists: categorical, a level
drawn from a unit coordinate as the campaign draws it) and the noise path :data:`NOISE` (the run's
random key: its turbulence and sensor-noise sequences, one group). Strata are ``fault_kind`` and
the gridded lists of the campaign: every stratum runs the same design, and an outcome is analysed
in the strata that have its runs (fault-free ones for the false-alarm margin, faulty ones for
detection). A range axis gridded by the campaign is a continuous factor here.

The pick-freeze design of :mod:`mcfdd.analysis.sensitivity` lies in the unit cube of the sampled
axes plus one noise coordinate. Its rows are run as a campaign (:func:`mcfdd.run_campaign` with an
explicit :class:`mcfdd.analysis.build.DesignPlan`: chunks, executors, Dask and resume, tables bit
for bit): run j of block b (A, B, A_B^(1), ...) in stratum c is raw design row c R + b N + j, with
R = N (factors + 2), and random key ``fold_in(seed, c 2N + j)``, or ``c 2N + N + j`` where its
noise coordinate is B's. Vcas's coordinate is its place in the speed range available at the
altitude (below the Mach limit), as in every campaign design.

Outcomes (:data:`OUTCOMES`) map a name to a scenario-table column, the strata it is analysed in,
and what a run where the column is undefined counts as (a number, another column, or nothing: the
base point is then left out); those with a smooth counterpart in :mod:`mcfdd.analysis.worst_case`
get the gradient screen (DGSM through the simulation, at the A points of each stratum). Binary
outcomes (:data:`EVENTS`) get the regional sensitivity, from the A and B runs here and from every
run in each campaign's summary.md (:mod:`mcfdd.workflows.sensitivity.tables`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from mcfdd import columns, config
from mcfdd.analysis import build, scenarios, sensitivity as sens

NOISE = "noise_path"  # the factor of a run's random numbers (turbulence and sensor noise), one group
# a campaign's largest number of scenarios (the range of campaign.scenarios)
MAX_RUNS = next(m.le for m in config.CampaignSettings.model_fields["scenarios"].metadata if hasattr(m, "le"))


class Outcome(NamedTuple):
    """A continuous outcome: its column, the strata it is analysed in ('fault_free', 'faulty' or 'all'),
    the value of a run where the column is undefined (a number, a column name, or None: the base point
    is left out), its smooth counterpart for the screen ((detector, bound) of :mod:`mcfdd.analysis.worst_case`)
    and what it is."""

    column: str
    strata: str
    undefined: float | str | None
    smooth: tuple | None
    what: str


OUTCOMES = {
    "loe_ratio0_max_pre": Outcome("loe_ratio0_max_pre", "fault_free", 0.0, ("loe", "free"),
                                  "largest fault-free LOE ratio theta_0/||u|| before any fault (false-alarm margin: "
                                  "alarms need it above detection_tau); 0 where never excited"),
    "loe_ratio0_max_post": Outcome("loe_ratio0_max_post", "faulty", 0.0, None,
                                   "largest fault-free ratio in the detection window (detection margin); 0 where "
                                   "never excited"),
    "detection_latency_s": Outcome("detection_latency_s", "faulty", "window_s", None,
                                   "detection latency after the onset (s); a miss counts as its whole window"),
    "loe_others_min_peak": Outcome("loe_others_min_peak", "faulty", 0.0, ("loe", "detect"),
                                   "identification margin: peak in the window of the smallest ratio among the "
                                   "filters that must fire"),
    "stall_theta_max_free": Outcome("stall_theta_max_free", "all", 0.0, ("stall", "free"),
                                    "stall detector's largest theta outside stall loads (eq. 26 margin, rod m)"),
    "stall_theta_peak_min": Outcome("stall_theta_peak_min", "all", None, ("stall", "detect"),
                                    "stall detector's smallest event peak (eq. 27 margin, rod m); runs with a "
                                    "relevant stall load"),
    "stall_worst_latency_signal_s": Outcome("stall_worst_latency_signal_s", "all", None, None,
                                            "worst stall-identification latency, signal rules (s); runs with "
                                            "identified stall loads"),
    "stall_worst_latency_model_s": Outcome("stall_worst_latency_model_s", "all", None, None,
                                           "worst stall-identification latency, model detection (s); runs with "
                                           "identified stall loads"),
}
DEFAULT_OUTCOMES = ("loe_ratio0_max_pre", "loe_ratio0_max_post", "detection_latency_s", "stall_worst_latency_signal_s")


class Event(NamedTuple):
    """A binary outcome: its column, the runs it can happen in (table -> mask) and what it is."""

    column: str
    runs: Callable
    what: str


def scored(t) -> np.ndarray:
    """Runs of a scenario table whose outcomes count (status OK)."""
    return t["status"].to_numpy() == 0


EVENTS = {
    "false_alarm": Event("false_alarm", lambda t: scored(t) & (t["fault_kind"].to_numpy() == "none"),
                         "LOE false alarms (fault-free runs)"),
    "missed": Event("missed", lambda t: scored(t) & t["fault_kind"].isin(columns.PARAMETRIC).to_numpy()
                    & (t["true_model"].to_numpy() > 0), "missed detections (runs with a parametric fault)"),
}


def applies(outcome: Outcome, fault_kind: str) -> bool:
    """Whether the outcome is analysed in a stratum of this fault kind."""
    return {"fault_free": fault_kind == "none", "faulty": fault_kind in columns.PARAMETRIC}.get(outcome.strata, True)


def acts(factor: str, fault_kind: str) -> bool:
    """False for the size column of another fault kind (it cannot act on the stratum's runs)."""
    return columns.SIZE_COLUMNS.get(factor, fault_kind) == fault_kind


@dataclasses.dataclass(frozen=True)
class Design:
    """A sensitivity design as a campaign.

    Attributes:
        config: the campaign of the design's runs (strata as grid, scenarios = strata x runs per stratum).
        plan: its explicit :class:`mcfdd.analysis.build.DesignPlan`.
        factors: the sampled axes in [space] order, then :data:`NOISE`.
        kinds: per factor 'continuous', 'categorical' or 'noise'.
        strata: the gridded axes (each combination of their values is a stratum).
        samples: base points N; blocks: runs per base point (factors + 2, or 1 for the screen alone).
        unit: (N blocks, factors) unit coordinates of a stratum's runs (the noise column is 1 where B's).
        seed: of the design, its random keys and the bootstraps.
    """

    config: config.CampaignConfig
    plan: build.DesignPlan
    factors: tuple
    kinds: tuple
    strata: tuple
    samples: int
    blocks: int
    unit: np.ndarray
    seed: int

    @property
    def per_stratum(self) -> int:
        return self.samples * self.blocks

    def locate(self, ids) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stratum, block, base point) of scenario ids of the design's runs."""
        raw = np.asarray(ids) if self.plan.rows is None else self.plan.rows[np.asarray(ids)]
        cell, draw = np.divmod(raw, self.per_stratum)
        block, base = np.divmod(draw, self.samples)
        return cell, block, base


def design(cfg: config.CampaignConfig) -> Design:
    """The pick-freeze (or screen) design of a campaign's [sensitivity] table over its space."""
    s, c = cfg.sensitivity, cfg.campaign
    seed = c.seed if s.seed is None else s.seed
    strata = tuple(a.name for a in cfg.space.axes if a.kind in ("choices", "values")
                   and (a.name == "fault_kind" or c.design == "grid" or a.name in c.grid))
    sampled = [a for a in cfg.space.axes if a.kind != "const" and a.name not in strata]
    if not any(a.kind == "range" for a in sampled):
        raise config.ConfigError("space: no continuous axis ([lo, hi]) to analyse; sensitivity needs at least one "
                                 "range")
    dim = len(sampled) + 1
    a, b = sens.saltelli_matrices(s.samples, dim, seed)
    unit, from_b = sens.pick_freeze(a, b) if s.method == "pick_freeze" else (a, np.zeros(a.shape, dtype=bool))
    per = len(unit)
    cells = math.prod(len(scenarios.grid_values(cfg.space.axis(n))) for n in strata)
    if cells * per > MAX_RUNS:
        raise config.ConfigError(f"sensitivity.samples: {s.samples} base samples give {cells * per} runs ({cells} "
                                 f"strata x {per}), more than {MAX_RUNS}; use fewer")
    derived = config.replace(cfg, {"campaign.design": "sobol", "campaign.grid": list(strata),
                                   "campaign.scenarios": cells * per, "campaign.seed": seed})
    raw = np.arange(cells * per)
    cell, draw = np.divmod(raw, per)
    keys = cell * 2 * s.samples + from_b[draw, -1] * s.samples + draw % s.samples
    plan = build.design_plan(derived, whole=unit[:, :-1], keys=keys)
    kinds = tuple("continuous" if a.kind == "range" else "categorical" for a in sampled) + ("noise",)
    unit = np.concatenate([unit[:, :-1], from_b[:, -1:].astype(float)], axis=1)
    return Design(derived, plan, tuple(a.name for a in sampled) + (NOISE,), kinds, strata, s.samples,
                  per // s.samples, unit, seed)


def outcome_names(cfg: config.CampaignConfig) -> tuple[str, ...]:
    """The outcomes to analyse: [sensitivity] outcomes (checked) or the defaults the space has strata for."""
    axis = cfg.space.axis("fault_kind")
    kinds = scenarios.grid_values(axis) if axis else (scenarios.DEFAULTS["fault_kind"],)
    names = cfg.sensitivity.outcomes
    for i, name in enumerate(names):
        if name not in OUTCOMES:
            raise config.ConfigError(f"sensitivity.outcomes[{i}]: {name!r} is not an outcome; expected one of "
                                     f"{', '.join(OUTCOMES)}")
        if not any(applies(OUTCOMES[name], k) for k in kinds):
            needs = OUTCOMES[name].strata.replace('_', '-')
            raise config.ConfigError(f"sensitivity.outcomes[{i}]: {name} needs {needs} runs; space.fault_kind has "
                                     f"{', '.join(map(str, kinds))}")
    return names or tuple(n for n in DEFAULT_OUTCOMES if any(applies(OUTCOMES[n], k) for k in kinds))


def outcome_values(outcome: Outcome, rows) -> np.ndarray:
    """The outcome of each run (nan where it counts as nothing or the run failed)."""
    y = rows[outcome.column].to_numpy(dtype=float)
    if isinstance(outcome.undefined, str):
        y = np.where(np.isnan(y), rows[outcome.undefined].to_numpy(dtype=float), y)
    elif outcome.undefined is not None:
        y = np.where(np.isnan(y), outcome.undefined, y)
    return np.where(scored(rows), y, np.nan)


def strata(d: Design, table):
    """Per stratum present in the design's run table: (label, fault kind, its rows ordered by block, then base
    point)."""
    cell, block, base = d.locate(table["scenario_id"].to_numpy())
    for c in np.unique(cell):
        idx = np.flatnonzero(cell == c)
        rows = table.iloc[idx[np.lexsort((base[idx], block[idx]))]]
        label = ", ".join(f"{name}={rows[name].iloc[0]}" for name in d.strata if name in rows) or "all"
        yield label, str(rows["fault_kind"].iloc[0]), rows

"""Scoring of runs: one place for each definition an FDD engineer signs (DESIGN.md sections 5, 5a).

Every outcome of a run is a column of a monitor (:mod:`mcfdd.analysis.scoring.core`), one module
per family: :mod:`~mcfdd.analysis.scoring.loe` (detection and identification of LOE faults, the
ratio statistics), :mod:`~mcfdd.analysis.scoring.stall` (the stall detector, stall events and
latencies, false stall identifications, jams taken for stalls), :mod:`~mcfdd.analysis.scoring.truth`
(status, detectability peaks, flight point) and :mod:`~mcfdd.analysis.scoring.smooth` (the online
log-sum-exp the smooth versions are built from). :func:`monitors` is the chain every tool runs:
the campaign (hard outcomes and signed margins), the worst-case search and the tuner (the same,
with a temperature: their smooth versions too) and the tuner's threshold scan; the reports read
its columns (:func:`table`). A new outcome is a monitor added to :func:`monitors` and a NumPy
reference test of it.
"""

from __future__ import annotations

import numpy as np

from mcfdd.analysis.scoring import loe, smooth, stall, truth as truth_monitors
from mcfdd.analysis.scoring.core import (
    Monitor,
    Sample,
    Settings,
    Truth,
    Windows,
    end_windows,
    events_init,
    named_chain,
    windows,
)
from mcfdd.analysis.scoring.truth import Status
from mcfdd.analysis.simulate import Observer
from mcfdd.plant import atmosphere

# column of the hard bound of each (detector, bound) of eqs. (26)-(27) (the LOE ones in theta / ||u||,
# the stall detector's in rod units); with a temperature, "smooth_log_" + name is its smooth logarithm
BOUNDS = {("stall", "free"): "stall_theta_max_free", ("stall", "detect"): "stall_theta_peak_min",
          ("loe", "free"): "loe_ratio0_max_pre", ("loe", "detect"): "loe_others_min_peak"}

# the LOE detection level's bounds (DESIGN.md 5): the FDD's signed statistic of the confirmed rejection
# (theta_0 / ||u|| units, positive where the FDD detects) as (column, sign): its largest value at the quiet
# samples (tau_f; a false alarm where positive) and its largest over the detection window of a run that
# must be detected (tau_d is the least of these; a miss where negative)
DETECTION = {"free": ("false_alarm_margin", 1.0), "detect": ("missed_margin", -1.0)}

__all__ = ["BOUNDS", "DETECTION", "Monitor", "Sample", "Settings", "Status", "Truth", "Windows", "finalize", "loe",
           "monitors", "named_chain", "observer", "smooth", "stall", "table", "truth_monitors"]


def monitors(settings: Settings, truth: Truth, fdd_params, dt_s: float, temperature=None) -> Monitor:
    """The chain of every outcome of a run (columns: see README, "What a campaign reports").

    ``fdd_params`` gives the stall detector's threshold of its margins and its evaluator, which the
    stall detector's monitor steps at the run's sample time ``dt_s`` (s); with a ``temperature`` the
    monitors also give their smooth versions (built only then: the campaign's step does not carry them).
    """
    tau = fdd_params.stall.tau
    return named_chain(
        ("status", truth_monitors.status()),
        ("loe_detection", loe.detection(settings, truth, temperature)),
        ("loe_identification", loe.identification(settings, truth)),
        ("stall_events", stall.events(settings, truth, tau, temperature)),
        *((f"false_identification_{m}", stall.false_identification(settings, truth, m, temperature))
          for m in stall.METHODS),
        ("stall_detector", stall.detector(settings, truth, tau, fdd_params.stall.evaluator, dt_s, temperature)),
        ("loe_ratios", loe.ratios(settings, truth, temperature)),
        ("peaks", truth_monitors.peaks(settings, truth)),
        ("jams", stall.jams(settings, truth)),
        ("flight_point", truth_monitors.flight_point()),
    )


def observer(settings: Settings, truth: Truth, monitor: Monitor) -> Observer:
    """A run's observer (:class:`mcfdd.analysis.simulate.Observer`): the windows of each sample computed
    once and passed to ``monitor``; nothing kept per step. Its state is (windows' events, monitor state)."""
    def init(dtype):
        return events_init(dtype, truth.accept.shape[-1]), monitor.init(dtype)

    def update(state, t_s, plant, fdd):
        events, inner = state
        events, w = windows(settings, truth, events, t_s, plant, fdd)
        return (events, monitor.update(inner, w, Sample(plant, fdd))), None

    return Observer(init, update)


def finalize(settings: Settings, monitor: Monitor, state, t_end) -> dict:
    """The columns of a run from the observer's final state; the run ends at t_end (s)."""
    events, inner = state
    return monitor.finalize(inner, end_windows(settings, events, t_end))


def table(columns: dict, onset_s, nearest, duration_s: float, t_detec_s: float) -> dict:
    """Scenario-table columns of a batch from the monitors' columns (host, NumPy; rows first).

    Floating columns in float64; the truth's nearest model (``true_model``); times after the onset
    (``detection_latency_s``, ``identification_latency_s``) and the detection window's length
    (``window_s``, cut at the run's end) against the scenario's onset in float64 (``onset_s``, inf
    without a fault); Vcas in kt.
    """
    out = {k: np.asarray(v, dtype=float) if np.issubdtype(np.asarray(v).dtype, np.floating) else np.asarray(v)
           for k, v in columns.items()}
    onset = np.asarray(onset_s, dtype=float)
    faulty = np.isfinite(onset)
    shift = np.where(faulty, onset, 0.0)
    out["true_model"] = np.asarray(nearest)
    out["window_s"] = np.where(faulty, np.minimum(t_detec_s, np.maximum(duration_s - onset, 0.0)), np.nan)
    out["detection_latency_s"] = out["detection_time_s"] - shift
    out["identification_latency_s"] = np.where(faulty, out["identification_time_s"] - shift, np.nan)
    for end in ("min", "max"):
        out[f"vcas_{end}_kt"] = out.pop(f"vcas_{end}_m_s") / atmosphere.KT_TO_M_S
    return out

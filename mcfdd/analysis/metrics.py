"""FDD performance statistics (DESIGN.md section 5): rates with exact intervals, quantiles, detectability.

The outcomes of a run (false alarm, detection, missed detection, identification, stall events)
are the scoring monitors' columns (:mod:`mcfdd.analysis.scoring`); here are the statistics over
runs built on them:

- Rates carry exact Clopper-Pearson intervals: zero events in n runs only shows a rate below
  about 3/n at 95 %.
- Detectability: the distance (16) |k_j - k_i| / (k_i + k_j) between the plant's own small-error
  gains, fault-free against the true fault, at the run's peak load; a run is separable under
  the campaign's uncertainty when that distance exceeds what the uncertainty alone creates.
- Paired comparison of two campaigns of one space (same scenarios, two FDDs): per outcome the
  discordant runs and McNemar's exact test, per fault kind the detection-time differences on the
  runs both detect and the Wilcoxon signed-rank test.
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.special import betaincinv

from mcfdd.analysis import scenarios
from mcfdd.plant import atmosphere


def clopper_pearson(k, n, confidence: float = 0.95):
    """Exact two-sided binomial interval (lo, hi) for k successes in n trials (broadcasts).

    Empty samples (n = 0) give (nan, nan).
    """
    k = np.asarray(k, dtype=float)
    n = np.asarray(n, dtype=float)
    alpha = 1.0 - confidence
    with np.errstate(invalid="ignore", divide="ignore"):
        lo = np.where(k > 0, betaincinv(k, n - k + 1.0, alpha / 2.0), 0.0)
        hi = np.where(k < n, betaincinv(k + 1.0, n - k, 1.0 - alpha / 2.0), 1.0)
    empty = n <= 0
    return np.where(empty, np.nan, lo), np.where(empty, np.nan, hi)


def rate(k: int, n: int, confidence: float = 0.95) -> dict:
    """Count, trials, rate and exact interval as a dict (rate nan when n = 0)."""
    lo, hi = clopper_pearson(k, n, confidence)
    return {"k": int(k), "n": int(n), "rate": (k / n) if n else float("nan"), "lo": float(lo), "hi": float(hi)}


def quantiles(values) -> dict:
    """Median, 95th percentile and maximum of the finite values (nan when there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}


UNCERTAIN_SCALES = ("kci_scale", "supply_pressure_scale", "hinge_scale")


def uncertainty_ranges(cols: dict) -> dict:
    """(lo, hi) of each uncertain scale of :func:`small_error_gain` over a campaign's columns (1 if absent)."""
    return {k: (float(np.min(cols[k])), float(np.max(cols[k]))) if k in cols else (1.0, 1.0)
            for k in UNCERTAIN_SCALES}


def small_error_gain(load, nu1=1.0, nu2=1.0, kci_scale=1.0, supply_pressure_scale=1.0, hinge_scale=1.0):
    """Small-error gain of eq. (2) relative to Kci Kp sqrt(dP / dP_ref), for motion against (first
    row) and with (second row) a hinge load ``load`` given as a fraction of the nominal stall force dP S.

    With e -> 0 the Kd term vanishes: k = Kci Kp sqrt((nu1 dP -+ nu2 F / S) / dP_ref); zero when the
    load wins (a stall). Broadcasts; returns shape (2, ...).
    """
    sign = np.array([1.0, -1.0]).reshape((2,) + (1,) * np.ndim(load))
    inner = nu1 * supply_pressure_scale - sign * nu2 * hinge_scale * np.asarray(load, dtype=float)
    return kci_scale * np.sqrt(np.maximum(inner, 0.0))


def gain_distance(k_i, k_j):
    """Distance (16) of first-order models, |k_j - k_i| / (k_i + k_j); 0 where both gains are 0."""
    total = k_i + k_j
    return np.where(total > 0, np.abs(k_j - k_i) / np.where(total > 0, total, 1.0), 0.0)


def separability(peak_load_fraction, nu1, nu2, supply_pressure_scale, ranges: dict) -> dict:
    """Per run: distance (16) of fault-free against the true fault and of the uncertainty alone.

    Both on the plant's small-error gains at the run's peak load (``peak_load_fraction`` of
    nu1 dP S, with the run's supply pressure), the larger of the two motion directions. The
    uncertainty distance is the largest over the corners of ``ranges`` (:func:`uncertainty_ranges`;
    the gain is monotonic in each scale) between the nominal fault-free gain and the perturbed one.
    Runs without a peak load (nan) get nan distances and are not separable.
    """
    load = np.asarray(peak_load_fraction, dtype=float) * np.asarray(nu1) * np.asarray(supply_pressure_scale)
    nominal = small_error_gain(load)
    fault = gain_distance(nominal, small_error_gain(load, nu1, nu2)).max(axis=0)
    corners = np.array(np.meshgrid(*(ranges[k] for k in UNCERTAIN_SCALES), indexing="ij")).reshape(3, -1).T
    noise = np.max([gain_distance(nominal, small_error_gain(load, kci_scale=c[0], supply_pressure_scale=c[1],
                                                             hinge_scale=c[2])).max(axis=0) for c in corners], axis=0)
    known = np.isfinite(load)
    fault, noise = np.where(known, fault, np.nan), np.where(known, noise, np.nan)
    return {"fault_distance": fault, "uncertainty_distance": noise, "separable": known & (fault > noise)}


def detectability_columns(cols: dict, peak_load_fraction, ranges: dict) -> dict:
    """Dynamic pressure (kPa) and :func:`separability` of scenarios given by their table columns."""
    n = len(peak_load_fraction)
    defaults = scenarios.DEFAULTS
    kind = np.asarray(cols.get("fault_kind", np.full(n, defaults["fault_kind"])))
    nu1, nu2 = scenarios.fault_nu(kind, cols.get("fault_size", np.zeros(n)))
    vcas = np.asarray(cols.get("vcas_kt", np.full(n, defaults["vcas_kt"])), dtype=float) * atmosphere.KT_TO_M_S
    altitude = np.asarray(cols.get("altitude_m", np.full(n, defaults["altitude_m"])), dtype=float)
    supply = np.asarray(cols.get("supply_pressure_scale", np.ones(n)), dtype=float)
    sep = separability(peak_load_fraction, nu1, nu2, supply, ranges)
    faulty = np.isin(kind, scenarios.PARAMETRIC)
    return {"qbar_kpa": np.asarray(atmosphere.dynamic_pressure(vcas, altitude), dtype=float) / 1e3,
            "fault_distance": np.where(faulty, sep["fault_distance"], np.nan),
            "uncertainty_distance": sep["uncertainty_distance"], "separable": faulty & sep["separable"]}


def bound_with_witness(values, scenario_ids, kind: str):
    """Supremum (kind='sup') or infimum ('inf') of the finite values and the scenario where it occurs."""
    v = np.asarray(values, dtype=float)
    finite = np.isfinite(v)
    if not finite.any():
        return float("nan"), -1
    idx = np.flatnonzero(finite)
    best = idx[np.argmax(v[idx])] if kind == "sup" else idx[np.argmin(v[idx])]
    return float(v[best]), int(np.asarray(scenario_ids)[best])


def decision_history(detected, t_s, onset_s):
    """Fault-model decisions after the onset, from decision histories.

    ``detected`` is (runs, steps) of decided model ids (-1 none, 0 fault-free). Returns a dict of
    (runs,) arrays: the first fault model and its time (nan if none), the prevailing decision
    (the model, fault-free included, decided for the most samples after the onset; -1 if none)
    and how many times the decided fault model changed after the first fault-model decision.
    """
    detected = np.asarray(detected)
    n_runs = detected.shape[0]
    after = np.asarray(t_s)[None, :] >= np.asarray(onset_s, dtype=float)[:, None]
    fault = (detected >= 1) & after
    first_idx = np.where(fault.any(axis=1), fault.argmax(axis=1), -1)
    rows = np.arange(n_runs)
    first = np.where(first_idx >= 0, detected[rows, first_idx], -1)
    time = np.where(first_idx >= 0, np.asarray(t_s)[np.maximum(first_idx, 0)], np.nan)
    prevailing = np.full(n_runs, -1)
    switches = np.zeros(n_runs, dtype=int)
    for r in rows:
        decided = detected[r, after[r] & (detected[r] >= 0)]
        if decided.size:
            prevailing[r] = np.bincount(decided).argmax()
        models = detected[r, fault[r]]
        switches[r] = int(np.count_nonzero(models[1:] != models[:-1]))
    return {"first_model": first, "detection_time_s": time, "prevailing_model": prevailing, "switches": switches}


LOAD_FRACTION_HIGH = 0.4  # peak hinge-load fraction from which a disconnection must be detected (issue 22)


def any_false_alarm(cols) -> np.ndarray:
    """A false alarm of either system: an LOE detection or a stall identification (signal rules) outside a stall."""
    return np.asarray(cols["false_alarm"]) | np.asarray(cols["eta_false_signal"])


def paired_outcomes(cols) -> dict:
    """Per outcome of a campaign's scenario table: (what its runs are, (n,) runs it counts, (n,) event).

    ``cols`` maps column names to (n,) arrays (a scenario table). The events are the campaign's
    own outcome columns; an outcome whose runs are none in a campaign is still listed.
    """
    ok = np.asarray(cols["status"]) == 0
    kind = np.asarray(cols["fault_kind"])
    free, faulty = ok & (kind == "none"), np.asarray(cols["must_detect"])
    missed = np.asarray(cols["missed"])
    loaded = faulty & (kind == "disconnection") & (np.asarray(cols["peak_load_fraction"]) >= LOAD_FRACTION_HIGH)
    events = np.asarray(cols["stall_events"])
    stalls = ok & (events > 0)
    return {
        "loe_false_alarm": ("fault-free runs", free, np.asarray(cols["false_alarm"])),
        "any_false_alarm": ("fault-free runs", free, any_false_alarm(cols)),
        "false_identification": ("fault-free runs", free, np.asarray(cols["false_identification"])),
        "missed": ("faulty runs", faulty, missed),
        "missed_separable": ("separable faulty runs", faulty & np.asarray(cols["separable"]), missed),
        "missed_disconnection_loaded": (f"disconnections, peak load fraction >= {LOAD_FRACTION_HIGH}", loaded, missed),
        "not_identified_correctly": ("faulty runs", faulty, ~np.asarray(cols["identified_correctly"])),
        "stall_missed_signal": ("runs with stall loads", stalls, np.asarray(cols["stall_missed_signal"])),
        "stall_missed_model": ("runs with stall loads", stalls, np.asarray(cols["stall_missed_model"])),
        "stall_false_detection": ("fault-free runs", free, np.asarray(cols["stall_false_detection"])),
        "stall_outside_signal": ("all runs", ok, np.asarray(cols["eta_false_signal"])),
        "stall_outside_model": ("all runs", ok, np.asarray(cols["eta_false_model"])),
        "jam_taken_for_stall": ("jammed runs", ok & (kind == "jamming"), np.asarray(cols["jam_taken_for_stall"])),
    }


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Two-sided p-value of McNemar's exact test: ``only_a`` runs with the event in campaign a only and
    ``only_b`` in b only; under no difference each discordant run is a fair coin (binomial test at 1/2).
    1.0 when no run is discordant."""
    n = int(only_a) + int(only_b)
    return 1.0 if n == 0 else float(stats.binomtest(int(only_a), n, 0.5).pvalue)


def paired_counts(event_a, event_b, confidence: float = 0.95) -> dict:
    """Events of one outcome on the same runs in campaigns a and b ((n,) bool each): counts, rates with
    Clopper-Pearson intervals, the discordant runs (``only_a``: event in a and not in b) and McNemar's p."""
    a, b = np.asarray(event_a, bool), np.asarray(event_b, bool)
    ra, rb = rate(int(a.sum()), a.size, confidence), rate(int(b.sum()), b.size, confidence)
    only_a, only_b = int((a & ~b).sum()), int((b & ~a).sum())
    return {"runs": a.size, "events_a": ra["k"], "rate_a": ra["rate"], "rate_a_lo": ra["lo"], "rate_a_hi": ra["hi"],
            "events_b": rb["k"], "rate_b": rb["rate"], "rate_b_lo": rb["lo"], "rate_b_hi": rb["hi"],
            "only_a": only_a, "only_b": only_b, "p_value": mcnemar_exact(only_a, only_b)}


def paired_differences(x_a, x_b) -> dict:
    """Paired values of the same runs in campaigns a and b (e.g. detection times, (n,) each): medians, the
    median of b - a and the two-sided Wilcoxon signed-rank p-value (zero differences dropped; 1.0 when every
    difference is zero, nan without runs)."""
    a, b = np.asarray(x_a, float), np.asarray(x_b, float)
    d = b - a
    nonzero = d[d != 0.0]
    if d.size == 0:
        p = float("nan")
    elif nonzero.size == 0:
        p = 1.0
    else:
        p = float(stats.wilcoxon(nonzero).pvalue)
    def med(v):
        return float(np.median(v)) if v.size else float("nan")

    return {"runs": d.size, "median_a": med(a), "median_b": med(b), "median_difference": med(d), "p_value": p}

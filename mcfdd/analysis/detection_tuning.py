"""Tuning of the LOE detection level (Section 5.3, DESIGN.md sections 5, 5a) by gradient through the FDD.

False alarms and missed detections are decided at the detection level (the fault-free model
rejected, confirmed: ``detection_tau``, ``detection_contrast``, the excitation floor and its noise
factor, ``detection_confirm_s``), fed by the bank's evaluator and filter pole. All of these are
tuned together here, as logarithms (so they stay positive), over stored plant histories
(:func:`mcfdd.analysis.tuning.training_columns`: the FDD alone in a rematerialised scan).

The campaign's own definitions give the bounds. Per run the detection monitor
(:func:`mcfdd.analysis.scoring.loe.detection`) gives ``false_alarm_margin``, the largest signed
statistic of the confirmed rejection at the quiet samples (positive exactly for a false alarm),
and ``missed_margin``, minus the largest within the detection window (positive exactly for a
missed detection), in units of theta_0 / ||u||; with a temperature T, their smooth versions
(log-sum-exp over time). Over runs, in the units of that statistic:

    tau_f = max over valid runs of false_alarm_margin              (eq. 26's role)
    tau_d = min over the runs that must be detected of -missed_margin  (eq. 27's role)

and the smooth surrogates replace the max (min) over runs by the log-sum-exp at T of the runs'
smooth margins (:func:`mcfdd.analysis.scoring.smooth.soft_max`); both tend to the hard bounds as
T -> 0. ``tau_d > tau_f`` is a positive gap: raising the detection thresholds by anything between
the two leaves no false alarm and no missed detection on the training set. The objective is the
smooth gap ``tau_d - tau_f``, ascended by Adam (:func:`mcfdd.analysis.tuning.tune`).

The runs that must be detected are a mask over the training set (:func:`must_detect_mask`): the
campaign's ``must_detect`` runs that are also ``separable`` (the fault's gain distance at the run's
peak load above the uncertainty's, :func:`mcfdd.analysis.metrics.separability`), or a predicate
of fault kinds and a minimum peak load fraction: tau_d over every faulty run is set by low-load
disconnections that no FDD can tell from the uncertainty.

The thresholds are then placed by a scan (:func:`scan`): the detection thresholds
(``detection_tau`` and ``detection_contrast`` together) scaled by candidate factors, each scored
by the hard monitors on the training set (false alarms, missed detections of the must-detect
runs, median detection time); the Pareto set of the three is reported, and the smallest factor
from which no candidate gives a training false alarm, times a safety factor, is chosen
(:func:`choose`), or, with a miss limit, the candidate with the fewest false alarms among those that
miss at most that fraction of the must-detect runs (:func:`choose_within`).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis import metrics, scoring, tuning
from mcfdd.analysis.scoring import smooth
from mcfdd.fdd import evaluator, system

THRESHOLDS = ("detection_tau", "detection_contrast")


def names(loe: system.LoeParams, tune_pole: bool, confirmation: bool) -> tuple:
    """The parameters tuned for an FDD whose LOE part is ``loe``: the evaluator (alpha, beta, gamma),
    the pole (``tune_pole``), the detection thresholds, the excitation floor, its noise factor (if the
    floor follows the noise) and the confirmation time (``confirmation``). A setting that is 0 (a
    contrast, floor or confirmation turned off) stays off: it is not tuned (logarithms)."""
    out = ["alpha", "beta", "gamma_1_s"] + (["pole_1_s"] if tune_pole else []) + list(THRESHOLDS)
    out.append("excitation_floor")
    if loe.excitation_noise_factor is not None:
        out.append("excitation_noise_factor")
    if confirmation:
        out.append("detection_confirm_s")
    return tuple(k for k in out if k == "alpha" or float(_value(loe, k)) > 0.0)


def _value(loe: system.LoeParams, name: str) -> float:
    ev = loe.evaluator
    return {"alpha": max(float(ev.alpha), tuning.ALPHA_FLOOR * float(ev.beta)), "beta": ev.beta,
            "gamma_1_s": ev.gamma, "pole_1_s": loe.pole}.get(name, getattr(loe, name, None))


def initial(params: system.FddParams, tuned: tuple) -> dict:
    """Logarithms of the current values of the ``tuned`` parameters (:func:`names`; a dict, the optimiser's
    pytree). A zero alpha starts from ``ALPHA_FLOOR * beta``."""
    return {name: jnp.log(jnp.asarray(float(_value(params.loe, name)), jnp.result_type(float))) for name in tuned}


def natural(theta: dict) -> dict:
    """The tuned parameters' values (floats; the floor in rod units, as in FddParams)."""
    return {k: float(jnp.exp(v)) for k, v in theta.items()}


def apply(params: system.FddParams, theta: dict, scale=1.0) -> system.FddParams:
    """FDD parameters with the LOE values of ``theta`` (logarithms), the detection thresholds times ``scale``."""
    loe = params.loe
    v = {k: jnp.exp(x) for k, x in theta.items()}
    ev = loe.evaluator
    ev = evaluator.NarendraParams(v.get("alpha", ev.alpha), v.get("beta", ev.beta), v.get("gamma_1_s", ev.gamma))
    fields = {k: v[k] for k in ("excitation_floor", "excitation_noise_factor", "detection_confirm_s") if k in v}
    fields.update({k: v.get(k, getattr(loe, k)) * scale for k in THRESHOLDS})
    loe = loe._replace(evaluator=ev, pole=v.get("pole_1_s", loe.pole), **fields)
    return params._replace(loe=loe)


def must_detect_mask(columns: dict, design: dict, ranges: dict, runs: str, kinds, min_load: float) -> np.ndarray:
    """(B,) runs whose detection counts in tau_d: the campaign's ``must_detect`` runs, restricted to the
    ``separable`` ones (``runs = 'separable'``) or all of them (``'all'``), then to ``kinds`` (fault kinds;
    empty: any) and to a peak load fraction of at least ``min_load``.

    ``columns``: the monitors' hard columns of the training set (host arrays); ``design``: its scenario
    columns; ``ranges``: the campaign's uncertainty ranges (:func:`mcfdd.analysis.metrics.uncertainty_ranges`).
    """
    must = np.array(columns["must_detect"], dtype=bool)
    peak = np.asarray(columns["peak_load_fraction"], dtype=float)
    if runs == "separable":
        must &= np.asarray(metrics.detectability_columns(design, peak, ranges)["separable"], dtype=bool)
    kind = np.asarray(design.get("fault_kind", np.full(len(must), "none")))
    if len(kinds):
        must &= np.isin(kind, list(kinds))
    if min_load > 0.0:
        must &= np.nan_to_num(peak, nan=-np.inf) >= min_load
    return must


def bounds(fdd_params, settings, data: tuning.TrainingSet, must, temperature, dt_s: float) -> dict:
    """tau_f and tau_d of the detection level over the training set, smooth and hard (theta_0 / ||u||).

    ``must``: (B,) the runs over which tau_d is taken. Keys: ``soft_free``, ``soft_detect`` (the
    surrogates; only with a ``temperature``), ``tau_f``, ``tau_d`` (hard; nan where no run counts),
    ``false_alarms`` (valid runs with a false alarm), ``missed`` (must-detect runs missed),
    ``detection_time_s`` (median over the must-detect runs detected, from the onset; nan if none).
    """
    columns = tuning.training_columns(fdd_params, settings, data, temperature, dt_s)
    ok = columns["status"] == scoring.Status.OK
    must = must & ok
    hard_free, hard_detect = columns["false_alarm_margin"], -columns["missed_margin"]
    free_in, detect_in = ok & jnp.isfinite(hard_free), must & jnp.isfinite(hard_detect)
    detected = must & columns["detected"]
    latency = jnp.where(detected, columns["detection_time_s"] - jnp.where(detected, data.truth.onset_s, 0.0), jnp.nan)
    soft = {}
    if temperature is not None:
        free, detect = columns["false_alarm_margin_smooth"], -columns["missed_margin_smooth"]
        soft = {"soft_free": smooth.soft_max(free, free_in & jnp.isfinite(free), temperature),
                "soft_detect": smooth.soft_min(detect, detect_in & jnp.isfinite(detect), temperature)}
    return {
        **soft,
        "tau_f": jnp.where(jnp.any(free_in), jnp.max(jnp.where(free_in, hard_free, -jnp.inf)), jnp.nan),
        "tau_d": jnp.where(jnp.any(detect_in), jnp.min(jnp.where(detect_in, hard_detect, jnp.inf)), jnp.nan),
        "false_alarms": jnp.sum(ok & columns["false_alarm"]), "missed": jnp.sum(must & columns["missed"]),
        "detection_time_s": jnp.nanmedian(latency),
    }


@partial(jax.jit, static_argnames=("dt_s",))
def gap_and_grad(theta: dict, fdd_params, settings, data: tuning.TrainingSet, must, temperature, dt_s: float):
    """Smooth gap ``soft_detect - soft_free`` at ``theta``, the bounds and the gradient in theta
    (non-finite components set to 0)."""
    def gap(theta):
        b = bounds(apply(fdd_params, theta), settings, data, must, temperature, dt_s)
        return b["soft_detect"] - b["soft_free"], b

    (value, b), grad = jax.value_and_grad(gap, has_aux=True)(theta)
    return value, b, jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)


@partial(jax.jit, static_argnames=("dt_s",))
def scan(theta: dict, fdd_params, settings, data: tuning.TrainingSet, must, scales, dt_s: float) -> dict:
    """Hard :func:`bounds` with the detection thresholds times each of ``scales`` (K,); one jit, the
    scales traced. Returns arrays (K,) of ``false_alarms``, ``missed``, ``detection_time_s``, ``tau_f``, ``tau_d``."""
    def at(scale):
        b = bounds(apply(fdd_params, theta, scale), settings, data, must, None, dt_s)
        return {k: b[k] for k in ("false_alarms", "missed", "detection_time_s", "tau_f", "tau_d")}

    return jax.lax.map(at, scales)


@partial(jax.jit, static_argnames=("dt_s",))
def evaluate(fdd_params, settings, data: tuning.TrainingSet, must, temperature, dt_s: float) -> dict:
    """:func:`bounds` of given FDD parameters (no gradient), one jit."""
    return bounds(fdd_params, settings, data, must, temperature, dt_s)


@partial(jax.jit, static_argnames=("dt_s",))
def evaluate_columns(fdd_params, settings, data: tuning.TrainingSet, dt_s: float) -> dict:
    """The monitors' hard columns over the training set (B,), one jit."""
    return tuning.training_columns(fdd_params, settings, data, None, dt_s)


def best_iterate(result: tuning.Result) -> int:
    """The iterate with the largest hard gap tau_d - tau_f on the training set (the first if none is finite)."""
    gaps = np.array([b["tau_d"] - b["tau_f"] for b in result.bounds])
    return int(np.argmax(np.where(np.isfinite(gaps), gaps, -np.inf)))


def pareto(false_alarms, missed, detection_time) -> np.ndarray:
    """(K,) points not dominated in (false alarms, missed detections, detection time), all to be small
    (a nan time counts as the largest)."""
    pts = np.stack([np.asarray(false_alarms, float), np.asarray(missed, float),
                    np.nan_to_num(np.asarray(detection_time, float), nan=np.inf)], axis=1)
    le = np.all(pts[:, None, :] <= pts[None, :, :], axis=2)
    lt = np.any(pts[:, None, :] < pts[None, :, :], axis=2)
    return ~np.any(le & lt, axis=0)


def choose(scales, false_alarms, safety: float) -> float:
    """The chosen threshold factor: the smallest scale from which every larger candidate gives no training
    false alarm, times ``safety``; the largest candidate times ``safety`` if even it alarms."""
    scales, fa = np.asarray(scales, float), np.asarray(false_alarms)
    clean = np.flatnonzero(np.cumsum((fa > 0)[::-1])[::-1] == 0)
    return float((scales[clean[0]] if len(clean) else scales[-1]) * safety)


def choose_within(scales, false_alarms, missed, detection_time, n_must: int, max_missed_fraction: float):
    """The chosen threshold factor under a miss limit, and whether any candidate met the limit.

    Among the candidates (K,) that miss at most ``max_missed_fraction`` of the ``n_must`` must-detect
    runs (``missed / n_must <= max_missed_fraction``; every candidate when ``n_must`` is 0): the fewest
    false alarms, ties to the faster median detection (nan counts as the slowest), then to the fewest
    missed, then to the larger factor. When none qualifies: the fewest missed, ties as above after it
    (fewest false alarms, faster, larger). The factor is a scanned candidate itself (no safety factor).
    """
    scales = np.asarray(scales, float)
    fa, miss = np.asarray(false_alarms, float), np.asarray(missed, float)
    time = np.nan_to_num(np.asarray(detection_time, float), nan=np.inf)
    ok = miss / n_must <= max_missed_fraction if n_must > 0 else np.ones(len(scales), bool)
    qualified = bool(ok.any())
    # np.lexsort sorts by its last key first
    keys = (-scales, miss, time, fa) if qualified else (-scales, time, fa, miss)
    first = next(i for i in np.lexsort(keys) if ok[i] or not qualified)
    return float(scales[first]), qualified

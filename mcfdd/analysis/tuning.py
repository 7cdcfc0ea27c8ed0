"""Tuning of the evaluators and thresholds, Sections 5.3 and 6.2.1, by gradient through the FDD.

The free parameters of a detector are its filter pole a (eq. 20, realisation 24) and its Narendra
evaluator alpha, beta, gamma (eq. 14); its threshold tau must lie in the detection gap
``tau_f < tau <= tau_d`` of eqs. (26)-(27). The FDD does not act on the plant, so the plant
histories of a training set (u_c, u, rod position, stall flag) are simulated once
(:func:`mcfdd.analysis.simulate.plant_batch`) and the FDD alone runs over them
(:func:`mcfdd.analysis.simulate.fdd_over`) in a scan that is differentiated in its parameters (the
scan body is rematerialised, so memory is one carry per step). The campaign's scoring monitors
(:func:`mcfdd.analysis.scoring.monitors`, with a temperature: their smooth versions too) run in
the same scan; over runs, tau_f is the smooth maximum of the runs' bounds and tau_d the smooth
minimum. The objective

    log tau_d - log tau_f = log(1 + (tau_d - tau_f) / tau_f)

is monotone in the normalised detection gap and free of the evaluator's scale. Parameters are
optimised as logarithms (Adam, optax), so they stay positive; a zero alpha (a pure integral
evaluator) starts from ``ALPHA_FLOOR * beta``. Confirmation time, excitation floor and the stall
identification rules are not tuned. The threshold is then placed inside the gap,
``tau = tau_f + margin (tau_d - tau_f)``: near tau_f for fast detection (Section 5.3). Where the
gap stays negative, candidate thresholds are compared by the false alarms and missed detections
they give on the training set (:func:`threshold_scan`; the threshold is traced, so one compilation
serves all candidates). The iterations are :func:`mcfdd.analysis.optimise.run`'s.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mcfdd.analysis import optimise, scoring, simulate
from mcfdd.analysis.scoring import smooth
from mcfdd.fdd import evaluator, system
from mcfdd.plant import closed_loop

ALPHA_FLOOR = 1e-3


class Tunable(NamedTuple):
    """Natural logarithms of a detector's free parameters (alpha, beta, gamma in 1/s, pole a in 1/s)."""

    log_alpha: jnp.ndarray
    log_beta: jnp.ndarray
    log_gamma: jnp.ndarray
    log_pole: jnp.ndarray


def _detector(params: system.FddParams, detector: str):
    return params.loe if detector == "loe" else params.stall


def initial(params: system.FddParams, detector: str) -> Tunable:
    """The detector's current parameters as a :class:`Tunable`."""
    part = _detector(params, detector)
    ev = part.evaluator
    alpha = max(float(ev.alpha), ALPHA_FLOOR * float(ev.beta))
    return Tunable(*(jnp.log(jnp.asarray(v, jnp.result_type(float))) for v in (alpha, ev.beta, ev.gamma, part.pole)))


def natural(theta: Tunable) -> dict:
    """alpha, beta, gamma_1_s, pole_1_s of a :class:`Tunable` (floats)."""
    alpha, beta, gamma, pole = (float(jnp.exp(v)) for v in theta)
    return {"alpha": alpha, "beta": beta, "gamma_1_s": gamma, "pole_1_s": pole}


def apply(params: system.FddParams, detector: str, theta: Tunable, tune_pole: bool) -> system.FddParams:
    """FDD parameters with the detector's evaluator (and pole, if ``tune_pole``) taken from ``theta``."""
    part = _detector(params, detector)
    part = part._replace(evaluator=evaluator.NarendraParams(jnp.exp(theta.log_alpha), jnp.exp(theta.log_beta),
                                                            jnp.exp(theta.log_gamma)),
                         pole=jnp.exp(theta.log_pole) if tune_pole else part.pole)
    return params._replace(**{detector: part})


def with_threshold(params: system.FddParams, detector: str, tau) -> system.FddParams:
    """FDD parameters with the detector's threshold replaced (rod m for the stall detector)."""
    return params._replace(**{detector: _detector(params, detector)._replace(tau=tau)})


def place_threshold(tau_f: float, tau_d: float, margin: float, taus=None, false_alarms=None, misses=None) -> float:
    """The threshold: ``tau_f + margin (tau_d - tau_f)`` inside a positive gap (eq. 26-27).

    Without a positive gap no threshold guarantees both no false alarm and no missed detection;
    then the candidate ``taus`` are ranked by their false alarms, then missed detections on the
    training set (:func:`threshold_scan`), and the middle of the best ones is taken.
    """
    if tau_d > tau_f or taus is None:
        return tau_f + margin * (tau_d - tau_f)
    rank = np.lexsort((np.asarray(misses), np.asarray(false_alarms)))
    best = rank[(np.asarray(false_alarms)[rank] == np.asarray(false_alarms)[rank[0]])
                & (np.asarray(misses)[rank] == np.asarray(misses)[rank[0]])]
    return float(np.asarray(taus)[np.sort(best)[len(best) // 2]])


def candidates(tau_f: float, tau_d: float, n: int) -> np.ndarray:
    """n thresholds spaced geometrically from half the smaller bound to 1.5 times the larger."""
    return np.geomspace(0.5 * min(tau_f, tau_d), 1.5 * max(tau_f, tau_d), n)


class TrainingSet(NamedTuple):
    """Stored plant histories of B runs and what their scoring needs.

    plant: :class:`~mcfdd.plant.closed_loop.PlantOutputs` with leaves (B, T); truth:
    :class:`mcfdd.analysis.scoring.Truth` with leaves (B,) and (B, N).
    """

    plant: closed_loop.PlantOutputs
    truth: scoring.Truth


def fdd_run(fdd_params: system.FddParams, settings: scoring.Settings, plant: closed_loop.PlantOutputs,
            truth: scoring.Truth, temperature, dt_s: float) -> dict:
    """The FDD over one stored history (leaves (T,)): the monitors' columns, with their smooth versions
    unless ``temperature`` is None."""
    monitor = scoring.monitors(settings, truth, fdd_params, dt_s, temperature)
    state, _ = simulate.fdd_over(fdd_params, plant, scoring.observer(settings, truth, monitor), dt_s, remat=True)
    return scoring.finalize(settings, monitor, state, plant.u_m.shape[0] * dt_s)


def training_columns(fdd_params, settings, data: TrainingSet, temperature, dt_s: float) -> dict:
    """:func:`fdd_run` over the training set (B,)."""
    return jax.vmap(lambda plant, truth: fdd_run(fdd_params, settings, plant, truth, temperature, dt_s))(
        data.plant, data.truth)


def bounds(fdd_params: system.FddParams, settings: scoring.Settings, data: TrainingSet, temperature, dt_s: float,
           detector: str) -> dict:
    """tau_f and tau_d of a detector over the training set, smooth (log units) and hard.

    Keys: ``soft_free``, ``soft_detect`` (log of theta units), ``tau_f``, ``tau_d`` (hard; rod units
    for the stall detector, theta / ||u|| for the LOE bank; nan if no run counts). The LOE detection
    bound counts the runs that must be detected (``must_detect``), as :func:`mcfdd.report.gaps` does.
    """
    columns = training_columns(fdd_params, settings, data, temperature, dt_s)
    ok = columns["status"] == scoring.Status.OK
    counts = columns["must_detect"] if detector == "loe" else ok
    free, detect = (columns[f"smooth_log_{scoring.BOUNDS[(detector, b)]}"] for b in ("free", "detect"))
    hard_free, hard_detect = (columns[scoring.BOUNDS[(detector, b)]] for b in ("free", "detect"))
    free_in = ok & jnp.isfinite(hard_free)
    detect_in = counts & jnp.isfinite(hard_detect)
    return {
        "soft_free": smooth.soft_max(free, free_in & jnp.isfinite(free), temperature),
        "soft_detect": smooth.soft_min(detect, detect_in & jnp.isfinite(detect), temperature),
        "tau_f": jnp.where(jnp.any(free_in), jnp.max(jnp.where(free_in, hard_free, -jnp.inf)), jnp.nan),
        "tau_d": jnp.where(jnp.any(detect_in), jnp.min(jnp.where(detect_in, hard_detect, jnp.inf)), jnp.nan),
    }


STATIC = ("dt_s", "detector", "tune_pole")


@partial(jax.jit, static_argnames=STATIC)
def gap_and_grad(theta: Tunable, fdd_params, settings, data: TrainingSet, temperature, dt_s: float, detector: str,
                 tune_pole: bool):
    """Smooth log gap ``soft_detect - soft_free`` at ``theta``, the bounds and the gradient in theta
    (non-finite components set to 0)."""
    def gap(theta):
        b = bounds(apply(fdd_params, detector, theta, tune_pole), settings, data, temperature, dt_s, detector)
        return b["soft_detect"] - b["soft_free"], b

    (value, b), grad = jax.value_and_grad(gap, has_aux=True)(theta)
    return value, b, jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)


@partial(jax.jit, static_argnames=("dt_s", "detector"))
def evaluate(fdd_params, settings, data: TrainingSet, temperature, dt_s: float, detector: str) -> dict:
    """:func:`bounds` of given FDD parameters (no gradient), one jit."""
    return bounds(fdd_params, settings, data, temperature, dt_s, detector)


@partial(jax.jit, static_argnames=("dt_s", "detector", "identification"))
def threshold_scan(fdd_params, settings, data: TrainingSet, taus, dt_s: float, detector: str, identification: str):
    """False alarms (runs) and missed detections for each candidate threshold (K,), one jit.

    The monitors' verdicts (DESIGN.md section 5): LOE bank (its threshold tau is the signature's, so
    the identification level), ``identification_false_alarm`` and a run that must be detected
    without an identification in the window; stall detector, ``eta_false_<identification>`` and
    ``stall_missed_<identification>`` (a relevant stall event not identified within
    ``stall_window_s``), ``identification`` being 'signal' or 'model'. Returns (runs with a false
    alarm (K,), runs with a miss (K,)).
    """
    def at(tau):
        columns = training_columns(with_threshold(fdd_params, detector, tau), settings, data, None, dt_s)
        if detector == "loe":
            false = columns["identification_false_alarm"]
            missed = columns["must_detect"] & ~jnp.isfinite(columns["identification_time_s"])
        else:
            false = columns[f"eta_false_{identification}"]
            missed = columns[f"stall_missed_{identification}"]
        return jnp.sum(false), jnp.sum(missed)

    return jax.lax.map(at, taus)


class Result(NamedTuple):
    """Iterates of a tuning run: parameters (I + 1) and per iteration the smooth gap and the bounds."""

    thetas: list
    gaps: np.ndarray
    bounds: list


def tune(gap_and_grad_fn, theta0, iterations: int, learning_rate: float, callback=None) -> Result:
    """Adam ascent of a smooth gap (:func:`mcfdd.analysis.optimise.run`) from ``theta0`` (a :class:`Tunable`,
    or the dict of :mod:`mcfdd.analysis.detection_tuning`). ``gap_and_grad_fn(theta)`` returns (gap, bounds,
    gradient); ``callback(i, gap, bounds)`` sees every evaluation. Evaluations:
    iterations + 1."""
    def fn(theta):
        gap, b, grad = gap_and_grad_fn(theta)
        return float(gap), {k: float(v) for k, v in b.items()}, grad

    trace = optimise.run(fn, theta0, optax.adam(learning_rate), iterations, maximize=True, callback=callback)
    return Result(trace.params, np.asarray(trace.values), trace.aux)


def normalised_gap(tau_f, tau_d):
    """(tau_d - tau_f) / tau_f."""
    return (np.asarray(tau_d) - np.asarray(tau_f)) / np.asarray(tau_f)


def best_iterate(result: Result) -> int:
    """Iteration with the largest hard normalised gap on the training set (the first if none is finite)."""
    gaps = np.array([normalised_gap(b["tau_f"], b["tau_d"]) for b in result.bounds])
    gaps = np.where(np.isfinite(gaps), gaps, -np.inf)
    return int(np.argmax(gaps))

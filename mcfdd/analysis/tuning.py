"""Tuning of the evaluators and thresholds, Sections 5.3 and 6.2.1, by gradient through the FDD.

The free parameters of a detector are its filter pole a (eq. 20, realisation 24) and its Narendra
evaluator alpha, beta, gamma (eq. 14); its threshold tau must lie in the detection gap
``tau_f < tau <= tau_d`` of eqs. (26)-(27). The FDD does not act on the plant, so the plant
histories of a training set (u_c, u, rod position, stall flag) are simulated once
(:func:`mcfdd.analysis.simulate.plant_batch`) and the FDD alone runs over them in a scan that is
differentiated in its parameters (the scan body is rematerialised, so memory is one carry per
step). The campaign reductions and the smooth bounds of :mod:`mcfdd.analysis.worst_case` run in
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
serves all candidates).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mcfdd.analysis import campaign, simulate, worst_case
from mcfdd.compute import standard_promotion
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
    """Stored plant histories of B runs and what their evaluation needs.

    plant: :class:`~mcfdd.plant.closed_loop.PlantOutputs` with leaves (B, T);
    vcas_m_s, altitude_m: (B,) flight points; truth: :class:`campaign.Truth` with leaves (B,) and
    (B, N); counts: (B,) runs whose LOE detection bound counts (parametric fault whose nearest
    model is a fault model), as in :func:`mcfdd.report.gaps`.
    """

    plant: closed_loop.PlantOutputs
    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray
    truth: campaign.Truth
    counts: jnp.ndarray


def fdd_run(fdd_params: system.FddParams, settings: campaign.Settings, plant: closed_loop.PlantOutputs, vcas_m_s,
            altitude_m, truth: campaign.Truth, temperature, dt_s: float):
    """The FDD over one stored history (leaves (T,)). Returns (smooth bounds dict, campaign outcomes)."""
    n_steps = plant.u_m.shape[0]
    zero = jnp.zeros_like(plant.u_m[0])
    carry = (system.init(fdd_params, zero), campaign.reduction_init(fdd_params.loe.bank.k0.shape[0], zero.dtype),
             worst_case.soft_init(zero.dtype))

    @jax.checkpoint
    def body(carry, xs):
        state, red, acc = carry
        k, out = xs
        t = simulate.sample_time(k, dt_s)
        state, fo = system.step(fdd_params, state, out.u_c_m, out.u_m, vcas_m_s, altitude_m, t, dt_s)
        new = campaign.reduction_step(settings, truth, red, t, out, fo)
        return (state, new, worst_case.soft_step(settings, truth, temperature, acc, red, new, t, out, fo)), None

    (_, red, acc), _ = jax.lax.scan(body, carry, (jnp.arange(n_steps), plant))
    outcomes = campaign.finalize(settings, red, n_steps * dt_s)
    return worst_case.soft_finalize(acc, red, outcomes, temperature), outcomes


def bounds(fdd_params: system.FddParams, settings: campaign.Settings, data: TrainingSet, temperature, dt_s: float,
           detector: str) -> dict:
    """tau_f and tau_d of a detector over the training set, smooth (log units) and hard.

    Keys: ``soft_free``, ``soft_detect`` (log of theta units), ``tau_f``, ``tau_d`` (hard; rod units
    for the stall detector, theta / ||u|| for the LOE bank; nan if no run counts).
    """
    def one(plant, v, h, truth):
        return fdd_run(fdd_params, settings, plant, v, h, truth, temperature, dt_s)

    soft, outcomes = jax.vmap(one)(data.plant, data.vcas_m_s, data.altitude_m, data.truth)
    ok = outcomes["status"] == campaign.Status.OK
    counts = ok & (data.counts if detector == "loe" else True)
    free = soft[f"{detector}_free"]
    detect = soft[f"{detector}_detect"]
    hard_free = worst_case.hard_value(outcomes, detector, "free")
    hard_detect = worst_case.hard_value(outcomes, detector, "detect")
    free_in = ok & jnp.isfinite(hard_free)
    detect_in = counts & jnp.isfinite(hard_detect)
    return {
        "soft_free": worst_case.soft_max(free, free_in & jnp.isfinite(free), temperature),
        "soft_detect": worst_case.soft_min(detect, detect_in & jnp.isfinite(detect), temperature),
        "tau_f": jnp.where(jnp.any(free_in), jnp.max(jnp.where(free_in, hard_free, -jnp.inf)), jnp.nan),
        "tau_d": jnp.where(jnp.any(detect_in), jnp.min(jnp.where(detect_in, hard_detect, jnp.inf)), jnp.nan),
    }


STATIC = ("dt_s", "detector", "tune_pole")


@partial(jax.jit, static_argnames=STATIC)
def gap_and_grad(theta: Tunable, fdd_params, settings, data: TrainingSet, temperature, dt_s: float, detector: str,
                 tune_pole: bool):
    """Smooth log gap ``soft_detect - soft_free`` at ``theta``, the bounds and the gradient in theta."""
    def gap(theta):
        b = bounds(apply(fdd_params, detector, theta, tune_pole), settings, data, temperature, dt_s, detector)
        return b["soft_detect"] - b["soft_free"], b

    (value, b), grad = jax.value_and_grad(gap, has_aux=True)(theta)
    return value, b, grad


@partial(jax.jit, static_argnames=("dt_s", "detector"))
def evaluate(fdd_params, settings, data: TrainingSet, temperature, dt_s: float, detector: str) -> dict:
    """:func:`bounds` of given FDD parameters (no gradient), one jit."""
    return bounds(fdd_params, settings, data, temperature, dt_s, detector)


@partial(jax.jit, static_argnames=("dt_s", "detector", "identification"))
def threshold_scan(fdd_params, settings, data: TrainingSet, taus, dt_s: float, detector: str, identification: str):
    """False alarms (runs) and missed detections for each candidate threshold (K,), one jit.

    Definitions of the campaign (DESIGN.md section 5): LOE bank (its threshold tau is the
    signature's, so the identification level), a fault model identified before the fault and a
    parametric fault without a fault model identified in the window; stall
    detector, eta = 1 of the ``identification`` method ('signal' or 'model') outside stall loads
    and a relevant stall event not identified within ``stall_window_s``. Returns (runs with a false
    alarm (K,), runs with a miss (K,)).
    """
    def at(tau):
        def one(plant, v, h, truth):
            return fdd_run(with_threshold(fdd_params, detector, tau), settings, plant, v, h, truth, 1.0, dt_s)[1]

        out = jax.vmap(one)(data.plant, data.vcas_m_s, data.altitude_m, data.truth)
        ok = out["status"] == campaign.Status.OK
        if detector == "loe":
            false = ok & jnp.isfinite(out["false_identification_time_s"])
            missed = ok & data.counts & ~jnp.isfinite(out["identification_time_s"])
        else:
            false = ok & (out[f"eta_outside_{identification}_time_s"] < data.truth.onset_s)
            late = out[f"stall_worst_latency_{identification}_s"] > settings.stall_window_s
            missed = ok & ((out["stall_events"] > out[f"stall_identified_{identification}"]) | late)
        return jnp.sum(false), jnp.sum(missed)

    return jax.lax.map(at, taus)


class Result(NamedTuple):
    """Iterates of a tuning run: parameters (I + 1) and per iteration the smooth gap and the bounds."""

    thetas: list
    gaps: np.ndarray
    bounds: list


def tune(gap_and_grad_fn, theta0: Tunable, iterations: int, learning_rate: float, callback=None) -> Result:
    """Adam ascent of the smooth log gap. ``gap_and_grad_fn(theta)`` returns (gap, bounds, gradient);
    ``callback(i, gap, bounds)`` sees every evaluation. Evaluations: iterations + 1."""
    opt = standard_promotion(optax.adam(learning_rate))
    theta = theta0
    state = opt.init(theta)
    thetas, gaps, all_bounds = [], [], []
    for i in range(iterations + 1):
        gap, b, grad = gap_and_grad_fn(theta)
        b = {k: float(v) for k, v in b.items()}
        thetas.append(theta)
        gaps.append(float(gap))
        all_bounds.append(b)
        if callback is not None:
            callback(i, float(gap), b)
        if i == iterations:
            break
        grad = jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        updates, state = opt.update(jax.tree.map(jnp.negative, grad), state, theta)
        theta = optax.apply_updates(theta, updates)
    return Result(thetas, np.asarray(gaps), all_bounds)


def normalised_gap(tau_f, tau_d):
    """(tau_d - tau_f) / tau_f."""
    return (np.asarray(tau_d) - np.asarray(tau_f)) / np.asarray(tau_f)


def best_iterate(result: Result) -> int:
    """Iteration with the largest hard normalised gap on the training set (the first if none is finite)."""
    gaps = np.array([normalised_gap(b["tau_f"], b["tau_d"]) for b in result.bounds])
    gaps = np.where(np.isfinite(gaps), gaps, -np.inf)
    return int(np.argmax(gaps))

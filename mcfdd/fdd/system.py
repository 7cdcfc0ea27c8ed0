"""The on-board FDD: both of the paper's systems in one pure step over measured signals.

- Model detection for parametric LOE faults (Fig. 1, Section 4): a bank of detectors (20) with
  the gains k^(i) of the LPV bank, Narendra evaluators, the normalised decision (15) and the
  signature decoding into a detected model id. Residuals are evaluated only while the tracking
  error stays inside the servo valve's linear range (beyond it the rod moves at a saturated rate,
  which no first-order model follows) and the estimated hinge-load fraction stays below
  ``max_load_fraction`` (1: no load gate): the affine gains of eq. (4) cannot follow the
  square-root fall of the gain towards a stall load, and the uncertainty of the hinge load and
  supply pressure moves the gain more the nearer the stall. The bank's estimate,
  ``1 - (k_fault-free / k_no-load)^2`` (the no-load model is the one with nu = [1, 0]), is the
  healthy surface's load: gated on it (``load_gate = "fault_free"``), the gate also hides a
  disconnected rod, which carries no load, exactly where its disconnection shows most (large
  deflections), and on a rod held at its stop the estimate chatters with the direction estimate
  between about +0.7 and -1.1, restarting the filters at every switch. Gated on the load the rod's
  motion shows (``load_gate = "best_fit"``), the estimate is multiplied by the surface
  effectiveness nu2 of the bank model with the smallest evaluated residual so far (the evaluator
  memories before this sample, which share ||u||): a disconnected rod is best explained by the
  no-load model and is never gated, a healthy rod near a stall load by the fault-free or a
  pressure-loss model (nu2 = 1) and is gated as before. nu2 alone, not nu2 / nu1 (a pressure-loss
  model's own load fraction): a slow servo fits a pressure-loss model, and gating it earlier
  raised false alarms under Kci +-10 % (README, FDD design). While evaluation is suspended, and at
  the first sample after (the last gated sample's step propagates the first-order prediction of a saturated
  sample, which the rod did not follow), the bank's filters and the excitation low-pass restart
  from equilibrium with the measured position (residual 0, ||u|| input 0), so no filter carries a
  transient of the gated interval out of it: after the gate reopens, every residual and ||u||
  are driven by the same measured tracking error from zero. Decisions are made while ||u|| is
  above the excitation floor, optionally with each sample's excitation weighted by the estimated
  load fraction (``excitation_load_fraction``): surface losses only show where the hinge load is
  large, and sensor noise dominates the ratio at small excitation. The floor is absolute or, with
  ``excitation_noise_factor`` > 0, at least that many times the run's own sensor-noise RMS
  (estimated online from the measured position, :func:`mcfdd.fdd.decision.noise_step`) in the
  units of ||u|| (times the evaluator's DC gain alpha + beta / gamma): ||u|| of a rod at rest is
  about 0.8 times the noise RMS, so an absolute floor set for the noisiest sensor decides nothing
  on a quiet one's small manoeuvres and sits at the noise of the noisiest. While a stall
  load is identified (eta = 1 by either method) and ``stall_hold_s`` after, no LOE decision is
  made: the stall awareness the paper's Section 6.2 asks for, so that the large residuals of a
  stall do not raise LOE alarms.
- sgn(xdot) of the LPV gains (eq. 3) is estimated on board as the sign of the measured tracking
  error low-passed (pole ``direction_pole``) up to the previous sample. The sign of the current
  sample's u_c - u would correlate with its sensor noise: where the error is within the noise (a
  held deflection), k(s) (u_c - u) then rectifies the noise through the model's direction
  dependence, which at a large hinge load gives the fault-free filter a bias the no-load model
  has not, just as a disconnection does.
- Two levels of output, as an FDD engineer reads them: detection (``fault_detected``: the
  fault-free model rejected, theta_0 / ||u|| >= ``detection_tau`` and at least
  ``detection_contrast`` above the smallest ratio of the fault models while excited, without
  interruption for ``detection_confirm_s``: "an LOE fault is present"; sensor noise at the
  excitation floor raises every ratio alike, a fault lowers the ratio of the models near it) and identification
  (``detected``: the decoded signature (15), confirmed over ``confirm_s``). Thresholds of the
  signature are constant or scheduled online on eq. (16) at the current scheduling point.
- Stall loads (Fig. 2, Section 5): the detector (20) scheduled on the fault-free model, its
  evaluator and decision (25), and both identification methods of Section 5.4. Optionally the
  detector is not evaluated while the rod slews at its saturated rate (:mod:`mcfdd.fdd.stall`'s
  rate-saturation gate: its filter restarts from equilibrium there and at the first sample after), and
  optionally both identification methods are opened by their own gate instead of the detector's iota
  (:mod:`mcfdd.fdd.stall`'s identification gate: theta above its own threshold and the residual now of
  the stall's sign).

Inputs are what an aircraft has: the command u_c, the measured rod position u and the flight
parameters p = (Vcas, h). All numbers that may be tuned are leaves of :class:`FddParams`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.compute import ONE, once
from mcfdd.fdd import decision, evaluator, lpv, residual, stall, thresholds


class LoeParams(NamedTuple):
    bank: lpv.GainBank
    pole: float  # a of the bank's filters and of the excitation low-pass (1/s)
    direction_pole: float  # pole of the tracking-error low-pass whose previous sample gives sgn(xdot) (1/s)
    evaluator: evaluator.NarendraParams
    tau: jnp.ndarray  # threshold(s) on theta_i / ||u||, scalar or (N,)
    tau_schedule: float | None  # tau_i(rho) = max(tau, tau_schedule * distance (16) to the nearest model at rho);
    # None: constant thresholds, the schedule not built (static structure, see :func:`switch`)
    detection_tau: float  # the fault-free model is rejected while theta_0 / ||u|| is above this (and excited)
    detection_confirm_s: float  # ... for this long without interruption: an LOE fault is detected
    # ... and theta_0 / ||u|| at least this above the best-fitting fault model's
    detection_contrast: float
    # minimum ||u|| (theta units, m s), load-weighted if excitation_load_fraction > 0, for a decision
    excitation_floor: float
    # excitation counts in full from this estimated hinge-load fraction up;
    # None: everywhere, the weighted evaluator not built
    excitation_load_fraction: float | None
    # the floor is at least this many sensor-noise RMS (estimated online) in the units of ||u||;
    # None: the floor is absolute, the noise estimate not built
    excitation_noise_factor: float | None
    noise_gamma: float  # forgetting rate of the online noise estimate (1/s)
    confirm_s: float  # a decoded model must persist this long to become a decision
    # evaluation is suspended above this estimated hinge-load fraction; None: no load gate (not built)
    max_load_fraction: float | None
    # (N,) surface effectiveness nu2 of each model: the gate applies to the load the surface of the model that
    # explains the rod best carries; None: to the fault-free estimate (the healthy surface's load)
    load_scales: jnp.ndarray | None
    linear_range_m: float  # ... and while |u_c - u| exceeds the servo valve's linear range
    stall_hold_s: float  # no LOE decision while a stall load is identified and this long after


class StallParams(NamedTuple):
    pole: float
    evaluator: evaluator.NarendraParams
    tau: float  # on theta, rod units
    signal: stall.SignalRules
    model: stall.ModelRule
    # rate-saturation gate of the detector (:mod:`mcfdd.fdd.stall`); None: no gate (not built)
    saturation: stall.SaturationGate | None = None
    # identification gate of both methods (:mod:`mcfdd.fdd.stall`); None: the detector's iota opens them
    identification: stall.IdentificationGate | None = None


class FddParams(NamedTuple):
    loe: LoeParams
    stall: StallParams
    one: float = ONE  # a runtime 1.0 for :func:`mcfdd.compute.once`


class FddState(NamedTuple):
    bank_xq: jnp.ndarray
    bank_xi: jnp.ndarray
    band: jnp.ndarray
    band_xi: jnp.ndarray
    band_w_xi: jnp.ndarray | None  # evaluated load-weighted excitation (None without load weighting)
    noise: decision.NoiseState | None  # online sensor-noise estimate (None with an absolute floor)
    was_valid: jnp.ndarray  # residuals were evaluated at the previous sample
    # low-passed measured tracking error u_c - u up to the previous sample (its sign is sgn(xdot))
    error_lp: jnp.ndarray
    confirm: tuple
    detect: tuple
    detect_min: jnp.ndarray  # least rejection margin over the current run of rejected samples
    since_stall: jnp.ndarray  # time since the last stall identification (s; :func:`never` before the first)
    stall_xq: jnp.ndarray
    stall_xi: jnp.ndarray
    signal: stall.SignalState
    model: stall.ModelState
    stall_rate: stall.RateState | None  # measured rate of the stall detector's gate (None without the gate)


class FddOutputs(NamedTuple):
    r: jnp.ndarray  # (N,) bank residuals (m)
    theta: jnp.ndarray  # (N,) evaluated residuals
    theta_u: jnp.ndarray  # ||u||, evaluated low-passed tracking error
    theta_w: jnp.ndarray  # the same weighted by the estimated load fraction (= theta_u without load weighting)
    ratio: jnp.ndarray  # (N,) theta_i / ||u|| (theta_i where ||u|| = 0)
    load_fraction: jnp.ndarray  # estimated hinge-load fraction (residual evaluation stops above the limit)
    excited: jnp.ndarray  # ||u|| above the excitation floor: decisions are made
    noise_rms: jnp.ndarray | None  # online estimate of the position sensor's noise RMS (m; None: not built)
    iota: jnp.ndarray  # (N,) signature
    decoded: jnp.ndarray  # model id of the signature, -1 for none
    detected: jnp.ndarray  # identification: confirmed model id, -1 for no decision
    fault_detected: jnp.ndarray  # detection: the fault-free model rejected, confirmed (an LOE fault is present)
    # signed statistic of fault_detected, positive where it is set up to rounding (:func:`decision.confirmed_margin`)
    detection_margin: jnp.ndarray
    r_stall: jnp.ndarray
    theta_stall: jnp.ndarray
    iota_stall: jnp.ndarray
    eta_signal: jnp.ndarray
    eta_model: jnp.ndarray
    # signed margins of eta of each method, relative: the least of the detector's theta over tau, the
    # gate (34)-(35) and rule (33) (signal) or theta_sl under tau_sl (model); positive where eta = 1 up to rounding
    eta_signal_margin: jnp.ndarray
    eta_model_margin: jnp.ndarray
    theta_sl: jnp.ndarray


def load_fraction(bank: lpv.GainBank, k):
    """Estimated hinge-load fraction F / (dP S) from the gains k (N,) of the bank's models.

    The fault-free gain scales as sqrt(1 - f) of the no-load gain (nu = [1, 0]) when the rod moves
    against the load and as sqrt(1 + f) when the load helps, so the estimate is signed; 0 if the
    bank has no no-load model.
    """
    no_load = jnp.isclose(bank.nu[:, 0], 1.0) & (bank.nu[:, 1] == 0.0)
    k_free = jnp.max(jnp.where(no_load, k, 0.0))
    return jnp.where(k_free > 0.0, 1.0 - (k[0] / jnp.where(k_free > 0.0, k_free, 1.0)) ** 2, 0.0)


def switch(value: float) -> float | None:
    """An option whose value 0 turns it off, as a leaf of :class:`LoeParams`: None when off.

    None is static structure (a pytree node with no leaves), so an option that is off is not
    built into the compiled step at all, while a value that is on stays a traced number (tuned,
    sampled, differentiated like any other).
    """
    return None if value == 0.0 else value


def excitation_weight(loe: LoeParams, load):
    """Weight of the excitation at estimated hinge-load fraction ``load``: min(1, |load| / f_ref).

    The fault-free and no-load models differ by about half the load fraction (the gain scales as
    sqrt(1 - f)), so excitation at small loads cannot separate a loss of surface effectiveness from
    the uncertainty; f_ref = ``excitation_load_fraction`` = 0 weighs every sample 1.
    """
    f_ref = loe.excitation_load_fraction
    return jnp.where(f_ref > 0.0, jnp.minimum(1.0, jnp.abs(load) / jnp.where(f_ref > 0.0, f_ref, 1.0)), 1.0)


def rejection_margin(loe: LoeParams, ratio0, contrast, theta_w, floor, since_stall):
    """Signed margin of the rejection of the fault-free model, in units of theta / ||u||: the least of
    ``theta_0 / ||u|| - detection_tau``, ``contrast - detection_contrast`` (contrast: theta_0 less the
    smallest fault model's theta, over ||u||), and the excitation over its ``floor`` (the fixed floor, or
    the one relative to the run's noise) and the time since
    the last stall identification over ``stall_hold_s``, each relative
    (:func:`mcfdd.fdd.decision.relative`) times ``detection_tau``. Positive where the sample rejects,
    up to rounding."""
    return jnp.minimum(jnp.minimum(ratio0 - loe.detection_tau, contrast - loe.detection_contrast),
                       jnp.minimum(decision.relative(theta_w, floor, loe.detection_tau),
                                   decision.relative(since_stall, loe.stall_hold_s, loe.detection_tau)))


def never(dtype):
    """The time since the last stall identification (s) of a run that has had none: sqrt of the dtype's
    largest float (1.8e19 s in float32), finite so that the stall-hold term of :func:`rejection_margin`
    and its derivative in ``detection_tau`` stay finite (an infinite time gives an infinite derivative,
    and the zero cotangent of the min not taken times it a NaN gradient), large enough that adding
    sample times never changes it and that the term is never the least; its square stays finite."""
    return jnp.sqrt(jnp.asarray(jnp.finfo(dtype).max, dtype))


def init(params: FddParams, u0) -> FddState:
    """State for a start at rest (in equilibrium) at measured position u0."""
    n = params.loe.bank.k0.shape[0]
    u0 = jnp.asarray(u0)
    bank_xq = jnp.broadcast_to(residual.init(u0), (n,))
    return FddState(
        bank_xq=bank_xq,
        bank_xi=jnp.zeros_like(bank_xq),
        band=decision.excitation_init(u0),
        band_xi=jnp.zeros_like(u0),
        band_w_xi=None if params.loe.excitation_load_fraction is None else jnp.zeros_like(u0),
        noise=None if params.loe.excitation_noise_factor is None else decision.noise_init(u0),
        was_valid=jnp.asarray(True),
        error_lp=jnp.zeros_like(u0),
        confirm=decision.confirm_init(),
        detect=decision.confirm_init(),
        detect_min=jnp.zeros_like(u0),
        since_stall=never(u0.dtype),
        stall_xq=residual.init(u0),
        stall_xi=jnp.zeros_like(u0),
        signal=stall.signal_init(u0),
        model=stall.model_init(u0),
        stall_rate=None if params.stall.saturation is None else stall.rate_init(u0),
    )


def step(params: FddParams, state: FddState, u_c, u, vcas_m_s, altitude_m, t_s, dt_s: float):
    """One sample of both FDD systems. Returns (new state, :class:`FddOutputs` at time t)."""
    loe, stl = params.loe, params.stall
    bank = loe.bank
    direction = jnp.sign(state.error_lp)
    phi_d = jnp.exp(-loe.direction_pole * dt_s)
    error_lp = phi_d * state.error_lp + (1.0 - phi_d) * (u_c - u)
    k = once(lpv.gains(bank, u, direction, vcas_m_s, altitude_m), params.one)

    load = load_fraction(bank, k)
    valid = jnp.abs(u_c - u) <= loe.linear_range_m
    if loe.max_load_fraction is not None:
        # asarray: the scales may be a host constant (parameters closed over, not passed to jit)
        gated = load if loe.load_scales is None else load * jnp.asarray(loe.load_scales)[jnp.argmin(state.bank_xi)]
        valid = (jnp.abs(gated) <= loe.max_load_fraction) & valid
    running = valid & state.was_valid
    bank_xq = jnp.where(running, state.bank_xq, residual.init(u))
    bank_xq, r = residual.step(k, bank.k0, loe.pole, bank_xq, u, u_c, dt_s)
    r = once(r, params.one)
    bank_xi, theta = evaluator.step(loe.evaluator, state.bank_xi, r, dt_s)
    theta = once(theta, params.one)
    band = jnp.where(running, state.band, decision.excitation_init(u))
    band, bp = decision.excitation_step(loe.pole, band, u_c, u, dt_s)
    band_xi, theta_u = once(evaluator.step(loe.evaluator, state.band_xi, bp, dt_s), params.one)
    if loe.excitation_load_fraction is None:
        band_w_xi, theta_w = None, theta_u
    else:
        band_w_xi, theta_w = once(evaluator.step(loe.evaluator, state.band_w_xi, bp * excitation_weight(loe, load),
                                                 dt_s), params.one)
    tau = loe.tau
    if loe.tau_schedule is not None:
        tau = jnp.maximum(tau, loe.tau_schedule * thresholds.nearest_ratio(k, bank.k0))
    iota = decision.signature(theta, theta_u, tau)
    floor = loe.excitation_floor
    if loe.excitation_noise_factor is None:
        noise, noise_rms = None, None
    else:
        noise, noise_rms = once(decision.noise_step(loe.noise_gamma, state.noise, u, dt_s), params.one)
        ev = loe.evaluator
        floor = once(jnp.maximum(floor, loe.excitation_noise_factor * (ev.alpha + ev.beta / ev.gamma) * noise_rms),
                     params.one)
    excited = theta_w >= floor
    stall_xq = state.stall_xq
    if stl.saturation is None:
        stall_rate = None
    else:
        stall_rate, rate = stall.rate_step(stl.saturation.rate_pole, state.stall_rate, u, dt_s)
        stall_open = once(stall.saturation_margin(stl.saturation, k[0], u_c, u, rate), params.one) < 0.0
        stall_xq = jnp.where(stall_open & stall_rate.was_open, stall_xq, residual.init(u))
        stall_rate = stall_rate._replace(was_open=stall_open)
    stall_xq, r_stall = once(residual.step(k[0], bank.k0[0], stl.pole, stall_xq, u, u_c, dt_s), params.one)
    stall_xi, theta_stall = once(evaluator.step(stl.evaluator, state.stall_xi, r_stall, dt_s), params.one)
    iota_stall = decision.threshold(theta_stall, stl.tau)
    if stl.identification is None:
        opens, iota_id = decision.relative(theta_stall, stl.tau), iota_stall
    else:
        opens = once(stall.identification_margin(stl.identification, theta_stall, r_stall, u), params.one)
        iota_id = opens >= 0.0
    gate_margin = once(stall.conditions_margin(stl.signal, u_c, u), params.one)
    gate = gate_margin >= 0.0  # both methods' gate, (34)-(35)
    signal, eta_signal, slow = stall.signal_step(stl.signal, state.signal, iota_id, gate, u, t_s, dt_s)
    model, eta_model, _, theta_sl = stall.model_step(stl.model, state.model, iota_id, gate, u_c, u, dt_s)
    eta_signal, eta_model = once(eta_signal, params.one), once(eta_model, params.one)
    both = once(jnp.minimum(opens, gate_margin), params.one)
    eta_margins = (jnp.minimum(both, slow), jnp.minimum(both, decision.below(theta_sl, stl.model.tau)))
    since_stall = jnp.where(eta_signal | eta_model, 0.0, state.since_stall + dt_s)

    stall_aware = since_stall <= loe.stall_hold_s
    decoded = jnp.where(stall_aware, decision.NO_DECISION, decision.decode(iota, excited))
    confirm, detected = decision.confirm_step(loe.confirm_s, state.confirm, decoded, dt_s)
    detected = once(detected, params.one)
    contrast = theta[0] - jnp.min(theta[1:])
    rejected = (excited & ~stall_aware & decision.signature(theta[0], theta_u, loe.detection_tau)
                & decision.signature(contrast, theta_u, loe.detection_contrast))
    detect, fault = decision.confirm_step(loe.detection_confirm_s, state.detect,
                                          jnp.where(rejected, 1, decision.NO_DECISION).astype(jnp.int32), dt_s)
    fault = once(fault == 1, params.one)
    per_u = 1.0 / jnp.where(theta_u > 0.0, theta_u, 1.0)
    ratio = once(theta / jnp.where(theta_u > 0.0, theta_u, 1.0), params.one)
    margin = once(rejection_margin(loe, ratio[0], contrast * per_u, theta_w, floor, since_stall), params.one)
    detect_min, detection_margin = decision.confirmed_margin(loe.detection_confirm_s, loe.detection_tau,
                                                             state.detect_min, margin, rejected, detect[1], dt_s)
    detection_margin = once(detection_margin, params.one)

    new = FddState(bank_xq, bank_xi, band, band_xi, band_w_xi, noise, valid, error_lp, confirm, detect, detect_min,
                   since_stall, stall_xq, stall_xi, signal, model, stall_rate)
    return new, FddOutputs(r, theta, theta_u, theta_w, ratio, load, excited, noise_rms, iota, decoded, detected, fault,
                           detection_margin, r_stall, theta_stall, iota_stall, eta_signal, eta_model, *eta_margins,
                           theta_sl)

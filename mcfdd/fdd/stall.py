"""Stall-load identification, Section 5.4: model detection (a) and signal-based rules (b).

(a) Model detection with Q_sl, eq. (30): the stalled actuator is modelled as a first-order lag
with a very small gain k_sl (0.01..0.1 1/s). Q_sl is the detector of eq. (20) with k = k0 = k_sl
and its own pole a_sl (:mod:`mcfdd.fdd.residual`), evaluated by its own Narendra filter; a stall
is identified while the stall detector fires (iota = 1) and theta_sl stays below tau_sl. A jammed
rod follows the stall model just as well, so conditions (34) and (35) of (b) gate (a) too:
jamming is of interest at small deflections, stall loads occur at large ones.

(b) Signal-based rules, started at the detection time t_d (rising edge of iota):

    (33) |mean rate| = |u(t) - u(t_a)| / (t - t_a) <= u_dot_min,  t - t_a >= window_s
    (34) |u_c| >= tau_uc,max  and  |u| >= tau_u,max
    (35) sgn(u_c - u) = sgn(u), with |u_c - u| above a small margin (sensor noise)

and eta = 1 while iota = 1 and all three hold. The anchor (t_a, u(t_a)) of the mean rate (32) is
set at t_d; because the evaluator holds iota up long after a stall ends, the anchor also moves to
the current sample whenever the rod has been seen moving (mean rate above u_dot_min) over at least
``window_s`` since the anchor. A later stall within the same alarm is then identified from a fresh
anchor instead of a mean rate diluted by the motion in between. The mean rate is only trusted
over at least ``window_s``: over a sample or two, position-sensor noise alone (0.05 mm over
0.01 s is 5 mm/s) decides (33), and single-sample identifications followed. On
``configs/stall_campaign.toml`` this took eta = 1 outside stall loads from 20 of 8,192 runs to
2 and the median identification latency from 0.05 s to 0.12 s.

Each rule also has a signed margin relative to its threshold (``(x - threshold) / threshold``,
positive where the rule holds up to rounding; :func:`mcfdd.fdd.decision.relative`), and eta of a method the least of
its rules' margins: the scoring's false stall identification margin (DESIGN.md section 5a) is
built from them.

Rate-saturation gate of the stall detector (off by default). The detector (20) models the rod as a
first-order lag, rate k (u_c - u); beyond the servo valve's linear range (|u_c - u| above
``error_m``, where the valve current saturates at i_max) the rod slews at the saturated rate, about
k ``error_m``, far below k (u_c - u), and the residual grows as in a stall: a full-stick reversal of a
slow servo gave theta 8 deg against tau = 1 deg with no stall load (README, Worst cases and tuning).
Both show a large tracking error; what tells them apart on board is the rod's measured motion: in
a saturated slew it moves towards the command at about the saturated rate, in a stall it stops.
The gate is closed (the detector's filter restarts from equilibrium with the measured position, at
that sample and the first one after, as the LOE bank's gates do) where :func:`saturation_margin`
is not negative: the least of the tracking error over ``error_m`` and the measured rate towards
the command, ``sgn(u_c - u) udot``, over ``rate_fraction`` times the model's saturated rate
``k error_m``, each relative. The measured rate is the backward difference of the measured position,
low-passed at ``rate_pole`` (:func:`rate_step`); a stall (rate near 0) is never gated.

Identification gate (off by default): the detector's own iota = [theta >= tau] opens both methods, and
theta carries the evaluator's memory (gamma 0.1 1/s: 10 s) of an earlier stall load. Measured on
``configs/stall_campaign.toml`` (seed 11, README "The stall detector"): the relevant stall loads
identified late are weak ones, the rod stopped with |u_c - u| of 0.5-1.1 deg and rules (33)-(35)
holding 0.2-0.7 s before theta reached tau = 1 deg (the residual of a stopped rod is about k / k0 times
the tracking error, k / k0 near 0.5 at those loads); the identifications outside stall loads are a
rod creeping towards its command at 0.5-5 deg/s after a stall load, iota held by the memory while
the residual itself is 0.1-0.25 deg. With :class:`IdentificationGate` the methods open where
:func:`identification_margin` is not negative: theta at least ``tau`` (its own threshold, e.g. lower
than the detector's) and, optionally, the residual now of the stall's sign, ``-sgn(u) r`` (the rod
short of the model's prediction outwards: a stalled rod stops while the model (20) moves it towards
u_c, and (35) has u_c beyond u), at least ``residual_min_m``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.fdd import decision, evaluator, residual


class SignalRules(NamedTuple):
    """Parameters of the signal-based identification, rod units (m, m/s, s)."""

    rate_min_m_s: float
    command_min_m: float
    position_min_m: float
    window_s: float
    error_min_m: float


class ModelRule(NamedTuple):
    """Parameters of identification by model detection with Q_sl."""

    k_sl: float
    pole: float
    evaluator: evaluator.NarendraParams
    tau: float


class SaturationGate(NamedTuple):
    """Parameters of the rate-saturation gate of the stall detector, rod units (m, 1/s)."""

    error_m: float  # servo valve linear range: beyond this tracking error the valve current saturates
    rate_fraction: float  # gated while the rod moves towards the command at least this fraction of k error_m
    rate_pole: float  # pole of the low-pass of the measured rate (1/s)


class IdentificationGate(NamedTuple):
    """Parameters of the identification gate (rod units, m)."""

    tau: float  # theta at least this opens identification
    residual_min_m: float | None  # ... and the outward residual -sgn(u) r at least this; None: no residual condition


def identification_margin(gate: IdentificationGate, theta, r, u):
    """Signed margin of the identification gate, open where it is not negative: the least of theta over
    ``gate.tau`` and (unless ``residual_min_m`` is None) of ``-sgn(u) r`` over ``residual_min_m``, each
    relative (:func:`mcfdd.fdd.decision.relative`). theta, r: the detector's (20) evaluated and raw
    residual at this sample, u the measured position, all in m."""
    margin = decision.relative(theta, gate.tau)
    if gate.residual_min_m is None:
        return margin
    return jnp.minimum(margin, decision.relative(-jnp.sign(u) * r, gate.residual_min_m))


class RateState(NamedTuple):
    """Low-passed measured rate of the rod and whether the stall detector was evaluated at the last sample."""

    previous: jnp.ndarray  # measured position of the sample before (m)
    rate: jnp.ndarray  # low-passed backward difference (m/s)
    was_open: jnp.ndarray  # the gate was open (the detector evaluated) at the sample before


def rate_init(u0) -> RateState:
    """A rod at rest at measured position u0, the gate open."""
    u0 = jnp.asarray(u0)
    return RateState(u0, jnp.zeros_like(u0), jnp.asarray(True))


def rate_step(pole, state: RateState, u, dt_s: float):
    """Measured rate including the sample u (m): ``rate+ = phi rate + (1 - phi) (u - u_prev) / dt``,
    ``phi = exp(-pole dt)``. Returns (state with the new position and rate, rate in m/s)."""
    phi = jnp.exp(-pole * dt_s)
    rate = phi * state.rate + (1.0 - phi) * (u - state.previous) / dt_s
    return state._replace(previous=u, rate=rate), rate


def saturation_margin(gate: SaturationGate, k, u_c, u, rate):
    """Signed margin of the rate-saturation gate (closed where it is not negative): the least of
    ``|u_c - u|`` over ``error_m`` and ``sgn(u_c - u) rate`` over ``rate_fraction k error_m`` (the
    model's saturated rate at gain k, 1/s), each relative (:func:`mcfdd.fdd.decision.relative`)."""
    error = u_c - u
    return jnp.minimum(decision.relative(jnp.abs(error), gate.error_m),
                       decision.relative(jnp.sign(error) * rate, gate.rate_fraction * k * gate.error_m))


class SignalState(NamedTuple):
    anchor_t_s: jnp.ndarray
    anchor_u_m: jnp.ndarray
    iota_prev: jnp.ndarray


def conditions_margin(rules: SignalRules, u_c, u):
    """Signed margin of conditions (34) and (35), the gate of both identification methods: the least of
    |u_c| and |u| over their large-signal thresholds (34) and of the outward error sgn(u) (u_c - u)
    over ``error_min_m`` (35), each relative (:func:`mcfdd.fdd.decision.relative`); the gate is open
    where it is not negative (:func:`conditions`).

    (35) is sgn(u_c - u) = sgn(u) with |u_c - u| at least ``error_min_m``, that is sgn(u) (u_c - u) >=
    error_min_m for a positive ``error_min_m``. Without that margin a rod resting on its command at a
    large deflection (e = 0 up to sensor noise) would meet (35) on every other sample.
    """
    large = jnp.minimum(decision.relative(jnp.abs(u_c), rules.command_min_m),
                        decision.relative(jnp.abs(u), rules.position_min_m))
    return jnp.minimum(large, decision.relative(jnp.sign(u) * (u_c - u), rules.error_min_m))


def conditions(rules: SignalRules, u_c, u):
    """Conditions (34) and (35) together: :func:`conditions_margin` not negative."""
    return conditions_margin(rules, u_c, u) >= 0.0


def signal_init(u0) -> SignalState:
    u0 = jnp.asarray(u0)
    return SignalState(jnp.zeros_like(u0), u0, jnp.zeros_like(u0, dtype=bool))


def signal_step(rules: SignalRules, state: SignalState, iota, gate, u, t_s, dt_s: float):
    """Rules (32)-(35) with the anchor logic of the module docstring; ``gate`` is :func:`conditions`.

    Returns (new state, eta, signed margin of rule (33): the lesser of the elapsed time over the window
    and the mean rate under u_dot_min, relative).
    """
    rising = iota & ~state.iota_prev
    anchor_t = jnp.where(rising, t_s, state.anchor_t_s)
    anchor_u = jnp.where(rising, u, state.anchor_u_m)
    elapsed = t_s - anchor_t
    mean_rate = jnp.abs(u - anchor_u) / jnp.maximum(elapsed, 1e-9)
    long_enough = elapsed >= rules.window_s - 0.5 * dt_s
    slow = long_enough & (mean_rate <= rules.rate_min_m_s)
    eta = iota & slow & gate
    moved = long_enough & (mean_rate > rules.rate_min_m_s)
    new = SignalState(jnp.where(moved, t_s, anchor_t), jnp.where(moved, u, anchor_u), iota)
    margin = jnp.minimum(decision.relative(elapsed, rules.window_s - 0.5 * dt_s),
                         decision.below(mean_rate, rules.rate_min_m_s))
    return new, eta, margin


class ModelState(NamedTuple):
    x_q: jnp.ndarray
    xi: jnp.ndarray


def model_init(u0) -> ModelState:
    return ModelState(residual.init(u0), evaluator.init(jnp.asarray(u0)))


def model_step(rule: ModelRule, state: ModelState, iota, gate, u_c, u, dt_s: float):
    """Identification (a), gated by ``gate`` (:func:`conditions`). Returns (new state, eta, r_sl, theta_sl)."""
    x_q, r_sl = residual.step(rule.k_sl, rule.k_sl, rule.pole, state.x_q, u, u_c, dt_s)
    xi, theta_sl = evaluator.step(rule.evaluator, state.xi, r_sl, dt_s)
    eta = iota & (theta_sl < rule.tau) & gate
    return ModelState(x_q, xi), eta, r_sl, theta_sl

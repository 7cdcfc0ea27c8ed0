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

"""A normal-law-like flight control law of the full aircraft (DESIGN.md section 3, issue 15).

Four channels, each with gains scheduled on the dynamic pressure through the aircraft's control
powers (computed by the caller from the measured flight point every sample):

- roll: the roll-rate law of :mod:`mcfdd.plant.control_law` (stick demands roll rate, neutral
  stick holds bank up to 33 deg, bank protection at 67 deg). In the bank-target mode
  (coordinated turn) and the heading-target mode (bank demand ``atan(V k_psi (psi_t - psi) / g)``
  limited to ``nav_bank``) the demanded roll rate is ``k_phi (phi_t - phi)``, changing by at most
  ``max_roll_accel`` per second (a mode engaging with a large bank error would otherwise step the
  aileron command to its stop); the stick's demand is the pilot's, as on the roll axis. The bank
  protection limits either.
- pitch: the longitudinal stick demands a load-factor increment ``dnz = stick max_dnz``: a pitch
  rate ``(g / V) (dnz + k_n (n_turn + dnz - nz))``, the steady pull-up's rate and the measured
  load factor's error (n_turn = 1 / cos(phi) up to 33 deg of bank); with the stick neutral the law
  holds the flight-path angle it had at release (plus the FPA target of the fpa_change manoeuvre)
  through ``q_c = k_gamma (gamma_t - gamma)``, with the pitch rate of a level turn added up to 33
  deg of bank. A PI law on the pitch-rate error moves the stabiliser, ``k_p = 1 / (tau |M_dt|)``; its
  integral is a pitch attitude hold.
- yaw: yaw damper on ``r - g sin(phi) cos(theta) / V`` (turn coordination), the rudder that holds
  the demanded sideslip against the directional stiffness (``N_beta beta_c``, feedforward) and a
  PI law on the sideslip error (steady-sideslip manoeuvre, pedal), all divided by the rudder
  power ``|N_dr|``.
- autothrust: a PI law on the calibrated-airspeed error towards the speed target, divided by the
  acceleration per unit throttle.

Integrators stop while their output saturates in the direction they push (anti-windup).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
from jax import lax

from mcfdd.compute import once
from mcfdd.plant import control_law, rcam
from mcfdd.plant.atmosphere import G0_M_S2


class FlightLawParams(NamedTuple):
    max_load_factor_step: float = 0.3  # g demanded beyond 1 g by full longitudinal stick (no alpha protection)
    load_factor_gain: float = 3.0  # pitch rate per load-factor error, in units of g / V
    path_gain_1_s: float = 0.6
    pitch_time_constant_s: float = 0.5
    pitch_integral_1_s: float = 1.0
    yaw_damping_1_s: float = 1.5
    sideslip_gain_1_s2: float = 1.0
    sideslip_integral_1_s3: float = 0.5
    pedal_sideslip_rad: float = math.radians(10.0)  # sideslip demanded by full pedal
    bank_gain_1_s: float = 0.5
    max_roll_accel_rad_s2: float = math.radians(20.0)  # the demanded roll rate changes no faster
    heading_gain_1_s: float = 0.1
    nav_bank_rad: float = math.radians(25.0)
    speed_gain_1_s: float = 0.15
    speed_integral_1_s2: float = 0.01
    stick_deadband: float = 0.02


class ControlPowers(NamedTuple):
    """Nominal control powers of the flight point: roll damping L_p (1/s), L_da, M_dt, N_dr (1/s^2),
    the acceleration per rad of throttle on both engines (m/s^2) and the directional stiffness
    N_beta (1/s^2)."""

    roll_damping: jnp.ndarray
    aileron: jnp.ndarray
    stabiliser: jnp.ndarray
    rudder: jnp.ndarray
    throttle: jnp.ndarray
    sideslip: jnp.ndarray


class Measurements(NamedTuple):
    """What the law reads: the body state (rates and attitude), air data, flight path (rad, m/s) and the
    body normal load factor (g)."""

    body: rcam.RcamState
    beta: jnp.ndarray
    gamma: jnp.ndarray
    tas: jnp.ndarray
    vcas: jnp.ndarray
    nz: jnp.ndarray


class Authority(NamedTuple):
    """Position limits (rad) of the stabiliser, the rudder (symmetric) and the throttles, where the law's
    outputs saturate and its integrators stop (the surfaces' limits, :mod:`mcfdd.plant.rcam_loop`)."""

    stabiliser_min_rad: float
    stabiliser_max_rad: float
    rudder_max_rad: float
    throttle_min_rad: float
    throttle_max_rad: float


class Trim(NamedTuple):
    """Trim values the law starts from: stabiliser (rad), throttle (rad), speed target (m/s CAS)."""

    stabiliser: jnp.ndarray
    throttle: jnp.ndarray
    vcas: jnp.ndarray


class LawState(NamedTuple):
    roll_demand: jnp.ndarray  # demanded roll rate (rad/s), rate-limited
    roll: jnp.ndarray
    pitch: jnp.ndarray
    sideslip: jnp.ndarray
    speed: jnp.ndarray
    path_rad: jnp.ndarray  # flight-path angle held with the stick neutral


class Commands(NamedTuple):
    aileron: jnp.ndarray
    stabiliser: jnp.ndarray
    rudder: jnp.ndarray
    throttle: jnp.ndarray


def init(zero) -> LawState:
    """Integrators empty, level flight path held."""
    return LawState(zero, zero, zero, zero, zero, zero)


def _pi(integrator, error, offset, kp, ki, lo, hi, dt_s, one):
    """``offset + kp (e + ki integral e)`` limited to [lo, hi]; returns (new integrator, output)."""
    error = once(error, one)  # read by the output, the anti-windup test and the integrator
    raw = once(offset + kp * (error + ki * integrator), one)
    push = kp * error
    winding = ((raw > hi) & (push > 0)) | ((raw < lo) & (push < 0))
    return jnp.where(winding, integrator, integrator + dt_s * error), lax.clamp(lo, raw, hi)


def step(params: FlightLawParams, roll: control_law.RollLawParams, trim: Trim, powers: ControlPowers,
         state: LawState, pilot, meas: Measurements, max_aileron_rad, limits: Authority, dt_s: float, one=1.0):
    """One sample of the four channels. ``pilot`` is a :class:`~mcfdd.plant.manoeuvres.ManoeuvreInputs`;
    ``one`` the runtime 1.0 of :func:`mcfdd.compute.once`.

    Returns (new state, :class:`Commands` in rad).
    """
    body, g_v = meas.body, G0_M_S2 / meas.tas
    heading_error = jnp.arctan2(jnp.sin(pilot.heading_change_rad - body.psi),
                                jnp.cos(pilot.heading_change_rad - body.psi))
    # atan(V k_psi e / g) as atan2 of two variables: XLA CPU's vectorised atan2 of a constant gives results that
    # depend on the lane at 512-bit vectors (the campaign's compiler options), so a run would depend on its batch
    nav_bank = lax.clamp(-params.nav_bank_rad, jnp.arctan2(params.heading_gain_1_s * heading_error, g_v),
                         params.nav_bank_rad)
    bank_target = jnp.where(pilot.heading_mode, nav_bank, pilot.bank_rad)
    target_rate = lax.clamp(-roll.max_roll_rate_rad_s, params.bank_gain_1_s * (bank_target - body.phi),
                            roll.max_roll_rate_rad_s)
    max_change = params.max_roll_accel_rad_s2 * dt_s
    demand = jnp.where(pilot.heading_mode | pilot.bank_mode,
                       state.roll_demand + lax.clamp(-max_change, target_rate - state.roll_demand, max_change),
                       control_law.roll_rate_demand(roll, pilot.stick, body.phi))
    p_cmd = control_law.protect(roll, demand, body.phi)
    gains = control_law.schedule(roll, powers.roll_damping, powers.aileron)
    roll_int, aileron = control_law.step(roll, gains, state.roll, p_cmd, body.p, max_aileron_rad, dt_s)

    flying = jnp.abs(pilot.pitch_stick) >= params.stick_deadband
    path = jnp.where(flying, meas.gamma, state.path_rad)
    bank = lax.clamp(-roll.bank_hold_rad, body.phi, roll.bank_hold_rad)
    dnz = params.max_load_factor_step * jnp.clip(pilot.pitch_stick, -1.0, 1.0)
    q_cmd = g_v * jnp.sin(bank) * jnp.tan(bank) + jnp.where(
        flying, g_v * (dnz + params.load_factor_gain * (1.0 / jnp.cos(bank) + dnz - meas.nz)),
        params.path_gain_1_s * (path + pilot.fpa_rad - meas.gamma))
    pitch_int, stabiliser = _pi(state.pitch, q_cmd - body.q, trim.stabiliser,
                                -1.0 / (params.pitch_time_constant_s * jnp.abs(powers.stabiliser)),
                                params.pitch_integral_1_s, limits.stabiliser_min_rad, limits.stabiliser_max_rad,
                                dt_s, one)

    beta_cmd = pilot.sideslip_rad + params.pedal_sideslip_rad * jnp.clip(pilot.pedal, -1.0, 1.0)
    rudder_per_accel = 1.0 / jnp.abs(powers.rudder)
    damper_rate = params.yaw_damping_1_s * (body.r - g_v * jnp.sin(body.phi) * jnp.cos(body.theta))
    offset = rudder_per_accel * (damper_rate + powers.sideslip * beta_cmd)
    slip_int, rudder = _pi(state.sideslip, beta_cmd - meas.beta, offset, rudder_per_accel * params.sideslip_gain_1_s2,
                           params.sideslip_integral_1_s3 / params.sideslip_gain_1_s2, -limits.rudder_max_rad,
                           limits.rudder_max_rad, dt_s, one)

    speed_int, throttle = _pi(state.speed, trim.vcas + pilot.delta_vcas_m_s - meas.vcas, trim.throttle,
                              params.speed_gain_1_s / powers.throttle,
                              params.speed_integral_1_s2 / params.speed_gain_1_s, limits.throttle_min_rad,
                              limits.throttle_max_rad, dt_s, one)
    return (LawState(demand, roll_int, pitch_int, slip_int, speed_int, path),
            Commands(aileron, stabiliser, rudder, throttle))

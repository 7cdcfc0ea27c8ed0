"""Roll-rate command law producing the actuator command u_c (DESIGN.md section 3).

The sidestick demands a roll rate (full stick = ``max_roll_rate``). With the stick neutral the
law holds the bank angle up to ``bank_hold`` and rolls back to it beyond; bank protection limits
the demanded rate so that the bank stays below ``bank_protection``. A PI law on the roll-rate
error, with gains scheduled on the flight point through the nominal roll derivatives, cancels
the roll-damping pole:

    delta_c = (1 / (tau L_da)) (e_p + (-L_p) integral e_p),   e_p = p_cmd - p

so that the loop p / p_cmd is first order with time constant ``tau`` when the actuator is fast.
The integrator stops while the command is saturated in the direction of the error (anti-windup).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp


class RollLawParams(NamedTuple):
    max_roll_rate_rad_s: float = math.radians(15.0)
    bank_hold_rad: float = math.radians(33.0)
    bank_protection_rad: float = math.radians(67.0)
    time_constant_s: float = 0.5
    bank_return_gain_1_s: float = 0.5
    protection_gain_1_s: float = 0.5  # <= 1 / (4 time_constant): bank approaches the limit without overshoot
    stick_deadband: float = 0.02


class RollLawGains(NamedTuple):
    """Gains scheduled on the flight point: proportional (rad per rad/s) and integral (1/s)."""

    kp: jnp.ndarray
    ki: jnp.ndarray


def schedule(params: RollLawParams, roll_damping_1_s, aileron_power_1_s2) -> RollLawGains:
    """PI gains from the nominal roll derivatives L_p < 0 and L_da of the flight point."""
    kp = 1.0 / (params.time_constant_s * aileron_power_1_s2)
    return RollLawGains(kp, kp * -roll_damping_1_s)


def roll_rate_demand(params: RollLawParams, stick, phi_rad):
    """Demanded roll rate (rad/s) from stick deflection in [-1, 1] and bank angle."""
    neutral = jnp.abs(stick) < params.stick_deadband
    hold = -params.bank_return_gain_1_s * (phi_rad - jnp.clip(phi_rad, -params.bank_hold_rad, params.bank_hold_rad))
    return protect(params, jnp.where(neutral, hold, params.max_roll_rate_rad_s * jnp.clip(stick, -1.0, 1.0)), phi_rad)


def protect(params: RollLawParams, demand_rad_s, phi_rad):
    """Bank protection: the demanded roll rate limited so that |phi| approaches the limit smoothly."""
    upper = params.protection_gain_1_s * (params.bank_protection_rad - phi_rad)
    lower = -params.protection_gain_1_s * (params.bank_protection_rad + phi_rad)
    return jnp.clip(demand_rad_s, lower, upper)


def init():
    """Integrator state (rad/s * s) of the PI law."""
    return jnp.asarray(0.0)


def step(params: RollLawParams, gains: RollLawGains, integrator, p_cmd_rad_s, p_rad_s, max_command_rad,
         dt_s: float):
    """Returns (new integrator, surface deflection command delta_c in rad, saturated)."""
    e = p_cmd_rad_s - p_rad_s
    raw = gains.kp * e + gains.ki * integrator
    command = jnp.clip(raw, -max_command_rad, max_command_rad)
    winding = (jnp.abs(raw) > max_command_rad) & (jnp.sign(gains.kp * e) == jnp.sign(raw))
    return jnp.where(winding, integrator, integrator + dt_s * e), command

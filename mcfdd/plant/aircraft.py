"""Roll axis of a generic transport aircraft (GARTEUR RCAM coefficients, DESIGN.md section 3).

    C_l = C_lbeta beta + (cbar / V) (C_lp p + C_lr r) + C_lda delta_eff + C_ldr delta_r
    pdot = qbar S cbar C_l / Ixx,   phidot = p

RCAM normalises the roll moment by the mean chord cbar. Two ailerons roll the aircraft; the
monitored actuator drives one of them, which carries the share ``monitored_share`` of the roll
power and whose effectiveness is scaled by nu2 (surface damage or disconnection); the other one
follows the command. ``monitored_share = 1`` gives the single-surface reading
``C_lda nu2 delta_a``. The yaw rate is that of a coordinated turn, r = g sin(phi) / V, the
sideslip comes from the manoeuvre (rudder held to the steady-sideslip ratio) plus the lateral gust
v_g / V, and the aerodynamic roll rate is p - p_g.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.arrays import array_module
from mcfdd.plant.atmosphere import G0_M_S2


class AircraftParams(NamedTuple):
    """RCAM-like constants. Angles in rad, inertia in kg m^2."""

    wing_area_m2: float = 260.0
    mean_chord_m: float = 6.6
    span_m: float = 44.8
    mass_kg: float = 120000.0
    roll_inertia_kg_m2: float = 4.81e6
    cl_alpha_per_rad: float = 5.5
    cl_beta: float = -1.4
    cl_p: float = -11.0
    cl_r: float = 5.0
    cl_da: float = -0.6
    cl_dr: float = 0.22
    rudder_per_sideslip: float = 1.0
    monitored_share: float = 0.5
    max_alpha_rad: float = 0.2


class RollState(NamedTuple):
    p_rad_s: jnp.ndarray
    phi_rad: jnp.ndarray


def trim_alpha(params: AircraftParams, qbar_pa):
    """Wing angle of attack from the zero-lift line in level flight (rad), capped at max_alpha."""
    cl = params.mass_kg * G0_M_S2 / (qbar_pa * params.wing_area_m2)
    return array_module(cl).minimum(cl / params.cl_alpha_per_rad, params.max_alpha_rad)


def effective_aileron(params: AircraftParams, delta_monitored_rad, delta_command_rad, nu2):
    """Aileron deflection seen by the roll moment (rad)."""
    w = params.monitored_share
    return w * nu2 * delta_monitored_rad + (1.0 - w) * delta_command_rad


def roll_derivatives(params: AircraftParams, qbar_pa, tas_m_s, roll_inertia_kg_m2):
    """Dimensional roll damping L_p (1/s) and aileron power L_da (1/s^2) of the healthy aircraft."""
    scale = qbar_pa * params.wing_area_m2 * params.mean_chord_m / roll_inertia_kg_m2
    return scale * params.mean_chord_m / tas_m_s * params.cl_p, scale * params.cl_da


def init(p0_rad_s=0.0, phi0_rad=0.0) -> RollState:
    return RollState(jnp.asarray(p0_rad_s), jnp.asarray(phi0_rad))


def step(params: AircraftParams, state: RollState, delta_eff_rad, beta_rad, p_gust_rad_s, v_gust_m_s,
         qbar_pa, tas_m_s, roll_inertia_kg_m2, dt_s: float) -> RollState:
    """Semi-implicit Euler step of the roll axis."""
    r = G0_M_S2 * jnp.sin(state.phi_rad) / tas_m_s
    beta = beta_rad + v_gust_m_s / tas_m_s
    c_l = (params.cl_beta * beta
           + params.mean_chord_m / tas_m_s * (params.cl_p * (state.p_rad_s - p_gust_rad_s) + params.cl_r * r)
           + params.cl_da * delta_eff_rad
           + params.cl_dr * params.rudder_per_sideslip * beta_rad)
    pdot = qbar_pa * params.wing_area_m2 * params.mean_chord_m * c_l / roll_inertia_kg_m2
    p = state.p_rad_s + dt_s * pdot
    return RollState(p, state.phi_rad + dt_s * p)

"""GARTEUR Research Civil Aircraft Model (RCAM), the 6-DoF rigid body of report TP-088-3.

The aircraft of the GARTEUR FM(AG08) robust flight-control benchmark (TP-088-3, "Research Civil
Aircraft Model", section 2: equations of motion; section 2.2: aerodynamic forces and moments;
section 2.3: engine forces and moments; section 2.4: gravity). States in body axes: velocity
(u, v, w), angular rate (p, q, r), Euler angles (phi, theta, psi), and position north, east and
altitude over a flat Earth. Controls: aileron, stabiliser (tailplane incidence), rudder (rad) and
the two throttles (rad of throttle lever, thrust F_i = delta_th_i m_ref g).

Aerodynamics, with alpha = atan2(w, u), beta = asin(v / V) of the air-relative velocity:

    CL_wb = n (alpha - alpha_L0)                         (alpha <= alpha_switch)
          = a3 alpha^3 + a2 alpha^2 + a1 alpha + a0       (beyond)
    eps   = deps/dalpha (alpha - alpha_L0)               downwash at the tail
    CL_t  = 3.1 (S_t / S) (alpha - eps + delta_t + 1.3 q l_t / V)
    CD    = 0.13 + 0.07 (5.5 alpha + 0.654)^2,   CY = -1.6 beta + 0.24 delta_r
    Cl    = -1.4 beta + (cbar/V)(-11 p + 5 r) - 0.6 delta_a + 0.22 delta_r
    Cm    = -0.59 - 3.1 (S_t l_t / (S cbar)) (alpha - eps + delta_t)
            - 4.03 (S_t l_t^2 / (S cbar^2)) (cbar / V) q
    Cn    = (1 - alpha 180 / (15 pi)) beta + (cbar/V)(1.7 p - 11.5 r) - 0.63 delta_r

moments about the aerodynamic centre, transferred to the centre of gravity with the report's
``M_cg = M_ac + F_A x (r_cg - r_ac)``; the engines act at (0, -+7.94, -1.9) m with the report's
lever ``(X_cg - X_apt, Y_apt - Y_cg, Z_cg - Z_apt)``. Density comes from the caller (ISA at the
altitude, held over a step) instead of the report's sea-level constant, so the model serves as a
generic transport over an envelope; it is only validated near its approach point (80 m/s, 1000 ft).
Turbulence enters as a lateral gust velocity and a roll-rate gust in the air-relative motion.

:func:`derivatives` is the pure right-hand side for one aircraft; :func:`step` one classical
Runge-Kutta step with the controls held; :func:`trim` a batched-by-vmap Newton solve of level
flight at (Vcas, h, mass). Everything is written for one scenario and safe in float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcfdd.plant import atmosphere


class RcamParams(NamedTuple):
    """Constants of TP-088-3 (SI units, angles in rad); ``mass_kg`` may be sampled."""

    mass_kg: float = 120000.0
    thrust_mass_kg: float = 120000.0  # m_ref of F_i = delta_th_i m_ref g: the engines do not scale with mass
    mean_chord_m: float = 6.6
    tail_arm_m: float = 24.8
    wing_area_m2: float = 260.0
    tail_area_m2: float = 64.0
    x_cg_m: float = 0.23 * 6.6
    z_cg_m: float = 0.10 * 6.6
    x_ac_m: float = 0.12 * 6.6
    engine_y_m: float = 7.94
    engine_z_m: float = -1.9
    ixx_m2: float = 40.07  # inertia per unit mass
    iyy_m2: float = 64.0
    izz_m2: float = 99.92
    ixz_m2: float = -2.0923  # off-diagonal entry of the inertia matrix per unit mass
    gravity_m_s2: float = 9.81
    lift_slope: float = 5.5
    alpha_l0_rad: float = math.radians(-11.5)
    alpha_switch_rad: float = math.radians(14.5)
    lift_poly: tuple = (-768.5, 609.2, -155.2, 15.212)  # a3, a2, a1, a0
    downwash_slope: float = 0.25


class RcamState(NamedTuple):
    """Body velocity (m/s), body rates (rad/s), Euler angles (rad), position (m)."""

    u: jnp.ndarray
    v: jnp.ndarray
    w: jnp.ndarray
    p: jnp.ndarray
    q: jnp.ndarray
    r: jnp.ndarray
    phi: jnp.ndarray
    theta: jnp.ndarray
    psi: jnp.ndarray
    north: jnp.ndarray
    east: jnp.ndarray
    altitude: jnp.ndarray


class RcamControls(NamedTuple):
    """Aileron, stabiliser and rudder deflections and the two throttles (rad)."""

    aileron: jnp.ndarray
    stabiliser: jnp.ndarray
    rudder: jnp.ndarray
    throttle1: jnp.ndarray
    throttle2: jnp.ndarray


class AirData(NamedTuple):
    """Air-relative speed (m/s), angle of attack and sideslip (rad)."""

    airspeed: jnp.ndarray
    alpha: jnp.ndarray
    beta: jnp.ndarray


def air_data(state: RcamState, v_gust_m_s=0.0) -> AirData:
    """Air-relative speed, alpha and beta of the state in a lateral gust ``v_gust`` (body y)."""
    v_air = state.v - v_gust_m_s
    speed = jnp.sqrt(state.u**2 + v_air**2 + state.w**2)
    return AirData(speed, jnp.arctan2(state.w, state.u), jnp.arcsin(jnp.clip(v_air / speed, -1.0, 1.0)))


def lift_wing_body(params: RcamParams, alpha):
    """CL_wb: linear up to alpha_switch, the report's cubic beyond."""
    a3, a2, a1, a0 = params.lift_poly
    linear = params.lift_slope * (alpha - params.alpha_l0_rad)
    cubic = ((a3 * alpha + a2) * alpha + a1) * alpha + a0
    return jnp.where(alpha <= params.alpha_switch_rad, linear, cubic)


def derivatives(params: RcamParams, state: RcamState, controls: RcamControls, density_kg_m3,
                v_gust_m_s=0.0, p_gust_rad_s=0.0) -> RcamState:
    """Time derivative of the state (an :class:`RcamState` of rates)."""
    s, c, lt = params.wing_area_m2, params.mean_chord_m, params.tail_arm_m
    tail = params.tail_area_m2 / s
    air = air_data(state, v_gust_m_s)
    alpha, beta, speed = air.alpha, air.beta, air.airspeed
    qs = 0.5 * density_kg_m3 * speed**2 * s
    chord_v = c / speed
    p_air = state.p - p_gust_rad_s

    downwash = params.downwash_slope * (alpha - params.alpha_l0_rad)
    tail_incidence = alpha - downwash + controls.stabiliser
    cl = lift_wing_body(params, alpha) + 3.1 * tail * (tail_incidence + 1.3 * state.q * lt / speed)
    cd = 0.13 + 0.07 * (5.5 * alpha + 0.654) ** 2
    cy = -1.6 * beta + 0.24 * controls.rudder
    ca, sa = jnp.cos(alpha), jnp.sin(alpha)
    fx = qs * (cl * sa - cd * ca)
    fy = qs * cy
    fz = -qs * (cd * sa + cl * ca)

    tail_volume = 3.1 * tail * lt / c
    roll = -1.4 * beta + chord_v * (-11.0 * p_air + 5.0 * state.r) - 0.6 * controls.aileron + 0.22 * controls.rudder
    pitch = (-0.59 - tail_volume * tail_incidence
             - 4.03 * tail * (lt / c) ** 2 * chord_v * state.q)
    yaw = ((1.0 - alpha * (180.0 / (15.0 * math.pi))) * beta + chord_v * (1.7 * p_air - 11.5 * state.r)
           - 0.63 * controls.rudder)
    dx, dz = params.x_cg_m - params.x_ac_m, params.z_cg_m
    thrust_scale = params.thrust_mass_kg * params.gravity_m_s2
    f1, f2 = controls.throttle1 * thrust_scale, controls.throttle2 * thrust_scale
    moment_l = qs * c * roll + fy * dz
    moment_m = qs * c * pitch + fz * dx - fx * dz + (params.z_cg_m - params.engine_z_m) * (f1 + f2)
    moment_n = qs * c * yaw - fy * dx + params.engine_y_m * (f1 - f2)

    m, g = params.mass_kg, params.gravity_m_s2
    sphi, cphi = jnp.sin(state.phi), jnp.cos(state.phi)
    sth, cth = jnp.sin(state.theta), jnp.cos(state.theta)
    spsi, cpsi = jnp.sin(state.psi), jnp.cos(state.psi)
    u, v, w, p, q, r = state.u, state.v, state.w, state.p, state.q, state.r
    udot = (fx + f1 + f2) / m - g * sth - (q * w - r * v)
    vdot = fy / m + g * cth * sphi - (r * u - p * w)
    wdot = fz / m + g * cth * cphi - (p * v - q * u)

    a, b, cz, e = params.ixx_m2, params.iyy_m2, params.izz_m2, params.ixz_m2
    # I w_dot = M - w x I w, with I = m [[a, 0, e], [0, b, 0], [e, 0, cz]]
    lx = moment_l / m - (q * (e * p + cz * r) - r * b * q)
    my = moment_m / m - (r * (a * p + e * r) - p * (e * p + cz * r))
    nz = moment_n / m - (p * b * q - q * (a * p + e * r))
    det = a * cz - e * e
    pdot = (cz * lx - e * nz) / det
    qdot = my / b
    rdot = (a * nz - e * lx) / det

    turn = q * sphi + r * cphi
    down = -u * sth + (v * sphi + w * cphi) * cth
    side = v * cphi - w * sphi
    along = u * cth + (v * sphi + w * cphi) * sth
    return RcamState(
        udot, vdot, wdot, pdot, qdot, rdot,
        p + jnp.tan(state.theta) * turn, q * cphi - r * sphi, turn / cth,
        along * cpsi - side * spsi, along * spsi + side * cpsi, -down)


def step(params: RcamParams, state: RcamState, controls: RcamControls, density_kg_m3, dt_s: float,
         v_gust_m_s=0.0, p_gust_rad_s=0.0):
    """One classical Runge-Kutta step of ``dt_s`` with controls, density and gusts held.

    Returns (new state, derivatives at the start of the step).
    """
    def f(x):
        return derivatives(params, x, controls, density_kg_m3, v_gust_m_s, p_gust_rad_s)

    def add(x, k, h):
        return jax.tree.map(lambda a, b: a + h * b, x, k)

    k1 = f(state)
    k2 = f(add(state, k1, 0.5 * dt_s))
    k3 = f(add(state, k2, 0.5 * dt_s))
    k4 = f(add(state, k3, dt_s))
    new = jax.tree.map(lambda x, a, b, c, d: x + dt_s / 6.0 * (a + 2.0 * (b + c) + d), state, k1, k2, k3, k4)
    return new, k1


def true_airspeed(vcas_m_s, altitude_m):
    """True airspeed (m/s) of a calibrated airspeed at a pressure altitude."""
    return atmosphere.flight_condition(vcas_m_s, altitude_m)[2]


def calibrated_airspeed(tas_m_s, altitude_m):
    """Calibrated airspeed (m/s) of a true airspeed at a pressure altitude (pitot relations)."""
    sound = atmosphere.isa(altitude_m)[3]
    return atmosphere.calibrated_airspeed(tas_m_s / sound, altitude_m)


class Trim(NamedTuple):
    """Level, wings-level, zero-sideslip trim: state, stabiliser and per-engine throttle (rad)."""

    state: RcamState
    stabiliser: jnp.ndarray
    throttle: jnp.ndarray
    residual: jnp.ndarray  # largest |u_dot|, |w_dot| (m/s^2) and |q_dot| (rad/s^2) left


def level_state(tas_m_s, alpha_rad, altitude_m, psi_rad=0.0) -> RcamState:
    """Level flight at a true airspeed and angle of attack (theta = alpha), wings level."""
    zero = jnp.zeros_like(tas_m_s * alpha_rad * altitude_m)
    return RcamState(tas_m_s * jnp.cos(alpha_rad), zero, tas_m_s * jnp.sin(alpha_rad), zero, zero, zero, zero,
                     alpha_rad + zero, psi_rad + zero, zero, zero, altitude_m + zero)


def trim(params: RcamParams, vcas_m_s, altitude_m, iterations: int = 12) -> Trim:
    """Level flight at (Vcas, h) for ``params.mass_kg`` by Newton's method on (alpha, delta_t, delta_th).

    Solves u_dot = w_dot = q_dot = 0 with theta = alpha, both throttles equal, all lateral
    states and controls zero (which makes the lateral derivatives vanish). Written for one flight
    point; vmap it for a batch. ``iterations`` is static.
    """
    tas = true_airspeed(vcas_m_s, altitude_m)
    density = atmosphere.isa(altitude_m)[2]

    def residual(x):
        alpha, stab, throttle = x[0], x[1], x[2]
        zero = jnp.zeros_like(alpha)
        d = derivatives(params, level_state(tas, alpha, altitude_m),
                        RcamControls(zero, stab, zero, throttle, throttle), density)
        return jnp.stack([d.u, d.w, d.q])

    weight_share = params.mass_kg * params.gravity_m_s2 / (0.5 * density * tas**2 * params.wing_area_m2)
    alpha0 = weight_share / params.lift_slope + params.alpha_l0_rad
    x = jnp.stack([alpha0, jnp.zeros_like(alpha0), jnp.full_like(alpha0, 0.05)])
    for _ in range(iterations):
        x = x - jnp.linalg.solve(jax.jacfwd(residual)(x), residual(x))
    left = residual(x)
    return Trim(level_state(tas, x[0], altitude_m), x[1], x[2], jnp.max(jnp.abs(left)))


def first_order_lag(value, target, time_constant_s, dt_s: float):
    """Exact zero-order-hold step of ``tau y' = target - y`` over ``dt_s``."""
    return target + (value - target) * jnp.exp(-dt_s / time_constant_s)

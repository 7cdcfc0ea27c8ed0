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
Turbulence (:class:`mcfdd.plant.turbulence.Gust`, body axes) enters the air-relative motion:
the aerodynamic forces and moments see the velocity (u - u_g, v - v_g, w - w_g) and the rates
(p - p_g, q - q_g, r - r_g); the kinematics and the inertial terms see the body's own motion.

:func:`derivatives` is the pure right-hand side for one aircraft; :func:`step` one classical
Runge-Kutta step with the controls and the gusts held (each stage's derivatives and state computed
once, :func:`mcfdd.compute.once`); :func:`trim` a batched-by-vmap Newton solve of level flight at
(Vcas, h, mass). Everything is written for one scenario and safe in float32.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcfdd.compute import once
from mcfdd.plant import atmosphere
from mcfdd.plant.turbulence import Gust

CALM = Gust(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


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


def air_data(state: RcamState, gust: Gust = CALM) -> AirData:
    """Air-relative speed, alpha and beta of the state in a gust (body axes)."""
    u_air, v_air, w_air = state.u - gust.u, state.v - gust.v, state.w - gust.w
    along_sq = u_air**2 + w_air**2
    speed = jnp.sqrt(along_sq + v_air**2)
    return AirData(speed, jnp.arctan2(w_air, u_air), jnp.arctan2(v_air, jnp.sqrt(along_sq)))  # beta = asin(v / V)


def lift_wing_body(params: RcamParams, alpha):
    """CL_wb: linear up to alpha_switch, the report's cubic beyond."""
    a3, a2, a1, a0 = params.lift_poly
    linear = params.lift_slope * (alpha - params.alpha_l0_rad)
    cubic = ((a3 * alpha + a2) * alpha + a1) * alpha + a0
    return jnp.where(alpha <= params.alpha_switch_rad, linear, cubic)


_CN_BETA_ALPHA = 180.0 / (15.0 * math.pi)  # Cn's beta term (1 - alpha 180 / (15 pi)) beta


class Lateral(NamedTuple):
    """One row of the lateral moments' rates folded into per-run coefficients (see :class:`Body`)."""

    beta: jnp.ndarray
    alpha_beta: jnp.ndarray
    p: jnp.ndarray
    r: jnp.ndarray
    side: jnp.ndarray
    aileron: jnp.ndarray
    rudder: jnp.ndarray


class Body(NamedTuple):
    """Per-run constants of the equations of motion (from :class:`RcamParams`; mass and inertia may be sampled).

    Euler's equations ``I w_dot = M - w x I w`` with ``I = m [[a, 0, e], [0, b, 0], [e, 0, c]]`` and
    the moments per unit mass (L, M, N) solve to
    ``p_dot = l_l L + l_n N + (p_p p + p_r r) q``, ``q_dot = m_m M + q_pr p r + q_pp (p^2 - r^2)``,
    ``r_dot = n_l L + n_n N + (r_p p + r_r r) q`` (``n_l = l_n``).

    The moments' aerodynamic and force terms enter these rates through per-run coefficients (the
    same sums in another order): with ``qS/m`` the dynamic pressure times S per unit mass, ``cbar/V``
    the chord over the airspeed, (p, q, r) the air-relative rates and (a_x, a_y, a_z) the
    aerodynamic forces per unit mass, each lateral row (k_l, k_n) = (l_l, l_n) for p_dot and (l_n,
    n_n) for r_dot gives ``k_l L + k_n N = qS/m (c0 + beta (c_beta + c_alpha_beta alpha) + cbar/V
    (c_p p + c_r r)) + c_y a_y + k_n N_thrust``, where c0 = ``c_aileron delta_a + c_rudder delta_r``
    holds Cl's and Cn's control terms and each c is cbar (k_l Cl_x + k_n Cn_x) of the term x;
    ``m_m M = qS/m (m_0 + m_incidence (alpha - eps + delta_t) + m_q cbar/V q) + m_x a_x + m_down (-a_z)
    + m_m M_thrust``.
    """

    inv_mass: jnp.ndarray  # 1/kg
    thrust_per_mass: jnp.ndarray  # m/s^2 per rad of throttle: m_ref g / m
    l_n: jnp.ndarray
    p_p: jnp.ndarray
    p_r: jnp.ndarray
    m_m: jnp.ndarray
    q_pr: jnp.ndarray
    q_pp: jnp.ndarray
    n_n: jnp.ndarray
    r_p: jnp.ndarray
    r_r: jnp.ndarray
    roll: Lateral  # p_dot's row (l_l, l_n)
    yaw: Lateral  # r_dot's row (l_n, n_n)
    m_0: jnp.ndarray
    m_incidence: jnp.ndarray
    m_q: jnp.ndarray
    m_x: jnp.ndarray
    m_down: jnp.ndarray  # -m_z: a_z enters as the down force -a_z per unit mass


def body_constants(params: RcamParams) -> Body:
    """The :class:`Body` constants of the parameters (once per run)."""
    a, b, c, e = params.ixx_m2, params.iyy_m2, params.izz_m2, params.ixz_m2
    det = a * c - e * e
    l_l, l_n, n_n, m_m = c / det, -e / det, a / det, 1.0 / b
    chord, lt = params.mean_chord_m, params.tail_arm_m
    tail = params.tail_area_m2 / params.wing_area_m2
    dx, dz = params.x_cg_m - params.x_ac_m, params.z_cg_m

    def lateral(k_l, k_n):  # Cl = -1.4 beta + cbar/V (-11 p + 5 r) - 0.6 delta_a + 0.22 delta_r
        return Lateral(chord * (-1.4 * k_l + k_n), -chord * k_n * _CN_BETA_ALPHA,  # Cn: (1 - alpha 12/pi) beta
                       chord * (-11.0 * k_l + 1.7 * k_n), chord * (5.0 * k_l - 11.5 * k_n),  # + cbar/V (1.7 p - 11.5 r)
                       k_l * dz - k_n * dx, chord * (-0.6 * k_l), chord * (0.22 * k_l - 0.63 * k_n))  # - 0.63 delta_r

    return Body(1.0 / params.mass_kg, params.thrust_mass_kg * params.gravity_m_s2 / params.mass_kg,
                l_n, e * (b - a - c) / det, -(c * (c - b) + e * e) / det,
                m_m, (c - a) / b, e / b,
                n_n, (e * e - a * (b - a)) / det, e * (a + c - b) / det,
                lateral(l_l, l_n), lateral(l_n, n_n),
                # Cm = -0.59 - 3.1 (S_t l_t / (S cbar)) (alpha - eps + delta_t) - 4.03 (S_t l_t^2 / (S cbar^2)) cbar/V q
                -0.59 * chord * m_m, -3.1 * tail * lt * m_m, -4.03 * tail * lt * lt / chord * m_m,
                -dz * m_m, -dx * m_m)


def derivatives(params: RcamParams, state: RcamState, controls: RcamControls, density_kg_m3,
                gust: Gust = CALM, one=1.0, body: Body | None = None) -> RcamState:
    """Time derivative of the state (an :class:`RcamState` of rates) in a gust (body axes).

    ``one`` is the runtime 1.0 of :func:`mcfdd.compute.once` (air data, forces and moments, and
    the attitude's sines and cosines each feed several of the twelve rates); ``body`` the run's
    :func:`body_constants` (computed here when not given).
    """
    return derivatives_and_load(params, state, controls, density_kg_m3, gust, one, body)[0]


def derivatives_and_load(params: RcamParams, state: RcamState, controls: RcamControls, density_kg_m3,
                         gust: Gust = CALM, one=1.0, body: Body | None = None) -> tuple[RcamState, jnp.ndarray]:
    """:func:`derivatives` and the body normal load factor n_z = -a_z / g (g) of the aerodynamic force."""
    body = body_constants(params) if body is None else body
    s, c, lt = params.wing_area_m2, params.mean_chord_m, params.tail_arm_m
    tail = params.tail_area_m2 / s
    roll, yaw = body.roll, body.yaw
    # terms of the controls and the density alone: the same in every Runge-Kutta stage, computed once per step
    t1, t2 = controls.throttle1 * body.thrust_per_mass, controls.throttle2 * body.thrust_per_mass
    thrust_n = params.engine_y_m * (t1 - t2)
    pressure_m, incidence_0, side_0, roll_0, yaw_0, thrust, roll_t, pitch_t, yaw_t = once((
        (0.5 * s) * density_kg_m3 * body.inv_mass,  # dynamic pressure times S per unit mass, over V^2
        controls.stabiliser + params.downwash_slope * params.alpha_l0_rad, 0.24 * controls.rudder,
        roll.aileron * controls.aileron + roll.rudder * controls.rudder,
        yaw.aileron * controls.aileron + yaw.rudder * controls.rudder,
        t1 + t2, body.l_n * thrust_n, body.m_m * (params.z_cg_m - params.engine_z_m) * (t1 + t2),
        body.n_n * thrust_n), one)

    air = air_data(state, gust)
    alpha, beta, speed = air.alpha, air.beta, air.airspeed
    qs_m = pressure_m * speed**2  # dynamic pressure times S, per unit mass
    chord_v = c / speed
    ca, sa = jnp.cos(alpha), jnp.sin(alpha)
    alpha, beta, speed, qs_m, chord_v, ca, sa = once((alpha, beta, speed, qs_m, chord_v, ca, sa), one)
    p_air, q_air, r_air = once((state.p - gust.p, state.q - gust.q, state.r - gust.r), one)

    tail_incidence = incidence_0 + (1.0 - params.downwash_slope) * alpha  # alpha - eps + delta_t
    cl = lift_wing_body(params, alpha) + 3.1 * tail * (tail_incidence + (1.3 * lt / c) * chord_v * q_air)
    cd = 0.13 + 0.07 * (5.5 * alpha + 0.654) ** 2
    cl, cd, tail_incidence = once((cl, cd, tail_incidence), one)
    cy = -1.6 * beta + side_0
    # the aerodynamic forces per unit mass: a_x, a_y and the down force -a_z
    ax, ay, down_force = once((qs_m * (cl * sa - cd * ca), qs_m * cy, qs_m * (cd * sa + cl * ca)), one)

    def lateral(row: Lateral, control, thrust_term):  # k_l L + k_n N of a row (see Body)
        aero = control + beta * (row.beta + row.alpha_beta * alpha) + chord_v * (row.p * p_air + row.r * r_air)
        return qs_m * aero + row.side * ay + thrust_term

    g = params.gravity_m_s2
    sphi, cphi = jnp.sin(state.phi), jnp.cos(state.phi)
    sth, cth = jnp.sin(state.theta), jnp.cos(state.theta)
    spsi, cpsi = jnp.sin(state.psi), jnp.cos(state.psi)
    sphi, cphi, sth, cth = once((sphi, cphi, sth, cth), one)
    u, v, w, p, q, r = state.u, state.v, state.w, state.p, state.q, state.r
    udot = thrust + ax - g * sth - (q * w - r * v)
    vdot = ay + g * cth * sphi - (r * u - p * w)
    wdot = g * cth * cphi - down_force - (p * v - q * u)
    pdot = lateral(roll, roll_0, roll_t) + (body.p_p * p + body.p_r * r) * q
    pitch = (qs_m * (body.m_0 + body.m_incidence * tail_incidence + body.m_q * chord_v * q_air)
             + body.m_x * ax + body.m_down * down_force + pitch_t)  # m_m M
    qdot = pitch + body.q_pr * p * r + body.q_pp * (p * p - r * r)
    rdot = lateral(yaw, yaw_0, yaw_t) + (body.r_p * p + body.r_r * r) * q

    turn = once(q * sphi + r * cphi, one)
    climb = u * sth - (v * sphi + w * cphi) * cth
    side = v * cphi - w * sphi
    along = u * cth + (v * sphi + w * cphi) * sth
    return RcamState(
        udot, vdot, wdot, pdot, qdot, rdot,
        p + jnp.tan(state.theta) * turn, q * cphi - r * sphi, turn / jnp.cos(state.theta),
        along * cpsi - side * spsi, along * spsi + side * cpsi, climb), down_force * (1.0 / g)


def store_rates(rates: RcamState, one) -> RcamState:
    """``rates`` computed once (:func:`mcfdd.compute.once`) but psi's: only the Runge-Kutta sum reads it, and
    psi_dot, a quotient, stored as (a / b) / 1 would be re-associated as a / (b 1) and recomputed there anyway."""
    return once(rates._replace(psi=None), one)._replace(psi=rates.psi)


def step(params: RcamParams, state: RcamState, controls: RcamControls, density_kg_m3, dt_s: float,
         gust: Gust = CALM, one=1.0, body: Body | None = None, k1: RcamState | None = None):
    """One classical Runge-Kutta step of ``dt_s`` with controls, density and gusts held.

    ``one`` is the runtime 1.0 of :func:`mcfdd.compute.once`: each stage's derivatives and state
    feed every component of the next stage and the final sum, so each is computed once; ``body``
    the run's :func:`body_constants` and ``k1`` the derivatives at the start (both computed here
    when not given). Returns (new state, derivatives at the start of the step).
    """
    body = body_constants(params) if body is None else body

    def f(x):
        return derivatives(params, x, controls, density_kg_m3, gust, one, body)

    def add(x, k, h):
        return once(jax.tree.map(lambda a, b: a + h * b, x, k), one)

    k1 = store_rates(f(state), one) if k1 is None else k1
    k2 = store_rates(f(add(state, k1, 0.5 * dt_s)), one)
    k3 = store_rates(f(add(state, k2, 0.5 * dt_s)), one)
    k4 = f(add(state, k3, dt_s))  # read by the final sum alone
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

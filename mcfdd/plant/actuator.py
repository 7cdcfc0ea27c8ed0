"""Nonlinear hydraulic actuator with loss-of-efficiency faults, eqs. (1)-(2) of the paper.

State x is the rod position (m); the surface deflection is delta = x / r_arm. Eq. (2), read with
nu2 on the aerodynamic term (DESIGN.md section 3), has xdot on both sides. With the servo-valve
current saturated, ``i = sat(Kp e, i_max)`` with ``e = u_c - x``, and ``g = (Kci i)^2 / dP_ref``,
squaring gives the closed form

    xdot^2 = g A / (1 + g Kd / S),   A = nu1 dP - nu2 sgn(e) F_aero / S,   sgn(xdot) = sgn(e).

``A <= 0`` means the hydraulic force cannot beat the load: the rod stalls (xdot = 0). The rod
reaches the stall position as A falls to zero, so the stall flag is raised when less than
``STALL_MARGIN`` of the supply pressure is left. Written as a
gain, ``xdot = k (u_c - x)`` with

    k = Kci Kp s sqrt(A / (dP_ref (1 + g Kd / S))),   s = min(1, i_max / (Kp |e|)),

With u_c held over a sample the ODE is piecewise smooth. At full valve current (``|e| >= i_max /
Kp``) the rate ``w = sqrt(g A / (1 + g Kd / S))`` changes at a constant rate along a linear load
line, so that part of the sample is integrated exactly (:func:`_saturated_travel`), up to the edge
of the linear range, a stall, or the end of the sample. The rest of the sample is cut into
sub-steps, each integrating ``xdot = k (u_c - x)`` exactly for the gain frozen over the sub-step,
``x+ = u_c - e exp(-k h)``; there k varies only through the Kd term and the load (a few percent
over the linear range), so the error of this part is small and first order in h. Neither part
overshoots the command, and the rod holds still in a stall.
The hinge load is read from the table once per sample; the sample follows the line of the table
cell the rod started in (exact for a piecewise-linear table while the rod stays in that cell, and
the rod moves less than a cell in a sample).
Faults step in at their onset times: leakage (nu1 < 1), surface damage or disconnection (nu2 < 1,
nu2 = 0 disconnected) and jamming (rod frozen where it is).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.compute import ONE, once
from mcfdd.plant import hinge


class ActuatorParams(NamedTuple):
    """Physical constants of the actuator, SI units (DESIGN.md section 3 table)."""

    supply_pressure_pa: float = 2.07e7
    ref_pressure_pa: float = 2.07e7
    piston_area_m2: float = 2.272e-3
    r_arm_m: float = 0.0525
    max_current_a: float = 8e-3
    kci_m_s_a: float = 11.46
    kp_a_m: float = 2.18
    kd_n_s2_m2: float = 5.6e5
    max_deflection_rad: float = math.radians(25.0)


STALL_MARGIN = 1e-3  # stall when less than this fraction of the supply pressure is left to move the rod


class ActuatorFault(NamedTuple):
    """LOE fault parameters of one run. Times in s; ``inf`` means the fault never occurs."""

    nu1: float = 1.0
    nu2: float = 1.0
    onset_s: float = math.inf
    jam_onset_s: float = math.inf


class ActuatorState(NamedTuple):
    x_m: jnp.ndarray


class ActuatorOutputs(NamedTuple):
    """Signals at the start of a step: rod position and rate, available pressure, stall flag, active
    nu, the hinge load as a fraction of the stall force ``|F_aero| / (nu1 dP S)`` and the jam flag."""

    x_m: jnp.ndarray
    rate_m_s: jnp.ndarray
    dp_avail_norm: jnp.ndarray
    stall: jnp.ndarray
    nu1: jnp.ndarray
    nu2: jnp.ndarray
    load_fraction: jnp.ndarray
    jammed: jnp.ndarray


def _safe_sqrt(value):
    """sqrt(max(value, 0)) with a finite gradient at and below zero."""
    positive = value > 0.0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, value, 1.0)), 0.0)


def available_pressure(params: ActuatorParams, nu1, nu2, load_n, error_m):
    """A = nu1 dP - nu2 sgn(e) F_aero / S (Pa): the pressure left to move the rod."""
    return nu1 * params.supply_pressure_pa - nu2 * jnp.sign(error_m) * load_n / params.piston_area_m2


def gain(params: ActuatorParams, nu1, nu2, load_n, x_m, u_c_m):
    """Nonlinear gain K of eq. (2) in closed form (1/s), such that ``xdot = K (u_c - x)``.

    Returns (gain, available pressure A in Pa).
    """
    e = u_c_m - x_m
    saturation = params.max_current_a / jnp.maximum(params.kp_a_m * jnp.abs(e), params.max_current_a)
    current = params.kp_a_m * e * saturation
    g = (params.kci_m_s_a * current) ** 2 / params.ref_pressure_pa
    a = available_pressure(params, nu1, nu2, load_n, e)
    denom = params.ref_pressure_pa * (1.0 + g * params.kd_n_s2_m2 / params.piston_area_m2)
    k = params.kci_m_s_a * params.kp_a_m * saturation * _safe_sqrt(a / denom)
    return k, a


def rate(params: ActuatorParams, nu1, nu2, load_n, x_m, u_c_m):
    """Rod rate xdot (m/s) from the closed form; zero when A <= 0 (stall)."""
    k, _ = gain(params, nu1, nu2, load_n, x_m, u_c_m)
    return k * (u_c_m - x_m)


def _saturated_travel(params: ActuatorParams, nu2, slope_n_rad, w0, e0_abs, dt_s, one=ONE):
    """Time (s), distance (m) and final rate (m/s) of the rod's travel at full valve current in one sample.

    At full current ``g`` is constant, and along the travel z >= 0 the table line gives
    ``A(z) = A0 + q z`` with ``q = -nu2 slope / (r_arm S)`` whatever the direction, so the rate
    ``w = sqrt(beta A)``, ``beta = g / (1 + g Kd / S)``, changes at the constant rate
    ``dw/dt = beta q / 2``: ``z(t) = w0 t + c t^2`` with ``c = beta q / 4``, exactly. The travel
    ends at the edge of the linear range (``|e| = i_max / Kp``), where the rate falls to zero
    (a stall load, when ``c < 0``) or at the end of the sample, whichever comes first.
    """
    g = (params.kci_m_s_a * params.max_current_a) ** 2 / params.ref_pressure_pa
    beta = g / (1.0 + g * params.kd_n_s2_m2 / params.piston_area_m2)
    c = -beta * nu2 * slope_n_rad / (4.0 * params.r_arm_m * params.piston_area_m2)
    d = e0_abs - params.max_current_a / params.kp_a_m
    moving = (d > 0.0) & (w0 > 0.0)
    disc = w0 * w0 + 4.0 * c * d
    reaches = moving & (disc >= 0.0)
    t_edge = jnp.where(reaches, 2.0 * d / jnp.where(reaches, w0 + _safe_sqrt(disc), 1.0), jnp.inf)
    decelerating = moving & (c < 0.0)
    t_stop = jnp.where(decelerating, -w0 / jnp.where(decelerating, 2.0 * c, -1.0), jnp.inf)
    t_sat = once(jnp.where(moving, jnp.minimum(jnp.minimum(t_edge, t_stop), dt_s), 0.0), one)
    travel = jnp.minimum(w0 * t_sat + c * t_sat * t_sat, jnp.maximum(d, 0.0))
    return t_sat, travel, jnp.maximum(w0 + 2.0 * c * t_sat, 0.0)


def init(params: ActuatorParams, x0_m=0.0) -> ActuatorState:
    return ActuatorState(jnp.asarray(x0_m))


def active_nu(fault: ActuatorFault, t_s):
    """Fault parameters in force at time t (1 before the onset)."""
    on = t_s >= fault.onset_s
    return jnp.where(on, fault.nu1, 1.0), jnp.where(on, fault.nu2, 1.0)


def step(params: ActuatorParams, fault: ActuatorFault, delta_grid_rad, load_slice_n, state: ActuatorState,
         u_c_m, t_s, dt_s: float, substeps: int, one=ONE):
    """Advance the rod over one sample with ``u_c`` held (zero-order hold).

    ``delta_grid_rad`` and ``load_slice_n`` are the hinge table at the run's flight point
    (:func:`mcfdd.plant.hinge.flight_point_slice`). ``dt_s`` and ``substeps`` are static; ``one``
    is the runtime 1.0 of :func:`mcfdd.compute.once` (the load line, the gain, the saturated travel
    and each sub-step feed several later stages).
    Returns (new state, :class:`ActuatorOutputs` at the start of the step).
    """
    line = once(hinge.local_line(delta_grid_rad, load_slice_n, state.x_m / params.r_arm_m), one)
    return advance(params, fault, line, state, u_c_m, t_s, dt_s, substeps, one)


def advance(params: ActuatorParams, fault: ActuatorFault, line, state: ActuatorState, u_c_m, t_s, dt_s: float,
            substeps: int, one=ONE):
    """:func:`step` on the hinge-load line of the rod's table cell, ``line`` = (load N at the rod, slope N/rad)."""
    nu1, nu2 = active_nu(fault, t_s)
    jammed = t_s >= fault.jam_onset_s
    x_max = params.r_arm_m * params.max_deflection_rad

    x0 = state.x_m
    load0, slope = line
    k0, a0 = once(gain(params, nu1, nu2, load0, x0, u_c_m), one)
    e0 = u_c_m - x0
    t_sat, travel, rate_end = _saturated_travel(params, nu2, slope, k0 * jnp.abs(e0), jnp.abs(e0), dt_s, one)
    saturated = t_sat > 0.0
    e1_abs = jnp.abs(e0) - travel
    x1 = x0 + jnp.sign(e0) * travel
    k = jnp.where(saturated, rate_end / jnp.where(saturated, e1_abs, 1.0), k0)
    h = (dt_s - t_sat) / substeps
    for i in range(substeps):
        if i:
            load = load0 + slope * (x1 - x0) / params.r_arm_m
            k, _ = gain(params, nu1, nu2, load, x1, u_c_m)
        x1 = once(u_c_m - (u_c_m - x1) * jnp.exp(-k * h), one)
    x1 = jnp.clip(jnp.where(jammed, x0, x1), -x_max, x_max)
    outputs = ActuatorOutputs(
        x_m=x0,
        rate_m_s=jnp.where(jammed, 0.0, k0 * (u_c_m - x0)),
        dp_avail_norm=a0 / params.supply_pressure_pa,
        stall=(a0 <= STALL_MARGIN * params.supply_pressure_pa) & ~jammed,
        nu1=nu1,
        nu2=nu2,
        load_fraction=jnp.abs(load0) / (nu1 * params.supply_pressure_pa * params.piston_area_m2),
        jammed=jammed,
    )
    return ActuatorState(x1), outputs

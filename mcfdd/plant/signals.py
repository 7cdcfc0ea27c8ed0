"""Signals of a closed-loop step, shared by both aircraft models."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class PlantOutputs(NamedTuple):
    """Signals at the start of a step (time t). Rod positions in m, rates in m/s, angles in rad.

    ``delta_rad`` (surface deflection), ``rate_m_s``, ``load_fraction`` (hinge load over the stall
    force nu1 dP S) and ``jammed`` are the plant's truth, for scoring only (the FDD sees u_c, u and
    the flight point). The measured Vcas (m/s) and altitude (m) are the flight point the FDD
    schedules on (constant on the roll axis).
    """

    u_c_m: jnp.ndarray
    u_m: jnp.ndarray
    x_m: jnp.ndarray
    delta_rad: jnp.ndarray
    rate_m_s: jnp.ndarray
    load_fraction: jnp.ndarray
    jammed: jnp.ndarray
    dp_avail_norm: jnp.ndarray
    stall: jnp.ndarray
    p_rad_s: jnp.ndarray
    phi_rad: jnp.ndarray
    stick: jnp.ndarray
    nu1: jnp.ndarray
    nu2: jnp.ndarray
    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray


FULL_AIRCRAFT_SIGNALS = ("alpha_rad", "beta_rad", "theta_rad", "q_rad_s", "r_rad_s", "psi_rad", "nz_g",
                         "stabiliser_rad", "rudder_rad", "throttle_rad")
RcamOutputs = NamedTuple("RcamOutputs", [(name, jnp.ndarray) for name in PlantOutputs._fields + FULL_AIRCRAFT_SIGNALS])
RcamOutputs.__doc__ = """The signals of :class:`PlantOutputs` and the full aircraft's: alpha, beta, theta (rad), q, r
(rad/s), psi (rad), the body normal load factor nz (g), and the stabiliser, rudder and throttle positions (rad)."""

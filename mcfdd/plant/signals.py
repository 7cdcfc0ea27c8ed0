"""Signals of a closed-loop step, shared by both aircraft models."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class PlantOutputs(NamedTuple):
    """Signals at the start of a step (time t). Rod positions in m, angles in rad.

    The measured Vcas (m/s) and altitude (m) are the flight point the FDD schedules on (constant
    on the roll axis). The full aircraft also fills alpha, beta, theta, q, r, psi and the body
    normal load factor nz (g); on the roll axis they are None (empty pytree nodes).
    """

    u_c_m: jnp.ndarray
    u_m: jnp.ndarray
    x_m: jnp.ndarray
    dp_avail_norm: jnp.ndarray
    stall: jnp.ndarray
    p_rad_s: jnp.ndarray
    phi_rad: jnp.ndarray
    stick: jnp.ndarray
    nu1: jnp.ndarray
    nu2: jnp.ndarray
    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray
    alpha_rad: jnp.ndarray | None = None
    beta_rad: jnp.ndarray | None = None
    theta_rad: jnp.ndarray | None = None
    q_rad_s: jnp.ndarray | None = None
    r_rad_s: jnp.ndarray | None = None
    psi_rad: jnp.ndarray | None = None
    nz_g: jnp.ndarray | None = None

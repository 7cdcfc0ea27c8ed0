"""LPV residual generators: the detector of eq. (20) in the state-space form (24).

Continuous form, with k = k(rho) the scheduled gain and k0 the nominal gain used as scaling:

    xQ' = -a xQ + a [(k - a)/k0, -k/k0] [u; u_c],   r = xQ + (a/k0) u

(the printed (24) lost the minus on the u_c entry; it follows from (20)). The constant
feed-through keeps jumps of sgn(xdot) in k out of r. It is used three times: as the stall-load
detector (k = fault-free model), as each filter of the model-detection bank, eqs. (10)-(12)
(k -> k^(i), k0 -> k0^(i)), and as the stall model filter of eq. (30) (k = k0 = k_sl).

Discretisation. The command u_c is held over a sample (the flight computer's output) while u is
the sampled response of a continuous actuator. For the first-order model with gain k frozen over
a sample, ``u+ = phi u + (1 - phi) u_c`` with ``phi = exp(-k T)`` exactly, and the filter

    xQ+ = phi_a xQ + (phi_a - phi) u - (1 - phi) u_c,   r = c (xQ + u),
    phi_a = exp(-a T),   c = (1 - phi_a) / (1 - exp(-k0 T))

then gives ``r+ = phi_a r`` on that model for any sequence of gains: the discrete counterpart of
the exact decoupling ``d/dt r = -a r``. As T -> 0 it tends to (24) (c -> a/k0,
(phi_a - phi)/T -> k - a). The feed-through c is constant, as in (24).
"""

from __future__ import annotations

import jax.numpy as jnp


def init(u0):
    """Filter state for a start in equilibrium at measured position u0 (r = 0)."""
    return -jnp.asarray(u0)


def step(k, k0, a, x_q, u, u_c, dt_s: float):
    """One sample of the filter(s) with gain k, scaling gain k0 and pole a (1/s) from state x_q on the
    measured position u and the command u_c (m); all arguments broadcast (a bank uses arrays over models).

    Returns (new state, residual r at the start of the step), r in the units of u.
    """
    phi = jnp.exp(-k * dt_s)
    phi_a = jnp.exp(-a * dt_s)
    c = (1.0 - phi_a) / (1.0 - jnp.exp(-k0 * dt_s))
    r = c * (x_q + u)
    return phi_a * x_q + (phi_a - phi) * u - (1.0 - phi) * u_c, r


def transfer_function(k, k0, a):
    """Continuous (numerator, denominator) pairs of eq. (20) from u and from u_c (frozen rho)."""
    return ((a / k0, a * k / k0), (1.0, a)), ((-a * k / k0,), (1.0, a))

"""Dryden turbulence for the roll axis (MIL-F-8785C forms), discretised exactly.

Two gust components disturb the roll axis: the lateral gust velocity v_g (enters as a sideslip
v_g / V) and the roll-rate gust p_g. Their forming filters, driven by white noise whose one-sided
spectrum is 1 (intensity pi), are

    H_v(s) = sigma_v sqrt(L_v / (pi V)) (1 + sqrt(3) tau_v s) / (1 + tau_v s)^2,   tau_v = L_v / V
    H_p(s) = sigma_w sqrt(0.8 / V) (pi / (4 b))^(1/6) / (L_w^(1/3) (1 + tau_p s)),  tau_p = 4 b / (pi V)

Scale lengths and intensities follow MIL-F-8785C: below 1000 ft the low-altitude model
(sigma_w = 0.1 W20, W20 = 15 kt light, 30 kt moderate), above 2000 ft L = 1750 ft and sigma from
the probability-of-exceedance curves (1e-2 light, 1e-3 moderate), linear in between.

The sampled process is exact: the filter states start from their stationary covariance P and
advance as ``x+ = Phi x + chol(Q_d) n`` with ``Phi = exp(A T)`` and
``Q_d = pi * integral_0^T exp(A s) B B^T exp(A^T s) ds`` in closed form (regularised incomplete
gamma functions, accurate in float32), so every sample has the Dryden variance.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
from jax.scipy.special import gammainc

from mcfdd.plant.atmosphere import FT_TO_M, KT_TO_M_S

# MIL-F-8785C, Fig. 7: sigma (ft/s) against altitude (ft) for the medium/high-altitude model.
_TABLE_ALT_FT = (500.0, 1750.0, 3750.0, 7500.0, 15000.0, 25000.0, 35000.0, 45000.0, 55000.0,
                 65000.0, 75000.0, 80000.0)
_SIGMA_LIGHT_FT_S = (6.6, 6.9, 7.4, 6.7, 4.6, 2.7, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0)
_SIGMA_MODERATE_FT_S = (8.6, 9.6, 10.6, 10.1, 8.0, 6.6, 5.0, 4.2, 2.7, 0.0, 0.0, 0.0)
_W20_KT = (0.0, 15.0, 30.0)
_HIGH_SCALE_FT = 1750.0
_NOISE_INTENSITY = math.pi


class TurbulenceParams(NamedTuple):
    """Discrete Dryden filters of one run. States: (x1, x2) of H_v, x3 of H_p."""

    phi: jnp.ndarray  # (3, 3) state transition over one sample
    chol_q: jnp.ndarray  # (3, 3) lower Cholesky factor of the sample noise covariance
    chol_p: jnp.ndarray  # (3, 3) lower Cholesky factor of the stationary covariance
    out: jnp.ndarray  # (2, 3) states to (v_g m/s, p_g rad/s)


def _level_interp(level, values):
    """Piecewise-linear in the turbulence level: 0 none, 1 light, 2 moderate."""
    lv = jnp.clip(level, 0.0, 2.0)
    return jnp.where(lv <= 1.0, values[0] + (values[1] - values[0]) * lv,
                     values[1] + (values[2] - values[1]) * (lv - 1.0))


def intensity(level, altitude_m):
    """Dryden intensities and scale lengths: (sigma_v m/s, L_v m, sigma_w m/s, L_w m)."""
    h_ft = jnp.maximum(jnp.asarray(altitude_m) / FT_TO_M, 10.0)
    h_lo = jnp.minimum(h_ft, 1000.0)
    w20 = _level_interp(level, _W20_KT) * KT_TO_M_S
    sigma_w_lo = 0.1 * w20
    shape = 0.177 + 0.000823 * h_lo
    sigma_v_lo = sigma_w_lo / shape**0.4
    length_w_lo = h_lo * FT_TO_M
    length_v_lo = h_lo / shape**1.2 * FT_TO_M
    h_hi = jnp.maximum(h_ft, 2000.0)
    light = jnp.interp(h_hi, jnp.asarray(_TABLE_ALT_FT), jnp.asarray(_SIGMA_LIGHT_FT_S))
    moderate = jnp.interp(h_hi, jnp.asarray(_TABLE_ALT_FT), jnp.asarray(_SIGMA_MODERATE_FT_S))
    sigma_hi = _level_interp(level, (0.0, light, moderate)) * FT_TO_M
    length_hi = _HIGH_SCALE_FT * FT_TO_M
    w = jnp.clip((h_ft - 1000.0) / 1000.0, 0.0, 1.0)

    def blend(lo, hi):
        return lo + (hi - lo) * w

    return (blend(sigma_v_lo, sigma_hi), blend(length_v_lo, length_hi),
            blend(sigma_w_lo, sigma_hi), blend(length_w_lo, length_hi))


def _exp_moment(n: int, c, t):
    """integral_0^t s^n exp(-c s) ds, via the regularised lower incomplete gamma function."""
    return math.factorial(n) * gammainc(n + 1.0, c * t) / c ** (n + 1)


def discretise(level, altitude_m, tas_m_s, span_m, dt_s):
    """Exact sampled-data Dryden filters of a flight point. Returns :class:`TurbulenceParams`."""
    sigma_v, length_v, sigma_w, length_w = intensity(level, altitude_m)
    q = _NOISE_INTENSITY
    tau_v = length_v / tas_m_s
    tau_p = 4.0 * span_m / (math.pi * tas_m_s)
    # H_v in controllable form: x1' = x2, x2' = -x1/tau^2 - 2 x2/tau + w, y = K/tau^2 (x1 + sqrt3 tau x2)
    ev = jnp.exp(-dt_s / tau_v)
    r = dt_s / tau_v
    phi_v = ev * jnp.array([[1.0 + r, dt_s], [-r / tau_v, 1.0 - r]])
    c = 2.0 / tau_v
    i0, i1, i2 = (_exp_moment(n, c, dt_s) for n in range(3))
    q11 = q * i2
    q12 = q * (i1 - i2 / tau_v)
    q22 = q * (i0 - 2.0 * i1 / tau_v + i2 / tau_v**2)
    l11 = jnp.sqrt(q11)
    l21 = q12 / l11
    l22 = jnp.sqrt(jnp.maximum(q22 - l21**2, 0.0))
    # H_p: x3' = -x3/tau_p + w, y = K_p/tau_p x3
    ep = jnp.exp(-dt_s / tau_p)
    q33 = q * tau_p / 2.0 * (1.0 - ep**2)
    zero = jnp.zeros_like(ev)
    phi = jnp.array([[phi_v[0, 0], phi_v[0, 1], zero], [phi_v[1, 0], phi_v[1, 1], zero], [zero, zero, ep]])
    chol_q = jnp.array([[l11, zero, zero], [l21, l22, zero], [zero, zero, jnp.sqrt(q33)]])
    chol_p = jnp.array([
        [jnp.sqrt(q * tau_v**3 / 4.0), zero, zero],
        [zero, jnp.sqrt(q * tau_v / 4.0), zero],
        [zero, zero, jnp.sqrt(q * tau_p / 2.0)],
    ])
    k_v = sigma_v * jnp.sqrt(length_v / (math.pi * tas_m_s))
    k_p = sigma_w * jnp.sqrt(0.8 / tas_m_s) * (math.pi / (4.0 * span_m)) ** (1.0 / 6.0) / length_w ** (1.0 / 3.0)
    out = jnp.array([[k_v / tau_v**2, k_v * math.sqrt(3.0) / tau_v, zero], [zero, zero, k_p / tau_p]])
    return TurbulenceParams(phi, chol_q, chol_p, out)


def init(params: TurbulenceParams, noise3):
    """Stationary initial state from three standard normal numbers."""
    return params.chol_p @ noise3


def step(params: TurbulenceParams, state, noise3):
    """Returns (new state, gusts (v_g m/s, p_g rad/s) at the start of the step).

    Written out over the block structure of the matrices (H_v's 2 x 2 block and H_p's scalar):
    element-wise arithmetic vectorises across a batch where small matrix products do not.
    """
    phi, chol, out = params.phi, params.chol_q, params.out
    x1, x2, x3 = state[0], state[1], state[2]
    n1, n2, n3 = noise3[0], noise3[1], noise3[2]
    new = jnp.stack([
        phi[0, 0] * x1 + phi[0, 1] * x2 + chol[0, 0] * n1,
        phi[1, 0] * x1 + phi[1, 1] * x2 + chol[1, 0] * n1 + chol[1, 1] * n2,
        phi[2, 2] * x3 + chol[2, 2] * n3,
    ])
    return new, (out[0, 0] * x1 + out[0, 1] * x2, out[1, 2] * x3)

"""Dryden turbulence (MIL-F-8785C forms), discretised exactly: the roll axis's two gust components and
the full aircraft's six.

Roll axis. Two gust components disturb the roll axis at its fixed flight point: the lateral gust
velocity v_g (enters as a sideslip v_g / V) and the roll-rate gust p_g. Their forming filters,
driven by white noise whose one-sided spectrum is 1 (intensity pi), are

    H_v(s) = sigma_v sqrt(L_v / (pi V)) (1 + sqrt(3) tau_v s) / (1 + tau_v s)^2,   tau_v = L_v / V
    H_p(s) = sigma_w sqrt(0.8 / V) (pi / (4 b))^(1/6) / (L_w^(1/3) (1 + tau_p s)),  tau_p = 4 b / (pi V)

Scale lengths and intensities follow MIL-F-8785C: below 1000 ft the low-altitude model
(sigma_w = 0.1 W20, W20 = 15 kt light, 30 kt moderate, 45 kt severe; sigma_u = sigma_v = sigma_w /
(0.177 + 0.000823 h)^0.4, L_w = h, L_u = L_v = h / (0.177 + 0.000823 h)^1.2), above 2000 ft
L = 1750 ft and sigma from the probability-of-exceedance curves of its Fig. 7 (1e-2 light,
1e-3 moderate, 1e-5 severe), scale lengths and intensities linear in between.

The sampled process is exact: the filter states start from their stationary covariance P and
advance as ``x+ = Phi x + chol(Q_d) n`` with ``Phi = exp(A T)`` and
``Q_d = pi * integral_0^T exp(A s) B B^T exp(A^T s) ds`` in closed form (regularised incomplete
gamma functions, accurate in float32), so every sample has the Dryden variance.

Full aircraft (:func:`gust_step`). Six components at the flight point of each sample (altitude,
true airspeed): u (first order, sigma_u sqrt(2 L_u / (pi V)) / (1 + L_u/V s)), v and w (the form
of H_v), p (H_p), and the angular gusts of the frozen field traversed at V,

    q_g = -(s / V) / (1 + 4 b / (pi V) s) w_g,     r_g = (s / V) / (1 + 3 b / (pi V) s) v_g

(q_g = -dw_g/dx, r_g = dv_g/dx: the aerodynamic rates are p - p_g, q - q_g, r - r_g, as the
rigid-body velocity of a point of the airframe gives them; MIL-F-8785C leaves the signs to the
axis convention). Each forming filter runs with states scaled to unit stationary variance, so
its discrete transition depends on dt / tau alone and its noise covariance is I - Phi Phi^T:
discretised exactly at the current point every sample, the states keep unit variance however
V and h move, and each gust is its state times the current point's intensity. q_g and r_g
low-pass the sampled w_g and v_g exactly for gusts linear between samples.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
from jax.scipy.special import gammainc

from mcfdd.compute import once
from mcfdd.plant.atmosphere import FT_TO_M, KT_TO_M_S

# MIL-F-8785C, Fig. 7: sigma (ft/s) against altitude (ft) for the medium/high-altitude model.
_TABLE_ALT_FT = (500.0, 1750.0, 3750.0, 7500.0, 15000.0, 25000.0, 35000.0, 45000.0, 55000.0,
                 65000.0, 75000.0, 80000.0)
_SIGMA_LIGHT_FT_S = (6.6, 6.9, 7.4, 6.7, 4.6, 2.7, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0)
_SIGMA_MODERATE_FT_S = (8.6, 9.6, 10.6, 10.1, 8.0, 6.6, 5.0, 4.2, 2.7, 0.0, 0.0, 0.0)
_SIGMA_SEVERE_FT_S = (15.6, 17.6, 23.0, 23.6, 22.1, 20.0, 16.0, 15.1, 12.1, 7.9, 6.2, 5.1)
_W20_KT = (0.0, 15.0, 30.0, 45.0)
_HIGH_SCALE_FT = 1750.0
_NOISE_INTENSITY = math.pi


class TurbulenceParams(NamedTuple):
    """Discrete Dryden filters of one run. States: (x1, x2) of H_v, x3 of H_p."""

    phi: jnp.ndarray  # (3, 3) state transition over one sample
    chol_q: jnp.ndarray  # (3, 3) lower Cholesky factor of the sample noise covariance
    chol_p: jnp.ndarray  # (3, 3) lower Cholesky factor of the stationary covariance
    out: jnp.ndarray  # (2, 3) states to (v_g m/s, p_g rad/s)


def _level_interp(level, values):
    """Piecewise-linear in the turbulence level: 0 none, 1 light, 2 moderate, 3 severe."""
    lv = jnp.clip(level, 0.0, 3.0)
    return jnp.where(lv <= 1.0, values[0] + (values[1] - values[0]) * lv,
                     jnp.where(lv <= 2.0, values[1] + (values[2] - values[1]) * (lv - 1.0),
                               values[2] + (values[3] - values[2]) * (lv - 2.0)))


def intensity(level, altitude_m):
    """Dryden intensities and scale lengths: (sigma_v m/s, L_v m, sigma_w m/s, L_w m)."""
    h_ft = jnp.maximum(jnp.asarray(altitude_m) / FT_TO_M, 10.0)
    w20 = _level_interp(level, _W20_KT) * KT_TO_M_S
    h_hi = jnp.maximum(h_ft, 2000.0)
    light, moderate, severe = (jnp.interp(h_hi, jnp.asarray(_TABLE_ALT_FT), jnp.asarray(row))
                               for row in (_SIGMA_LIGHT_FT_S, _SIGMA_MODERATE_FT_S, _SIGMA_SEVERE_FT_S))
    sigma_hi = _level_interp(level, (0.0, light, moderate, severe)) * FT_TO_M
    return _scales(h_ft, 0.1 * w20, sigma_hi)


def _scales(h_ft, sigma_w_lo, sigma_hi, one=None):
    """MIL-F-8785C intensities and scale lengths at ``h_ft`` (ft, at least 10): the low-altitude model
    below 1000 ft (``sigma_w_lo`` = 0.1 W20), the medium/high-altitude one (``sigma_hi``, L = 1750 ft)
    above 2000 ft, linear in between. Returns (sigma_v m/s, L_v m, sigma_w m/s, L_w m); u as v.
    With ``one`` (every sample, :func:`mcfdd.compute.once`) the shared terms are computed once."""
    h_lo = jnp.minimum(h_ft, 1000.0)
    shape = 0.177 + 0.000823 * h_lo
    w = jnp.clip((h_ft - 1000.0) / 1000.0, 0.0, 1.0)
    if one is not None:
        h_lo, shape, w = once((h_lo, shape, w), one)
    sigma_v_lo = sigma_w_lo / shape**0.4
    length_w_lo = h_lo * FT_TO_M
    length_v_lo = h_lo / shape**1.2 * FT_TO_M
    length_hi = _HIGH_SCALE_FT * FT_TO_M

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


# --------------------------------------------------------------------------------------------
# The full aircraft: six gust components at the moving flight point

GUST_NORMALS = 6  # normals per step (and at the start): u, v (2), w (2), p
_HIGH_KNOTS_FT = _TABLE_ALT_FT[1:]  # the high-altitude model starts at 2000 ft: the 500 ft knot is never used
_HIGH_START_FT, _HIGH_STEP_FT = 2000.0, 250.0  # every knot above 2000 ft is 2000 ft plus a multiple of 250 ft
_HIGH_CELLS = round((_HIGH_KNOTS_FT[-1] - _HIGH_START_FT) / _HIGH_STEP_FT)
_S_TERMS = 9  # terms of the series S(X) below: relative error below 2e-7 for X <= 1.4


class GustParams(NamedTuple):
    """Per-run constants of the six-component Dryden turbulence (level and span; SI units).

    ``high`` holds the medium/high-altitude intensity of the run's level (m/s), the piecewise-linear
    function of altitude of MIL-F-8785C Fig. 7, at 2000 ft and every 250 ft above up to the last
    knot (80,000 ft): every knot of the figure above 2000 ft is on this grid, so linear interpolation
    between neighbouring entries is the figure's function (a cell index and one weight a sample).
    """

    sigma_w_low: jnp.ndarray  # 0.1 W20 (m/s)
    high: jnp.ndarray  # (_HIGH_CELLS + 1,)
    span_rate: jnp.ndarray  # pi / (4 b) (1/m): 1 / (V tau_p), tau_p = tau_q = 4 b / (pi V)
    p_scale: jnp.ndarray  # sigma_p L_w^(1/3) / sigma_w = pi sqrt(0.1 / b) (pi / (4 b))^(1/6) (m^(-1/6))


class GustState(NamedTuple):
    """Unit-variance states of the forming filters (u and p first order, v and w in normalised
    controllable form) and the low-passed normalised v and w gusts of the r and q filters."""

    u: jnp.ndarray
    v1: jnp.ndarray
    v2: jnp.ndarray
    w1: jnp.ndarray
    w2: jnp.ndarray
    p: jnp.ndarray
    v_low: jnp.ndarray
    w_low: jnp.ndarray


class Gust(NamedTuple):
    """Gust velocities (m/s) and angular rates (rad/s) in body axes: the air moves with them."""

    u: jnp.ndarray
    v: jnp.ndarray
    w: jnp.ndarray
    p: jnp.ndarray
    q: jnp.ndarray
    r: jnp.ndarray


def gust_params(level, span_m) -> GustParams:
    """Per-run constants of :func:`gust_step` for a turbulence level (0 none .. 3 severe) and wing span (m)."""
    rows = [jnp.asarray(row[1:]) * FT_TO_M for row in (_SIGMA_LIGHT_FT_S, _SIGMA_MODERATE_FT_S, _SIGMA_SEVERE_FT_S)]
    values = _level_interp(level, (jnp.zeros_like(rows[0]), *rows))
    grid = _HIGH_START_FT + _HIGH_STEP_FT * jnp.arange(_HIGH_CELLS + 1, dtype=values.dtype)
    high = jnp.interp(grid, jnp.asarray(_HIGH_KNOTS_FT, values.dtype), values)
    span = jnp.asarray(span_m)
    return GustParams(0.1 * _level_interp(level, _W20_KT) * KT_TO_M_S, high, math.pi / (4.0 * span),
                      math.pi * jnp.sqrt(0.1 / span) * (math.pi / (4.0 * span)) ** (1.0 / 6.0))


def gust_scales(params: GustParams, altitude_m, one=1.0):
    """(sigma_u = sigma_v m/s, L_u = L_v m, sigma_w m/s, L_w m) at an altitude (m), as :func:`intensity`."""
    h_ft = once(jnp.maximum(altitude_m / FT_TO_M, 10.0), one)  # read by the table's cell and the scales
    x = (jnp.clip(h_ft, _HIGH_START_FT, _HIGH_KNOTS_FT[-1]) - _HIGH_START_FT) * (1.0 / _HIGH_STEP_FT)
    cell = jnp.minimum(jnp.floor(x), _HIGH_CELLS - 1)
    i = cell.astype(jnp.int32)
    sigma_hi = params.high[i] + (params.high[i + 1] - params.high[i]) * (x - cell)
    return _scales(h_ft, params.sigma_w_low, once(sigma_hi, one), one)


def _second_order(z1, z2, r, decay, n1, n2, one):
    """Exact step of the normalised Dryden v/w filter over ``r`` time constants (``decay`` = exp(-r)).

    In units of its time constant, with states scaled to unit stationary variance, the filter
    (1 + sqrt3 s) / (1 + s)^2 has ``Phi = exp(-r) [[1 + r, r], [-r, 1 - r]]`` and the sample noise
    covariance ``Q = I - Phi Phi^T``: Q11 = P(3, X), Q12 = X^2 e^-X / 2, Q22 = 1 - e^-X (1 - X + X^2/2)
    with X = 2 r and P the regularised incomplete gamma function, P(3, X) = e^-X X^3 S(X) / 6,
    S(X) = sum_k 6 X^k / (k + 3)!. Each factor is computed without cancellation (Q22 as
    -expm1(-X) + e^-X X (1 - X/2)), so the Cholesky factor holds in float32 down to r of 1e-4.
    With y = sqrt(X S(X) / 6) the factors are L11 = e^-X/2 X y and L21 = Q12 / L11 = e^-X/2 X / (2 y).
    """
    x = 2.0 * r
    series = 1.0 / math.factorial(_S_TERMS + 2)  # S(X) / 6
    for k in range(_S_TERMS - 2, -1, -1):
        series = series * x + 1.0 / math.factorial(k + 3)
    root = jnp.sqrt(x * series)
    decay_x = decay * x
    l11 = decay_x * root
    l21 = decay_x / (2.0 * root)
    q22 = -jnp.expm1(-x) + decay * decay_x * (1.0 - 0.5 * x)
    l22 = jnp.sqrt(jnp.maximum(q22 - l21 * l21, 0.0))
    l11, l21, l22, a = once((l11, l21, l22, decay * r * (z1 + z2)), one)
    return decay * z1 + a + l11 * n1, decay * z2 - a + l21 * n1 + l22 * n2


def _first_order(z, r, decay, n):
    """Exact step of a unit-variance first-order Gauss-Markov state over ``r`` time constants (``decay`` = exp(-r))."""
    return decay * z + jnp.sqrt(-jnp.expm1(-2.0 * r)) * n


def _low_pass(f, y, y_next, r, decay):
    """f + : y low-passed by 1 / (1 + tau s) over ``r`` = dt / tau, exact for y linear between its samples."""
    return decay * f - jnp.expm1(-r) * y + (y_next - y) * (1.0 + jnp.expm1(-r) / r)


def _normalised(z1, z2):
    """The unit-variance output (z1 + sqrt3 z2) / 2 of a normalised v/w filter."""
    return 0.5 * (z1 + math.sqrt(3.0) * z2)


def gust_init(noise6) -> GustState:
    """Stationary forming filters from six standard normals; the q and r gusts start at zero."""
    n = [noise6[i] for i in range(GUST_NORMALS)]
    return GustState(n[0], n[1], n[2], n[3], n[4], n[5], _normalised(n[1], n[2]), _normalised(n[3], n[4]))


def gust_step(params: GustParams, state: GustState, altitude_m, tas_m_s, noise6, dt_s: float, one=1.0):
    """One sample of the six gust components at the flight point (altitude m, true airspeed m/s).

    Returns (new state, :class:`Gust` at the start of the sample). The forming filters are those of
    the flight point of the sample, discretised exactly over it; their states keep unit variance
    however the point moves, so each gust has the Dryden variance of the current point. ``one`` is
    the runtime 1.0 of :func:`mcfdd.compute.once` (scales and filter coefficients feed several states).
    """
    sigma_uv, length_uv, sigma_w, length_w = gust_scales(params, altitude_m, one)
    sigma_uv, sigma_w = once((sigma_uv, sigma_w), one)  # the lengths are read as divisors, where a stored
    # quotient x / 1 would be re-associated and recomputed: each is computed where it is read
    step_length = dt_s * tas_m_s
    r_uv, r_w, r_p = step_length / length_uv, step_length / length_w, step_length * params.span_rate
    r_r = r_p * (4.0 / 3.0)  # tau_r = 3 b / (pi V)
    r_uv, r_w, r_p, r_r = once((r_uv, r_w, r_p, r_r), one)  # stored before their exponentials read them
    e_uv, e_w, e_p, e_r = once((jnp.exp(-r_uv), jnp.exp(-r_w), jnp.exp(-r_p), jnp.exp(-r_r)), one)
    zeta_v, zeta_w = once((_normalised(state.v1, state.v2), _normalised(state.w1, state.w2)), one)
    gust = Gust(sigma_uv * state.u, sigma_uv * zeta_v, sigma_w * zeta_w,
                sigma_w * params.p_scale * length_w ** (-1.0 / 3.0) * state.p,
                -sigma_w * params.span_rate * (zeta_w - state.w_low),
                sigma_uv * params.span_rate * (4.0 / 3.0) * (zeta_v - state.v_low))
    v1, v2 = once(_second_order(state.v1, state.v2, r_uv, e_uv, noise6[1], noise6[2], one), one)
    w1, w2 = once(_second_order(state.w1, state.w2, r_w, e_w, noise6[3], noise6[4], one), one)
    new = GustState(_first_order(state.u, r_uv, e_uv, noise6[0]), v1, v2, w1, w2,
                    _first_order(state.p, r_p, e_p, noise6[5]),
                    _low_pass(state.v_low, zeta_v, _normalised(v1, v2), r_r, e_r),
                    _low_pass(state.w_low, zeta_w, _normalised(w1, w2), r_p, e_p))
    return new, gust

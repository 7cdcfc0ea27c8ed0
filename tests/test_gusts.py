"""Six-component Dryden turbulence of the full aircraft against MIL-F-8785C.

Intensities and scale lengths against the specification's formulas and table written out here;
the sampled gusts' Welch spectra (``scipy.signal.welch``) against the MIL-F-8785C spectra of all
six components, aliased as sampling aliases them; their variances against sigma^2 and the
integrals of the spectra (``scipy.integrate.quad``); and, at a flight point that moves through
the low, transition and high-altitude models while the airspeed changes, the ensemble variance
and the one-sample correlation of each gust at every time against the current point's values.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, signal

from mcfdd.plant import turbulence

SPAN_M = 44.8
DT_S = 0.01
FT = 0.3048
KT = 1852.0 / 3600.0
# MIL-F-8785C Fig. 7, sigma (ft/s) of the medium/high-altitude model against altitude (ft), by level
ALT_FT = [500, 1750, 3750, 7500, 15000, 25000, 35000, 45000, 55000, 65000, 75000, 80000]
SIGMA_HIGH_FT_S = {1: [6.6, 6.9, 7.4, 6.7, 4.6, 2.7, 0.4, 0, 0, 0, 0, 0],
                   2: [8.6, 9.6, 10.6, 10.1, 8.0, 6.6, 5.0, 4.2, 2.7, 0, 0, 0],
                   3: [15.6, 17.6, 23.0, 23.6, 22.1, 20.0, 16.0, 15.1, 12.1, 7.9, 6.2, 5.1]}
W20_KT = {1: 15.0, 2: 30.0, 3: 45.0}


def spec_scales(level: int, h_m: float):
    """(sigma_u = sigma_v, L_u = L_v, sigma_w, L_w) in SI units from MIL-F-8785C 3.7.2 as written."""
    h = max(h_m / FT, 10.0)

    def low(hh):
        sigma_w = 0.1 * W20_KT[level] * KT
        shape = 0.177 + 0.000823 * hh
        return sigma_w / shape**0.4, hh / shape**1.2 * FT, sigma_w, hh * FT

    def high(hh):
        sigma = float(np.interp(hh, ALT_FT, SIGMA_HIGH_FT_S[level])) * FT
        return sigma, 1750.0 * FT, sigma, 1750.0 * FT

    if h <= 1000.0:
        return low(h)
    if h >= 2000.0:
        return high(h)
    w = (h - 1000.0) / 1000.0
    return tuple(a + (b - a) * w for a, b in zip(low(1000.0), high(2000.0)))


@pytest.mark.parametrize("level", [1, 2, 3])
def test_scales_follow_the_specification_at_every_altitude(level):
    params = turbulence.gust_params(float(level), SPAN_M)
    for h_m in [0.0, 2.0, 100.0, 304.8, 400.0, 500.0, 609.6, 1000.0, 2500.0, 5000.0, 9000.0, 13000.0, 16000.0,
                20000.0, 26000.0]:
        want = spec_scales(level, h_m)
        got = [float(v) for v in turbulence.gust_scales(params, jnp.asarray(h_m))]
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12, err_msg=f"{h_m} m")
        # the roll axis's per-run intensities (sigma_v, L_v, sigma_w, L_w) are the same functions
        np.testing.assert_allclose([float(v) for v in turbulence.intensity(float(level), h_m)], want, rtol=1e-12,
                                   atol=1e-12)


def dryden_spectra(level: int, h_m: float, tas: float):
    """The MIL-F-8785C spectra Phi(omega) of u, v, w, p, q, r (one-sided in rad/s: integral over 0..inf = variance)."""
    sigma_uv, length_uv, sigma_w, length_w = spec_scales(level, h_m)
    b = SPAN_M

    def lateral(w, sigma, length):
        x = length * w / tas
        return sigma**2 * length / (math.pi * tas) * (1.0 + 3.0 * x**2) / (1.0 + x**2) ** 2

    def u(w):
        return sigma_uv**2 * 2.0 * length_uv / (math.pi * tas) / (1.0 + (length_uv * w / tas) ** 2)

    def p(w):
        return (sigma_w**2 * 0.8 * (math.pi * length_w / (4.0 * b)) ** (1.0 / 3.0)
                / (length_w * tas * (1.0 + (4.0 * b * w / (math.pi * tas)) ** 2)))

    def q(w):
        return (w / tas) ** 2 / (1.0 + (4.0 * b * w / (math.pi * tas)) ** 2) * lateral(w, sigma_w, length_w)

    def r(w):
        return (w / tas) ** 2 / (1.0 + (3.0 * b * w / (math.pi * tas)) ** 2) * lateral(w, sigma_uv, length_uv)

    return [u, lambda w: lateral(w, sigma_uv, length_uv), lambda w: lateral(w, sigma_w, length_w), p, q, r]


def simulate(params, altitude_m, tas_m_s, n_chains: int, key):
    """Gusts (n_chains, steps, 6) of independent chains flying the altitude and airspeed histories (steps,)."""
    @jax.jit
    def run(altitude_m, tas_m_s, key):
        def chain(k):
            k0, k1 = jax.random.split(k)

            def body(state, x):
                h, v, kk = x
                state, gust = turbulence.gust_step(params, state, h, v, jax.random.normal(kk, (6,)), DT_S)
                return state, jnp.stack(gust)

            state = turbulence.gust_init(jax.random.normal(k0, (turbulence.GUST_NORMALS,)))
            return jax.lax.scan(body, state, (altitude_m, tas_m_s, jax.random.split(k1, altitude_m.shape[0])))[1]

        return jax.vmap(chain)(jax.random.split(key, n_chains))

    return np.asarray(run(jnp.asarray(altitude_m), jnp.asarray(tas_m_s), key))


CONSTANT_POINTS = [(1, 150.0, 100.0), (2, 450.0, 130.0), (3, 5000.0, 200.0)]  # low, transition, high model


@pytest.mark.parametrize("case", range(len(CONSTANT_POINTS)))
def test_spectra_and_variances_at_a_constant_flight_point(case):
    """Welch spectra in six bands of 0.2-10 Hz and variances of all six gusts, per chain, against MIL-F-8785C.

    Chains are independent, so the spread of their estimates gives a standard error that includes
    the correlation within a chain; estimates must lie within 4.5 of them (a false failure about
    once in 10^5 per check), and the standard errors must be small enough for that to mean something.
    The reference spectra are summed over the aliases of the 100 Hz sampling (the exact spectrum of
    the samples); q and r start at zero, so the first 5 s are dropped.
    """
    level, h_m, tas = CONSTANT_POINTS[case]
    n_steps, drop = 2**14 + 500, 500
    gusts = simulate(turbulence.gust_params(float(level), SPAN_M), np.full(n_steps, h_m), np.full(n_steps, tas), 64,
                     jax.random.key(case))[:, drop:, :]
    spectra = dryden_spectra(level, h_m, tas)
    freq, psd = signal.welch(gusts, fs=1.0 / DT_S, nperseg=2048, axis=1)  # one-sided, per Hz
    edges = np.geomspace(0.2, 10.0, 7)
    fs = 1.0 / DT_S
    for i, name in enumerate("uvwpqr"):
        reference = sum(2.0 * math.pi * spectra[i](2.0 * math.pi * np.abs(freq + k * fs)) for k in range(-40, 41))
        for lo, hi in zip(edges[:-1], edges[1:]):
            band = (freq >= lo) & (freq < hi)
            ratio = (psd[:, band, i] / reference[band]).mean(axis=1)
            std_error = ratio.std(ddof=1) / math.sqrt(len(ratio))
            assert std_error < 0.03, (name, lo)
            assert abs(ratio.mean() - 1.0) < 4.5 * std_error, (name, lo, hi, ratio.mean(), std_error)
        variance = integrate.quad(spectra[i], 0.0, np.inf, limit=400)[0]
        per_chain = (gusts[:, :, i] ** 2).mean(axis=1) / variance
        std_error = per_chain.std(ddof=1) / math.sqrt(len(per_chain))
        assert std_error < 0.03, name
        assert abs(per_chain.mean() - 1.0) < 4.5 * std_error, (name, per_chain.mean(), std_error)
    sigma_uv, _, sigma_w, _ = spec_scales(level, h_m)  # the velocity variances are sigma^2 exactly
    for i, sigma in ((0, sigma_uv), (1, sigma_uv), (2, sigma_w)):
        assert integrate.quad(spectra[i], 0.0, np.inf, limit=400)[0] == pytest.approx(sigma**2, rel=1e-6)


@jax.jit
def ensemble_moments(params, altitude_m, tas_m_s, key):
    """Per sample, over 4,096 independent chains flying the altitude and airspeed histories (steps,):
    the mean squares of the six gusts and the mean of u_k u_(k+1). Returns (steps, 7)."""
    n_chains = 4096
    states = jax.vmap(turbulence.gust_init)(jax.random.normal(key, (n_chains, turbulence.GUST_NORMALS)))
    step = jax.vmap(lambda s, h, v, n: turbulence.gust_step(params, s, h, v, n, DT_S), in_axes=(0, None, None, 0))

    def body(carry, x):
        state, u_prev = carry
        h, v, k = x
        state, gust = step(state, h, v, jax.random.normal(jax.random.fold_in(key, k), (n_chains, 6)))
        gust = jnp.stack(gust, axis=1)
        return (state, gust[:, 0]), jnp.concatenate([(gust**2).mean(axis=0), (u_prev * gust[:, 0]).mean()[None]])

    n = altitude_m.shape[0]
    return jax.lax.scan(body, (states, jnp.zeros(n_chains)), (altitude_m, tas_m_s, jnp.arange(n)))[1]


def test_gusts_follow_a_moving_flight_point():
    """Altitude 20 -> 1,200 m (low, transition and high-altitude models) and airspeed 70 -> 190 m/s in 30 s.

    At every sample the ensemble variance of u, v, w and p across 4,096 chains equals the current
    point's sigma^2 (within 4.5 standard errors of a Gaussian variance estimate, sigma^2 sqrt(2/n)),
    and the one-sample correlation coefficient of u equals exp(-V dt / L_u) of the current point
    (its standard error is (1 - rho^2) / sqrt(n)): the filters are discretised at the point of
    each sample, not at the first one.
    """
    n_steps, n_chains = 3000, 4096
    t = np.arange(n_steps) * DT_S
    h = 20.0 + 1180.0 * t / t[-1]
    v = 70.0 + 120.0 * (t / t[-1]) ** 2
    level = 2
    moments = np.asarray(ensemble_moments(turbulence.gust_params(float(level), SPAN_M), jnp.asarray(h),
                                          jnp.asarray(v), jax.random.key(7)))
    scales = np.array([spec_scales(level, hk) for hk in h])  # (steps, 4)
    # all three models were crossed
    assert scales[0, 3] == pytest.approx(20.0) and scales[-1, 3] == pytest.approx(1750.0 * FT)
    every = slice(None, None, 50)
    p_variance = [integrate.quad(dryden_spectra(level, hk, vk)[3], 0.0, np.inf)[0]
                  for hk, vk in zip(h[every], v[every])]
    tolerance = 4.5 * math.sqrt(2.0 / n_chains)
    for i, variance in ((0, scales[:, 0] ** 2), (1, scales[:, 0] ** 2), (2, scales[:, 2] ** 2)):
        assert np.all(np.abs(moments[:, i] / variance - 1.0) < tolerance), "uvw"[i]
    assert np.all(np.abs(moments[every, 3] / p_variance - 1.0) < tolerance)
    correlation = moments[1:, 6] / np.sqrt(moments[:-1, 0] * moments[1:, 0])
    expected = np.exp(-v[:-1] * DT_S / scales[:-1, 1])
    std_error = (1.0 - expected**2) / math.sqrt(n_chains)
    assert np.all(np.abs(correlation - expected) < 4.5 * std_error + 1e-5)
    assert expected.max() - expected.min() > 10.0 * std_error.max()  # the correlation itself moved that much

"""The FDD layer against independent references.

Exact ZOH samples and scipy ``solve_ivp`` trajectories of the first-order LPV models, scipy.signal
(``lsim``, ``cont2discrete``/``dlsim``) responses of the paper's transfer functions, python-control
H-inf norms, the convolution integral (13), plain Python loops for the grid reductions, and
hand-made traces for the decision and stall-identification logic. Float64 (conftest).
"""

import math

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal as sig
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar

from helpers import ROUNDING
from mcfdd import io
from mcfdd.analysis import build
from mcfdd.config import FddConfig, LoeDetectionConfig, StallDetectionConfig
from mcfdd.fdd import decision, evaluator, lpv, residual, stall, system, thresholds

DT_S = 0.01
R_ARM_M = 0.0525
DEG_M = math.radians(1.0) * R_ARM_M  # rod travel (m) of one degree of surface deflection
VCAS_M_S, ALT_M = 150.0, 8000.0  # off the normalisation reference, so every affine term acts


@pytest.fixture(scope="module")
def bank():
    return lpv.from_dict(io.load_bank_dict(), dtype=np.float64)[0]


def eq4_gains(bank, vcas_m_s, altitude_m):
    """Eq. (4) written out in numpy at one flight point: a function (x, s) -> gains of all models."""
    nm = bank.norm
    p = np.array([1.0, (vcas_m_s - nm.vcas_ref_m_s) / nm.vcas_scale_m_s,
                  (altitude_m - nm.altitude_ref_m) / nm.altitude_scale_m])
    c = np.asarray(bank.coef) @ p  # (N, 4): C0..C3
    return lambda x, s: c[:, 0] + c[:, 1] * s + x / nm.x_scale_m * (c[:, 2] + c[:, 3] * s)


def lpv_plant(gain, model, u_c, u0):
    """Exact samples of x' = k(u_c - x) for u_c held and k frozen over each sample at its start.

    ``gain(x, s)`` gives the gains of all models; returns u (n+1,) of ``model`` and the gains (n, N)
    every model takes along that trajectory with s = sgn(u_c - u), as the on-board filters see them.
    """
    u, ks = [u0], []
    for c in u_c:
        k = gain(u[-1], np.sign(c - u[-1]))
        phi = math.exp(-k[model] * DT_S)
        u.append(phi * u[-1] + (1.0 - phi) * c)
        ks.append(k)
    return np.array(u), np.array(ks)


def smooth_command(n, offset_deg=15.0):
    """A ZOH command at large deflection that keeps moving: two sines, rod units."""
    t = np.arange(n) * DT_S
    return (offset_deg + 6.0 * np.sin(2 * np.pi * 0.7 * t) + 3.0 * np.sin(2 * np.pi * 1.9 * t)) * DEG_M


@jax.jit
def run_residual(x_q0, u, u_c, k, k0, a):
    """residual.step scanned over samples; u, u_c (n,), k (n, ...) -> r (n, ...)."""
    def body(x_q, inp):
        u_n, u_c_n, k_n = inp
        return residual.step(k_n, k0, a, x_q, u_n, u_c_n, DT_S)
    return jax.lax.scan(body, x_q0, (u, u_c, k))[1]


@jax.jit
def run_evaluator(params, r):
    """evaluator.step scanned over the leading axis of r -> theta."""
    return jax.lax.scan(lambda xi, r_n: evaluator.step(params, xi, r_n, DT_S), jnp.zeros_like(r[0]), r)[1]


def zoh_response(num, den, x):
    """ZOH discretisation (scipy cont2discrete) of num/den applied to the held samples x, from rest."""
    return sig.dlsim(sig.cont2discrete(sig.tf2ss(num, den), DT_S, method="zoh"), x)[1][:, 0]


# ---------------------------------------------------------------------------------------------
# LPV gains


def test_gains_match_eq4(bank):
    """lpv.gains against eq. (4) written out, over deflections, both directions, off-reference p."""
    ref = eq4_gains(bank, VCAS_M_S, ALT_M)
    for x in (-0.02, 0.0, 0.013):
        for s in (-1.0, 0.0, 1.0):
            np.testing.assert_allclose(lpv.gains(bank, x, s, VCAS_M_S, ALT_M), ref(x, s), rtol=1e-14)


# ---------------------------------------------------------------------------------------------
# Residual generators, eqs. (20)/(24)


FROZEN_K = np.array([24.0, 17.0, 11.0])


@pytest.mark.parametrize("scheduled", [False, True], ids=["frozen", "scheduled"])
@pytest.mark.parametrize("model", [0, 1, 2])
def test_residual_decays_on_its_own_model(bank, scheduled, model):
    """On the ZOH-sampled model i, r_i(n+1) = exp(-aT) r_i(n) to 1e-12 (relative to max|u_c|).

    Exact up to rounding for this discretisation, for frozen and for time-varying k_n (LPV bank,
    s = sgn(u_c - u), x = u), from a random filter state. The other filters j see the continuous
    residual a/(s+a) [(k_i - k_j)/k0_j (u_c - u)] (from (24) with u' = k_i (u_c - u)); while u_c
    moves their theta stays within a factor 2 of that prediction's (the O(kT) discretisation
    error is about 15 %) and at least 100 times filter i's.
    """
    n, a = 600, 4.0
    u_c = smooth_command(n)
    if scheduled:
        gain, k0 = eq4_gains(bank, VCAS_M_S, ALT_M), np.asarray(bank.k0)
    else:
        gain, k0 = (lambda x, s: FROZEN_K), FROZEN_K
    u, k = lpv_plant(gain, model, u_c, u_c[0])
    x_q0 = np.random.default_rng(model).normal(0.0, 0.01, k0.shape)
    r = np.asarray(run_residual(x_q0, u[:-1], u_c, k, k0, a))

    own = r[:, model]
    assert np.abs(own[0]) > 1e-4
    assert np.max(np.abs(own[1:] - math.exp(-a * DT_S) * own[:-1])) <= 1e-12 * np.max(np.abs(u_c))
    assert np.abs(own[-1]) < 1e-9

    drive = (k[:, [model]] - k) / k0 * (u_c - u[:-1])[:, None]
    predicted = np.stack([zoh_response([a], [1.0, a], drive[:, j]) for j in range(k0.size)], axis=1)
    params = evaluator.NarendraParams(0.0, 1.0, a)
    theta, theta_ref = np.asarray(run_evaluator(params, r)), np.asarray(run_evaluator(params, predicted))
    moving = slice(300, None)  # after 3 s: the initial filter state has decayed
    others = [j for j in range(k0.size) if j != model]
    ratio = theta[moving, others] / theta_ref[moving, others]
    assert np.all((ratio >= 0.5) & (ratio <= 2.0))
    assert np.all(theta_ref[moving, others] >= 100.0 * theta[moving, [model]])


@pytest.mark.parametrize("model", [0, 4])
def test_residual_on_continuous_lpv_plant(bank, model):
    """Continuous plant x' = k(x, s)(u_c - x) by solve_ivp, u_c held: |r_i| <= the O(T) bound.

    Over a sample s is constant and k affine in x, k = k_n + k_x (x - u_n), with x between u_n and
    the next sample, so the sample's defect against the frozen-k ZOH step the filter assumes is
    |d_n| <= |u_c - u_n| |int (k - k_n) dt| <= |k_x| k_max |u_c - u_n|^2 T^2 / 2. The residual obeys
    r(n+1) = exp(-aT) r(n) + c d_n with c = (1 - exp(-aT)) / (1 - exp(-k0 T)), hence
    |r_i| <= max|d| / (1 - exp(-k0_i T)) = O(T). The mismatched filters stay far above it.
    """
    n, a = 300, 10.0
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    u_c = smooth_command(n)
    u, k, bound = [u_c[0]], [], []
    for c in u_c:
        s = np.sign(c - u[-1])
        sol = solve_ivp(lambda t, x, c, s: gain(x[0], s)[model] * (c - x), (0.0, DT_S), [u[-1]], args=(c, s),
                        method="DOP853", rtol=1e-12, atol=1e-16)
        k_ends = [gain(x, s)[model] for x in (u[-1], sol.y[0, -1])]
        k_x = abs(gain(1.0, s)[model] - gain(0.0, s)[model])
        bound.append(k_x * max(k_ends) * (c - u[-1]) ** 2 * DT_S ** 2 / 2.0)
        k.append(gain(u[-1], s))
        u.append(sol.y[0, -1])
    k0 = np.asarray(bank.k0)
    r = np.abs(np.asarray(run_residual(-u_c[0] * np.ones_like(k0), np.array(u[:-1]), u_c, np.array(k), k0, a)))
    limit = max(bound) / (1.0 - math.exp(-k0[model] * DT_S)) + 1e-12
    assert r[:, model].max() <= limit
    others = [j for j in range(k0.size) if j != model]
    assert r[100:, others].max(axis=0).min() > 10.0 * limit


@pytest.mark.parametrize("k, k_j", [(24.0, 24.0), (24.0, 18.0), (24.0, 30.0), (12.0, 20.0)])
def test_frozen_filter_matches_transfer_function(k, k_j):
    """Filter with frozen rho against scipy lsim of (20) cascaded with the plant k_j/(s+k_j).

    u_c is held per sample and u is the exact response of gain k_j to it, so the continuous filter
    driven by the continuous u(t) and held u_c(t) is the exact ZOH response (lsim, interp=False) of
    Q(s) [G_j; 1], connected in state space by python-control. Both obey, per sample,
    r+ = exp(-aT) r + g (u_c - u_n) with our g_d = c (e^{-kT} - e^{-k_j T}) and the exact
    g_c = (a/k0)(k_j - k)(e^{-k_j T} - e^{-aT})/(a - k_j), both (a/k0)(k_j - k) T (1 + O(T)); so
    |r_d - r_c| <= |g_d - g_c| max|u_c - u| / (1 - e^{-aT}), which is O(|k_j - k| T) max|u_c - u| and 0
    (up to rounding) for k_j = k.
    """
    k0, a, n = 20.0, 3.0, 400
    u_c = np.cumsum(np.random.default_rng(1).normal(0.0, 2e-4, n))
    u, _ = lpv_plant(lambda x, s: np.array([k_j]), 0, u_c, 0.0)
    r_d = np.asarray(run_residual(jnp.asarray(0.0), u[:-1], u_c, np.full(n, k), k0, a))

    (n_u, d_u), (n_c, d_c) = residual.transfer_function(k, k0, a)
    np.testing.assert_allclose(np.concatenate([n_u, d_u, n_c, d_c]),
                               [a / k0, a * k / k0, 1.0, a, -a * k / k0, 1.0, a], rtol=1e-15)  # eq. (20)
    cascade = (control.ss(control.tf(n_u, d_u)) * control.ss(control.tf([k_j], [1.0, k_j]))
               + control.ss(control.tf(n_c, d_c)))  # state-space connection: no polynomial cancellation
    t = np.arange(n) * DT_S
    r_c = sig.lsim((cascade.A, cascade.B, cascade.C, cascade.D), u_c, t, interp=False)[1]

    g_d = (1 - math.exp(-a * DT_S)) / (1 - math.exp(-k0 * DT_S)) * (math.exp(-k * DT_S) - math.exp(-k_j * DT_S))
    g_c = a / k0 * (k_j - k) * (math.exp(-k_j * DT_S) - math.exp(-a * DT_S)) / (a - k_j)
    tol = abs(g_d - g_c) * np.max(np.abs(u_c - u[:-1])) / (1 - math.exp(-a * DT_S)) + 1e-13
    assert tol <= abs(k_j - k) * DT_S * np.max(np.abs(u_c - u[:-1])) + 1e-13
    np.testing.assert_allclose(r_d, r_c, rtol=0, atol=tol)
    if k_j != k:
        assert np.max(np.abs(r_c)) > 10 * tol


@pytest.mark.parametrize("k", [20.0, 14.0, 27.0])
def test_additive_fault_response(k):
    """Issue 5: on u = G (u_c + f) the detector gives r = (k/k0) a/(s+a) f, u_c decoupled.

    Reference: ZOH of (k/k0) a/(s+a) (cont2discrete + dlsim) on f. Ours has the same pole and gain
    (1 - e^{-aT})(1 - e^{-kT})/(1 - e^{-k0 T}), i.e. the reference times h(kT)/h(k0T) with
    h(x) = (1 - e^{-x})/x; |h'| <= 1/2, so |r - r_ref| <= |k - k0| T / (2 h(k0 T)) |r_ref|: exact for k = k0.
    """
    k0, a, n = 20.0, 10.0, 400
    rng = np.random.default_rng(2)
    u_c = np.cumsum(rng.normal(0.0, 5e-4, n))
    t = np.arange(n) * DT_S
    f = np.where(t >= 1.0, 2e-3, 0.0) + np.where(t >= 2.5, 4e-3 * (t - 2.5), 0.0)
    u, _ = lpv_plant(lambda x, s: np.array([k]), 0, u_c + f, 0.0)
    r = np.asarray(run_residual(jnp.asarray(0.0), u[:-1], u_c, np.full(n, k), k0, a))
    r_ref = zoh_response([k / k0 * a], [1.0, a], f)

    h_k0 = -math.expm1(-k0 * DT_S) / (k0 * DT_S)
    rel = abs(k - k0) * DT_S / (2 * h_k0)
    assert np.all(np.abs(r - r_ref) <= rel * np.abs(r_ref) + 1e-14)
    assert np.max(np.abs(r_ref)) > 1e-3


# ---------------------------------------------------------------------------------------------
# Thresholds, eq. (16)


@pytest.mark.parametrize("k_i, k_j", [(25.0, 20.0), (24.3, 10.8), (5.0, 30.0), (16.0, 16.5)])
def test_hinf_distance_against_python_control(k_i, k_j):
    """||G_j - G_i||_inf and its peak frequency against python-control.

    ``control.norm(p='inf')`` (slycot absent: its scipy Hamiltonian bisection, tol 1e-6), and a
    dense log sweep of the frequency response refined by scipy's bounded scalar minimisation.
    """
    diff = control.tf([k_j], [1, k_j]) - control.tf([k_i], [1, k_i])
    dist = float(thresholds.hinf_distance(k_i, k_j))
    w_peak = float(thresholds.peak_frequency(k_i, k_j))
    assert dist == pytest.approx(control.norm(diff, p="inf"), rel=1e-5)

    w = np.logspace(-2, 4, 20001)
    mag = np.abs(diff(1j * w))
    assert mag.max() <= dist * (1 + 1e-12)
    i = int(np.argmax(mag))
    best = minimize_scalar(lambda lw: -abs(diff(1j * 10.0 ** lw)), bounds=(math.log10(w[i - 1]), math.log10(w[i + 1])),
                           method="bounded", options={"xatol": 1e-10})
    assert -best.fun == pytest.approx(dist, rel=1e-12)
    assert 10.0 ** best.x == pytest.approx(w_peak, rel=1e-4)


def test_grid_distances_and_thresholds_match_a_loop(bank):
    """pairwise_distances, minimum_distances (with a mask) and eq. (16) against plain loops."""
    vcas, alt, xs = [80.0, 130.0, 220.0], [0.0, 6000.0, 11000.0], [-0.02, 0.0, 0.011, 0.0229]
    mask = np.ones((3, 3, 4, 2), bool)
    mask[2, 0] = False  # e.g. a (Vcas, h) corner outside the envelope
    d = np.asarray(thresholds.pairwise_distances(bank, jnp.array(vcas), jnp.array(alt), jnp.array(xs)))
    d_min = np.asarray(thresholds.minimum_distances(d, jnp.asarray(mask)))
    tau = np.asarray(thresholds.thresholds(jnp.asarray(d_min)))

    n = bank.k0.shape[0]
    ref_d, ref = np.empty_like(d), np.full((n, n), np.inf)
    for iv, v in enumerate(vcas):
        for ih, h in enumerate(alt):
            gain = eq4_gains(bank, v, h)
            for ix, x in enumerate(xs):
                for isg, s in enumerate((-1.0, 1.0)):
                    k = gain(x, s)
                    for i in range(n):
                        for j in range(n):
                            dij = abs(k[j] - k[i]) / (k[i] + k[j])
                            ref_d[i, j, iv, ih, ix, isg] = dij
                            if mask[iv, ih, ix, isg]:
                                ref[i, j] = min(ref[i, j], dij)
    np.testing.assert_allclose(d, ref_d, **ROUNDING)
    np.testing.assert_allclose(d_min, ref, **ROUNDING)
    np.testing.assert_allclose(tau, [min(ref[i, j] for j in range(n) if j != i) for i in range(n)], rtol=1e-12)
    assert np.all(tau > 0)


# ---------------------------------------------------------------------------------------------
# Narendra evaluator, eqs. (13)-(14)


def narendra_integral(alpha, beta, gamma, r):
    """Eq. (13) at the sample instants for |r| held over each sample: the convolution summed exactly."""
    mag = np.abs(r)
    t = np.arange(len(r)) * DT_S
    weight = -math.expm1(-gamma * DT_S) / gamma  # int over one sample of e^{-gamma (t_{m+1} - tau)}
    theta = []
    for n in range(len(r)):
        theta.append(alpha * mag[n] + beta * weight * np.sum(np.exp(-gamma * (t[n] - t[1:n + 1])) * mag[:n]))
    return np.array(theta)


@pytest.mark.parametrize("alpha, beta, gamma", [(0.0, 1.0, 0.1), (1.0, 1.0, 0.1), (0.3, 10.0, 10.0)])
def test_evaluator_matches_eq13(alpha, beta, gamma):
    """Discrete theta equals the exact integral (13) at the sample instants, |r| piecewise constant."""
    r = np.random.default_rng(3).normal(0.0, 1.0, 300)
    theta = np.asarray(run_evaluator(evaluator.NarendraParams(alpha, beta, gamma), r))
    np.testing.assert_allclose(theta, narendra_integral(alpha, beta, gamma, r), rtol=1e-12, atol=1e-14)


def test_evaluator_solve_ivp():
    """One case of (14) integrated by solve_ivp (tight tolerances), sample by sample."""
    alpha, beta, gamma = 0.5, 2.0, 3.0
    r = np.random.default_rng(4).normal(0.0, 1.0, 50)
    xi, ref = 0.0, []
    for r_n in r:
        ref.append(xi + alpha * abs(r_n))
        xi = solve_ivp(lambda t, y, m: -gamma * y + beta * m, (0.0, DT_S), [xi], args=(abs(r_n),),
                       rtol=1e-12, atol=1e-15).y[0, -1]
    theta = np.asarray(run_evaluator(evaluator.NarendraParams(alpha, beta, gamma), r))
    np.testing.assert_allclose(theta, ref, rtol=1e-10, atol=1e-13)


def test_evaluator_parameters_each_matter():
    """alpha adds (d alpha)|r|, beta scales xi, gamma sets the level beta R / gamma for |r| = R."""
    r = np.random.default_rng(5).normal(0.0, 1.0, 200)
    base = evaluator.NarendraParams(0.5, 1.0, 2.0)
    theta = np.asarray(run_evaluator(base, r))
    more_alpha = np.asarray(run_evaluator(base._replace(alpha=1.5), r))
    np.testing.assert_allclose(more_alpha - theta, np.abs(r), rtol=1e-12)
    more_beta = np.asarray(run_evaluator(base._replace(beta=3.0), r))
    np.testing.assert_allclose(more_beta - 0.5 * np.abs(r), 3.0 * (theta - 0.5 * np.abs(r)), **ROUNDING)

    t = np.arange(2000) * DT_S
    for gamma in (0.5, 2.0):
        xi = np.asarray(run_evaluator(evaluator.NarendraParams(0.0, 1.0, gamma), np.full(t.size, 0.2)))
        np.testing.assert_allclose(xi, 0.2 / gamma * -np.expm1(-gamma * t), **ROUNDING)


# ---------------------------------------------------------------------------------------------
# Decisions, eqs. (15) and (25)


def test_excitation_is_the_low_passed_tracking_error():
    """excitation_step = ZOH of a/(s+a) on the held magnitude of the measured tracking error |u_c - u|, to 1e-12."""
    a = 1.5
    rng = np.random.default_rng(6)
    u_c = 0.01 + np.cumsum(rng.normal(0.0, 1e-3, 500))
    u = u_c - rng.normal(0.0, 2e-3, 500)

    def body(state, inp):
        return decision.excitation_step(a, state, inp[0], inp[1], DT_S)

    out = np.asarray(jax.jit(lambda x, m: jax.lax.scan(body, decision.excitation_init(m[0]), (x, m))[1])(u_c, u))
    ref = zoh_response([a], [1.0, a], np.abs(u_c - u))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12 * np.max(np.abs(u_c - u)))
    assert np.max(np.abs(ref)) > 0.1 * np.std(u_c - u) and np.min(u_c - u) < 0.0 < np.max(u_c - u)


@pytest.mark.parametrize("plant_k", [17.0, 30.0], ids=["slower", "faster"])
def test_ratio_is_the_relative_gain_mismatch(plant_k):
    """On a ZOH-sampled first-order plant of gain k_j with the filters' gains frozen, filter i's residual
    is the excitation low-pass times s_i = (exp(-k_i T) - exp(-k_j T)) / (1 - exp(-k0_i T)) at every
    sample while the tracking error keeps its sign (a step from rest and its transient), so
    theta_i / ||u|| = |s_i| (about |k_j - k_i| / k0_i) there; in a manoeuvre out and back after it,
    theta_i / ||u|| stays at most |s_i| and falls below it (the signed error cancels in r_i)."""
    a, n, step_end = 0.5, 900, 400
    k, k0 = FROZEN_K, np.array([24.0, 18.0, 10.0])
    i = np.arange(n)
    u_c = (np.where(i >= 50, 3.0, 0.0) + np.where(i >= step_end, 6.0 * np.sin(2 * np.pi * 0.7 * (i - step_end) * DT_S),
                                                   0.0)) * DEG_M
    phi_j = math.exp(-plant_k * DT_S)
    u = [0.0]
    for c in u_c[:-1]:
        u.append(phi_j * u[-1] + (1.0 - phi_j) * c)
    u = np.array(u)
    r = np.asarray(run_residual(np.zeros(3), u, u_c, np.broadcast_to(k, (n, 3)), k0, a))
    band = zoh_response([a], [1.0, a], np.abs(u_c - u))
    scale = (np.exp(-k * DT_S) - phi_j) / -np.expm1(-k0 * DT_S)
    one_sign = i < step_end
    np.testing.assert_allclose(r[one_sign], band[one_sign, None] * scale, rtol=0, atol=1e-12 * np.max(np.abs(r)))
    params = evaluator.NarendraParams(0.0, 1.0, 1.0)
    theta, theta_u = np.asarray(run_evaluator(params, r)), np.asarray(run_evaluator(params, band))
    ratio = theta[theta_u > 0] / theta_u[theta_u > 0, None]
    first = ratio[:step_end - 51]
    np.testing.assert_allclose(first, np.broadcast_to(np.abs(scale), first.shape), rtol=1e-9, atol=1e-12)
    assert np.all(ratio <= np.abs(scale) * (1.0 + 1e-9) + 1e-12)
    assert np.all(ratio[-100:, [0, 2]] < 0.8 * np.abs(scale[[0, 2]]))
    np.testing.assert_allclose(np.abs(scale), np.abs(plant_k - k) / k0, rtol=0.15, atol=1e-12)


def test_gated_filters_restart_from_equilibrium(bank):
    """While evaluation is suspended (here: tracking error beyond the linear range) every residual and
    the band-pass input are zero and, once the gate reopens, the run equals a fresh start at the first
    ungated sample from the measured position: no transient of the gated interval survives it, not
    even the first-order prediction of the last saturated sample (which a start at that sample carries
    into the first residual after the gate)."""
    params = build.fdd_params(FddConfig(loe=LoeDetectionConfig(max_load_fraction=1.0, linear_range_deg=3.5)), bank,
                              r_arm_m=R_ARM_M)
    n, jump = 600, 100
    u_c = np.where(np.arange(n) >= jump, 20.0, 0.0) * DEG_M + smooth_command(n, 0.0) * 0.1
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    u = [0.0]
    for c in u_c[:-1]:  # a rod at a saturated rate of 40 deg/s: far from every first-order model
        u.append(u[-1] + np.clip(c - u[-1], -0.4 * DEG_M, 0.4 * DEG_M))
    u = np.array(u)
    gated = np.abs(u_c - u) > 3.5 * DEG_M
    reopen = int(np.flatnonzero(gated)[-1]) + 1
    assert gated[jump] and reopen > jump + 10 and gain(u[0], 1.0)[0] > 0

    def run(state, u_c, u, t0):
        def body(state, inp):
            c, m, t = inp
            state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
            return state, (out.r, out.theta, out.theta_u)
        return jax.lax.scan(body, state, (u_c, u, t0 + np.arange(u_c.size) * DT_S))[1]

    r, theta, theta_u = (np.asarray(x) for x in jax.jit(run)(system.init(params, u[0]), u_c, u, 0.0))
    assert np.all(r[gated] == 0.0) and np.all(r[reopen] == 0.0)

    phi_d = np.exp(-params.loe.direction_pole * DT_S)
    error_lp = np.zeros(n + 1)  # the direction's low-pass of u_c - u, samples before i
    for i in range(n):
        error_lp[i + 1] = phi_d * error_lp[i] + (1.0 - phi_d) * (u_c[i] - u[i])

    def fresh_start(i):  # filters in equilibrium at u[i], evaluators and the direction holding what they had
        state = system.init(params, u[i])._replace(bank_xi=jnp.asarray(theta[i]), band_xi=jnp.asarray(theta_u[i]),
                                                   error_lp=jnp.asarray(error_lp[i]))
        return (np.asarray(x) for x in jax.jit(run)(state, u_c[i:], u[i:], i * DT_S))

    r2, theta2, theta_u2 = fresh_start(reopen)
    np.testing.assert_allclose(r[reopen:], r2, rtol=0, atol=1e-15)
    np.testing.assert_allclose(theta[reopen:], theta2, rtol=0, atol=1e-15)
    np.testing.assert_allclose(theta_u[reopen:], theta_u2, rtol=0, atol=1e-15)
    assert np.max(np.abs(r[reopen:])) > 0.0 and np.max(np.abs(r[:jump])) > 0.0
    last = reopen - 1  # a filter started at the last gated sample steps with its saturated error
    k = lpv.gains(bank, u[last], np.sign(u_c[last] - u[last]), VCAS_M_S, ALT_M)
    x_q, _ = residual.step(k, bank.k0, params.loe.pole, residual.init(u[last]), u[last], u_c[last], DT_S)
    r_carried = residual.step(k, bank.k0, params.loe.pole, x_q, u[reopen], u_c[reopen], DT_S)[1]
    assert np.min(np.abs(r_carried)) > 1e-3 * DEG_M  # where the restart gives exactly 0


@pytest.mark.parametrize("iota, excited, expected", [
    ([1, 1, 0, 1], True, 2),
    ([0, 1, 1, 1], True, 0),
    ([1, 1, 1, 0], True, 3),
    ([1, 1, 1, 1], True, -1),
    ([0, 0, 0, 0], True, -1),
    ([1, 0, 1, 0], True, -1),
    ([1, 1, 0, 1], False, -1),
])
def test_decode(iota, excited, expected):
    """Only a signature with exactly one zero decodes (to its index), and only while excited."""
    got = decision.decode(jnp.array(iota, bool), jnp.asarray(excited))
    assert int(got) == expected and got.dtype == jnp.int32


def test_signature_and_threshold_direction():
    """Eq. (15): iota_i = 1 iff theta_i >= tau_i ||u|| (equality fires); eq. (25) likewise."""
    theta = jnp.array([0.0, 0.2, 0.3, 0.5])
    iota = decision.signature(theta, 2.0, jnp.array([0.1, 0.1, 0.2, 0.2]))
    assert iota.tolist() == [False, True, False, True]
    assert decision.signature(theta, 2.0, 0.1).tolist() == [False, True, True, True]
    assert decision.threshold(theta, 0.3).tolist() == [False, False, True, True]


def test_scheduled_thresholds_follow_eq16_at_the_current_point(bank):
    """tau_i(rho) = max(tau, f * min_j ||G_j - G_i||_inf (k_i + k_j) / k0_i) with the gains of eq. (4) at
    the sample's u and direction (the sign of the low-passed u_c - u before it): the signature of system.step
    against numpy, and f = 0 is constant tau."""
    n = 400
    u_c = smooth_command(n)
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    u, _ = lpv_plant(gain, 1, u_c, u_c[0])
    k0 = np.asarray(bank.k0)
    for f in (0.0, 1.0):
        params = build.fdd_params(FddConfig(loe=LoeDetectionConfig(tau=0.02, tau_schedule=f, max_load_fraction=1.0)),
                                  bank, r_arm_m=R_ARM_M)

        def body(state, inp):
            c, m, t = inp
            state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
            return state, (out.theta, out.theta_u, out.iota)

        theta, theta_u, iota = (np.asarray(x) for x in jax.jit(lambda: jax.lax.scan(
            body, system.init(params, u[0]), (u_c, u[:-1], np.arange(n) * DT_S))[1])())
        expect = np.empty_like(iota)
        phi_d, error_lp = math.exp(-params.loe.direction_pole * DT_S), 0.0
        for i in range(n):
            k = gain(u[i], np.sign(error_lp))  # sgn(xdot): the low-passed error of the samples before
            error_lp = phi_d * error_lp + (1.0 - phi_d) * (u_c[i] - u[i])
            d = np.array([[thresholds.hinf_distance(a, b) * (a + b) / k0[ia] if ia != ib else np.inf
                           for ib, b in enumerate(k)] for ia, a in enumerate(k)])
            expect[i] = theta[i] >= np.maximum(0.02, f * d.min(axis=1)) * theta_u[i]
        assert (iota == expect).all()
        assert f == 0.0 or (iota != (theta >= 0.02 * theta_u[:, None])).any(), "the schedule must change decisions"


# ---------------------------------------------------------------------------------------------
# Stall identification, Section 5.4


RULES = stall.SignalRules(rate_min_m_s=2.0 * DEG_M, command_min_m=10.0 * DEG_M, position_min_m=8.0 * DEG_M,
                          window_s=0.1, error_min_m=0.5 * DEG_M)


@jax.jit
def run_signal(rules, iota, u_c, u):
    """stall.signal_step over a trace (n,) sampled at DT_S -> eta (n,)."""
    t = jnp.arange(iota.shape[0], dtype=float) * DT_S

    def body(state, inp):
        i, c, m, tk = inp
        return stall.signal_step(rules, state, i, stall.conditions(rules, c, m), m, tk, DT_S)[:2]
    return jax.lax.scan(body, stall.signal_init(u[0]), (iota, u_c, u, t))[1]


def held(n, value_deg):
    return np.full(n, value_deg * DEG_M)


N_TRACE, ONSET = 100, 20
IOTA = np.arange(N_TRACE) >= ONSET
WINDOW = round(RULES.window_s / DT_S)  # samples the mean rate (33) is taken over at least


@pytest.mark.parametrize("u_deg, u_c_deg, identified", [
    (15.0, 20.0, True),  # stuck at large deflection, command beyond
    (-15.0, -20.0, True),  # the same on the other side
    (5.0, 20.0, False),  # (34): |u| small
    (9.0, 9.5, False),  # (34): |u_c| small (|u| large enough)
    (1.0, 3.0, False),  # jam at small deflection: never a stall
    (15.0, 12.0, False),  # (35): command inside the position
    (15.0, -20.0, False),  # (35): command on the other side
])
def test_signal_rules_on_a_stuck_rod(u_deg, u_c_deg, identified):
    """Rod held still, iota rising at ONSET: eta = 1 from window_s later iff (34) and (35) hold."""
    eta = np.asarray(run_signal(RULES, IOTA, held(N_TRACE, u_c_deg), held(N_TRACE, u_deg)))
    first = ONSET + WINDOW
    assert not eta[:first].any()
    assert eta[first:].all() if identified else not eta.any()


def test_signal_rules_moving_rod_and_no_detection():
    """(33): a rod moving faster than rate_min gives eta = 0; and eta = 0 whenever iota = 0."""
    t = np.arange(N_TRACE) * DT_S
    u = (15.0 + 5.0 * t) * DEG_M  # 5 deg/s > rate_min
    assert not np.asarray(run_signal(RULES, IOTA, u + 5.0 * DEG_M, u)).any()

    n = 1000
    stuck, beyond = held(n, 15.0), held(n, 20.0)
    assert not np.asarray(run_signal(RULES, np.zeros(n, bool), beyond, stuck)).any()
    iota = np.random.default_rng(7).random(n) < 0.95
    eta = np.asarray(run_signal(RULES, iota, beyond, stuck))
    assert eta.any() and not (eta & ~iota).any()


def test_signal_rules_ignore_a_mean_rate_over_less_than_the_window():
    """(33) is not trusted over less than window_s: a rod at rest whose measurement jitters by
    0.03 deg every other sample (3 deg/s over one sample, 0 over two) gives eta only once
    window_s has passed since t_d, not two samples after it."""
    n = 60
    jitter = np.where(np.arange(n) % 2 == 0, 0.0, 0.03) * DEG_M
    u = 15.0 * DEG_M + jitter
    eta = np.asarray(run_signal(RULES, IOTA[:n], held(n, 20.0), u))
    assert not eta[:ONSET + WINDOW].any()
    assert eta[ONSET + WINDOW:].all()


def test_signal_rules_second_stall_in_one_alarm():
    """A later stall in the same iota = 1 episode is identified from a re-anchored mean rate.

    Stuck at 15 deg until 1 s, moving at 10 deg/s to 20 deg at 1.5 s, stuck after. The mean rate
    from t_d = 0.1 s would stay above rate_min until 2.6 s; re-anchoring (every window while moving)
    gives eta = 1 within two windows and a sample of the stop.
    """
    n = 300
    t = np.arange(n) * DT_S
    u = np.clip(15.0 + 10.0 * (t - 1.0), 15.0, 20.0) * DEG_M
    iota = np.arange(n) >= 10
    eta = np.asarray(run_signal(RULES, iota, held(n, 25.0), u))
    assert not eta[:10 + WINDOW].any() and eta[10 + WINDOW:100].all()  # first stall
    assert not eta[(t >= 1.3) & (t < 1.5)].any()  # moving
    second = t >= 1.5 + 2 * RULES.window_s + DT_S
    assert eta[second].all()
    first = np.argmax(second)
    assert abs(u[first] - u[10]) / (t[first] - t[10]) > RULES.rate_min_m_s  # premise: no eta without re-anchoring


MODEL_RULE = stall.ModelRule(k_sl=0.05, pole=5.0, evaluator=evaluator.NarendraParams(0.0, 10.0, 10.0),
                             tau=1.0 * DEG_M)


@jax.jit
def run_model_rule(iota, u_c, u):
    """stall.model_step over a trace -> (eta, theta_sl)."""
    def body(state, inp):
        i, c, m = inp
        state, eta, _, theta_sl = stall.model_step(MODEL_RULE, state, i, stall.conditions(RULES, c, m), c, m, DT_S)
        return state, (eta, theta_sl)
    return jax.lax.scan(body, stall.model_init(u[0]), (iota, u_c, u))[1]


@pytest.mark.parametrize("k", [MODEL_RULE.k_sl, 25.0])
def test_model_rule(k):
    """(a): theta_sl stays below tau_sl on a rod following the stall model (its residual is zero
    from rest, as for any own model), far above on a normally moving rod; eta requires iota."""
    n = 200
    u_c = smooth_command(n, offset_deg=25.0)  # 16..34 deg: beyond the rod, which starts at 12 deg
    u, _ = lpv_plant(lambda x, s: np.array([k]), 0, u_c, 12.0 * DEG_M)
    iota = np.arange(n) >= ONSET
    eta, theta_sl = map(np.asarray, run_model_rule(iota, u_c, u[:-1]))
    eta_off, _ = map(np.asarray, run_model_rule(np.zeros(n, bool), u_c, u[:-1]))
    assert not eta_off.any()
    if k == MODEL_RULE.k_sl:
        assert np.all(theta_sl < 1e-9 * MODEL_RULE.tau)
        np.testing.assert_array_equal(eta, iota)
    else:
        assert np.all(theta_sl[20:] > 10.0 * MODEL_RULE.tau)
        assert not eta.any()


# ---------------------------------------------------------------------------------------------
# The composed on-board step


@jax.jit
def fdd_on_lpv_model(params, model, u_c):
    """system.step scanned over a ZOH-sampled LPV plant of bank ``model`` (its sgn(xdot) the bank's estimate), from rest
    -> detected ids."""
    fdd_on_lpv_model.traces += 1
    bank = params.loe.bank
    t = jnp.arange(u_c.shape[0], dtype=float) * DT_S

    def body(carry, inp):
        u, state = carry
        c, t_n = inp
        k = lpv.gains(bank, u, jnp.sign(state.error_lp), VCAS_M_S, ALT_M)[model]  # the bank's sgn(xdot): model exact
        state, out = system.step(params, state, c, u, VCAS_M_S, ALT_M, t_n, DT_S)
        phi = jnp.exp(-k * DT_S)
        return (phi * u + (1.0 - phi) * c, state), out.detected

    state0 = system.init(params, u_c[0])
    return jax.lax.scan(body, (u_c[0], state0), (u_c, t))[1]


fdd_on_lpv_model.traces = 0


def test_system_detects_the_plant_model(bank):
    """Fault-free plant: never a fault model, and model 0 once excited; disconnection (model 1):
    1 once excited. A second run with another tau does not recompile."""
    loe = LoeDetectionConfig(tau=0.04, confirm_s=0.0, max_load_fraction=1.0, excitation_floor_deg=0.05)  # noise-free
    params = build.fdd_params(FddConfig(loe=loe), bank, r_arm_m=R_ARM_M)
    t = np.arange(1500) * DT_S
    u_c = jnp.asarray((15.0 + 8.0 * np.sin(2 * np.pi * t)) * DEG_M)
    excited = t >= 5.0

    healthy = np.asarray(fdd_on_lpv_model(params, 0, u_c))
    assert healthy[0] == decision.NO_DECISION
    assert np.isin(healthy, [0, decision.NO_DECISION]).all()
    assert (healthy[excited] == 0).all()

    disconnected = np.asarray(fdd_on_lpv_model(params, 1, u_c))
    assert (disconnected[excited] == 1).all()
    traces = fdd_on_lpv_model.traces
    retuned = params._replace(loe=params.loe._replace(tau=1.5 * params.loe.tau))
    fdd_on_lpv_model(retuned, 1, u_c).block_until_ready()
    assert fdd_on_lpv_model.traces == traces


def test_load_weighted_excitation(bank):
    """With excitation_load_fraction f > 0 the floor applies to the evaluated low-passed tracking error with
    each sample weighted by min(1, |estimated load fraction| / f), against numpy; f = 0 weighs every
    sample 1; the ratio's ||u|| is unweighted either way."""
    n = 600
    u_c = smooth_command(n, 3.0)
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    u, _ = lpv_plant(gain, 4, u_c, u_c[0])
    u = u[:-1]
    outs = {}
    floor_deg = 0.9  # between the weighted (0.78 deg) and unweighted (1.03 deg) peaks of this command
    for f in (0.0, 0.15):
        loe = LoeDetectionConfig(max_load_fraction=1.0, excitation_load_fraction=f, excitation_floor_deg=floor_deg)
        params = build.fdd_params(FddConfig(loe=loe), bank, r_arm_m=R_ARM_M)

        def body(state, inp):
            c, m, t = inp
            return system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)

        outs[f] = jax.tree.map(np.asarray, jax.jit(lambda: jax.lax.scan(
            body, system.init(params, u[0]), (u_c, u, np.arange(n) * DT_S))[1])())
    out = outs[0.15]
    band = zoh_response([0.5], [1.0, 0.5], np.abs(u_c - u))
    weight = np.minimum(1.0, np.abs(out.load_fraction) / 0.15)
    decay = math.exp(-DT_S)
    xi, ref = 0.0, np.empty(n)
    for i in range(n):
        ref[i] = xi
        xi = decay * xi + (1.0 - decay) * abs(band[i]) * weight[i]
    np.testing.assert_allclose(out.theta_w, ref, rtol=1e-9, atol=1e-15)
    assert 0.0 < weight.min() < 0.5 and weight.max() == 1.0
    np.testing.assert_array_equal(out.excited, out.theta_w >= floor_deg * DEG_M)
    assert (out.theta_w <= outs[0.0].theta_u * (1 + 1e-12)).all()
    np.testing.assert_array_equal(out.theta_u, outs[0.0].theta_u)
    np.testing.assert_array_equal(outs[0.0].theta_w, outs[0.0].theta_u)
    assert (outs[0.0].excited & ~out.excited).any() and not (out.excited & ~outs[0.0].excited).any()


def noisy_hold(bank, model, n=1500, dither_deg=0.1, seed=5):
    """A rod of bank ``model`` (true sgn(u_c - x)) holding 15 deg (load fraction 0.41 at this flight point) under
    a small dither, measured with 0.06 mm of white sensor noise: (u_c, measured u) of n samples."""
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    t = np.arange(n) * DT_S
    u_c = (15.0 + dither_deg * np.sin(2 * np.pi * 0.5 * t)) * DEG_M
    x = [u_c[0]]
    for c in u_c[:-1]:
        phi = math.exp(-gain(x[-1], np.sign(c - x[-1]))[model] * DT_S)
        x.append(phi * x[-1] + (1.0 - phi) * c)
    return u_c, np.array(x) + np.random.default_rng(seed).standard_normal(n) * 0.06e-3


def run_system(params, u_c, u):
    """system.step scanned over (u_c, u) at the test's flight point -> (theta, theta_u, fault_detected)."""
    def body(state, inp):
        c, m, t = inp
        state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
        return state, (out.theta, out.theta_u, out.fault_detected)
    return (np.asarray(v) for v in jax.jit(lambda: jax.lax.scan(
        body, system.init(params, u[0]), (u_c, u, np.arange(u_c.size) * DT_S))[1])())


def test_direction_estimate_does_not_rectify_sensor_noise(bank):
    """On a fault-free rod holding a deflection at 41 % load with the tracking error inside the sensor noise,
    the bank's sgn(xdot) (the low-passed error of the samples before) leaves the fault-free filter no bias
    over the no-load model's (both see the noise alike), while filters of eq. (24) written here in numpy with
    the sign of the current sample's u_c - u rectify the noise through the load-dependent gain: the
    fault-free ratio several times the no-load model's, as on a disconnected rod."""
    u_c, u = noisy_hold(bank, 0)
    params = build.fdd_params(FddConfig(loe=LoeDetectionConfig(max_load_fraction=1.0)), bank, r_arm_m=R_ARM_M)
    theta, theta_u, _ = run_system(params, u_c, u)
    tail = slice(500, None)
    ratio = theta[tail] / theta_u[tail, None]
    assert np.all(np.isfinite(ratio)) and ratio[:, 0].max() < 0.1
    assert ratio[:, 0].mean() < 1.25 * ratio[:, 1].mean()

    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    k0 = np.asarray(bank.k0)
    phi_a, phi_g = math.exp(-params.loe.pole * DT_S), math.exp(-1.0 * DT_S)  # evaluator: alpha 0, beta 1, gamma 1
    c = (1.0 - phi_a) / (1.0 - np.exp(-k0 * DT_S))
    x_q, xi, current = -u[0] * np.ones_like(k0), np.zeros_like(k0), []
    for u_n, u_c_n in zip(u, u_c):
        phi = np.exp(-gain(u_n, np.sign(u_c_n - u_n)) * DT_S)
        r = c * (x_q + u_n)
        x_q = phi_a * x_q + (phi_a - phi) * u_n - (1.0 - phi) * u_c_n
        xi = phi_g * xi + (1.0 - phi_g) * np.abs(r)
        current.append(xi)
    ratio_current = np.array(current)[tail] / theta_u[tail, None]
    assert ratio_current[:, 0].mean() > 3.0 * ratio_current[:, 1].mean()
    assert ratio_current[:, 0].mean() > 3.0 * ratio[:, 0].mean()


def test_detection_contrast_needs_a_better_fault_model(bank):
    """Sensor noise on a fault-free held rod raises every filter's ratio alike: with a low detection_tau the
    fault-free model is rejected unless its ratio must also exceed the best fault model's by
    detection_contrast; a disconnected rod (the bank's no-load model) is detected with the contrast."""
    def params(contrast):
        loe = LoeDetectionConfig(max_load_fraction=1.0, excitation_floor_deg=0.0, excitation_noise_factor=0.0,
                                 detection_tau=0.03, detection_contrast=contrast, detection_confirm_s=0.5)
        return build.fdd_params(FddConfig(loe=loe), bank, r_arm_m=R_ARM_M)

    u_c, u = noisy_hold(bank, 0)
    assert list(run_system(params(0.0), u_c, u))[2].any()
    assert not list(run_system(params(0.05), u_c, u))[2].any()
    u_c, u = noisy_hold(bank, 1, dither_deg=3.0)
    assert list(run_system(params(0.05), u_c, u))[2][500:].all()


def test_options_off_are_not_built_and_equal_the_options_at_zero(bank):
    """tau_schedule = 0, excitation_load_fraction = 0, excitation_noise_factor = 0 and max_load_fraction = 1 in a
    config build no schedule, no weighted evaluator, no noise estimate and no load gate (None leaves, no state);
    the step then gives the outputs of the same options built with the traced values 0 (1 for the gate, which
    this run's load estimate stays below), and with the options on the step stays differentiable in their
    values."""
    n = 300
    u_c = smooth_command(n, 3.0)
    u, _ = lpv_plant(eq4_gains(bank, VCAS_M_S, ALT_M), 4, u_c, u_c[0])
    u = u[:-1]
    off = build.fdd_params(FddConfig(loe=LoeDetectionConfig(max_load_fraction=1.0, excitation_floor_deg=0.5,
                                                         excitation_noise_factor=0.0)), bank,
                           r_arm_m=R_ARM_M)
    assert off.loe.tau_schedule is None and off.loe.excitation_load_fraction is None
    assert off.loe.excitation_noise_factor is None and off.loe.max_load_fraction is None
    assert system.init(off, u[0]).band_w_xi is None and system.init(off, u[0]).noise is None
    at_zero = off._replace(loe=off.loe._replace(tau_schedule=0.0, excitation_load_fraction=0.0,
                                                excitation_noise_factor=0.0, max_load_fraction=1.0))

    def run(params):
        def body(state, inp):
            c, m, t = inp
            return system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
        return jax.lax.scan(body, system.init(params, u[0]), (u_c, u, np.arange(n) * DT_S))[1]

    a, b = (jax.tree.map(np.asarray, jax.jit(run)(p)) for p in (off, at_zero))
    assert a.noise_rms is None and b.noise_rms.max() > 0.0 and np.abs(b.load_fraction).max() < 1.0
    for name in a._fields:
        if name != "noise_rms":
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, atol=0, err_msg=name)
    assert a.excited.any() and not a.excited.all()

    def weighted(values):
        on = off._replace(loe=off.loe._replace(tau_schedule=values[0], excitation_load_fraction=values[1],
                                               excitation_noise_factor=values[2]))
        out = run(on)
        return jnp.sum(out.theta_w) + jnp.sum(jnp.where(out.iota, 0.0, 1.0)) + jnp.sum(out.noise_rms)

    grad = jax.jit(jax.grad(weighted))(jnp.array([0.5, 0.2, 2.0]))
    assert np.isfinite(grad).all() and grad[1] != 0.0


def noise_reference(u, gamma):
    """The online noise estimate written out in numpy: mean |u_k - 2 u_(k-1) + u_(k-2)| over the samples so far
    with weights exp(-gamma (t_k - t_j)), from the third sample on, over its mean for white Gaussian noise."""
    decay = math.exp(-gamma * DT_S)
    s, w, out = 0.0, 0.0, np.zeros(u.size)
    for k in range(u.size):
        if k >= 2:
            s = decay * s + (1.0 - decay) * abs(u[k] - 2.0 * u[k - 1] + u[k - 2])
            w = decay * w + (1.0 - decay)
        out[k] = s / w / math.sqrt(12.0 / math.pi) if w > 0 else 0.0
    return out


@pytest.mark.parametrize("sigma_mm", [0.03, 0.07])
def test_noise_estimate_is_the_sensor_noise_rms(bank, sigma_mm):
    """On a rod flying doublets and held deflections (first-order model of the bank, 20 deg/s ramps) measured
    with white noise of known RMS, the step's online estimate equals the numpy reference to rounding and, after
    its forgetting time, the RMS within 5 % (gamma 0.02 1/s: 50 s of samples); the manoeuvres move it by less than
    2 % against the same noise on a rod at rest; the excitation floor is max(absolute floor, factor x estimate)."""
    n = 12000
    t = np.arange(n) * DT_S
    phase = t % 20.0  # every 20 s a 10 deg doublet of 4 s with 0.5 s ramps (20 deg/s), held 1.5 s each way
    u_c = 10.0 * DEG_M * (np.clip(phase / 0.5, 0, 1) - 2.0 * np.clip((phase - 2.0) / 0.5, 0, 1)
                          + np.clip((phase - 4.0) / 0.5, 0, 1))
    x, _ = lpv_plant(eq4_gains(bank, VCAS_M_S, ALT_M), 0, u_c, 0.0)
    noise = np.random.default_rng(11).standard_normal(n) * sigma_mm * 1e-3
    loe = LoeDetectionConfig(max_load_fraction=1.0, excitation_noise_factor=2.5, noise_gamma_1_s=0.02,
                             excitation_floor_deg=0.01)
    params = build.fdd_params(FddConfig(loe=loe), bank, r_arm_m=R_ARM_M)

    def run(u):
        def body(state, inp):
            c, m, t_n = inp
            return system.step(params, state, c, m, VCAS_M_S, ALT_M, t_n, DT_S)
        run = jax.jit(lambda: jax.lax.scan(body, system.init(params, u[0]), (u_c, u, t))[1])
        return jax.tree.map(np.asarray, run())

    out = run(x[:-1] + noise)
    np.testing.assert_allclose(out.noise_rms, noise_reference(x[:-1] + noise, 0.02), rtol=1e-9, atol=1e-15)
    settled = t >= 50.0
    assert np.abs(out.noise_rms[settled] / (sigma_mm * 1e-3) - 1.0).max() < 0.05
    at_rest = run(noise).noise_rms
    assert np.abs(out.noise_rms[settled] / at_rest[settled] - 1.0).max() < 0.02
    floor = np.maximum(0.01 * DEG_M, 2.5 * out.noise_rms)  # evaluator alpha 0, beta 1, gamma 1: DC gain 1
    np.testing.assert_array_equal(out.excited, out.theta_w >= floor)
    assert (floor[settled] > 2.0 * sigma_mm * 1e-3).all() and out.excited.any() and not out.excited[settled].all()


def test_noise_floor_decides_on_a_quiet_sensor_what_an_absolute_floor_hides(bank):
    """A small dither on a rod at rest, measured with a quiet (0.02 mm) and a noisy (0.07 mm) sensor. The
    absolute floor set for the noisy sensor (0.1 deg, above its noise's ||u|| of about 0.06 deg) never excites
    the quiet run's dither; a floor of 2 x the run's own noise RMS excites the quiet run during the dither and
    neither run on noise alone."""
    n = 3000
    t = np.arange(n) * DT_S
    u_c = np.where((t > 15.0) & (t < 25.0), 0.2 * np.sin(2.0 * np.pi * 2.0 * t), 0.0) * DEG_M
    x, _ = lpv_plant(eq4_gains(bank, VCAS_M_S, ALT_M), 0, u_c, 0.0)
    dither, at_rest = (t > 17.0) & (t < 25.0), (t > 8.0) & (t < 15.0)

    def excited(loe, sigma_mm):
        params = build.fdd_params(FddConfig(loe=loe), bank, r_arm_m=R_ARM_M)
        u = x[:-1] + np.random.default_rng(4).standard_normal(n) * sigma_mm * 1e-3

        def body(state, inp):
            c, m, t_n = inp
            state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t_n, DT_S)
            return state, out.excited
        return np.asarray(jax.jit(lambda: jax.lax.scan(body, system.init(params, u[0]), (u_c, u, t))[1])())

    absolute = LoeDetectionConfig(excitation_floor_deg=0.1, excitation_noise_factor=0.0)
    relative = LoeDetectionConfig(excitation_floor_deg=0.0, excitation_noise_factor=2.0)
    assert not excited(absolute, 0.02)[dither].any() and not excited(absolute, 0.07)[at_rest].any()
    quiet = excited(relative, 0.02)
    assert quiet[dither].mean() > 0.9 and not quiet[at_rest].any()
    assert not excited(relative, 0.07)[at_rest | dither].any()


# ---------------------------------------------------------------------------------------------
# Rate-saturation gate of the stall detector

GATE = stall.SaturationGate(error_m=3.5 * DEG_M, rate_fraction=0.5, rate_pole=100.0)


def gate_reference(u_c, u, k, gate):
    """The gate written out in numpy, sample by sample: the backward difference of u low-passed at the rate pole
    (from rest), then closed where |u_c - u| >= error_m and the rate towards the command reaches
    rate_fraction k error_m; its margin the lesser of the two comparisons, each relative to its threshold."""
    phi = math.exp(-gate.rate_pole * DT_S)
    rate, previous, rates = 0.0, u[0], []
    for m in u:
        rate = phi * rate + (1.0 - phi) * (m - previous) / DT_S
        previous = m
        rates.append(rate)
    rates = np.array(rates)
    error = u_c - u
    towards = np.sign(error) * rates
    need = gate.rate_fraction * k * gate.error_m
    closed = (np.abs(error) >= gate.error_m) & (towards >= need)
    margin = np.minimum((np.abs(error) - gate.error_m) / gate.error_m, (towards - need) / need)
    return rates, closed, margin


@jax.jit
def run_gate(u_c, u, k):
    def body(state, inp):
        c, m, k_n = inp
        state, rate = stall.rate_step(GATE.rate_pole, state, m, DT_S)
        return state, (rate, stall.saturation_margin(GATE, k_n, c, m, rate))
    return jax.lax.scan(body, stall.rate_init(u[0]), (u_c, u, k))[1]


def saturated_rod(u_c, gain, limit_deg=4.0, stop_deg=np.inf):
    """Exact samples of a rod x' = k sat(u_c - x) whose servo valve saturates beyond ``limit_deg`` of tracking error
    (u_c held and k = gain(x, sgn(u_c - x)) frozen over each sample), stopped from ``stop_deg`` on (a stall)."""
    x, rod = 0.0, []
    for c in u_c:
        rod.append(x)
        k = gain(x, np.sign(c - x))
        x = min(x + (1.0 - math.exp(-k * DT_S)) * np.clip(c - x, -limit_deg * DEG_M, limit_deg * DEG_M),
                stop_deg * DEG_M)
    return np.array(rod)


def hand_made_histories():
    """(name, u_c, u, k) of 1.5 s each, rod units, 0.05 mm of sensor noise: a slew at the saturated rate both ways
    (a 20 deg step at 0.2 s, gain 25 1/s, valve saturated beyond 4 deg: 88 deg/s), a rod stopped at 12 deg short of
    that command (a stall), a rod tracking a slow command (small error) and a slew against the command."""
    n, noise = 150, np.random.default_rng(22).normal(0.0, 0.05e-3, 150)
    k = np.full(n, 25.0)
    step = np.where(np.arange(n) >= 20, 20.0, 0.0) * DEG_M
    rod = saturated_rod(step, lambda x, s: 25.0)
    stopped = saturated_rod(step, lambda x, s: 25.0, stop_deg=12.0)
    slow = 10.0 * DEG_M * np.arange(n) * DT_S
    return [("slew out", step, rod + noise, k), ("slew back", -step, -rod + noise, k),
            ("stall", step, stopped + noise, k), ("tracking", slow + 0.5 * DEG_M, slow + noise, k),
            ("against", -step, rod + noise, k)]


@pytest.mark.parametrize("case", range(5))
def test_saturation_gate_against_a_numpy_reference(case):
    """The gate's measured rate and signed margin equal the numpy reference on hand-made histories, the margin's sign
    is the gate (closed exactly where the margin is not negative), and the gate closes on a saturated slew towards the
    command only: never on a stalled rod, a tracking rod or a rod moving away from its command."""
    name, u_c, u, k = hand_made_histories()[case]
    rate, margin = (np.asarray(x) for x in run_gate(u_c, u, k))
    ref_rate, closed, ref_margin = gate_reference(u_c, u, k, GATE)
    np.testing.assert_allclose(rate, ref_rate, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(margin, ref_margin, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(margin >= 0.0, closed)
    if name.startswith("slew"):
        assert closed.sum() >= 10 and not closed[:20].any()
    elif name == "stall":
        assert not closed[40:].any()  # stopped since 0.35 s: rate low-passed down, never gated after
    else:
        assert not closed.any()


def stall_params(bank, fraction):
    return build.fdd_params(FddConfig(stall=StallDetectionConfig(saturation_rate_fraction=fraction)), bank,
                            r_arm_m=R_ARM_M)


@jax.jit
def run_stall_detector(params, u_c, u):
    def body(state, inp):
        c, m, t = inp
        state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
        return state, (out.r_stall, out.theta_stall)
    return jax.lax.scan(body, system.init(params, u[0]), (u_c, u, np.arange(u.size) * DT_S))[1]


def test_stall_gate_hides_a_saturated_slew_not_a_stall(bank):
    """A slew at the valve's saturated rate (a rod of the fault-free model whose valve saturates beyond 4 deg of
    error) raises the ungated detector above tau (1 deg) with no stall; with the gate the residual is exactly 0 on
    the gated samples and the sample after, and theta stays below tau. A rod that stops short of its command (a
    stall) is detected within 0.1 s of its stop with the gate. Fraction 0 builds no gate and no state."""
    off, on = stall_params(bank, 0.0), stall_params(bank, 0.5)
    assert off.stall.saturation is None and system.init(off, 0.0).stall_rate is None
    gain = eq4_gains(bank, VCAS_M_S, ALT_M)
    n, noise = 150, np.random.default_rng(23).normal(0.0, 0.05e-3, 150)
    u_c = np.where(np.arange(n) >= 20, 20.0, 0.0) * DEG_M
    u = saturated_rod(u_c, lambda x, s: gain(x, s)[0]) + noise
    tau = on.stall.tau
    r_off, theta_off = (np.asarray(x) for x in run_stall_detector(off, u_c, u))
    r_on, theta_on = (np.asarray(x) for x in run_stall_detector(on, u_c, u))
    k0 = np.array([gain(m, s)[0] for m, s in zip(u, np.sign(u_c - u))])
    _, closed, _ = gate_reference(u_c, u, k0, on.stall.saturation)
    restarted = closed | np.roll(closed, 1)
    assert theta_off.max() > 2.0 * tau and theta_on.max() < 0.5 * tau
    assert closed.sum() >= 10 and np.all(r_on[restarted] == 0.0)
    np.testing.assert_allclose(r_on[:20], r_off[:20], rtol=1e-12, atol=1e-18)
    stopped = saturated_rod(u_c, lambda x, s: gain(x, s)[0], stop_deg=12.0) + noise
    stop = int(np.argmax(stopped - noise >= 12.0 * DEG_M))
    fired = np.asarray(run_stall_detector(on, u_c, stopped)[1]) >= tau
    assert not fired[:stop].any() and fired[stop:stop + 10].any() and fired[stop + 10:].all()


# ---------------------------------------------------------------------------------------------
# Identification gate of the stall identification

def identification_reference(theta, r, u, tau, residual_min):
    """The identification gate written out in numpy: open where theta >= tau and (unless residual_min is None) the
    outward residual -sgn(u) r >= residual_min; its margin the lesser of the two comparisons, each relative."""
    opened = theta >= tau
    margin = (theta - tau) / tau
    if residual_min is not None:
        outward = -np.sign(u) * r
        opened &= outward >= residual_min
        margin = np.minimum(margin, (outward - residual_min) / residual_min)
    return opened, margin


@pytest.mark.parametrize("residual_min_deg", [None, 0.3])
def test_identification_gate_against_a_numpy_reference(residual_min_deg):
    """The gate's margin equals the numpy reference on hand-made residual histories (theta, r and u drawn over both
    signs, a stalled rod's residual opposite to u among them), and its sign is the gate's flag: open exactly where
    the margin is not negative."""
    rng = np.random.default_rng(31)
    n = 2000
    u = rng.uniform(-25.0, 25.0, n) * DEG_M
    r = rng.uniform(-1.5, 1.5, n) * DEG_M
    theta = np.abs(r) + rng.uniform(0.0, 1.0, n) * DEG_M
    residual_min = None if residual_min_deg is None else residual_min_deg * DEG_M
    gate = stall.IdentificationGate(0.7 * DEG_M, residual_min)
    margin = np.asarray(jax.jit(stall.identification_margin)(gate, theta, r, u))
    opened, ref_margin = identification_reference(theta, r, u, gate.tau, residual_min)
    np.testing.assert_allclose(margin, ref_margin, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(margin >= 0.0, opened)
    assert 0.1 < opened.mean() < 0.9
    if residual_min is not None:  # the residual's sign decides: the same |r| of the other sign closes it
        flipped = np.asarray(stall.identification_margin(gate, theta, -r, u)) >= 0.0
        assert not (flipped & opened & (np.abs(r) >= residual_min)).any()


def identification_params(bank, **keys):
    return build.fdd_params(FddConfig(stall=StallDetectionConfig(**keys)), bank, r_arm_m=R_ARM_M)


@jax.jit
def run_identification(params, u_c, u):
    """system.step over a trace -> (theta_stall, eta_signal, eta_model, eta_signal_margin, eta_model_margin)."""
    def body(state, inp):
        c, m, t = inp
        state, out = system.step(params, state, c, m, VCAS_M_S, ALT_M, t, DT_S)
        return state, (out.theta_stall, out.eta_signal, out.eta_model, out.eta_signal_margin, out.eta_model_margin)
    return jax.lax.scan(body, system.init(params, u[0]), (u_c, u, np.arange(u.size) * DT_S))[1]


def test_identification_gate_identifies_a_weak_stall_within_the_window(bank):
    """A weak stall: the command ramps at 10 deg/s to 21 deg, the rod (first-order, 25 1/s) stops at 20 deg, 1 deg
    short of it (0.05 mm of sensor noise). The paper's rule (iota = [theta >= 1 deg] opens (32)-(35)) identifies it
    more than 0.5 s after the stop; with the gate (theta >= 0.6 deg and the outward residual >= 0.3 deg) within
    0.35 s. Both keys 0 build no gate. The eta margins' signs are the eta flags in both."""
    off = identification_params(bank)
    on = identification_params(bank, identification_tau_deg=0.6, identification_residual_deg=0.3)
    assert off.stall.identification is None and on.stall.identification is not None
    n = 200
    t = np.arange(n) * DT_S
    u_c = np.clip(15.0 + 10.0 * (t - 0.2), 15.0, 21.0) * DEG_M
    x, rod = 15.0 * DEG_M, []
    for c in u_c:
        rod.append(x)
        x = min(x + (1.0 - math.exp(-25.0 * DT_S)) * (c - x), 20.0 * DEG_M)
    rod = np.array(rod)
    u = rod + np.random.default_rng(5).normal(0.0, 0.05e-3, n)
    stop = t[np.argmax(rod >= 20.0 * DEG_M - 1e-12)]
    first = {}
    for name, params in (("off", off), ("on", on)):
        theta, eta_signal, eta_model, m_signal, m_model = (np.asarray(a) for a in run_identification(params, u_c, u))
        np.testing.assert_array_equal(m_signal >= 0.0, eta_signal)
        np.testing.assert_array_equal(m_model >= 0.0, eta_model)
        assert eta_signal.any()
        first[name] = t[np.argmax(eta_signal)] - stop
    assert first["off"] > 0.5 and 0.0 < first["on"] <= 0.35


def test_identification_gate_residual_ignores_the_memory_of_a_stall(bank):
    """After a stall (rod stopped at 15 deg, command 25 deg, 0.2-1.2 s) the rod creeps outwards at 1.5 deg/s with
    the command 0.6 deg ahead: the evaluator's memory holds theta far above tau and (33)-(35) hold, so the paper's
    rule identifies a stall in the creep; with the outward-residual condition (0.8 deg, above this creep's residual
    and below the stall's) neither method does, and the stall itself is identified by both settings alike."""
    n = 400
    t = np.arange(n) * DT_S
    rod = np.where(t < 1.2, 15.0, 15.0 + 1.5 * (t - 1.2)) * DEG_M
    u_c = np.where(t < 0.2, 15.0 * DEG_M, np.where(t < 1.2, 25.0 * DEG_M, rod + 0.6 * DEG_M))
    u = rod + np.random.default_rng(6).normal(0.0, 0.05e-3, n)
    creep, stalled = t >= 1.7, t < 1.2
    off = [np.asarray(a) for a in run_identification(identification_params(bank), u_c, u)]
    on = [np.asarray(a) for a in run_identification(identification_params(bank, identification_residual_deg=0.8),
                                                     u_c, u)]
    assert off[0][creep].min() > 5.0 * DEG_M  # theta far above tau = 1 deg: the memory of the stall
    assert off[1][creep].any() and off[2][creep].any()
    assert not on[1][creep].any() and not on[2][creep].any()
    np.testing.assert_array_equal(on[1][stalled], off[1][stalled])
    assert on[1][stalled].sum() > 50
    np.testing.assert_array_equal(on[3] >= 0.0, on[1])

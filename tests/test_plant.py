"""The plant layer against independent references.

ISA tables and a root-finding Mach inversion, root finding on the implicit eq. (2), scipy
``solve_ivp`` trajectories, the hinge formula, scipy's matrix exponential and the MIL-F-8785C
spectra for the Dryden filters, and the design targets of the closed roll loop.
"""

import itertools
import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from helpers import ROUNDING
from mcfdd.analysis import batch, simulate
from mcfdd.plant import actuator, aircraft, atmosphere, closed_loop, control_law, hinge, manoeuvres, turbulence

DT_S = 0.01
ACT = actuator.ActuatorParams()
DEG_M = ACT.r_arm_m * math.pi / 180.0  # rod travel (m) of one degree of surface deflection
STALL_FORCE_N = ACT.supply_pressure_pa * ACT.piston_area_m2
FULL_RATE_M_S = ACT.kci_m_s_a * ACT.max_current_a  # no-load rod rate at full valve current


@pytest.fixture(scope="module")
def model():
    return closed_loop.build_model()


# ---------------------------------------------------------------------------------------------
# Atmosphere


def _isa_pressure_pa(h_m):
    """Standard-atmosphere pressure from the textbook constants (geopotential altitude, m)."""
    if h_m <= 11000.0:
        return 101325.0 * (1.0 - 2.25577e-5 * h_m) ** 5.25588
    return 22632.06 * math.exp(-(h_m - 11000.0) / 6341.62)


def test_dynamic_pressure_250_kt_sea_level():
    assert float(atmosphere.dynamic_pressure(250.0 * atmosphere.KT_TO_M_S, 0.0)) == pytest.approx(10.13e3, rel=5e-3)


@pytest.mark.parametrize("h_m, t_k, p_pa, rho, a_m_s", [
    (11000.0, 216.65, 22632.0, 0.36392, 295.07),
    (20000.0, 216.65, 5474.9, 0.088035, 295.07),
])
def test_isa_against_standard_table(h_m, t_k, p_pa, rho, a_m_s):
    """US Standard Atmosphere 1976 values at geopotential altitudes."""
    got = [float(v) for v in atmosphere.isa(h_m)]
    assert got == pytest.approx([t_k, p_pa, rho, a_m_s], rel=1e-3)


@pytest.mark.parametrize("vcas_kt, h_m", [(250.0, 0.0), (250.0, 3000.0), (300.0, 8000.0), (280.0, 11000.0),
                                          (250.0, 12500.0), (120.0, 500.0)])
def test_mach_matches_pitot_inversion(vcas_kt, h_m):
    """Mach solves p ((1 + 0.2 M^2)^3.5 - 1) = qc(Vcas) with the static pressure of the altitude."""
    v = vcas_kt * 1852.0 / 3600.0
    qc = 101325.0 * ((1.0 + 0.2 * (v / 340.294) ** 2) ** 3.5 - 1.0)
    p = _isa_pressure_pa(h_m)
    expected = brentq(lambda m: p * ((1.0 + 0.2 * m**2) ** 3.5 - 1.0) - qc, 1e-6, 1.0, xtol=1e-14)
    assert float(atmosphere.mach(v, h_m)) == pytest.approx(expected, rel=1e-5)


# ---------------------------------------------------------------------------------------------
# Actuator, eqs. (1)-(2)


def _implicit_rate(params, nu1, nu2, load_n, error_m):
    """Root of the implicit eq. (2), xdot = Kci sat(Kp e) sqrt((nu1 dP - (nu2 sgn(xdot) F + Kd xdot^2)/S) / dP_ref).

    Any root has the sign of e (the square root is non-negative); it lies between 0 and the rate with
    the Kd term left out. Returns None when no such root exists (the load wins).
    """
    current = np.clip(params.kp_a_m * error_m, -params.max_current_a, params.max_current_a)
    s = np.sign(error_m)

    def residual(xdot):
        inner = (nu1 * params.supply_pressure_pa
                 - (nu2 * np.sign(xdot) * load_n + params.kd_n_s2_m2 * xdot**2) / params.piston_area_m2)
        return xdot - params.kci_m_s_a * current * math.sqrt(max(inner / params.ref_pressure_pa, 0.0))

    undamped = nu1 * params.supply_pressure_pa - nu2 * s * load_n / params.piston_area_m2
    if undamped <= 0.0:
        return None
    bound = abs(params.kci_m_s_a * current) * math.sqrt(undamped / params.ref_pressure_pa)
    return brentq(residual, s * bound * 1e-12, s * bound * (1.0 + 1e-12), xtol=1e-300, rtol=1e-15, maxiter=500)


def test_closed_form_rate_solves_implicit_equation():
    """Errors of both signs, inside and beyond the current saturation (3.7 mm), aiding and opposing loads.

    Where the load beats the available pressure there is no root and the rate must be zero.
    """
    errors = [-2e-2, -5e-3, -1e-3, -1e-5, 1e-6, 2e-4, 3e-3, 5e-3, 2e-2]
    loads = [-4e4, -1e4, 0.0, 1.5e4, 3.5e4]
    nus = [(1.0, 1.0), (0.73, 1.0), (0.85, 0.66), (1.0, 0.33), (1.0, 0.0)]
    x_m = 4e-3
    for e, load, (nu1, nu2) in itertools.product(errors, loads, nus):
        expected = _implicit_rate(ACT, nu1, nu2, load, e)
        got = float(actuator.rate(ACT, nu1, nu2, load, x_m, x_m + e))
        assert got == (0.0 if expected is None else pytest.approx(expected, rel=1e-9)), (e, load, nu1, nu2)


@pytest.mark.parametrize("nu1, load_factor", [(1.0, 1.05), (0.73, 0.8)])
def test_load_above_available_force_stalls(model, nu1, load_factor):
    """A <= 0: no rate, the step keeps x and raises ``stall``; the same load aiding the motion does not."""
    load = load_factor * STALL_FORCE_N  # positive: opposes a positive deflection
    assert load > nu1 * STALL_FORCE_N
    x0 = 5.0 * DEG_M
    assert _implicit_rate(ACT, nu1, 1.0, load, 10.0 * DEG_M) is None
    k, a = actuator.gain(ACT, nu1, 1.0, load, x0, x0 + 10.0 * DEG_M)
    assert float(a) <= 0.0 and float(k) == 0.0

    fault = actuator.ActuatorFault(nu1=nu1, onset_s=0.0)
    flat = jnp.full_like(model.table.delta_rad, load)
    state = actuator.init(ACT, x0)
    step = jax.jit(actuator.step, static_argnames=("params", "dt_s", "substeps"))
    opposed, out = step(ACT, fault, model.table.delta_rad, flat, state, x0 + 10.0 * DEG_M, 0.0, dt_s=DT_S, substeps=4)
    assert float(opposed.x_m) == pytest.approx(x0, abs=1e-15)
    assert bool(out.stall) and float(out.rate_m_s) == 0.0
    aided, out = step(ACT, fault, model.table.delta_rad, flat, state, x0 - 10.0 * DEG_M, 0.0, dt_s=DT_S, substeps=4)
    assert float(aided.x_m) < x0
    assert not bool(out.stall)


def test_disconnected_gain_is_eq_36():
    """nu = [1, 0]: the small-error gain is Kci Kp sqrt(dP / dP_ref) whatever the load (Kd xdot^2 -> 0)."""
    params = ACT._replace(supply_pressure_pa=0.85 * ACT.ref_pressure_pa)
    expected = params.kci_m_s_a * params.kp_a_m * math.sqrt(params.supply_pressure_pa / params.ref_pressure_pa)
    for load, e in itertools.product([-6e4, -1e4, 0.0, 2e4, 6e4], [-1e-7, 1e-8, 1e-7]):
        k, _ = actuator.gain(params, 1.0, 0.0, load, 3e-3, 3e-3 + e)
        assert float(k) == pytest.approx(expected, rel=1e-9), (load, e)


@partial(jax.jit, static_argnames=("params", "substeps"))
def _actuator_scan(params, fault, delta_grid, load_slice, commands, substeps):
    def body(state, kc):
        k, u_c = kc
        return actuator.step(params, fault, delta_grid, load_slice, state, u_c, k * DT_S, DT_S, substeps)

    out = jax.lax.scan(body, actuator.init(params, 0.0), (jnp.arange(commands.shape[0], dtype=float), commands))[1]
    return out.x_m, out.stall


def _run_actuator(fault, delta_grid, load_slice, commands, substeps=4):
    """Rod position (m) at the start of each sample and the stall flags, stepped by lax.scan."""
    x, stall = _actuator_scan(ACT, fault, delta_grid, load_slice, jnp.asarray(commands), substeps=substeps)
    return np.asarray(x), np.asarray(stall)


def _reference_trajectory(delta_grid, load_slice, commands):
    """solve_ivp of xdot = rate(x, u_c) with u_c held over each sample; x at the sample starts."""
    rhs = jax.jit(lambda x, u_c: actuator.rate(
        ACT, 1.0, 1.0, hinge.interpolate_delta(delta_grid, load_slice, x / ACT.r_arm_m), x, u_c))
    x, xs = 0.0, []
    for u_c in commands:
        xs.append(x)
        sol = solve_ivp(lambda _, y, u: [float(rhs(y[0], u))], (0.0, DT_S), [x], args=(u_c,), rtol=1e-9,
                        atol=1e-14, max_step=DT_S / 10)
        x = sol.y[0, -1]
    return np.array(xs)


def _command_deg(name):
    """4 s of command (deg): steps then a 0.5-3 Hz chirp, or a step into the stall and back."""
    t = np.arange(400) * DT_S
    if name == "stall":
        return np.select([t < 0.2, t < 2.5], [0.0, 22.0], -5.0)
    chirp = 8.0 * np.sin(2.0 * math.pi * (0.5 * (t - 2.0) + 1.25 * (t - 2.0) ** 2))
    return np.where(t < 2.0, np.select([t < 0.2, t < 1.2], [0.0, 15.0], -10.0), chirp)


@pytest.mark.parametrize("case, load_scale", [("steps_sweep", 0.0), ("steps_sweep", 1.0), ("stall", 1.5)])
def test_trajectory_matches_solve_ivp(model, case, load_scale):
    """The sampled actuator against solve_ivp (rtol 1e-9) of the same zero-order-hold ODE.

    Load: the 350 kt sea-level table slice scaled by ``load_scale`` (1.5: stall near 16 deg). The
    saturated part of a sample is integrated exactly; only the linear range is sub-stepped, with
    the gain frozen over a sub-step, where it varies by a few percent (Kd term and load). So the
    error stays far below a sub-step of full-rate travel c h (0.1 mm at 2 sub-steps) even at one
    sub-step, and what is left falls like 1/substeps.
    """
    delta_grid = model.table.delta_rad
    load_slice = hinge.flight_point_slice(model.table, 350.0 * atmosphere.KT_TO_M_S, 0.0) * load_scale
    commands = _command_deg(case) * DEG_M
    reference = _reference_trajectory(delta_grid, load_slice, commands)
    errors = {}
    for substeps in (1, 4, 16):
        x, stall = _run_actuator(actuator.ActuatorFault(), delta_grid, load_slice, commands, substeps)
        errors[substeps] = np.abs(x - reference).max()
        assert errors[substeps] <= 0.05 * FULL_RATE_M_S * DT_S, (substeps, errors[substeps] / DEG_M)
    assert errors[16] < errors[4] / 3.0 < errors[1] / 9.0
    if case == "stall":
        hold = (np.arange(len(commands)) * DT_S > 1.5) & (np.arange(len(commands)) * DT_S < 2.5)
        delta_stall = brentq(lambda d: np.interp(d, delta_grid, load_slice) - STALL_FORCE_N, 0.0, delta_grid[-1])
        assert delta_stall < math.radians(22.0)
        assert reference[hold] == pytest.approx(delta_stall * ACT.r_arm_m, rel=1e-6)
        assert stall[hold].all()
    else:
        assert not stall.any()


def _implicit_reference(fault, delta_grid, load_slice, commands):
    """solve_ivp (rtol 1e-10) of eq. (2) solved implicitly by root finding at every evaluation, with
    the load interpolated in the table slice by NumPy and u_c held over each sample."""
    grid, loads = np.asarray(delta_grid), np.asarray(load_slice)

    def rhs(_, y, u_c):
        load = np.interp(y[0] / ACT.r_arm_m, grid, loads)
        xdot = _implicit_rate(ACT, fault.nu1, fault.nu2, load, u_c - y[0])
        return [0.0 if xdot is None else xdot]

    x, xs = 0.0, []
    for u_c in commands:
        xs.append(x)
        x = solve_ivp(rhs, (0.0, DT_S), [x], args=(u_c,), rtol=1e-10, atol=1e-14).y[0, -1]
    return np.array(xs)


@pytest.mark.parametrize("fault", [actuator.ActuatorFault(), actuator.ActuatorFault(nu1=0.73, onset_s=0.0),
                                   actuator.ActuatorFault(nu2=0.0, onset_s=0.0)],
                         ids=["healthy", "leakage", "disconnected"])
def test_saturated_slews_at_low_dynamic_pressure_match_implicit_reference(model, fault):
    """Full-deflection steps and a 2 Hz, 20 deg sine (faster than the rod) at 142 kt and 10 km.

    The valve current saturates for most of the run (|u_c - x| up to 50 deg of travel against a
    3.7 mm linear range), where the old frozen-gain sub-steps lagged by 0.23 mm at 4 sub-steps.
    The default 2 sub-steps and a single one must agree with the reference within 0.05 mm.
    """
    delta_grid = model.table.delta_rad
    load_slice = hinge.flight_point_slice(model.table, 142.0 * atmosphere.KT_TO_M_S, 10000.0)
    t = np.arange(500) * DT_S
    commands = np.select([t < 0.2, t < 1.2, t < 2.2, t < 3.0], [0.0, 25.0, -25.0, 20.0],
                         -20.0 * np.sin(2.0 * math.pi * 2.0 * (t - 3.0))) * DEG_M
    reference = _implicit_reference(fault, delta_grid, load_slice, commands)
    saturated = np.abs(commands - reference) > ACT.max_current_a / ACT.kp_a_m
    assert saturated.mean() > 0.3
    for substeps in (1, 2):
        x, stall = _run_actuator(fault, delta_grid, load_slice, commands, substeps)
        assert np.abs(x - reference).max() <= 5e-5, (substeps, np.abs(x - reference).max())
        assert not stall.any()


def test_jamming_freezes_the_rod_without_stall_flag(model):
    """After jam_onset_s the rod stays where it was; the stall flag stays false even under a stall load."""
    delta_grid = model.table.delta_rad
    load_slice = hinge.flight_point_slice(model.table, 350.0 * atmosphere.KT_TO_M_S, 0.0) * 1.5
    t = np.arange(300) * DT_S
    commands = np.select([t < 0.2, t < 1.5], [0.0, 10.0], 22.0) * DEG_M
    onset = 1.0
    free_x, free_stall = _run_actuator(actuator.ActuatorFault(), delta_grid, load_slice, commands)
    jam_x, jam_stall = _run_actuator(actuator.ActuatorFault(jam_onset_s=onset), delta_grid, load_slice, commands)
    before, after = t < onset, t >= onset
    assert free_stall[t > 2.0].all()
    np.testing.assert_array_equal(jam_x[before], free_x[before])
    assert np.all(jam_x[after] == free_x[np.argmax(after)])
    assert abs(free_x[np.argmax(after)]) > 5.0 * DEG_M
    assert not jam_stall.any()


# ---------------------------------------------------------------------------------------------
# Hinge-load table


def test_hinge_table_matches_formula(model):
    table = model.table
    rng = np.random.default_rng(0)
    n = 500
    vcas = rng.uniform(table.vcas_m_s[0], table.vcas_m_s[-1], n)
    alt = rng.uniform(table.altitude_m[0], table.altitude_m[-1], n)
    delta = rng.uniform(table.delta_rad[0], table.delta_rad[-1], n)
    tabulated = jax.jit(jax.vmap(hinge.interpolate, in_axes=(None, 0, 0, 0)))(table, vcas, alt, delta)
    qbar = atmosphere.dynamic_pressure(vcas, alt)
    alpha = aircraft.trim_alpha(model.aircraft, qbar)
    formula = hinge.hinge_load(hinge.HingeSurface(), ACT.r_arm_m, qbar, alpha, delta)
    assert np.abs(np.asarray(tabulated - formula)).max() <= 5e-3 * np.abs(np.asarray(table.load_n)).max()


def test_set_up_formulas_run_in_numpy_and_agree_with_the_traced_ones(model):
    """On host numbers the atmosphere, trim and hinge formulas compute in NumPy (nothing compiled);
    traced they compute in jax.numpy; both give the same numbers (float64)."""
    rng = np.random.default_rng(1)
    vcas, alt = rng.uniform(40.0, 220.0, 64), rng.uniform(0.0, 15000.0, 64)

    def formulas(v, h):
        qbar, mach, tas = atmosphere.flight_condition(v, h)
        alpha = aircraft.trim_alpha(model.aircraft, qbar)
        return (qbar, mach, tas, atmosphere.calibrated_airspeed(mach, h), alpha,
                hinge.hinge_load(hinge.HingeSurface(), ACT.r_arm_m, qbar, alpha, 0.1), *atmosphere.isa(h))

    host = formulas(vcas, alt)
    traced = jax.jit(formulas)(vcas, alt)
    for a, b in zip(host, traced):
        assert type(a) is np.ndarray and a.dtype == np.float64 and isinstance(b, jax.Array)
        np.testing.assert_allclose(a, np.asarray(b), rtol=1e-12)
    np.testing.assert_allclose(host[3], vcas, rtol=1e-10)
    assert isinstance(model.table.load_n, jax.Array) and model.table.load_n.shape == (37, 27, 51)


# ---------------------------------------------------------------------------------------------
# Dryden turbulence

SPAN_M = aircraft.AircraftParams().span_m
NOISE_INTENSITY = math.pi  # white noise of one-sided spectrum 1 has intensity pi
DRYDEN_CASES = [(1.0, 300.0), (2.0, 300.0), (1.0, 5000.0), (2.0, 5000.0)]  # (level, altitude m): low and high model


def _tas(altitude_m):
    return float(atmosphere.flight_condition(250.0 * atmosphere.KT_TO_M_S, altitude_m)[2])


def _p_gust_variance(level, altitude_m, tas_m_s):
    """Integral over 0..inf of the MIL-F-8785C p-gust spectrum.

    Phi_p(omega) = sigma_w^2 0.8 (pi L_w / (4 b))^(1/3) / (L_w V) / (1 + (4 b omega / (pi V))^2), and
    the integral of 1 / (1 + (omega / w0)^2) is w0 pi / 2 with w0 = pi V / (4 b).
    """
    _, _, sigma_w, length_w = (float(v) for v in turbulence.intensity(level, altitude_m))
    peak = sigma_w**2 * 0.8 * (math.pi * length_w / (4.0 * SPAN_M)) ** (1.0 / 3.0) / (length_w * tas_m_s)
    return peak * (math.pi * tas_m_s / (4.0 * SPAN_M)) * (math.pi / 2.0)


def _continuous_dryden(level, altitude_m, tas_m_s):
    """(A, B, C) of the module docstring's forming filters, H_v in controllable form and H_p first order."""
    sigma_v, length_v, sigma_w, length_w = (float(v) for v in turbulence.intensity(level, altitude_m))
    tau_v = length_v / tas_m_s
    tau_p = 4.0 * SPAN_M / (math.pi * tas_m_s)
    a = np.array([[0.0, 1.0, 0.0], [-1.0 / tau_v**2, -2.0 / tau_v, 0.0], [0.0, 0.0, -1.0 / tau_p]])
    b = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])

    def h_v(s):
        return (sigma_v * math.sqrt(length_v / (math.pi * tas_m_s)) * (1.0 + math.sqrt(3.0) * tau_v * s)
                / (1.0 + tau_v * s) ** 2)

    def h_p(s):
        gain = sigma_w * math.sqrt(0.8 / tas_m_s) * (math.pi / (4.0 * SPAN_M)) ** (1.0 / 6.0) / length_w ** (1.0 / 3.0)
        return gain / (1.0 + tau_p * s)

    return a, b, h_v, h_p


@pytest.mark.parametrize("level, altitude_m", DRYDEN_CASES)
def test_dryden_discretisation_matches_scipy(level, altitude_m):
    """Phi = expm(A T), Q_d by Van Loan, stationary P by Lyapunov, output map reproduces H_v and H_p."""
    tas = _tas(altitude_m)
    a, b, h_v, h_p = _continuous_dryden(level, altitude_m, tas)
    params = turbulence.discretise(level, altitude_m, tas, SPAN_M, DT_S)
    qbb = NOISE_INTENSITY * b @ b.T
    van_loan = scipy.linalg.expm(np.block([[-a, qbb], [np.zeros((3, 3)), a.T]]) * DT_S)
    phi = van_loan[3:, 3:].T
    q_d = phi @ van_loan[:3, 3:]
    p_stat = scipy.linalg.solve_continuous_lyapunov(a, -qbb)
    np.testing.assert_allclose(np.asarray(params.phi), scipy.linalg.expm(a * DT_S), **ROUNDING)
    chol_q, chol_p = np.asarray(params.chol_q), np.asarray(params.chol_p)
    np.testing.assert_allclose(chol_q @ chol_q.T, q_d, rtol=1e-9, atol=1e-12 * np.abs(q_d).max())
    np.testing.assert_allclose(chol_p @ chol_p.T, p_stat, rtol=1e-9, atol=1e-12 * np.abs(p_stat).max())
    c = np.asarray(params.out)
    for w in (0.0, 0.1, 1.0, 10.0):
        response = c @ np.linalg.solve(1j * w * np.eye(3) - a, b)
        np.testing.assert_allclose(response, [[h_v(1j * w), 0.0], [0.0, h_p(1j * w)]], rtol=1e-9, atol=1e-15)


@jax.jit
def _mean_square_gusts(level, altitude_m, tas_m_s, key):
    """Per-chain time averages of v_g^2 and p_g^2 over 512 independent stationary chains of 30 s."""
    n_chains, n_steps = 512, 3000
    params = turbulence.discretise(level, altitude_m, tas_m_s, SPAN_M, DT_S)
    chains = jax.vmap(lambda k: turbulence.init(params, jax.random.normal(k, (3,))))(jax.random.split(key, n_chains))

    def one_step(state, noise):
        state, (v_g, p_g) = turbulence.step(params, state, noise)
        return state, jnp.stack([v_g, p_g])

    def body(carry, k):
        state, total = carry
        state, gusts = jax.vmap(one_step)(state, jax.random.normal(jax.random.fold_in(key, k), (n_chains, 3)))
        return (state, total + gusts**2), None

    (_, total), _ = jax.lax.scan(body, (chains, jnp.zeros((n_chains, 2))), jnp.arange(n_steps))
    return total / n_steps


@pytest.mark.parametrize("case", range(len(DRYDEN_CASES)))
def test_dryden_sampled_variances(case):
    """Variances of v_g and p_g against sigma_v^2 and the integral of the MIL-F-8785C p spectrum.

    The gusts have zero mean, so each chain's mean square is an unbiased variance estimate; the
    chains are independent, so the spread of those estimates over the chains gives a standard error
    that includes the autocorrelation within a chain. The test allows 4.5 standard errors (a false
    failure about once in 10^5 per check).
    """
    level, altitude_m = DRYDEN_CASES[case]
    tas = _tas(altitude_m)
    sigma_v = float(turbulence.intensity(level, altitude_m)[0])
    expected = np.array([sigma_v**2, _p_gust_variance(level, altitude_m, tas)])
    per_chain = np.asarray(_mean_square_gusts(level, altitude_m, tas, jax.random.key(case)))
    estimate = per_chain.mean(axis=0)
    std_error = per_chain.std(axis=0, ddof=1) / math.sqrt(per_chain.shape[0])
    assert np.all(std_error < 0.025 * expected)
    assert np.all(np.abs(estimate - expected) < 4.5 * std_error), (estimate / expected, std_error / expected)


# ---------------------------------------------------------------------------------------------
# Closed loop

ROLL = manoeuvres.KIND_CODE["roll_protection"]
CLOSED_LOOP_STEPS = 3200
LAW = control_law.RollLawParams()
CLOSED_LOOP_RUNS = {
    # name: (vcas kt, altitude m, stick, stick held s)
    "rise_250kt_3000m": (250.0, 3000.0, 0.3, 5.0),
    "rise_160kt_500m": (160.0, 500.0, 0.3, 5.0),
    "rise_330kt_9000m": (330.0, 9000.0, -0.3, 5.0),
    "protection_250kt_3000m": (250.0, 3000.0, 1.0, 30.0),
    "protection_140kt_0m": (140.0, 0.0, -1.0, 30.0),
    "hold_after_roll": (250.0, 3000.0, 0.5, 3.0),
    "return_to_hold_limit": (250.0, 3000.0, 1.0, 4.0),
}
STICK_START_S = 1.0


def _calm_scenario(vcas_kt, altitude_m, stick, duration_s):
    """Stick stepped (10 ms ramp) at STICK_START_S and held, no turbulence, no sensor noise."""
    return closed_loop.Scenario(
        vcas_m_s=vcas_kt * atmosphere.KT_TO_M_S, altitude_m=altitude_m, turbulence_level=0.0, noise_std_m=0.0,
        manoeuvre=manoeuvres.ManoeuvreParams(kind=ROLL, amplitude=stick, t_start_s=STICK_START_S,
                                             duration_s=duration_s, ramp_s=0.01))


@pytest.fixture(scope="module")
def calm_runs(model):
    """Roll-axis histories without turbulence or noise, by run name: (p deg/s, phi deg) over 32 s."""
    scenarios = [_calm_scenario(*spec) for spec in CLOSED_LOOP_RUNS.values()]
    hist = simulate.plant_batch(model, batch.stack(scenarios, np.float64), simulate.run_keys(0, range(len(scenarios))),
                                CLOSED_LOOP_STEPS, DT_S, 4, (ROLL,))
    p, phi = np.degrees(np.asarray(hist.p_rad_s)), np.degrees(np.asarray(hist.phi_rad))
    return {name: (p[i], phi[i]) for i, name in enumerate(CLOSED_LOOP_RUNS)}


@pytest.mark.parametrize("name", [n for n in CLOSED_LOOP_RUNS if n.startswith("rise")])
def test_roll_rate_time_constant(calm_runs, name):
    """63 % rise time of p after a small stick step is the designed 0.5 s (+-15 %: actuator lag)."""
    p, _ = calm_runs[name]
    stick = CLOSED_LOOP_RUNS[name][2]
    demand = stick * math.degrees(LAW.max_roll_rate_rad_s)
    t = np.arange(CLOSED_LOOP_STEPS) * DT_S
    rising = p / demand
    k = int(np.argmax(rising >= 1.0 - math.exp(-1.0)))
    t63 = np.interp(1.0 - math.exp(-1.0), rising[k - 1:k + 1], t[k - 1:k + 1]) - STICK_START_S
    assert t63 == pytest.approx(LAW.time_constant_s, rel=0.15)


@pytest.mark.parametrize("name", ["protection_250kt_3000m", "protection_140kt_0m"])
def test_bank_protection_limits_full_stick_roll(calm_runs, name):
    """Full stick held 30 s: the bank approaches 67 deg and stays below it (+1 deg)."""
    _, phi = calm_runs[name]
    limit = math.degrees(LAW.bank_protection_rad)
    before_release = int((STICK_START_S + CLOSED_LOOP_RUNS[name][3] - 1.0) / DT_S)
    assert np.abs(phi).max() < limit + 1.0
    assert abs(phi[before_release]) == pytest.approx(limit, abs=1.0)


def test_stick_neutral_holds_bank(calm_runs):
    """Released at about 20 deg the bank stays; released beyond 33 deg it returns to 33 deg."""
    t = np.arange(CLOSED_LOOP_STEPS) * DT_S
    release_s = STICK_START_S + CLOSED_LOOP_RUNS["hold_after_roll"][3]
    _, phi = calm_runs["hold_after_roll"]
    settled = t > release_s + 2.0
    assert phi[settled][0] > 15.0
    assert np.ptp(phi[settled]) < 0.1
    _, phi = calm_runs["return_to_hold_limit"]
    hold = math.degrees(LAW.bank_hold_rad)
    assert phi.max() > hold + 10.0
    assert phi[-1] == pytest.approx(hold, abs=0.5)
    assert phi[t > STICK_START_S + 4.0].min() > hold - 0.5


def _mixed_scenarios():
    """Five runs of different families, with turbulence, sensor noise and faults.

    Manoeuvres start between samples: at a sample time the first open-loop command is 0 or about
    1e-19 m depending on how XLA contracts ``k dt - t_start``, which flips sgn(u_c - x) in
    ``dp_avail_norm`` and ``stall`` (both discontinuous at u_c = x).
    """
    code = manoeuvres.KIND_CODE
    fault = actuator.ActuatorFault
    kt = atmosphere.KT_TO_M_S
    specs = [
        (250.0, 3000.0, 1.0, fault(), dict(kind=code["doublet"], amplitude=0.8, duration_s=1.0)),
        (320.0, 1000.0, 2.0, fault(nu1=0.75, onset_s=1.0), dict(kind=code["sideslip"], sideslip_rad=0.1, ramp_s=0.5)),
        (200.0, 6000.0, 1.0, fault(nu2=0.0, onset_s=2.0), dict(kind=code["ol_sweep"], amplitude=0.4, duration_s=3.0)),
        (280.0, 2000.0, 2.0, fault(), dict(kind=code["quiet"])),
        (180.0, 500.0, 1.0, fault(jam_onset_s=2.5), dict(kind=code["ol_step"], amplitude=0.5)),
    ]
    return [closed_loop.Scenario(vcas_m_s=v * kt, altitude_m=h, turbulence_level=level, noise_std_m=5e-5, fault=f,
                                 manoeuvre=manoeuvres.ManoeuvreParams(t_start_s=0.505, **m))
            for v, h, level, f, m in specs]


MIXED_STEPS = 400
MIXED_SEED = 7


@pytest.fixture(scope="module")
def mixed_batch(model):
    """(stacked scenarios, keys, static kinds, batched histories) of the five mixed runs."""
    scenarios = batch.stack(_mixed_scenarios(), np.float64)
    kinds = batch.kinds_in(scenarios.manoeuvre.kind)
    keys = simulate.run_keys(MIXED_SEED, range(len(_mixed_scenarios())))
    return scenarios, keys, kinds, simulate.plant_batch(model, scenarios, keys, MIXED_STEPS, DT_S, 4, kinds)


def _run(histories, i):
    return jax.tree.map(lambda a: a[i], histories)


def _assert_same_outputs(got, expected):
    for name, a, b in zip(closed_loop.PlantOutputs._fields, got, expected, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype == bool:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max(), err_msg=name)


def test_vmapped_batch_equals_loop_of_single_runs(model, mixed_batch):
    scenarios, keys, kinds, batched = mixed_batch
    assert np.abs(np.asarray(batched.phi_rad)).max() > 0.01
    single = jax.jit(simulate.plant_history, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
    for i in range(keys.shape[0]):
        run = single(model, _run(scenarios, i), keys[i], n_steps=MIXED_STEPS, dt_s=DT_S, substeps=4, kinds=kinds)
        _assert_same_outputs(_run(batched, i), run)


def test_run_does_not_depend_on_its_batch(model, mixed_batch):
    """Run 3, keyed by run_keys(seed, [3]), at the head of a batch of other runs equals run 3 of the first batch."""
    _, _, kinds, batched = mixed_batch
    runs = _mixed_scenarios()
    others = [r._replace(altitude_m=r.altitude_m + 1500.0, turbulence_level=2.0 - r.turbulence_level) for r in runs[1:]]
    keys = jnp.concatenate([simulate.run_keys(MIXED_SEED, [3]), simulate.run_keys(MIXED_SEED + 1, range(4))])
    elsewhere = simulate.plant_batch(model, batch.stack([runs[3]] + others, np.float64), keys, MIXED_STEPS, DT_S, 4,
                                     kinds)
    _assert_same_outputs(_run(elsewhere, 0), _run(batched, 3))


@pytest.mark.parametrize("altitude_m", [0.0, 3000.0, 11000.0, 15000.0])
def test_calibrated_airspeed_inverts_mach(altitude_m):
    """calibrated_airspeed(mach(v, h), h) == v over the subsonic range."""
    v = np.linspace(40.0, 220.0, 7)
    m = np.asarray(atmosphere.mach(v, altitude_m))
    np.testing.assert_allclose(np.asarray(atmosphere.calibrated_airspeed(m, altitude_m)), v, rtol=1e-10)

"""The RCAM rigid body against an independent NumPy model of TP-088-3 (matrix form), its trim and modes."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp

from mcfdd import cli, config
from mcfdd.analysis import batch, build, campaign, scenarios, scoring, simulate
from mcfdd.fdd import system
from mcfdd.plant import atmosphere, closed_loop, rcam, turbulence
from mcfdd.workflows.common import load_bank

P = rcam.RcamParams()
APPROACH_TAS = 80.0
APPROACH_H = 1000.0 * atmosphere.FT_TO_M


def reference_derivatives(x, u, rho, gust=(0.0,) * 6):
    """TP-088-3 in matrix form: stability-to-body rotation, cross products, inertia solve, DCM.

    ``gust``: (u, v, w) gust velocity and (p, q, r) gust rates in body axes, subtracted from the
    body's velocity and rates wherever the air sees them (aerodynamic angles, speed, rate terms)."""
    cbar, lt, s, st, m, g = 6.6, 24.8, 260.0, 64.0, 120000.0, 9.81
    vel, omega = np.array(x[0:3]), np.array(x[3:6])
    phi, theta, psi = x[6:9]
    da, dt, dr, th1, th2 = u
    v_air = vel - np.array(gust[:3])
    omega_air = omega - np.array(gust[3:])
    va = np.linalg.norm(v_air)
    alpha = math.atan2(v_air[2], v_air[0])
    beta = math.asin(v_air[1] / va)
    qdyn = 0.5 * rho * va**2
    if alpha <= math.radians(14.5):
        cl_wb = 5.5 * (alpha - math.radians(-11.5))
    else:
        cl_wb = -768.5 * alpha**3 + 609.2 * alpha**2 - 155.2 * alpha + 15.212
    eps = 0.25 * (alpha - math.radians(-11.5))
    cl = cl_wb + 3.1 * (st / s) * (alpha - eps + dt + 1.3 * omega_air[1] * lt / va)
    cd = 0.13 + 0.07 * (5.5 * alpha + 0.654) ** 2
    cy = -1.6 * beta + 0.24 * dr
    c_bs = np.array([[math.cos(alpha), 0.0, -math.sin(alpha)], [0.0, 1.0, 0.0],
                     [math.sin(alpha), 0.0, math.cos(alpha)]])
    fa = c_bs @ (qdyn * s * np.array([-cd, cy, -cl]))
    eta = np.array([-1.4 * beta, -0.59 - 3.1 * st * lt / (s * cbar) * (alpha - eps),
                    (1.0 - alpha * 180.0 / (15.0 * math.pi)) * beta])
    dcm_dx = cbar / va * np.array([[-11.0, 0.0, 5.0], [0.0, -4.03 * st * lt**2 / (s * cbar**2), 0.0],
                                   [1.7, 0.0, -11.5]])
    dcm_du = np.array([[-0.6, 0.0, 0.22], [0.0, -3.1 * st * lt / (s * cbar), 0.0], [0.0, 0.0, -0.63]])
    cm = eta + dcm_dx @ omega_air + dcm_du @ np.array([da, dt, dr])
    ma = cm * qdyn * s * cbar + np.cross(fa, np.array([0.23 * cbar, 0.0, 0.10 * cbar]) - np.array([0.12 * cbar, 0, 0]))
    fe1, fe2 = np.array([th1 * m * g, 0.0, 0.0]), np.array([th2 * m * g, 0.0, 0.0])
    cg = np.array([0.23 * cbar, 0.0, 0.10 * cbar])
    me = (np.cross(np.array([cg[0] - 0.0, -7.94 - cg[1], cg[2] + 1.9]), fe1)
          + np.cross(np.array([cg[0] - 0.0, 7.94 - cg[1], cg[2] + 1.9]), fe2))
    grav = m * g * np.array([-math.sin(theta), math.cos(theta) * math.sin(phi), math.cos(theta) * math.cos(phi)])
    inertia = m * np.array([[40.07, 0.0, -2.0923], [0.0, 64.0, 0.0], [-2.0923, 0.0, 99.92]])
    vdot = (fa + fe1 + fe2 + grav) / m - np.cross(omega, vel)
    wdot = np.linalg.solve(inertia, ma + me - np.cross(omega, inertia @ omega))
    h_phi = np.array([[1.0, math.sin(phi) * math.tan(theta), math.cos(phi) * math.tan(theta)],
                      [0.0, math.cos(phi), -math.sin(phi)],
                      [0.0, math.sin(phi) / math.cos(theta), math.cos(phi) / math.cos(theta)]])

    def rot(axis, a):
        c, s_ = math.cos(a), math.sin(a)
        if axis == 0:
            return np.array([[1, 0, 0], [0, c, s_], [0, -s_, c]])
        if axis == 1:
            return np.array([[c, 0, -s_], [0, 1, 0], [s_, 0, c]])
        return np.array([[c, s_, 0], [-s_, c, 0], [0, 0, 1]])

    c_bn = rot(0, phi) @ rot(1, theta) @ rot(2, psi)
    ned = c_bn.T @ vel
    return np.concatenate([vdot, wdot, h_phi @ omega, ned[:2], [-ned[2]]])


def _state(x):
    return rcam.RcamState(*[jnp.asarray(v) for v in x])


def _controls(u):
    return rcam.RcamControls(*[jnp.asarray(v) for v in u])


def _module_derivatives(x, u, rho, gust=(0.0,) * 6):
    return np.array(rcam.derivatives(P, _state(x), _controls(u), rho, turbulence.Gust(*gust)))


def _random_point(rng):
    x = np.concatenate([[rng.uniform(60, 200), rng.uniform(-8, 8), rng.uniform(-10, 40)],
                        rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.8, 0.8, 2), [rng.uniform(-3, 3)],
                        rng.uniform(-1e3, 1e3, 2), [rng.uniform(0, 1e4)]])
    u = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.17), rng.uniform(-0.5, 0.5),
                  rng.uniform(0.01, 0.17), rng.uniform(0.01, 0.17)])
    return x, u


def test_derivatives_match_the_independent_model_at_random_states():
    rng = np.random.default_rng(1)
    high_alpha = 0
    for _ in range(40):
        x, u = _random_point(rng)
        rho = rng.uniform(0.4, 1.225)
        gust = (0.0,) * 6 if rng.random() < 0.3 else tuple(rng.uniform(-5, 5, 3)) + tuple(rng.uniform(-0.05, 0.05, 3))
        ref = reference_derivatives(x, u, rho, gust)
        got = _module_derivatives(x, u, rho, gust)
        high_alpha += math.atan2(x[2], x[0]) > math.radians(14.5)
        np.testing.assert_allclose(got, ref, rtol=1e-11, atol=1e-10)
    assert high_alpha > 0, "the post-stall branch of CL_wb was not exercised"


def test_trim_gives_zero_derivatives_and_is_batched():
    vcas = jnp.array([140.0, 180.0, 230.0]) * atmosphere.KT_TO_M_S
    alt = jnp.array([300.0, 3000.0, 7000.0])
    trims = jax.vmap(lambda v, h: rcam.trim(P, v, h))(vcas, alt)
    for i in range(3):
        x = [float(leaf[i]) for leaf in trims.state]
        u = [0.0, float(trims.stabiliser[i]), 0.0, float(trims.throttle[i]), float(trims.throttle[i])]
        rho = float(atmosphere.isa(alt[i])[2])
        d = reference_derivatives(x, u, rho)
        np.testing.assert_allclose(d[:9], 0.0, atol=1e-9)
        assert abs(d[11]) < 1e-9  # level: no climb
        assert d[9] == pytest.approx(np.hypot(x[0], x[2]))  # flying north at the true airspeed
        assert float(rcam.calibrated_airspeed(d[9], alt[i])) == pytest.approx(float(vcas[i]), rel=1e-9)


def test_heavier_aircraft_trims_at_higher_alpha():
    light = rcam.trim(P._replace(mass_kg=100000.0), 80.0, APPROACH_H)
    heavy = rcam.trim(P._replace(mass_kg=140000.0), 80.0, APPROACH_H)
    assert float(heavy.state.theta) > float(light.state.theta) + math.radians(1.0)
    assert float(heavy.residual) < 1e-9


def _jacobian(f, x0, u0, steps):
    n = len(x0)
    jac = np.zeros((n, n))
    for j in range(n):
        dx = np.zeros(n)
        dx[j] = steps[j]
        jac[:, j] = (f(x0 + dx, u0) - f(x0 - dx, u0)) / (2.0 * steps[j])
    return jac


def _modes(jac):
    """Short-period and Dutch-roll eigenvalues: the complex pairs of the (u, w, q, theta) and (v, p, r, phi) blocks."""
    lon = np.ix_([0, 2, 4, 7], [0, 2, 4, 7])
    lat = np.ix_([1, 3, 5, 6], [1, 3, 5, 6])
    sp = max(np.linalg.eigvals(jac[lon]), key=lambda z: abs(z))
    dr = [z for z in np.linalg.eigvals(jac[lat]) if abs(z.imag) > 1e-6]
    return sp, max(dr, key=lambda z: abs(z.imag))


def test_short_period_and_dutch_roll_at_the_approach_point_match_the_independent_jacobian():
    vcas = float(rcam.calibrated_airspeed(APPROACH_TAS, APPROACH_H))
    trim = rcam.trim(P, vcas, APPROACH_H)
    x0 = np.array([float(v) for v in trim.state])
    u0 = np.array([0.0, float(trim.stabiliser), 0.0, float(trim.throttle), float(trim.throttle)])
    rho = float(atmosphere.isa(APPROACH_H)[2])
    steps = np.array([1e-3] * 3 + [1e-5] * 3 + [1e-5] * 3 + [1.0] * 3)
    ref = _jacobian(lambda x, u: reference_derivatives(x, u, rho), x0, u0, steps)

    def module_f(x):
        return jnp.stack(rcam.derivatives(P, rcam.RcamState(*x), _controls(u0), rho))

    exact = np.asarray(jax.jacfwd(module_f)(jnp.asarray(x0)))
    sp_ref, dr_ref = _modes(ref)
    sp, dr = _modes(exact)
    assert sp == pytest.approx(sp_ref, rel=1e-6)
    assert dr == pytest.approx(dr_ref, rel=1e-6)
    # a damped short period of about 1.7 rad/s and a lighter, slower Dutch roll, as for a transport on approach
    assert sp.real < 0 and 1.0 < abs(sp) < 3.0 and 0.3 < -sp.real / abs(sp) < 0.8
    assert dr.real < 0 and 0.4 < dr.imag < 1.5 and -dr.real / abs(dr) < -sp.real / abs(sp)


def test_runge_kutta_step_matches_solve_ivp():
    rng = np.random.default_rng(4)
    x, u = _random_point(rng)
    x[2] = 3.0
    rho = 1.0
    sol = solve_ivp(lambda t, y: reference_derivatives(y, u, rho), (0.0, 0.5), x, rtol=1e-11, atol=1e-9)
    state = _state(x)
    for _ in range(50):
        before = state
        state, rates = rcam.step(P, state, _controls(u), rho, 0.01)
    np.testing.assert_allclose(np.array(state), sol.y[:, -1], rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(np.array(rates), reference_derivatives(np.array(before), u, rho), rtol=1e-10,
                               atol=1e-10)  # the step also returns the derivatives where it started


def test_float32_step_stays_close_to_float64():
    trim = rcam.trim(P, 150.0 * atmosphere.KT_TO_M_S, 2000.0)
    u = [0.01, float(trim.stabiliser), 0.02, float(trim.throttle), float(trim.throttle)]
    x64 = trim.state
    x32 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), trim.state)
    c32 = rcam.RcamControls(*[jnp.float32(v) for v in u])
    for _ in range(200):
        x64 = rcam.step(P, x64, _controls(u), 1.0066, 0.01)[0]
        x32 = rcam.step(P, x32, c32, jnp.float32(1.0066), 0.01)[0]
    assert x32.u.dtype == jnp.float32
    np.testing.assert_allclose(np.array(x32)[:9], np.array(x64)[:9], rtol=2e-3, atol=2e-3)


# --------------------------------------------------------------------------------------------
# The full aircraft in closed loop

CLOSED_LOOP_RUNS = {
    "level_low": dict(vcas_kt=150.0, altitude_m=500.0, manoeuvre_kind="level_flight"),
    "level_high": dict(vcas_kt=240.0, altitude_m=7000.0, mass_scale=0.9, manoeuvre_kind="level_flight"),
    "speed": dict(vcas_kt=150.0, altitude_m=1000.0, manoeuvre_kind="speed_change", delta_vcas_kt=10.0, t_start_s=5.0),
    "turn": dict(vcas_kt=200.0, altitude_m=3000.0, manoeuvre_kind="coordinated_turn", bank_deg=30.0, t_start_s=5.0,
                 duration_s=40.0, ramp_s=1.0),
    "protection": dict(vcas_kt=200.0, altitude_m=3000.0, manoeuvre_kind="roll_protection", amplitude=1.0,
                       t_start_s=5.0, duration_s=20.0),
    "heading": dict(vcas_kt=180.0, altitude_m=2000.0, manoeuvre_kind="heading_change", heading_change_deg=-40.0,
                    t_start_s=5.0),
}


@pytest.fixture(scope="module")
def closed_loop_runs():
    model = closed_loop.build_model(vcas_range_m_s=(40.0, 220.0), grid=(19, 14, 11), aircraft_model="rcam")
    rows = list(CLOSED_LOOP_RUNS.values())
    cols = {k: np.array([r.get(k, v) for r in rows]) for k, v in scenarios.DEFAULTS.items()}
    cols["turbulence"] = np.full(len(rows), "none")
    cols["noise_std_mm"] = np.zeros(len(rows))
    scen = scenarios.to_scenario(cols, np.float64)
    out = simulate.plant_batch(model, scen, simulate.run_keys(0, range(len(rows))), 6000, 0.01, 4,
                               batch.kinds_in(scen.manoeuvre.kind))
    return {name: jax.tree.map(lambda a, i=i: np.asarray(a[i]), out) for i, name in enumerate(CLOSED_LOOP_RUNS)}


def _kt(out):
    return out.vcas_m_s / atmosphere.KT_TO_M_S


@pytest.mark.parametrize("name", ["level_low", "level_high"])
def test_trimmed_level_flight_holds_altitude_and_speed_for_60_s(closed_loop_runs, name):
    out, run = closed_loop_runs[name], CLOSED_LOOP_RUNS[name]
    assert np.abs(out.altitude_m - run["altitude_m"]).max() < 1.0
    assert np.abs(_kt(out) - run["vcas_kt"]).max() < 0.2
    assert np.abs(np.degrees(out.phi_rad)).max() < 0.1 and np.abs(out.nz_g - 1.0).max() < 0.01


def test_speed_change_reaches_the_new_speed(closed_loop_runs):
    out, run = closed_loop_runs["speed"], CLOSED_LOOP_RUNS["speed"]
    target = run["vcas_kt"] + run["delta_vcas_kt"]
    t = np.arange(out.vcas_m_s.shape[0]) * 0.01
    settled = t >= 45.0
    assert np.abs(_kt(out)[settled] - target).max() < 1.0  # within 1 kt 40 s after the target step
    assert _kt(out).max() < target + 3.0  # overshoot below 3 kt
    assert np.abs(out.altitude_m - run["altitude_m"]).max() < 30.0  # the path hold keeps the altitude meanwhile


def test_coordinated_turn_keeps_sideslip_small(closed_loop_runs):
    out, run = closed_loop_runs["turn"], CLOSED_LOOP_RUNS["turn"]
    t = np.arange(out.phi_rad.shape[0]) * 0.01
    held = (t > 20.0) & (t < 44.0)
    assert np.abs(np.degrees(out.phi_rad[held]) - run["bank_deg"]).max() < 1.0
    assert np.abs(np.degrees(out.beta_rad)).max() < 1.0
    # a coordinated level turn: yaw rate g tan(phi) / V in the Euler heading rate, load factor 1 / cos(phi)
    rate = np.gradient(np.unwrap(out.psi_rad), t)[held]
    tas = np.array(rcam.true_airspeed(out.vcas_m_s[held], out.altitude_m[held]))
    np.testing.assert_allclose(rate, 9.81 * np.tan(out.phi_rad[held]) / tas, rtol=0.05)
    np.testing.assert_allclose(out.nz_g[held], 1.0 / np.cos(out.phi_rad[held]), rtol=0.03)
    assert np.abs(np.degrees(out.phi_rad[t > 55.0])).max() < 2.0  # rolled out after the turn


def test_roll_protection_bounds_bank_at_67_deg(closed_loop_runs):
    phi = np.degrees(closed_loop_runs["protection"].phi_rad)
    assert 60.0 < np.abs(phi).max() <= 67.0


def test_heading_change_captures_the_new_heading(closed_loop_runs):
    out, run = closed_loop_runs["heading"], CLOSED_LOOP_RUNS["heading"]
    psi = np.degrees(out.psi_rad)
    assert np.abs(psi[-1000:] - run["heading_change_deg"]).max() < 1.0
    assert np.abs(np.degrees(out.phi_rad)).max() <= 25.5  # navigation bank limit


def test_campaign_reductions_record_the_flight_point_range_and_the_fdd_schedules_on_it():
    """run_batch's Vcas/altitude ranges against the full histories of the same rcam runs."""
    cfg = config.parse(config.CampaignConfig, {
        "campaign": {"scenarios": 3, "duration_s": 12.0, "design": "random"},
        "plant": {"aircraft": {"model": "rcam"}},
        "space": {"vcas_kt": [150.0, 220.0], "altitude_m": [500.0, 5000.0],
                  "manoeuvre_kind": ["speed_change", "fpa_change", "pitch_doublet"], "delta_vcas_kt": 15.0,
                  "fpa_deg": 4.0, "amplitude": 0.5, "t_start_s": 1.0, "duration_s": 3.0}})
    cols, n = build.design(cfg)
    model = build.plant_model(cfg.plant)
    bank, _ = load_bank(cfg.fdd, np.float64)
    fdd = build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m)
    scen = scenarios.to_scenario(cols, np.float64)
    kinds, keys = batch.kinds_in(scen.manoeuvre.kind), simulate.run_keys(0, range(n))
    truth = scoring.Truth(np.full(n, np.inf), np.zeros((n, bank.k0.shape[0]), bool), np.zeros(n, np.int32))
    raw = campaign.run_batch(model, fdd, build.settings(cfg.evaluation, model.actuator.r_arm_m), scen, truth, keys,
                             1200, 0.01, 4, kinds)
    plant, fdd_out = simulate.fdd_batch(model, fdd, scen, keys, 1200, 0.01, 4, kinds)
    v, h = np.asarray(plant.vcas_m_s), np.asarray(plant.altitude_m)
    np.testing.assert_array_equal(np.asarray(raw["vcas_min_m_s"]), v.min(axis=1))
    np.testing.assert_array_equal(np.asarray(raw["vcas_max_m_s"]), v.max(axis=1))
    np.testing.assert_array_equal(np.asarray(raw["altitude_min_m"]), h.min(axis=1))
    np.testing.assert_array_equal(np.asarray(raw["altitude_max_m"]), h.max(axis=1))
    assert (v.max(axis=1) - v.min(axis=1)).min() > 0.5 and (h.max(axis=1) - h.min(axis=1)).min() > 0.5
    # the FDD's hinge-load estimate follows the measured flight point, not the initial one
    i = int(np.argmax(h.max(axis=1) - h.min(axis=1)))
    moving = frozen = system.init(fdd, 0.0)
    for k in range(1200):
        moving, step_out = system.step(fdd, moving, plant.u_c_m[i, k], plant.u_m[i, k], plant.vcas_m_s[i, k],
                                       plant.altitude_m[i, k], k * 0.01, 0.01)
        frozen, frozen_out = system.step(fdd, frozen, plant.u_c_m[i, k], plant.u_m[i, k], plant.vcas_m_s[i, 0],
                                         plant.altitude_m[i, 0], k * 0.01, 0.01)
    np.testing.assert_allclose(np.asarray(step_out.load_fraction), np.asarray(fdd_out.load_fraction[i, -1]),
                               rtol=1e-12)
    assert abs(float(frozen_out.load_fraction) - float(step_out.load_fraction)) > 1e-6


@pytest.mark.parametrize("data,message", [
    ({"plant": {"aircraft": {"model": "boeing"}}}, "plant.aircraft.model"),
    ({"space": {"manoeuvre_kind": ["doublet", "pitch_doublet"]}}, "space.manoeuvre_kind.*rcam"),
    ({"plant": {"aircraft": {"model": "rcam"}}, "space": {"mass_scale": [0.5, 1.0]}}, "space.mass_scale"),
])
def test_bad_full_aircraft_settings_are_named(data, message):
    with pytest.raises(config.ConfigError, match=message):
        config.parse(config.CampaignConfig, data)


def test_simulate_writes_the_flight_signals_of_rcam_runs(tmp_path):
    path = tmp_path / "rcam.toml"
    path.write_text('[simulation]\nduration_s = 3.0\nprecision = "float64"\n\n[plant.aircraft]\nmodel = "rcam"\n\n'
                    '[[runs]]\nname = "speed"\nvcas_kt = 180.0\naltitude_m = 2000.0\nturbulence = "none"\n'
                    'manoeuvre = { kind = "speed_change", delta_vcas_kt = 10.0, t_start_s = 0.5 }\n')
    assert cli.main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 0
    df = pd.read_parquet(tmp_path / "out" / "timeseries.parquet")
    for column in ("vcas_kt", "altitude_m", "alpha_deg", "beta_deg", "theta_deg", "q_deg_s", "r_deg_s", "psi_deg",
                   "nz_g"):
        assert np.isfinite(df[column]).all(), column
    assert df["vcas_kt"].iloc[0] == pytest.approx(180.0, abs=1e-6) and df["vcas_kt"].iloc[-1] > 180.0
    assert (tmp_path / "out" / "speed-flight.png").is_file()


def test_roll_axis_refuses_a_full_aircraft_manoeuvre_in_one_line(tmp_path, capsys):
    path = tmp_path / "roll.toml"
    path.write_text('[[runs]]\nname = "turn"\nmanoeuvre = { kind = "coordinated_turn", bank_deg = 30.0 }\n')
    assert cli.main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "runs[0].manoeuvre.kind" in err and "rcam" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_tuning_refuses_the_full_aircraft():
    with pytest.raises(config.ConfigError, match="plant.aircraft.model.*roll_axis"):
        config.parse(config.TuneConfig, {"plant": {"aircraft": {"model": "rcam"}}, "validation": {"seed": 1}})

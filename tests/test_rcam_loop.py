"""The full aircraft's closed loop around the rigid body: surfaces, hinge-load line, turbulence, manoeuvre families.

The surfaces against ``solve_ivp`` of the continuous rate- and position-limited lag; the hinge-load
line at a moving flight point against the slice of the roll axis; and the closed loop flying the
paper's piloted and navigation families (Section 6.2.2) with the responses each family asks for,
the surfaces within their TP-088-3 limits, turbulence reaching pitch, load factor and airspeed in
order of its level, and the monitored aileron working as hard as on the roll axis.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mcfdd.analysis import batch, scenarios, simulate
from mcfdd.plant import closed_loop, hinge, rcam, rcam_loop

DT_S = 0.01


def test_point_line_is_the_line_of_the_flight_point_slice():
    model = closed_loop.build_model(grid=(19, 14, 11))
    rng = np.random.default_rng(3)
    for _ in range(50):
        vcas, h = rng.uniform(20.0, 240.0), rng.uniform(-500.0, 14000.0)  # beyond the grid too: clamped alike
        delta = rng.uniform(-0.5, 0.5)
        slice_ = hinge.flight_point_slice(model.table, jnp.asarray(vcas), jnp.asarray(h))
        want = hinge.local_line(model.table.delta_rad, slice_, jnp.asarray(delta))
        got = hinge.point_line(model.table, jnp.asarray(vcas), jnp.asarray(h), jnp.asarray(delta))
        np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-13, atol=1e-9)


@pytest.mark.parametrize("surface", [rcam_loop.Surfaces().stabiliser, rcam_loop.Surfaces().rudder,
                                     rcam_loop.Surfaces().throttle])
def test_surface_is_a_rate_and_position_limited_lag(surface):
    """Commands beyond the stops and steps large enough to hit the rate limit, against solve_ivp of
    tau x' = sat(c) - x with |x'| <= rate: within one sample's rate-limited travel at every sample."""
    step = rcam_loop.surface_step(surface, DT_S)
    span = surface.max_rad - surface.min_rad
    commands = [surface.max_rad + 0.2 * span, surface.min_rad + 0.3 * span, surface.min_rad - 0.5 * span,
                surface.min_rad + 0.05 * span]
    hold = 400
    command = np.repeat(commands, hold)
    x, xs = surface.min_rad + 0.5 * span, []
    for c in command:
        xs.append(x)
        x = float(rcam_loop.follow(step, jnp.asarray(x), jnp.asarray(c)))
    xs = np.array(xs)

    def rate(t, y):
        c = np.clip(command[min(int(t / DT_S), len(command) - 1)], surface.min_rad, surface.max_rad)
        return [np.clip((c - y[0]) / surface.time_constant_s, -surface.max_rate_rad_s, surface.max_rate_rad_s)]

    t = np.arange(len(command)) * DT_S
    ref = solve_ivp(rate, (0.0, t[-1]), [xs[0]], t_eval=t, max_step=DT_S / 4, rtol=1e-9, atol=1e-12).y[0]
    assert np.all(xs >= surface.min_rad - 1e-12) and np.all(xs <= surface.max_rad + 1e-12)
    assert np.abs(np.diff(xs)).max() <= surface.max_rate_rad_s * DT_S * (1 + 1e-12)
    assert np.abs(xs - ref).max() < surface.max_rate_rad_s * DT_S
    assert np.abs(np.diff(xs)).max() > 0.99 * surface.max_rate_rad_s * DT_S  # the rate limit was reached


# --------------------------------------------------------------------------------------------
# Closed loop

RUNS = {
    "sideslip": dict(vcas_kt=220.0, altitude_m=2000.0, manoeuvre_kind="sideslip", sideslip_deg=8.0, duration_s=12.0,
                     hold_s=3.0, ramp_s=0.5),
    "pedal": dict(vcas_kt=200.0, altitude_m=1000.0, manoeuvre_kind="pedal_doublet", amplitude=0.6, duration_s=4.0,
                  ramp_s=0.5),
    "nose_up": dict(vcas_kt=220.0, altitude_m=3000.0, manoeuvre_kind="nose_up", amplitude=0.8, duration_s=4.0,
                    ramp_s=0.3),
    "nose_down": dict(vcas_kt=220.0, altitude_m=3000.0, manoeuvre_kind="nose_down", amplitude=0.8, duration_s=4.0,
                      ramp_s=0.3),
    "pitch_doublet": dict(vcas_kt=180.0, altitude_m=500.0, manoeuvre_kind="pitch_doublet", amplitude=1.0,
                          duration_s=2.0, ramp_s=0.3),
    "fpa": dict(vcas_kt=200.0, altitude_m=2000.0, manoeuvre_kind="fpa_change", fpa_deg=3.0, duration_s=40.0,
                ramp_s=1.0),
    "doublet": dict(vcas_kt=250.0, altitude_m=3000.0, manoeuvre_kind="doublet", amplitude=1.0, duration_s=2.0,
                    ramp_s=0.2),
    **{f"level_{level}": dict(vcas_kt=200.0, altitude_m=3000.0, manoeuvre_kind="level_flight", turbulence=level)
       for level in ("none", "light", "moderate", "severe")},
}
START_S = 5.0
STEPS = 3000


def _columns(runs):
    cols = {k: np.array([r.get(k, v) for r in runs]) for k, v in scenarios.DEFAULTS.items()}
    cols["turbulence"] = np.array([r.get("turbulence", "none") for r in runs])
    cols["noise_std_mm"] = np.zeros(len(runs))
    cols["t_start_s"] = np.full(len(runs), START_S)
    return cols


@pytest.fixture(scope="module")
def flown():
    model = closed_loop.build_model(grid=(19, 14, 11), aircraft_model="rcam")
    scen = scenarios.to_scenario(_columns(list(RUNS.values())), np.float64)
    # one key for all: the level-flight runs fly the same unit-variance gust paths, scaled by their level
    out = simulate.plant_batch(model, scen, simulate.run_keys(0, [0] * len(RUNS)), STEPS, DT_S, 2,
                               batch.kinds_in(scen.manoeuvre.kind))
    return {name: jax.tree.map(lambda a, i=i: np.asarray(a[i]), out) for i, name in enumerate(RUNS)}


TIME = np.arange(STEPS) * DT_S


def test_steady_sideslip_is_held_wings_level_with_the_aileron(flown):
    out, run = flown["sideslip"], RUNS["sideslip"]
    held = (TIME > START_S + 3.0) & (TIME < START_S + run["duration_s"])
    assert np.abs(np.degrees(out.beta_rad[held]) - run["sideslip_deg"]).max() < 1.0
    assert np.abs(np.degrees(out.phi_rad[held])).max() < 10.0
    # the aileron holds the dihedral's roll (C_l_beta) against the rudder's: about 1.75 deg per deg of sideslip
    assert np.degrees(np.abs(out.delta_rad[held])).mean() > 1.2 * run["sideslip_deg"]


def test_pedal_doublet_yaws_both_ways(flown):
    beta = np.degrees(flown["pedal"].beta_rad)
    first = (TIME > START_S) & (TIME < START_S + 4.0)
    second = (TIME > START_S + 4.0) & (TIME < START_S + 8.0)
    assert beta[first].max() > 3.0 and beta[second].min() < -3.0
    assert np.argmax(beta) < np.argmin(beta)


@pytest.mark.parametrize("name,sign", [("nose_up", 1.0), ("nose_down", -1.0)])
def test_nose_up_and_down_demands_give_their_load_factor(flown, name, sign):
    """The longitudinal stick demands dnz = stick 0.3 g: over the second half of the hold the load factor
    has more than 70 % of the increment and overshoots it by less than 30 %; the aircraft climbs or descends."""
    out, run = flown[name], RUNS[name]
    held = (TIME > START_S + run["duration_s"] / 2) & (TIME < START_S + run["duration_s"])
    demand = sign * 0.3 * run["amplitude"]
    assert np.all(np.abs(out.nz_g[held] - 1.0 - demand) < 0.3 * abs(demand))
    assert sign * (out.altitude_m[-1] - out.altitude_m[0]) > 20.0


def test_pitch_doublet_pulls_then_pushes(flown):
    nz = flown["pitch_doublet"].nz_g
    assert nz.max() > 1.2 and nz.min() < 0.8 and np.argmax(nz) < np.argmin(nz)


def test_flight_path_target_is_captured(flown):
    out, run = flown["fpa"], RUNS["fpa"]
    held = (TIME > START_S + 15.0) & (TIME < START_S + run["duration_s"] - 1.0)
    climb = np.gradient(out.altitude_m, TIME)
    gamma = np.degrees(np.arcsin(climb / np.asarray(rcam.true_airspeed(out.vcas_m_s, out.altitude_m))))
    assert np.abs(gamma[held] - run["fpa_deg"]).max() < 0.3


def test_surfaces_stay_within_their_limits_in_every_run(flown):
    s = rcam_loop.Surfaces()
    for name, out in flown.items():
        for signal, limit in (("stabiliser_rad", s.stabiliser), ("rudder_rad", s.rudder), ("throttle_rad", s.throttle)):
            x = getattr(out, signal)
            assert x.min() >= limit.min_rad - 1e-12 and x.max() <= limit.max_rad + 1e-12, (name, signal)
            assert np.abs(np.diff(x)).max() <= limit.max_rate_rad_s * DT_S * (1 + 1e-9), (name, signal)


def test_turbulence_reaches_pitch_load_factor_and_airspeed_in_order_of_its_level(flown):
    """Level flight: the six gusts move nz, q, Vcas, p and beta, more with each level; calm air none."""
    settled = TIME > 5.0
    spread = {level: [np.std(getattr(flown[f"level_{level}"], s)[settled]) for s in
                      ("nz_g", "q_rad_s", "vcas_m_s", "p_rad_s", "beta_rad", "r_rad_s")]
              for level in ("none", "light", "moderate", "severe")}
    assert max(spread["none"]) < 1e-6
    for lower, higher in (("light", "moderate"), ("moderate", "severe")):
        assert all(a < b for a, b in zip(spread[lower], spread[higher])), (lower, higher)
    assert spread["light"][0] > 0.01 and spread["light"][2] > 0.2  # about 0.03 g and 0.5 m/s in light turbulence


def test_the_aileron_works_as_hard_as_on_the_roll_axis(flown):
    """A full-stick lateral doublet at 250 kt: the monitored aileron's peak deflection and load at least 85 %
    of the roll axis's on the same run (the stick's roll-rate demand is the same law on both)."""
    run = RUNS["doublet"]
    roll_axis = closed_loop.build_model(grid=(19, 14, 11))
    scen = scenarios.to_scenario(_columns([run]), np.float64)
    out = simulate.plant_batch(roll_axis, scen, simulate.run_keys(0, [0]), STEPS, DT_S, 2,
                               batch.kinds_in(scen.manoeuvre.kind))
    full = flown["doublet"]
    peak = (np.abs(np.asarray(out.delta_rad[0])).max(), np.abs(full.delta_rad).max())
    load = (np.asarray(out.load_fraction[0]).max(), full.load_fraction.max())
    assert peak[1] > 0.85 * peak[0] and math.degrees(peak[1]) > 15.0
    assert load[1] > 0.85 * load[0]


def test_a_run_does_not_depend_on_its_place_in_the_campaign_batch():
    """The campaign program (float32, its XLA CPU options) on 128 copies of one scenario of each navigation
    and piloted family: every copy gives the same outcomes to the last bit. XLA CPU's 512-bit atan2 of a
    constant gave lane-dependent results (the heading mode's bank demand was atan of one argument), so a
    heading change depended on its chunk."""
    from mcfdd import config
    from mcfdd.analysis import campaign
    from mcfdd.workflows import campaign as runner
    from mcfdd.workflows.common import precision

    with precision("float32"):
        cfg = config.parse(config.CampaignConfig, {
            "campaign": {"scenarios": 3, "duration_s": 12.0, "design": "random", "grid": ["manoeuvre_kind"]},
            "evaluation": {"settle_s": 1.0},
            "plant": {"aircraft": {"model": "rcam"}},
            "space": {"vcas_kt": [180.0, 240.0], "altitude_m": [500.0, 4000.0], "turbulence": "moderate",
                      "manoeuvre_kind": ["heading_change", "coordinated_turn", "doublet"], "heading_change_deg": 60.0,
                      "bank_deg": 30.0, "amplitude": 1.0, "t_start_s": 2.0, "fault_kind": "disconnection",
                      "fault_onset_s": 1.0}})
        setup = runner.campaign_setup(cfg)
        for scenario in range(setup.n):
            inputs = runner.chunk_inputs(setup, cfg.campaign.seed, np.full(128, scenario), 128)
            raw = campaign.device_batch(setup.model, setup.fdd_params, setup.settings, *inputs, 1200, 0.01, 2,
                                        setup.kinds)
            for name, value in raw.items():
                value = np.asarray(value)
                assert np.array_equal(value, np.repeat(value[:1], len(value), axis=0), equal_nan=True), (scenario, name)

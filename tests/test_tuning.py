"""Worst-case search and tuning (Sections 5.3 and 6.2.1) against independent references.

The search space's traced scenarios against the table conversion ``to_scenario`` and the
Mach-limit speed against the Mach number it gives; gradients through the scan against central
finite differences (float64, conftest); the search on an analytic objective with
a known maximiser and on a plant case whose maximiser a brute-force grid locates; the gradient
search against Monte Carlo with the same number of simulations; tuning enlarging the detection
gap; no recompilation for new FDD numbers; configuration errors naming their key.
"""

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcfdd import cli, config
from mcfdd.analysis import build, campaign, scenarios, scoring, simulate, tuning, worst_case as wc
from mcfdd.plant import atmosphere
from mcfdd.workflows.common import CompileCounter, load_bank
from mcfdd.workflows.tune import training_set

DT_S = 0.01
# Open-loop doublets at one flight point without turbulence, below any stall load. The stall
# detector's residual is the LPV model's mismatch, which grows with the command amplitude, plus
# the filtered sensor noise, linear in its standard deviation: tau_f is largest at the corner of
# largest amplitude and noise (a brute-force grid confirms it in the test).
CORNER = """
[evaluation]
settle_s = 0.3

[space]
vcas_kt = 250.0
altitude_m = 3000.0
turbulence = "none"
noise_std_mm = [0.0, 0.05]
fault_kind = "none"
manoeuvre_kind = "ol_doublet"
amplitude = [0.2, 0.6]
t_start_s = 0.5
duration_s = 1.0
"""
BATCH = 2  # every corner evaluation runs in batches of two: one compilation per jitted function
# Fault-free open-loop steps and doublets at high speed: stall loads come and go.
STALL_TUNE = """
[tune]
iterations = 20
learning_rate = 0.1

[training]
scenarios = 32
design = "sobol"
seed = 1
duration_s = 6.0
precision = "float64"

[validation]
scenarios = 8
design = "lhs"
seed = 2
duration_s = 6.0
precision = "float64"

[evaluation]
settle_s = 0.3

[space]
vcas_kt = [300.0, 380.0]
altitude_m = [0.0, 1000.0]
hinge_scale = [1.0, 1.3]
noise_std_mm = [0.03, 0.07]
fault_kind = "none"
manoeuvre_kind = ["ol_step", "ol_doublet"]
amplitude = [0.4, 1.0]
t_start_s = [0.5, 2.0]
duration_s = [1.0, 2.5]
ramp_s = [0.1, 0.5]
"""


def load(cls, tmp_path, text, name="cfg.toml"):
    path = tmp_path / name
    path.write_text(text)
    return config.load(cls, path)


def make_problem(cfg: config.CampaignConfig, n_steps: int, detector="stall", bound="free"):
    model = build.plant_model(cfg.plant)
    bank, _ = load_bank(cfg.fdd, np.float64)
    r_arm = model.actuator.r_arm_m
    space = wc.SearchSpace.from_axes(cfg.space.axes, cfg.plant.aircraft.max_mach)
    return wc.Problem(model, build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm), space,
                      np.asarray(bank.nu), detector, bound, 0.05, n_steps, DT_S, 4, np.float64)


@pytest.fixture(scope="module")
def corner(tmp_path_factory):
    """The doublet problem over (noise_std_mm, amplitude), 3 s runs."""
    return make_problem(load(config.CampaignConfig, tmp_path_factory.mktemp("corner"), CORNER), 300)


@pytest.fixture(scope="module")
def tune_data(tmp_path_factory):
    cfg = load(config.TuneConfig, tmp_path_factory.mktemp("tune"), STALL_TUNE)
    model = build.plant_model(cfg.plant)
    bank, _ = load_bank(cfg.fdd, np.float64)
    r_arm = model.actuator.r_arm_m
    data, _ = training_set(cfg.campaign("training"), model, bank, np.float64)
    return cfg, bank, build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm), data


def test_traced_scenarios_match_the_table_conversion(tmp_path):
    cfg = load(config.CampaignConfig, tmp_path, """
[space]
vcas_kt = [200.0, 380.0]
altitude_m = [0.0, 12000.0]
turbulence = ["light", "moderate"]
hinge_scale = [0.8, 1.2]
noise_std_mm = [0.03, 0.07]
fault_kind = ["none", "leakage", "surface_damage", "disconnection", "jamming"]
leakage_size = [0.1, 0.3]
surface_damage_size = [0.3, 1.0]
fault_onset_s = [5.0, 10.0]
manoeuvre_kind = ["doublet", "sideslip"]
amplitude = [0.3, 1.0]
sideslip_deg = [-8.0, 8.0]
""")
    problem = make_problem(cfg, 10)
    space = problem.space
    box = space.box(np.float64)
    u, cats = wc.unit_points(space, "sobol", 32, 3)
    anchors = wc.anchors_at(problem, box, u, cats)
    # the column map: Vcas between its bound and the Mach-limit speed at the altitude
    alt = space.names.index("altitude_m")
    vcas = space.names.index("vcas_kt")
    x = np.asarray(jax.vmap(wc.to_columns, in_axes=(None, 0, 0))(box, anchors.altitude_m, jnp.asarray(u)))
    v_max = scenarios.mach_limit_speed_kt(x[:, alt], cfg.plant.aircraft.max_mach)
    np.testing.assert_allclose(x[:, vcas], 200.0 + u[:, vcas] * (np.minimum(380.0, v_max) - 200.0), rtol=1e-9)
    np.testing.assert_allclose(atmosphere.mach(v_max * atmosphere.KT_TO_M_S, x[:, alt]),
                               cfg.plant.aircraft.max_mach, rtol=1e-9)
    # the affine map away from the anchor against to_scenario of the table row
    u2 = np.random.default_rng(1).random(u.shape)
    x2 = np.asarray(jax.vmap(wc.to_columns, in_axes=(None, 0, 0))(box, anchors.altitude_m, jnp.asarray(u2)))
    traced, onset = jax.vmap(wc.scenario_at)(anchors, jnp.asarray(x2))
    table = space.table(cats, x2)
    reference = scenarios.to_scenario(table, np.float64)
    for got, want in zip(jax.tree.leaves(traced), jax.tree.leaves(reference)):
        np.testing.assert_allclose(np.asarray(got, dtype=float), np.asarray(want, dtype=float), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(onset), scenarios.fault_onsets(table, len(u2)))
    at_anchor = space.table(cats, np.asarray(anchors.x0))
    _, accept = scenarios.true_model(problem.nu_bank, at_anchor["fault_kind"], at_anchor["fault_size"])
    np.testing.assert_array_equal(np.asarray(anchors.accept), accept)
    assert accept.any()


def test_search_gradient_matches_central_differences(corner):
    """d(smooth tau_f)/du through the 3 s scan of plant, FDD and reductions (float64)."""
    box = corner.space.box(np.float64)
    u = np.array([[0.45, 0.55], [0.8, 0.3]])
    anchors = wc.anchors_at(corner, box, u, {})
    keys = simulate.run_keys(0, [0, 1])
    _, _, grad = wc.score_and_grad(corner.model, corner.fdd_params, corner.settings, box, anchors, jnp.asarray(u), keys,
                                   corner.temperature, detector="stall", bound="free", **corner.static())

    def f(v):
        columns, _ = wc.evaluate(corner.model, corner.fdd_params, corner.settings, box, anchors, jnp.asarray(v), keys,
                                 corner.temperature, **corner.static())
        return np.asarray(columns["smooth_log_stall_theta_max_free"])

    h = 1e-5
    fd = np.stack([(f(u + h * e) - f(u - h * e)) / (2 * h) for e in np.eye(2)], axis=1)
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-4)
    assert np.all(fd > 1e-3)


def test_tuning_gradient_matches_central_differences(tune_data):
    """d(smooth log gap)/d(log alpha, log beta, log gamma, log a) through the FDD-only scan (float64)."""
    _, _, params, settings, data = tune_data
    theta = tuning.initial(params, "stall")
    _, _, grad = tuning.gap_and_grad(theta, params, settings, data, 0.05, DT_S, "stall", True)

    def gap(th):
        b = tuning.evaluate(tuning.apply(params, "stall", th, True), settings, data, 0.05, DT_S, "stall")
        return float(b["soft_detect"] - b["soft_free"])

    h = 1e-5
    for name, g in zip(tuning.Tunable._fields, grad):
        plus = theta._replace(**{name: getattr(theta, name) + h})
        minus = theta._replace(**{name: getattr(theta, name) - h})
        assert float(g) == pytest.approx((gap(plus) - gap(minus)) / (2 * h), rel=1e-4, abs=1e-7), name


def test_ascent_finds_a_known_maximiser():
    """Interior optimum in two coordinates, a corner of the box in the third, from three starts."""
    target = jnp.array([0.3, 0.7])

    @jax.jit
    def fn(u):
        def score(v):
            return -jnp.sum((v[:2] - target) ** 2) + 0.5 * v[2]

        value, grad = jax.vmap(jax.value_and_grad(score))(u)
        return value, None, grad

    u0 = np.array([[0.9, 0.1, 0.2], [0.0, 0.0, 0.0], [0.5, 0.5, 0.9]])
    trace = wc.ascend(fn, u0, 150, 0.03)
    np.testing.assert_allclose(np.asarray(trace.params[-1]), np.tile([0.3, 0.7, 1.0], (3, 1)), atol=5e-3)
    assert np.all(np.asarray(trace.values[-1]) >= np.asarray(trace.values[0]))


def test_search_finds_the_plant_maximiser(corner):
    """From two interior starts the search reaches the corner that a brute-force grid finds (with much
    noise and little command, the other start may end on a lower local maximum: hence multi-start)."""
    grid = np.linspace(0.0, 1.0, 4)
    points = np.array(np.meshgrid(grid, grid, indexing="ij")).reshape(2, -1).T
    brute = wc.evaluate_points(corner, points, {}, simulate.run_keys(0, np.zeros(len(points), int)), BATCH)
    np.testing.assert_array_equal(points[np.argmax(brute.hard)], [1.0, 1.0])
    found = wc.gradient_search(corner, np.array([[0.2, 0.3], [0.6, 0.1]]), {}, simulate.run_keys(0, [0, 0]), 15, 0.1)
    best = np.argmax(found[-1].hard)
    np.testing.assert_allclose(found[-1].u[best], [1.0, 1.0])
    assert found[-1].hard[best] == pytest.approx(brute.hard.max(), rel=1e-9)
    assert np.all(found[-1].hard >= found[0].hard)


def test_gradient_search_at_least_as_bad_as_monte_carlo_on_equal_budget(corner):
    screening, starts, iterations = 8, 2, 5
    screened = wc.sample(corner, "sobol", screening, 0, BATCH)
    _, u0, cats, keys = wc.starts_from(screened, starts, "free", 0)
    found = wc.gradient_search(corner, u0, cats, keys, iterations, 0.1)
    gradient = max(screened.hard.max(), max(p.hard.max() for p in found))
    budget = wc.budget(screening, starts, iterations)
    assert budget == screening + sum(len(p.hard) for p in found)
    monte_carlo = wc.sample(corner, "random", budget, 1, BATCH)
    assert gradient >= monte_carlo.hard.max()
    assert gradient > screened.hard.max()


def test_tuning_enlarges_the_stall_detection_gap(tune_data):
    cfg, _, params, settings, data = tune_data
    assert int(np.asarray(data.plant.stall).any(axis=1).sum()) >= 3

    def fn(theta):
        return tuning.gap_and_grad(theta, params, settings, data, 0.05, DT_S, "stall", True)

    result = tuning.tune(fn, tuning.initial(params, "stall"), cfg.tune.iterations, cfg.tune.learning_rate)
    before = tuning.evaluate(params, settings, data, 0.05, DT_S, "stall")
    best = result.bounds[tuning.best_iterate(result)]
    gap_before = tuning.normalised_gap(float(before["tau_f"]), float(before["tau_d"]))
    gap_after = tuning.normalised_gap(best["tau_f"], best["tau_d"])
    assert gap_after > gap_before + 0.15
    assert result.gaps[-1] > result.gaps[0]
    # a threshold inside a positive gap sits at the margin; otherwise the training scan decides
    assert tuning.place_threshold(1.0, 2.0, 0.2) == pytest.approx(1.2)
    taus = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    assert tuning.place_threshold(2.0, 1.0, 0.2, taus, [3, 0, 0, 0, 0], [0, 0, 0, 1, 2]) == 3.0


def test_new_fdd_numbers_do_not_recompile(tune_data, corner):
    """A second call with new FDD numbers makes no XLA compilation (JAX's own compile events)."""
    cfg, bank, params, settings, data = tune_data
    with CompileCounter() as fresh:
        jax.jit(lambda x: x * 3.0 + 1.0)(np.arange(7.0))
    assert fresh.count >= 1, "the counter sees every XLA compilation"
    theta = tuning.initial(params, "stall")
    other = config.parse(config.FddConfig, {"stall": {"tau_deg": 2.0, "pole_1_s": 3.0,
                                                      "evaluator": {"alpha": 2.0, "beta": 0.5, "gamma_1_s": 1.0}}})
    new_params = build.fdd_params(other, bank, cfg.plant.actuator.r_arm_m)
    tuning.gap_and_grad(theta, params, settings, data, 0.05, DT_S, "stall", True)
    moved = theta._replace(log_gamma=theta.log_gamma + 1.0)  # an eager op of its own: outside the counter
    with CompileCounter() as second:
        tuning.gap_and_grad(moved, new_params, settings, data, 0.07, DT_S, "stall", True)
    assert second.count == 0

    tuning.threshold_scan(params, settings, data, np.array([1e-3, 2e-3]), DT_S, "stall", "signal")
    with CompileCounter() as second:
        tuning.threshold_scan(new_params, settings, data, np.array([3e-3, 4e-3]), DT_S, "stall", "signal")
    assert second.count == 0

    # a campaign batch with the FDD before and after tuning: one compilation
    cols, n = build.design(cfg.campaign("validation"))
    scen = scenarios.to_scenario(cols, np.float64)
    truth = scoring.Truth(np.asarray(scenarios.fault_onsets(cols, n)), np.zeros((n, bank.k0.shape[0]), bool),
                          np.zeros(n, np.int32))
    args = (build.settings(cfg.evaluation, cfg.plant.actuator.r_arm_m), scen, truth, simulate.run_keys(2, range(n)),
            200, DT_S, 4, (5, 6))
    model = build.plant_model(cfg.plant)
    campaign.run_batch(model, params, *args)
    with CompileCounter() as second:
        campaign.run_batch(model, new_params, *args)
    assert second.count == 0

    box = corner.space.box(np.float64)
    u = np.array([[0.5, 0.5], [0.2, 0.1]])
    anchors = wc.anchors_at(corner, box, u, {})
    keys = simulate.run_keys(0, [0, 1])
    r_arm = cfg.plant.actuator.r_arm_m
    wc.evaluate(corner.model, corner.fdd_params, corner.settings, box, anchors, jnp.asarray(u), keys, 0.05,
                **corner.static())
    with CompileCounter() as second:
        wc.evaluate(corner.model, build.fdd_params(other, load_bank(other, np.float64)[0], r_arm), corner.settings, box,
                    anchors, jnp.asarray(u), keys, 0.05, **corner.static())
    assert second.count == 0


def test_fragment_round_trip_and_campaign_option(tmp_path):
    fdd = config.parse(config.FddConfig, {"stall": {"tau_deg": 3.25, "evaluator": {"alpha": 6.0, "beta": 0.16}},
                                          "loe": {"tau": 0.07}})
    path = tmp_path / "tuned_fdd.toml"
    path.write_text(config.fdd_fragment(fdd, "tuned\nby a test"))
    assert config.load_fdd_fragment(path) == fdd
    campaign_cfg = tmp_path / "c.toml"
    campaign_cfg.write_text("[campaign]\nscenarios = 4\n[fdd.stall]\ntau_deg = 9.0\n[space]\nkci_scale = [0.9, 1.1]\n")
    args = argparse.Namespace(config=str(campaign_cfg), scenarios=None, seed=None, chunk_size=None, fdd=str(path))
    assert cli._campaign_config(args).fdd == fdd
    args.fdd = None
    assert cli._campaign_config(args).fdd.stall.tau_deg == 9.0


@pytest.mark.parametrize("text, key", [
    ("[fdd]\nbank = 'default'\n[extra]\nx = 1\n", "extra"),
    ("[fdd.stall.evaluator]\ngama_1_s = 1.0\n", "fdd.stall.evaluator.gama_1_s"),
    ("[fdd.loe]\ntau = -1.0\n", "fdd.loe.tau"),
    ("[fdd.stall]\nidentification = 'both'\n", "fdd.stall.identification"),
])
def test_bad_fragment_keys_are_named(tmp_path, text, key):
    path = tmp_path / "f.toml"
    path.write_text(text)
    with pytest.raises(config.ConfigError, match=key.replace(".", r"\.")):
        config.load_fdd_fragment(path)


WORST = """
[search]
{search}
[space]
vcas_kt = [200.0, 300.0]
fault_kind = {faults}
"""


@pytest.mark.parametrize("cls, text, key", [
    (config.WorstCaseConfig, WORST.format(search="stepsize = 0.1", faults='"none"'), "search.stepsize"),
    (config.WorstCaseConfig, WORST.format(search="starts = 8\nscreening = 4", faults='"none"'), "search.starts"),
    (config.WorstCaseConfig, WORST.format(search="bound = 'free'", faults='["none", "leakage"]'), "space.fault_kind"),
    (config.WorstCaseConfig, WORST.format(search="detector = 'loe'\nbound = 'detect'", faults='["none", "leakage"]'),
     "space.fault_kind"),
    (config.WorstCaseConfig, WORST.format(search="temperature = 0.0", faults='"none"'), "search.temperature"),
    (config.WorstCaseConfig, WORST.format(search="screening_max = 32", faults='"none"'), "search.screening_max"),
    (config.WorstCaseConfig, WORST.format(search="patience = 0", faults='"none"'), "search.patience"),
    (config.TuneConfig, "[tune]\nmargin = 1.5\n", "tune.margin"),
    (config.TuneConfig, "[tune]\ndetector = 'bank'\n", "tune.detector"),
    (config.TuneConfig, "[training]\nseed = 3\n[validation]\nseed = 3\n", "validation.seed"),
    (config.TuneConfig, "[training]\ngrid = ['vcas_kt']\n[space]\nvcas_kt = 250.0\n", r"training.grid\[0\]"),
])
def test_bad_search_and_tune_keys_are_named(tmp_path, cls, text, key):
    with pytest.raises(config.ConfigError, match=key.replace("search.", r"search\.").replace("tune.", r"tune\.")):
        load(cls, tmp_path, text)


def test_shipped_configs_parse():
    folder = Path(__file__).resolve().parents[1] / "configs"
    for name, cls in (("worst_case_stall.toml", config.WorstCaseConfig),
                      ("worst_case_stall_detect.toml", config.WorstCaseConfig),
                      ("tune_stall.toml", config.TuneConfig), ("tune_loe.toml", config.TuneConfig)):
        cfg = config.load(cls, folder / name)
        assert isinstance(cfg, cls)

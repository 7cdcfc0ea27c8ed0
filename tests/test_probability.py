"""mcfdd probability: campaign runs as points of a standard-normal space, the events' margins, the command.

- the coordinates reproduce the design's scenarios and the campaign's truth (NumPy ``to_scenario``
  and ``true_model`` are the references), on every fault kind and manoeuvre family of SMALL;
- the limit state at a campaign run's coordinates and normals gives the campaign's own margins,
  whose sign is the campaign's flag, on 2,048 runs and every event (short horizon, lowered thresholds);
- exposure weights, the per-flight-hour rate and the [probability] table's errors;
- the command end to end on a lowered threshold: subset simulation against plain Monte Carlo
  (both intervals), the same numbers for the same seed, the files it writes;
- the per-airframe view: corners at the configured quantiles, the worst one against plain Monte Carlo
  of the space with those axes fixed there, and the quantile over drawn airframes as its order statistic.
"""

import subprocess
import sys
import tomllib
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy.stats import norm

import mcfdd
from helpers import SMALL, compiles
from mcfdd import columns, config
from mcfdd.analysis import build, campaign, probability as normal_space, rare, scenarios, simulate
from mcfdd.workflows import probability as workflow
from mcfdd.workflows.common import precision

LOWERED = """
[fdd.loe]
load_gate = "fault_free"
excitation_floor_deg = 0.15
excitation_noise_factor = 0.0
detection_tau = 0.004
detection_contrast = 0.0
detection_confirm_s = 0.0
confirm_s = 0.2
[fdd.stall]
tau_deg = 0.3
[fdd.stall.signal]
command_min_deg = 0.5
position_min_deg = 0.5
error_min_deg = 0.02
window_s = 0.02
rate_min_deg_s = 0.5
[fdd.stall.model]
tau_deg = 400.0
"""  # thresholds lowered until every event happens in some runs of SMALL and not in others


def small(n: int, duration: float = 2.5, extra: str = "") -> config.CampaignConfig:
    data = tomllib.loads(SMALL.format(n=n) + extra)
    data["campaign"]["duration_s"] = duration
    return config.parse(config.CampaignConfig, data)


def _rows_args(cfg, cols, rows, dtype=np.float32):
    """The stratum arguments of each row, stacked (leading axis rows)."""
    discrete = [a.name for a in cfg.space.axes if a.kind in ("values", "choices")]
    each = [normal_space.stratum_args(cfg.space.axes, {k: cols[k][r] for k in discrete}, dtype) for r in rows]
    return jax.tree.map(lambda *x: np.stack(x), *each)


def test_coordinates_give_the_designs_scenarios_and_truth():
    cfg = small(512)
    cols, n = build.design(cfg)
    problem, _ = workflow.problem_of(cfg)
    space, nu = problem.space, problem.nu_bank
    rows = np.arange(n)
    z = np.stack([normal_space.coordinates_of(space, cols, r) for r in rows])
    args = _rows_args(cfg, cols, rows)

    def one(zr, a):
        scenario, onset = normal_space.scenario_at(space, normal_space.values_at(space, zr, a), a)
        return scenario, normal_space.truth_at(nu, scenario.fault, onset, a)

    with precision(cfg.campaign.precision):
        got, truth = jax.vmap(one)(jnp.asarray(z, jnp.float32), args)
    ref = scenarios.to_scenario(cols, np.float32)
    for path, a, b in zip(jax.tree_util.tree_leaves_with_path(got), jax.tree.leaves(got), jax.tree.leaves(ref)):
        a, b = np.asarray(a, float), np.asarray(b, float)
        assert np.array_equal(np.isfinite(a), np.isfinite(b)), path[0]
        np.testing.assert_allclose(a[np.isfinite(b)], b[np.isfinite(b)], rtol=2e-5, atol=1e-6, err_msg=str(path[0]))
    nearest, accept = scenarios.true_model(nu, cols["fault_kind"], cols["fault_size"])
    assert set(cols["fault_kind"]) == set(columns.FAULT_KINDS)
    np.testing.assert_array_equal(np.asarray(truth.nearest), nearest)
    np.testing.assert_array_equal(np.asarray(truth.accept), accept)
    onset = scenarios.fault_onsets(cols, n)
    np.testing.assert_allclose(np.asarray(truth.onset_s), onset, rtol=1e-6)


def test_truth_matches_true_model_on_dense_size_sweeps():
    cfg = small(8)
    problem, _ = workflow.problem_of(cfg)
    nu = problem.nu_bank
    sizes = ((np.arange(2000) + 0.37) / 2000).astype(np.float32)  # off the ties halfway between models
    for kind in ("leakage", "surface_damage", "disconnection", "jamming", "none"):
        args = normal_space.stratum_args(cfg.space.axes, {"fault_kind": kind}, np.float32)
        values = {"leakage_size": sizes, "surface_damage_size": sizes}

        def one(x):
            scenario, onset = normal_space.scenario_at(problem.space, {"leakage_size": x, "surface_damage_size": x},
                                                       args)
            return normal_space.truth_at(nu, scenario.fault, onset, args)

        truth = jax.vmap(one)(values["leakage_size"])
        size = sizes.astype(float) if kind in ("leakage", "surface_damage") else np.zeros_like(sizes, float)
        nearest, accept = scenarios.true_model(nu, np.full(len(sizes), kind), size)
        np.testing.assert_array_equal(np.asarray(truth.nearest), nearest, err_msg=kind)
        np.testing.assert_array_equal(np.asarray(truth.accept), accept, err_msg=kind)


def test_run_normals_is_the_run_its_key_draws():
    """Given the normals a key draws, a run is that key's run: plant and FDD histories equal to the bit."""
    cfg = small(8, duration=2.5)
    with precision(cfg.campaign.precision):
        cols, _ = build.design(cfg)
        problem, _ = workflow.problem_of(cfg)
        space = problem.space
        for i in (0, 5):
            scenario = jax.tree.map(lambda x: x[i], scenarios.to_scenario(cols, np.float32))
            key = simulate.run_keys(cfg.campaign.seed, [i])[0]
            ref = simulate.run(problem.model, problem.fdd_params, scenario, key, space.n_steps, problem.dt_s,
                               problem.substeps, problem.kinds)[1]
            init, steps = normal_space.campaign_normals(key, space.n_steps, (space.init_dim, space.step_dim))
            got = simulate.run_normals(problem.model, problem.fdd_params, scenario, init, steps, problem.dt_s,
                                       problem.substeps, problem.kinds)[1]
            for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(ref)):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_margin_sign_equals_the_campaigns_flag_on_2048_runs(tmp_path):
    """A campaign's runs replayed from their normals: each margin's sign is the flag of the same run's
    scoring, and margins and flags are the campaign's up to rounding (normals given to the scan are
    compiled apart from the campaign's, which draws them inside it), also at the runs' coordinates."""
    cfg = small(2048, duration=2.5, extra=LOWERED)
    result = mcfdd.run_campaign(cfg, out=tmp_path / "c", progress=False)
    table = result.scenarios.sort_values("scenario_id", ignore_index=True)
    with precision(cfg.campaign.precision):
        replay, moved = _replayed(cfg)
    for event, (flag, margin, kinds) in normal_space.EVENTS.items():
        rows = np.isin(table["fault_kind"], kinds)
        theirs, flags = table[margin].to_numpy()[rows], table[flag].to_numpy(bool)[rows]
        assert flags.any() and (~flags).any(), f"{event}: the test needs runs of both signs"
        finite = np.isfinite(theirs)
        atol = 1e-3 * np.max(np.abs(theirs[finite]))
        for ours, own in ((replay[margin][rows], replay[flag][rows]), (moved[margin][rows], moved[flag][rows])):
            g = np.where(np.isnan(ours), -np.inf, ours)
            np.testing.assert_array_equal(g > 0, own, err_msg=event)  # the sign is the run's own flag, always
            np.testing.assert_array_equal(np.isfinite(ours), finite, err_msg=event)
            np.testing.assert_allclose(ours[finite], theirs[finite], rtol=0, atol=atol, err_msg=event)
            flipped = (g > 0) != flags
            assert np.all(np.abs(theirs[flipped]) <= atol) and flipped.mean() <= 0.005, event


def _replayed(cfg):
    """The scoring columns of a campaign's runs replayed from their normals: with the campaign's
    scenarios and truth, and at the runs' coordinates."""
    cols, n = build.design(cfg)
    problem, _ = workflow.problem_of(cfg)
    space, dtype = problem.space, np.float32
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(cfg.campaign.seed), i))(jnp.arange(n, dtype=jnp.uint32))
    init, steps = jax.vmap(lambda k: normal_space.campaign_normals(k, space.n_steps, (space.init_dim, space.step_dim))
                           )(keys)
    nearest, accept = scenarios.true_model(problem.nu_bank, cols["fault_kind"], cols["fault_size"])
    truth = normal_space.scoring.Truth(scenarios.fault_onsets(cols, n).astype(dtype), accept, nearest)

    @partial(jax.jit, compiler_options=campaign.XLA_CPU_OPTIONS)  # as the campaign compiles its runs
    def exact(scenario, truth, init, steps):
        return jax.vmap(lambda *a: normal_space.run_columns(problem, *a))(scenario, truth, init, steps)

    z = np.stack([normal_space.coordinates_of(space, cols, r) for r in range(n)])
    u = np.concatenate([z, np.asarray(init), np.asarray(steps).reshape(n, -1)], axis=1).astype(dtype)
    args = _rows_args(cfg, cols, np.arange(n))

    @jax.jit
    def moved(u, args):
        def one(row, a):
            zr, i0, st = space.split(row)
            scenario, onset = normal_space.scenario_at(space, normal_space.values_at(space, zr, a), a)
            return normal_space.run_columns(problem, scenario, normal_space.truth_at(problem.nu_bank, scenario.fault,
                                                                                      onset, a), i0, st)

        return jax.vmap(one)(u, args)

    replay = jax.tree.map(np.asarray, exact(scenarios.to_scenario(cols, dtype), truth, init, steps))
    at_u = jax.tree.map(np.asarray, moved(u, args))
    return replay, at_u


def test_exposure_weights_follow_the_table_and_its_sources():
    cfg = small(8, extra='[probability.exposure]\nmanoeuvre_kind = { doublet = 0.5 }\n')
    strata = normal_space.strata(cfg.space.axes, ("none",))
    assert len(strata) == 3 and {s["fault_kind"] for s in strata} == {"none"}
    w = workflow.exposure_weights(cfg, strata)
    np.testing.assert_allclose(w, [0.5, 0.25, 0.25])
    two = config.replace(cfg, {"space.turbulence": ["light", "severe"]})
    s2 = normal_space.strata(two.space.axes, ("none",))
    w2 = workflow.exposure_weights(two, s2)
    light = sum(wi for wi, s in zip(w2, s2) if s["turbulence"] == "light")
    assert light == pytest.approx(9e-3 / (9e-3 + 1e-5))  # MIL-F-8785C shares, renormalised


def test_per_flight_hour_is_the_weighted_sum_of_the_strata():
    es = [rare.Estimate("mc", p, 0.1, (p * 0.8, p * 1.2), 0.95, "normal", 100, 10) for p in (1e-4, 4e-4)]
    rate = rare.per_flight_hour(es, [0.75, 0.25], 25.0)
    assert rate.estimate == pytest.approx((0.75 * 1e-4 + 0.25 * 4e-4) * 3600 / 25.0)


@pytest.mark.parametrize("table, key", [("event = 'crash'", "probability.event"),
                                        ("method = 'mcmc'", "probability.method"),
                                        ("[probability.exposure]\nturbulence = { stormy = 0.1 }",
                                         "probability.exposure.turbulence.stormy"),
                                        ("budget = 0", "probability.budget"),
                                        ("method = 'importance'\nstarts = 300", "probability.starts"),
                                        ("starts_from = 'chains'", "probability.starts_from"),
                                        ("spread = 0", "probability.spread")])
def test_bad_probability_table_is_one_line_naming_the_key(tmp_path, table, key):
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.format(n=8) + "\n[probability]\n" + table + "\n")
    proc = subprocess.run([sys.executable, "-m", "mcfdd.cli", "probability", str(path), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and key in proc.stderr, proc.stderr


def test_event_without_its_runs_is_a_config_error():
    cfg = small(8)
    cfg = config.replace(cfg, {"space.fault_kind": ["jamming"]})
    with pytest.raises(config.ConfigError, match="probability.event"):
        mcfdd.probability(cfg, progress=False)


FAST = """
[probability]
event = "false_alarm"
samples = 200
p0 = 0.1
chunk = 100
budget = 2000
target_cov = 0.5
"""


def tiny(extra: str = "") -> config.CampaignConfig:
    data = tomllib.loads(SMALL.format(n=8) + LOWERED + FAST + extra)
    data["campaign"]["duration_s"] = 1.2
    data["space"]["fault_kind"] = "none"
    data["space"]["manoeuvre_kind"] = "doublet"
    return config.parse(config.CampaignConfig, data)


@pytest.fixture(scope="module")
def tiny_mc():
    """Plain Monte Carlo of 4,000 runs of the tiny space: the reference of the estimators."""
    return mcfdd.probability(config.replace(tiny(), {"probability.method": "mc", "probability.samples": 4000,
                                                     "probability.budget": 4000, "probability.repeats": 1}),
                             progress=False)


def test_subset_simulation_agrees_with_monte_carlo_and_repeats_to_the_bit(tmp_path, tiny_mc):
    cfg = tiny()
    subset = mcfdd.probability(cfg, progress=False)
    again = mcfdd.probability(cfg, progress=False)
    assert subset.overall.estimate == again.overall.estimate
    np.testing.assert_array_equal(subset.failure_points, again.failure_points)
    mc = tiny_mc
    lo, hi = mc.overall.interval
    assert lo <= subset.overall.estimate <= hi
    assert subset.overall.interval[0] <= mc.overall.estimate <= subset.overall.interval[1]
    importance = mcfdd.probability(config.replace(cfg, {"probability.method": "importance"}), progress=False)
    assert importance.overall.interval[0] <= mc.overall.estimate <= importance.overall.interval[1]
    assert subset.rate.estimate == pytest.approx(subset.overall.estimate * 3600 / (1.2 - 0.5))
    files = subset.save(tmp_path)
    assert {p.name for p in files} >= {"strata.parquet", "failures.parquet", "summary.md"}
    failures = pd.read_parquet(tmp_path / "failures.parquet")
    assert (failures["margin"] > 0).all() and len(failures) == len(subset.failure_points)
    plant, fdd = subset.replay(0)  # a failure point replayed: its histories
    assert plant.u_m.shape == (cfg.campaign.n_steps,)


def test_importance_sampling_from_subset_failure_points_agrees_with_monte_carlo_to_the_bit(tiny_mc):
    """starts_from "subset": the searches start at a subset simulation run's failure points (inside F: feasible
    steps), the mixture widened (spread 1.5, where a design point converges); the interval holds the Monte
    Carlo estimate, the run repeats to the bit, compiles nothing the second time and counts the subset run's
    simulations; a run without a converged design point (the FDD's margin is kinked: benchmarks/RESULTS.md)
    says so and is plain Monte Carlo, hits / n."""
    cfg = config.replace(tiny(), {"probability.method": "importance", "probability.starts_from": "subset",
                                  "probability.start_samples": 100, "probability.starts": 4,
                                  "probability.iterations": 5, "probability.spread": 1.5, "probability.samples": 400,
                                  "probability.budget": 4000})
    one = mcfdd.probability(cfg, progress=False)
    assert compiles(lambda: mcfdd.probability(cfg, progress=False)) == 0
    again = mcfdd.probability(cfg, progress=False)
    assert (one.overall.estimate, one.overall.cov) == (again.overall.estimate, again.overall.cov)
    np.testing.assert_array_equal(one.failure_points, again.failure_points)
    lo, hi = one.overall.interval
    assert lo <= tiny_mc.overall.estimate <= hi
    plain = ~one.runs["reached"].astype(bool)
    np.testing.assert_allclose(one.runs["estimate"][plain], one.runs["hits"][plain] / 400, rtol=1e-6)
    # each run: a subset run of 100 per level (at least 100) + 4 checks + 5 x 4 x 7 search + 4 + 400 samples
    assert (one.runs["simulations"] >= 100 + 4 + 140 + 4 + 400).all()
    assert (one.runs["hits"] > 0).all()


def test_missed_detection_is_conditional_on_the_runs_that_must_be_detected():
    data = tomllib.loads(SMALL.format(n=8) + LOWERED + FAST.replace('"false_alarm"', '"missed_detection"'))
    data["campaign"]["duration_s"] = 2.5
    data["space"].update(fault_kind="leakage", manoeuvre_kind="doublet", leakage_size=[0.0, 0.3])
    data["probability"].update(method="mc", samples=200, budget=200)
    cfg = config.parse(config.CampaignConfig, data)
    result = mcfdd.probability(cfg, progress=False)
    must = normal_space.must_fraction(workflow.problem_of(cfg)[0].nu_bank, "leakage", 0.0, 0.3)
    assert 0.0 < must < 1.0  # small leaks are nearest to the nominal model: not must-detect
    assert result.rate is None and set(result.groups) == {"leakage"}
    assert result.overall.n_simulations == 4 * 200  # four runs (repeats), their hits pooled
    assert result.overall.estimate == pytest.approx(result.overall.hits / 800 / must)
    assert result.overall.interval[1] == pytest.approx(result.strata["hi"].iloc[0])


def test_strata_share_one_compiled_program():
    one = config.replace(tiny(), {"probability.samples": 100, "probability.budget": 100, "probability.repeats": 2})
    two = config.replace(one, {"space.turbulence": ["light", "moderate"]})
    mcfdd.probability(config.replace(one, {"probability.seed": 1}), progress=False)  # the rest is compiled now
    per_run = compiles(lambda: mcfdd.probability(one, progress=False))  # a new config, a new g: its programs again
    assert per_run >= 1
    assert compiles(lambda: mcfdd.probability(one, progress=False)) == 0  # the process keeps the last limit state
    assert compiles(lambda: mcfdd.probability(two, progress=False)) == per_run


AIRFRAME = """
[probability.airframe]
axes = ["kci_scale", "kd_scale", "supply_pressure_scale"]
view = "corner"
corner = 0.95
"""


def test_per_airframe_view_at_the_worst_corner_and_as_a_quantile():
    """kci_scale and kd_scale vary (supply pressure does not: left out). P(FA | corner) by plain Monte Carlo
    against plain Monte Carlo of the space with those two axes fixed at the worst corner's values."""
    cfg = config.replace(tiny(AIRFRAME), {"space.kci_scale": [0.8, 1.2], "space.kd_scale": [0.5, 1.5],
                                          "probability.method": "mc", "probability.samples": 1000,
                                          "probability.budget": 1000, "probability.repeats": 1})
    result = mcfdd.probability(cfg, progress=False)
    frame, view = result.airframes, result.airframe
    r = norm.ppf(0.95)
    assert len(frame) == 4 and view.points.tolist() == (r * np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]])).tolist()
    unit = norm.cdf(view.points)
    expected = {"kci_scale": 0.8 + 0.4 * unit[:, 0], "kd_scale": 0.5 + 1.0 * unit[:, 1]}
    for name, values in expected.items():
        np.testing.assert_allclose(frame[name], values, rtol=1e-6)
    worst = int(np.argmax(frame["estimate"]))
    assert view.worst == worst and result.strata["airframe_worst"].iloc[0] == frame["estimate"].max()
    assert frame["estimate"].max() > frame["estimate"].min()  # the servo parameters matter here
    assert result.airframe_rate.estimate == pytest.approx(frame["estimate"].max() * 3600 / (1.2 - 0.5))
    fixed = config.replace(cfg, {"space.kci_scale": float(frame["kci_scale"][worst]),
                                 "space.kd_scale": float(frame["kd_scale"][worst]), "probability.samples": 4000,
                                 "probability.budget": 4000, "probability.airframe.view": "none"})
    direct = mcfdd.probability(fixed, progress=False).overall
    lo, hi = view.estimates[worst].interval
    assert lo <= direct.estimate <= hi and direct.interval[0] <= view.estimates[worst].estimate <= direct.interval[1]
    assert any("worst of 4 corners" in line for line in result.lines())
    spread = mcfdd.probability(config.replace(cfg, {"probability.airframe.view": "quantile",
                                                    "probability.airframe.points": 40,
                                                    "probability.airframe.quantile": 0.5}), progress=False)
    values = np.sort(spread.airframes["estimate"])
    assert spread.airframe.value == values[19]  # the 20th of 40: the median order statistic
    assert spread.airframe.interval[0] <= spread.airframe.value <= spread.airframe.interval[1]
    assert "airframe_quantile" in spread.strata and any("0.5 quantile" in line for line in spread.lines())

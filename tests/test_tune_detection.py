"""Tuning of the LOE detection level (issue 22): the smooth tau_f / tau_d against the hard monitors, the
must-detect predicate, the Pareto set and the chosen threshold against brute force, bad config keys, the
tuner on the full aircraft, and the command end to end at a tiny size.

The smooth bounds are nested log-sum-exps (over a run's samples, then over runs) at temperature T,
so closed-form bounds hold: the smooth maximum of n values lies in [max, max + T log n] and the
smooth minimum in [min - T log n, min]; with a run's smooth statistic at most T log(steps) above its
hard one, tau_f <= smooth tau_f <= tau_f + T (log steps + log runs) and tau_d - T log runs <=
smooth tau_d <= tau_d + T log steps.
"""

import math
import re
import tomllib
from pathlib import Path

import jax
import numpy as np
import pytest
import tomli_w

from mcfdd import cli, config
from mcfdd.analysis import build, detection_tuning as dt, metrics
from mcfdd.fdd import system
from mcfdd.workflows.common import load_bank, precision
from mcfdd.workflows.tune import training_set

DT_S = 0.01
TINY = """
[tune]
detector = "loe"
level = "detection"
iterations = {iterations}
temperature = 0.005
threshold_candidates = 4
must_detect = "all"

[training]
scenarios = 8
grid = ["fault_kind"]
seed = 3
duration_s = {duration}
precision = "float64"

[validation]
scenarios = 8
grid = ["fault_kind"]
seed = 4
duration_s = {duration}
precision = "float64"

[evaluation]
settle_s = 0.5

[fdd.loe]
excitation_noise_factor = 2.5
excitation_floor_deg = 0.05
detection_tau = 0.04
detection_contrast = 0.03
detection_confirm_s = 0.2

[plant.aircraft]
model = "{model}"

[space]
vcas_kt = [300.0, 350.0]
altitude_m = [1000.0, 2000.0]
noise_std_mm = [0.03, 0.07]
fault_kind = ["none", "leakage", "surface_damage", "disconnection"]
fault_onset_s = [1.0, 1.5]
manoeuvre_kind = "doublet"
amplitude = [0.7, 1.0]
t_start_s = [1.5, 2.0]
duration_s = [1.0, 1.5]
"""


def tiny(tmp_path, iterations=1, duration=5.0, model="roll_axis"):
    path = tmp_path / "tune.toml"
    path.write_text(TINY.format(iterations=iterations, duration=duration, model=model))
    return path


def problem(cfg):
    model = build.plant_model(cfg.plant)
    bank, _ = load_bank(cfg.fdd, np.float64)
    r_arm = model.actuator.r_arm_m
    data, n = training_set(cfg.campaign("training"), model, bank, np.float64)
    return build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm), data, n


@pytest.fixture(scope="module")
def roll(tmp_path_factory):
    cfg = config.load(config.TuneConfig, tiny(tmp_path_factory.mktemp("roll")))
    params, settings, data, n = problem(cfg)
    columns = jax.device_get(dt.evaluate_columns(params, settings, data, DT_S))
    return cfg, params, settings, data, n, columns


def test_smooth_bounds_tend_to_the_hard_monitors_as_temperature_falls(roll):
    cfg, params, settings, data, n, columns = roll
    must = np.array(columns["must_detect"])
    assert must.sum() >= 2
    steps = cfg.training.n_steps
    errors = []
    for temperature in (0.02, 0.002, 0.0002):
        b = jax.device_get(dt.evaluate(params, settings, data, must, temperature, DT_S))
        assert b["tau_f"] - 1e-12 <= b["soft_free"] <= b["tau_f"] + temperature * (math.log(steps) + math.log(n))
        assert (b["tau_d"] - temperature * math.log(n) - 1e-12 <= b["soft_detect"]
                <= b["tau_d"] + temperature * math.log(steps) + 1e-12)
        errors.append((abs(b["soft_free"] - b["tau_f"]), abs(b["soft_detect"] - b["tau_d"])))
    assert np.all(np.diff(np.array(errors), axis=0) <= 1e-12)
    assert max(errors[-1]) < 3e-3


def test_tau_d_is_taken_over_the_must_detect_runs_only(roll):
    cfg, params, settings, data, n, columns = roll
    must = np.array(columns["must_detect"])
    stat = -np.asarray(columns["missed_margin"])
    for mask in (must, must & (np.arange(n) % 2 == 0), must & (np.arange(n) % 2 == 1)):
        if not mask.any():
            continue
        b = jax.device_get(dt.evaluate(params, settings, data, mask, 1e-4, DT_S))
        assert b["tau_d"] == pytest.approx(np.min(stat[mask]), abs=1e-12)
        assert b["soft_detect"] == pytest.approx(np.min(stat[mask]), abs=1e-3)
        assert b["missed"] == np.sum(np.asarray(columns["missed"]) & mask)
        # tau_f and the false alarms do not depend on the mask: every valid run counts
        assert b["tau_f"] == pytest.approx(np.max(np.asarray(columns["false_alarm_margin"])), abs=1e-12)
        assert b["false_alarms"] == np.sum(columns["false_alarm"])


def test_must_detect_predicate_by_kind_load_and_separability():
    rng = np.random.default_rng(0)
    n = 200
    kinds = rng.choice(["none", "leakage", "surface_damage", "disconnection"], n)
    design = {"fault_kind": kinds, "fault_size": rng.uniform(0.1, 1.0, n), "kci_scale": rng.uniform(0.97, 1.03, n),
              "supply_pressure_scale": rng.uniform(0.98, 1.02, n), "hinge_scale": rng.uniform(0.9, 1.1, n)}
    peak = rng.uniform(0.0, 0.8, n)
    columns = {"must_detect": (kinds != "none") & (rng.uniform(size=n) < 0.9), "peak_load_fraction": peak}
    ranges = metrics.uncertainty_ranges(design)
    mask = dt.must_detect_mask(columns, design, ranges, "all", ("disconnection",), 0.4)
    assert np.array_equal(mask, columns["must_detect"] & (kinds == "disconnection") & (peak >= 0.4))
    separable = np.asarray(metrics.detectability_columns(design, peak, ranges)["separable"])
    both = dt.must_detect_mask(columns, design, ranges, "separable", (), 0.0)
    assert np.array_equal(both, columns["must_detect"] & separable)
    assert 0 < both.sum() < columns["must_detect"].sum()


def test_pareto_set_and_choice_against_brute_force():
    rng = np.random.default_rng(1)
    fa, missed, time = rng.integers(0, 4, 30), rng.integers(0, 4, 30), rng.choice([1.0, 2.0, np.nan], 30)
    front = dt.pareto(fa, missed, time)
    t = np.nan_to_num(time, nan=np.inf)
    for i in range(30):
        dominated = any(fa[j] <= fa[i] and missed[j] <= missed[i] and t[j] <= t[i]
                        and (fa[j], missed[j], t[j]) != (fa[i], missed[i], t[i]) for j in range(30))
        assert front[i] == (not dominated)
    scales = np.array([0.5, 0.7, 1.0, 1.4, 2.0])
    assert dt.choose(scales, [3, 0, 1, 0, 0], 1.1) == pytest.approx(1.4 * 1.1)
    assert dt.choose(scales, [0, 0, 0, 0, 0], 1.0) == pytest.approx(0.5)
    assert dt.choose(scales, [2, 2, 1, 1, 1], 1.2) == pytest.approx(2.0 * 1.2)


def reference_within(scales, fa, missed, time, n_must, limit):
    """The miss-limited choice written out: filter, then the best by the rule's order, one key at a time."""
    t = [math.inf if math.isnan(x) else x for x in time]
    idx = list(range(len(scales)))
    qualified = [i for i in idx if n_must == 0 or missed[i] / n_must <= limit]
    pool, order = (qualified, ("fa", "t", "missed")) if qualified else (idx, ("missed", "fa", "t"))
    values = {"fa": fa, "t": t, "missed": missed}
    for name in order:
        best = min(values[name][i] for i in pool)
        pool = [i for i in pool if values[name][i] == best]
    return max(scales[i] for i in pool), bool(qualified)


def test_miss_limited_choice_against_an_independent_selection():
    scales = [0.5, 0.7, 1.0, 1.4, 2.0]
    # 20 must-detect runs, at most 10 % missed: candidates 0-2 qualify; 1 and 2 have no alarm, 1 is faster
    fa, missed, time = [4, 0, 0, 0, 0], [0, 1, 2, 3, 9], [5.0, 5.5, 6.0, 7.0, np.nan]
    assert dt.choose_within(scales, fa, missed, time, 20, 0.1) == (0.7, True)
    # equal alarms and time: the fewer missed, then the larger factor
    assert dt.choose_within(scales, [1, 1, 1, 0, 0], [0, 0, 1, 5, 6], [5.0] * 5, 20, 0.05) == (0.7, True)
    # the limit is inclusive (2 of 20 is 10 %); none within 1 %: the fewest missed, then the fewest alarms
    assert dt.choose_within(scales, fa, missed, time, 20, 0.01) == (0.5, True)
    assert dt.choose_within(scales, fa, [1, 1, 2, 3, 9], time, 20, 0.01) == (0.7, False)
    rng = np.random.default_rng(7)
    for _ in range(300):
        k = int(rng.integers(2, 9))
        scales = np.sort(rng.choice(np.geomspace(0.25, 2.0, 24), k, replace=False))
        fa, missed = rng.integers(0, 3, k), rng.integers(0, 6, k)
        time = rng.choice([4.0, 5.0, np.nan], k)
        n_must, limit = int(rng.integers(0, 12)), float(rng.choice([0.0, 0.1, 0.25, 0.5]))
        got = dt.choose_within(scales, fa, missed, time, n_must, limit)
        assert got == reference_within(list(scales), list(fa), list(missed), list(time), n_must, limit)


@pytest.mark.parametrize("text, key", [
    ("[tune]\ndetector = 'stall'\nlevel = 'detection'\n", "tune.level"),
    ("[tune]\nmax_missed_fraction = 1.5\nlevel = 'detection'\ndetector = 'loe'\n", "tune.max_missed_fraction"),
    ("[tune]\nmax_missed_fraction = -0.1\nlevel = 'detection'\ndetector = 'loe'\n", "tune.max_missed_fraction"),
    ("[tune]\nmax_missed_fraction = 0.05\n", "tune.max_missed_fraction"),
    ("[tune]\nlevel = 'signature'\n", "tune.level"),
    ("[tune]\nmust_detect_kinds = ['jamming']\n", r"tune.must_detect_kinds\[0\]"),
    ("[tune]\nmust_detect = 'some'\n", "tune.must_detect"),
    ("[tune]\nscan_scales = [2.0, 1.0]\n", "tune.scan_scales"),
    ("[tune]\nsafety = 0.5\n", "tune.safety"),
    ("[tune]\nmin_peak_load_fraction = 1.5\n", "tune.min_peak_load_fraction"),
])
def test_bad_detection_tune_keys_are_named_in_one_line(tmp_path, capsys, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text + "[space]\nvcas_kt = [200.0, 300.0]\n")
    with pytest.raises(config.ConfigError, match=key.replace(".", r"\.")):
        config.load(config.TuneConfig, path)
    assert cli.main(["tune", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key.replace("\\", "") in err[0]


def test_tuner_runs_on_the_full_aircraft(tmp_path):
    cfg = config.load(config.TuneConfig, tiny(tmp_path, duration=3.0, model="rcam"))
    params, settings, data, n = problem(cfg)
    vcas = np.asarray(data.plant.vcas_m_s)
    assert np.ptp(vcas, axis=1).max() > 0.0  # the flight point moves within a run: the FDD schedules on it
    must = np.ones(n, bool)
    theta = dt.initial(params, dt.names(params.loe, True, False))
    value, b, grad = jax.device_get(dt.gap_and_grad(theta, params, settings, data, must, 0.005, DT_S))
    assert np.isfinite(value) and np.isfinite(b["tau_f"])
    assert all(np.isfinite(g) for g in grad.values()) and any(g != 0.0 for g in grad.values())


@pytest.mark.parametrize("limit", [None, 0.5])
def test_detection_tuning_end_to_end(tmp_path, limit):
    import mcfdd

    path = tiny(tmp_path, iterations=2, duration=3.0)
    if limit is not None:
        path.write_text(path.read_text().replace("[tune]\n", f"[tune]\nmax_missed_fraction = {limit}\n"))
    result = mcfdd.tune(path, progress=False)
    scan = result.threshold_scan
    assert scan["chosen"].sum() == 1 and scan["pareto"].any()
    chosen = scan[scan["chosen"]].iloc[0]
    if limit is not None:  # the chosen row is the miss-limited choice among the scanned rows, no safety factor
        n_must = int(re.search(r"tau_d over the (\d+) ", result.report_text).group(1))
        assert n_must > 0 and f"at most {limit} of the {n_must} must-detect runs missed" in result.report_text
        want = reference_within(list(scan["scale"]), list(scan["training_false_alarms"]),
                                list(scan["training_missed"]), list(scan["training_detection_time_s"]), n_must, limit)
        assert chosen["scale"] == want[0]
    assert result.fdd.loe.detection_tau == pytest.approx(chosen["detection_tau"], rel=1e-5)
    assert list(result.validation["fdd"]) == ["before", "after"]
    assert set(result.comparison.outcomes["outcome"]) >= {"loe_false_alarm", "missed_disconnection_loaded"}
    written = result.save(tmp_path / "out")
    assert (tmp_path / "out" / "validation" / "compare" / "compare.md") in written
    fragment = config.load_fdd_fragment(tmp_path / "out" / "tuned_fdd.toml")
    assert fragment == result.fdd


CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("tune_name, shipped_name", [("tune_validation", "validation"),
                                                     ("tune_default", "loe_campaign"),
                                                     ("tune_validation_rcam", "validation_rcam"),
                                                     ("tune_validation_kci10", "validation_kci10")])
def test_shipped_detection_tune_config_holds_out_enough_fault_free_runs(tune_name, shipped_name):
    cfg = config.load(config.TuneConfig, CONFIGS / f"{tune_name}.toml")
    shipped = config.load(config.CampaignConfig, CONFIGS / f"{shipped_name}.toml")
    assert cfg.tune.level == "detection" and cfg.validation.seed != cfg.training.seed
    cells = len(cfg.values("fault_kind"))
    assert cfg.validation.scenarios // cells >= 3072 and cfg.training.scenarios <= 4096
    # the tuning and its held-out campaign are of the shipped campaign's space, aircraft and scoring
    assert cfg.space == shipped.space and cfg.evaluation == shipped.evaluation and cfg.plant == shipped.plant
    assert cfg.validation.duration_s == shipped.campaign.duration_s
    assert shipped.campaign.seed not in (cfg.training.seed, cfg.validation.seed)


def test_settings_turned_off_stay_off():
    fdd = config.replace(config.FddConfig(), {"loe.detection_contrast": 0.0, "loe.excitation_floor_deg": 0.0,
                                              "loe.excitation_noise_factor": 2.0, "loe.detection_confirm_s": 0.0})
    bank, _ = load_bank(fdd, np.float64)
    params = build.fdd_params(fdd, bank, 0.1)
    tuned = dt.names(params.loe, False, True)
    assert tuned == ("alpha", "beta", "gamma_1_s", "detection_tau", "excitation_noise_factor")
    theta = dt.initial(params, tuned)
    assert float(np.exp(theta["alpha"])) == pytest.approx(1e-3 * fdd.loe.evaluator.beta)
    back = dt.apply(params, theta, 2.0).loe
    assert back.detection_contrast == 0.0 and back.excitation_floor == 0.0 and back.detection_confirm_s == 0.0
    assert float(back.detection_tau) == pytest.approx(2.0 * fdd.loe.detection_tau)


def documented_default_fdd() -> dict:
    """The [fdd.loe] defaults written in tune_default.toml's comment (the indented lines after '# Result')."""
    lines = (CONFIGS / "tune_default.toml").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("# Result"))
    body = [line[4:] for line in lines[start + 1:] if line.startswith("#   ")]
    return tomllib.loads("\n".join(body))


def test_a_config_without_fdd_builds_the_default_tune_default_documents(tmp_path):
    """loe_campaign.toml has no [fdd]: its LOE bank is built from the defaults, which are the FDD that
    `mcfdd tune configs/tune_default.toml`'s held-out rule adopted, as its comment writes it (every
    detection-level number and option): the tuner's start, written out in tune_default.toml."""
    documented = documented_default_fdd()
    assert set(documented) >= {"load_gate", "pole_1_s", "evaluator", "detection_tau", "detection_contrast",
                               "excitation_floor_deg", "excitation_noise_factor", "detection_confirm_s"}
    campaign = config.load(config.CampaignConfig, CONFIGS / "loe_campaign.toml")
    (tmp_path / "fdd.toml").write_text(tomli_w.dumps({"fdd": {"loe": documented}}))
    written = config.load_fdd_fragment(tmp_path / "fdd.toml")
    assert campaign.fdd == config.FddConfig() == written
    start = config.load(config.TuneConfig, CONFIGS / "tune_default.toml").fdd
    assert start == campaign.fdd
    bank, _ = load_bank(campaign.fdd, np.float64)
    r_arm = build.plant_model(campaign.plant).actuator.r_arm_m
    built, expected = (build.fdd_params(f, bank, r_arm).loe for f in (campaign.fdd, written))
    for a, b in zip(jax.tree_util.tree_leaves(built), jax.tree_util.tree_leaves(expected)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_run_without_stall_gives_a_finite_detection_tau_gradient():
    # the stall-hold term of the rejection margin, at the time since a stall of a run that has had none, is
    # finite with a finite derivative: the min's zero cotangent times it is 0, not nan (issue 22)
    fdd = config.FddConfig()
    bank, _ = load_bank(fdd, np.float64)
    params = build.fdd_params(fdd, bank, 0.0525)
    never = system.init(params, 0.0).since_stall
    assert np.isfinite(never) and never + 1e3 == never and np.isfinite(never * never)
    loe = params.loe

    def margin(tau, since):
        return system.rejection_margin(loe._replace(detection_tau=tau), 0.5, 0.5, 1.0, 0.1, since)

    assert jax.grad(margin)(0.1, never) == pytest.approx(-1.0)
    assert margin(0.1, never) == margin(0.1, np.inf)  # the margin itself is the one an infinite time gives
    assert np.isnan(jax.grad(margin)(0.1, np.inf))  # what the infinite start gave


FD_STEP = 1e-6  # central differences in the logarithms; the gap has kinks (a min of terms, the confirmation)
FD_TOLERANCE = 1e-4  # |AD - FD| <= FD_TOLERANCE (|FD| + max |FD|) for every tuned parameter


def test_gap_gradient_matches_central_differences_in_every_tuned_parameter(tmp_path):
    # 32 runs of 5 s in float64, every parameter the tuner moves (pole and confirmation included), the
    # gradient unmasked (jax.grad of the gap) and as the tuner gets it (gap_and_grad) against central
    # differences of the smooth gap
    with precision("float64"):
        cfg = config.replace(config.load(config.TuneConfig, tiny(tmp_path)), {"training.scenarios": 32})
        params, settings, data, n = problem(cfg)
        columns = jax.device_get(dt.evaluate_columns(params, settings, data, DT_S))
        must = np.array(columns["must_detect"])
        assert n == 32 and must.sum() >= 4
        theta = dt.initial(params, dt.names(params.loe, True, True))
        assert set(theta) >= {"pole_1_s", "detection_tau", "detection_contrast", "detection_confirm_s"}
        assert all(v.dtype == np.float64 for v in theta.values())

        def gap(theta, params, settings, data, must):
            b = dt.bounds(dt.apply(params, theta), settings, data, must, 0.005, DT_S)
            return b["soft_detect"] - b["soft_free"]

        value, _, grad = jax.device_get(dt.gap_and_grad(theta, params, settings, data, must, 0.005, DT_S))
        raw = jax.device_get(jax.jit(jax.grad(gap))(theta, params, settings, data, must))
        at = jax.jit(gap)
        assert float(at(theta, params, settings, data, must)) == pytest.approx(float(value), abs=1e-14)
        fd = {}
        for name in theta:
            up, down = dict(theta), dict(theta)
            up[name], down[name] = theta[name] + FD_STEP, theta[name] - FD_STEP
            fd[name] = float(at(up, params, settings, data, must) - at(down, params, settings, data, must)) / (
                2 * FD_STEP)
    scale = max(abs(v) for v in fd.values())
    assert abs(fd["detection_tau"]) > 0.01 * scale  # the common threshold shift does move the gap
    for name in theta:
        assert np.isfinite(raw[name]), name
        assert raw[name] == pytest.approx(grad[name], rel=1e-9, abs=1e-15), name
        assert abs(grad[name] - fd[name]) <= FD_TOLERANCE * (abs(fd[name]) + scale), (name, grad[name], fd[name])

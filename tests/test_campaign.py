"""Campaigns: designs, reproducibility over chunk sizes and resumption, online reductions, metrics."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binomtest

from mcfdd import cli, config
from mcfdd.analysis import build, campaign, metrics, scenarios, simulate

SMALL = """
[campaign]
scenarios = {n}
design = "lhs"
seed = 7
chunk_size = 64
duration_s = 4.0

[evaluation]
settle_s = 0.5
t_detec_s = 120.0

[space]
vcas_kt = [200.0, 360.0]
altitude_m = [0.0, 6000.0]
noise_std_mm = [0.03, 0.07]
hinge_scale = [0.9, 1.4]
fault_kind = ["none", "leakage", "surface_damage", "disconnection", "jamming"]
leakage_size = [0.1, 0.3]
surface_damage_size = [0.3, 1.0]
fault_onset_s = [1.0, 2.0]
manoeuvre_kind = ["doublet", "ol_doublet", "sideslip"]
amplitude = [0.5, 1.0]
t_start_s = [0.2, 1.0]
duration_s = [0.5, 1.0]
sideslip_deg = [8.0, 14.0]
"""


def write_config(tmp_path, n=40, extra=""):
    path = tmp_path / "small.toml"
    path.write_text(SMALL.format(n=n) + extra)
    return path


def run_cli(*argv):
    return cli.main([str(a) for a in argv])


def scenario_table(out: Path) -> pd.DataFrame:
    parts = sorted((out / "scenarios").glob("part-*.parquet"))
    return pd.concat([pd.read_parquet(p) for p in parts]).sort_values("scenario_id", ignore_index=True)


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("campaign")
    cfg = write_config(tmp)
    out = tmp / "a"
    assert run_cli("campaign", cfg, "--out", out, "--chunk-size", 64) == 0
    return cfg, out


def test_chunk_size_does_not_change_the_table(reference_run, tmp_path):
    cfg, out = reference_run
    other = tmp_path / "b"
    assert run_cli("campaign", cfg, "--out", other, "--chunk-size", 256) == 0
    a, b = scenario_table(out), scenario_table(other)
    assert len(a) == 40
    pd.testing.assert_frame_equal(a, b)


def test_interrupted_campaign_resumes_to_the_same_table(reference_run, tmp_path, monkeypatch):
    cfg, out = reference_run
    resumed = tmp_path / "c"
    calls = []
    real = cli.run_campaign

    def interrupt_after_first_chunk(*args, **kwargs):
        def on_chunk(ids):
            calls.append(ids)
            raise KeyboardInterrupt

        return real(*args, on_chunk=on_chunk, **kwargs)

    monkeypatch.setattr(cli, "run_campaign", interrupt_after_first_chunk)
    assert run_cli("campaign", cfg, "--out", resumed, "--chunk-size", 16) == 130
    monkeypatch.setattr(cli, "run_campaign", real)
    assert len(list((resumed / "scenarios").glob("part-*.parquet"))) == 1
    assert run_cli("campaign", cfg, "--out", resumed, "--chunk-size", 16) == 2  # refused without --resume
    assert run_cli("campaign", cfg, "--out", resumed, "--chunk-size", 16, "--resume") == 0
    pd.testing.assert_frame_equal(scenario_table(out), scenario_table(resumed))


def test_outputs_carry_provenance_and_summaries(reference_run):
    _, out = reference_run
    for name in ("summary.parquet", "confusion.parquet", "gaps.parquet", "scenarios/part-00000000.parquet"):
        meta = cli.io.read_metadata(out / name)
        assert json.loads(meta["config"])["campaign"]["seed"] == 7
        assert meta["seed"] == "7" and meta["version"] and meta["git_revision"]
    summ = pd.read_parquet(out / "summary.parquet")
    overall = summ[summ["group"] == "overall"].iloc[0]
    table = scenario_table(out)
    assert overall["runs"] == len(table)
    assert overall["false_alarms"] == int((table["false_alarm"] | table["eta_false_signal"]).sum())
    assert (out / "summary.md").read_text().startswith("# Campaign")
    for png in ("rates_by_fault.png", "detection_times.png", "confusion.png"):
        assert (out / png).stat().st_size > 0


def test_online_reductions_equal_reductions_of_full_histories(tmp_path):
    """run_batch's carry reductions against the same quantities computed from fdd_batch histories."""
    harsh = (SMALL.format(n=24).replace("vcas_kt = [200.0, 360.0]", "vcas_kt = [300.0, 360.0]")
             .replace("altitude_m = [0.0, 6000.0]", "altitude_m = [0.0, 1500.0]")
             .replace("hinge_scale = [0.9, 1.4]", "hinge_scale = [1.3, 1.6]")
             .replace('manoeuvre_kind = ["doublet", "ol_doublet", "sideslip"]', 'manoeuvre_kind = ["ol_doublet", "doublet"]')
             .replace("amplitude = [0.5, 1.0]", "amplitude = [0.8, 1.0]")
             + "\n[fdd.loe]\nconfirm_s = 0.0\ntau = 0.1\nexcitation_floor_deg = 0.01\n")
    path = tmp_path / "harsh.toml"
    path.write_text(harsh)
    cfg = config.load(config.CampaignConfig, path)
    c = cfg.campaign
    cols, n = build.design(cfg)
    cli._set_precision("float64")
    model = build.plant_model(cfg.plant)
    bank, _ = cli._load_bank(cfg.fdd, np.float64)
    fdd = build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m)
    settings = build.settings(cfg.evaluation, model.actuator.r_arm_m)
    onset = scenarios.fault_onsets(cols, n)
    _, accept = scenarios.true_model(np.asarray(bank.nu), cols["fault_kind"], cols["fault_size"])
    scen = scenarios.to_scenario(cols, np.float64)
    kinds = tuple(sorted(set(np.asarray(scen.manoeuvre.kind).tolist())))
    keys = simulate.run_keys(c.seed, range(n))
    raw = campaign.run_batch(model, fdd, settings, scen, campaign.Truth(onset, accept), keys, c.n_steps, c.dt_s,
                             c.substeps, kinds)
    plant, out = simulate.fdd_batch(model, fdd, scen, keys, c.n_steps, c.dt_s, c.substeps, kinds)
    t = np.arange(c.n_steps) * c.dt_s
    det = np.asarray(out.detected)
    stall = np.asarray(plant.stall)
    for i in range(n):
        after_stall = np.full(c.n_steps, np.inf)
        last_end = -np.inf
        for k in range(c.n_steps):
            if k and stall[i, k - 1] and not stall[i, k]:
                last_end = t[k]
            after_stall[k] = t[k] - last_end
        clear = ~stall[i] & (after_stall > settings.stall_grace_s)
        settled = t >= settings.settle_s
        before = t < onset[i]
        fa = settled & before & clear & (det[i] >= 1)
        expect_fa = t[fa][0] if fa.any() else np.inf
        assert float(raw["false_alarm_time_s"][i]) == expect_fa
        window = (t >= onset[i]) & (t <= onset[i] + settings.t_detec_s) & (det[i] >= 1)
        assert float(raw["detection_time_s"][i]) == (t[window][0] if window.any() else np.inf)
        excited = np.asarray(out.excited[i])
        ratio = np.asarray(out.theta[i]) / np.where(excited, np.asarray(out.theta_u[i]), 1.0)[:, None]
        pre = settled & before & clear & excited
        expect_max = ratio[pre].max(axis=0) if pre.any() else np.full(ratio.shape[1], -np.inf)
        np.testing.assert_allclose(np.asarray(raw["ratio_max_pre"][i]), expect_max, rtol=1e-12)
        quiet = settled & before & clear
        theta_stall = np.asarray(out.theta_stall[i])
        expect_stall = theta_stall[quiet].max() if quiet.any() else -np.inf
        np.testing.assert_allclose(float(raw["stall_theta_max_free"][i]), expect_stall, rtol=1e-12)
        events = np.flatnonzero(np.diff(np.concatenate([[0], stall[i].astype(int), [0]])))
        relevant = 0
        worst = -np.inf
        for start, end in zip(events[::2], events[1::2]):
            err = np.abs(np.asarray(plant.u_c_m[i]) - np.asarray(plant.x_m[i]))[start:end].max()
            duration = (t[end] if end < c.n_steps else c.n_steps * c.dt_s) - t[start]
            if duration >= settings.stall_min_duration_s and err >= settings.stall_min_error_m:
                relevant += 1
                eta = np.asarray(out.eta_signal[i])[start:end]
                if eta.any():
                    worst = max(worst, t[start + eta.argmax()] - t[start])
        assert int(raw["stall_events"][i]) == relevant
        np.testing.assert_allclose(float(raw["stall_worst_latency_signal_s"][i]), worst, atol=1e-12)
    assert int(np.asarray(raw["stall_events"]).sum()) > 0, "the test space should produce stall loads"
    assert np.isfinite(np.asarray(raw["detection_time_s"])).any(), "the test space should produce detections"


@pytest.mark.parametrize("k,n", [(0, 10), (0, 3000), (3, 40), (40, 40), (17, 123)])
def test_clopper_pearson_matches_scipy(k, n):
    ref = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
    lo, hi = metrics.clopper_pearson(k, n)
    assert lo == pytest.approx(ref.low, abs=1e-12)
    assert hi == pytest.approx(ref.high, abs=1e-12)


def test_zero_events_bound_is_about_three_over_n():
    _, hi = metrics.clopper_pearson(0, 1000)
    assert 1 - 0.025 ** (1 / 1000) == pytest.approx(float(hi), rel=1e-9)
    assert 2.5e-3 < hi < 3.8e-3


def test_latin_hypercube_puts_one_point_in_each_stratum():
    axes = [scenarios.Axis("amplitude", "range", lo=-1.0, hi=1.0), scenarios.Axis("t_start_s", "range", lo=0.0, hi=10.0),
            scenarios.Axis("kd_scale", "range", lo=0.7, hi=1.3)]
    n = 97
    cols, rows = scenarios.design_table(axes, n, "lhs", seed=3)
    assert rows == n
    for a in axes:
        u = (np.asarray(cols[a.name]) - a.lo) / (a.hi - a.lo)
        assert sorted(np.floor(u * n).astype(int)) == list(range(n))


def test_designs_respect_the_mach_limit_and_grid_axes():
    axes = [scenarios.Axis("vcas_kt", "range", lo=150.0, hi=420.0), scenarios.Axis("altitude_m", "range", lo=0.0, hi=12000.0),
            scenarios.Axis("fault_kind", "choices", ("none", "leakage"))]
    cols, n = scenarios.design_table(axes, 64, "sobol", seed=1, grid_axes=("fault_kind",), max_mach=0.82)
    assert n == 128
    assert list(cols["fault_kind"][:64]) == ["none"] * 64
    mach = np.asarray(scenarios.atmosphere.mach(cols["vcas_kt"] * scenarios.atmosphere.KT_TO_M_S, cols["altitude_m"]))
    assert mach.max() <= 0.82 + 1e-9
    grid = [scenarios.Axis("vcas_kt", "range", lo=150.0, hi=420.0, n=4), scenarios.Axis("altitude_m", "values", (0.0, 12000.0))]
    cols, n = scenarios.design_table(grid, 0, "grid", seed=0, max_mach=0.82)
    assert n < 8 and set(cols["altitude_m"]) == {0.0, 12000.0}


def test_true_model_brackets():
    nu = np.array([[1, 1], [1, 0], [1, 0.33], [1, 0.66], [0.85, 1], [0.73, 1]])
    nearest, accept = scenarios.true_model(nu, np.array(["surface_damage", "leakage", "disconnection", "none"]),
                                           np.array([0.5, 0.2, 0.0, 0.0]))
    assert list(nearest) == [3, 4, 1, 0]
    assert set(np.flatnonzero(accept[0])) == {2, 3}
    assert set(np.flatnonzero(accept[1])) == {4, 5}
    assert set(np.flatnonzero(accept[2])) == {1}
    assert not accept[3].any()


@pytest.mark.parametrize("extra,message", [
    ("\n[space.bad]\n", "space.bad"),
    ("", None),
])
def test_space_table_errors(tmp_path, extra, message):
    path = write_config(tmp_path, extra=extra)
    if message is None:
        config.load(config.CampaignConfig, path)
        return
    with pytest.raises(config.ConfigError, match=message):
        config.load(config.CampaignConfig, path)


@pytest.mark.parametrize("replace,message", [
    ('vcas_kt = [200.0, 360.0]', "space.vcas_kt"),
    ('fault_kind = ["none", "leakage", "surface_damage", "disconnection", "jamming"]', "space.fault_kind\\[0\\]"),
    ('leakage_size = [0.1, 0.3]', "space.leakage_size"),
    ('design = "lhs"', "campaign.design"),
    ('chunk_size = 64', "campaign.chunk_size"),
])
def test_bad_campaign_values_are_named(tmp_path, replace, message):
    bad = {
        "vcas_kt = [200.0, 360.0]": "vcas_kt = [360.0, 200.0]",
        'fault_kind = ["none", "leakage", "surface_damage", "disconnection", "jamming"]': 'fault_kind = ["nothing"]',
        "leakage_size = [0.1, 0.3]": "leakage_size = [0.1, 1.0]",
        'design = "lhs"': 'design = "halton"',
        "chunk_size = 64": "chunk_size = 0",
    }[replace]
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.format(n=8).replace(replace, bad))
    with pytest.raises(config.ConfigError, match=message):
        config.load(config.CampaignConfig, path)


def test_grid_axis_must_vary(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.format(n=8).replace('design = "lhs"', 'design = "lhs"\ngrid = ["turbulence"]'))
    with pytest.raises(config.ConfigError, match=r"campaign.grid\[0\]"):
        config.load(config.CampaignConfig, path)


def test_bad_flags_are_named(tmp_path, capsys):
    path = write_config(tmp_path, n=4)
    assert run_cli("campaign", path, "--out", tmp_path / "x", "--chunk-size", 0) == 2
    assert "--chunk-size" in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "y", "--scenarios", -3) == 2
    assert "--scenarios" in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "z", "--resume") == 2
    assert "--resume" in capsys.readouterr().err


def test_non_finite_scenario_is_marked_and_the_batch_goes_on():
    cfg = config.parse(config.CampaignConfig, {"campaign": {"scenarios": 4, "duration_s": 1.0, "design": "random"},
                                               "space": {"vcas_kt": [200.0, 300.0]}})
    cols, n = build.design(cfg)
    cli._set_precision("float64")
    model = build.plant_model(cfg.plant)
    bank, _ = cli._load_bank(cfg.fdd, np.float64)
    fdd = build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m)
    scen = scenarios.to_scenario(cols, np.float64)
    scen = scen._replace(noise_std_m=np.where(np.arange(n) == 2, np.nan, scen.noise_std_m))
    truth = campaign.Truth(np.full(n, np.inf), np.zeros((n, bank.k0.shape[0]), bool))
    raw = campaign.run_batch(model, fdd, build.settings(cfg.evaluation, model.actuator.r_arm_m), scen, truth,
                             simulate.run_keys(0, range(n)), 100, 0.01, 4, (0,))
    status = np.asarray(raw["status"])
    assert list(status) == [0, 0, campaign.STATUS_NON_FINITE, 0]
    out = metrics.outcomes({k: np.asarray(v) for k, v in raw.items()}, np.full(n, np.inf),
                           np.zeros((n, 6), bool), np.zeros(n, int), 1.0, 120.0)
    assert not out["false_alarm"][2] and not out["detected"][2]

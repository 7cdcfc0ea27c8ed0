"""Campaigns: designs, reproducibility over chunk sizes and resumption, online reductions, metrics."""

import concurrent.futures
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import numpy as np
import pandas as pd
import pytest
from scipy.stats import binomtest

import mcfdd
from helpers import CONFIGS, FAULT_FREE, SMALL, compiles, scenario_table, small_config
from mcfdd import cli, config, io
from mcfdd.analysis import build, metrics, scenarios
from mcfdd.workflows.common import precision


def run_cli(*argv):
    return cli.main([str(a) for a in argv])


# The shipped false-alarm campaign, shortened: 320 scenarios of 2 s = 64 Sobol samples on each of the
# 5 manoeuvre families. With 2 devices (conftest) chunk_size 128 runs 3 chunks (128, 128, 64), 256 runs
# 2 (160, 160). A low tau_m and excitation floor (the noise-relative floor kept on, as in the default FDD, so
# both runs share one compilation) give false alarms to count.
SHORT = {"campaign.scenarios": 320, "campaign.duration_s": 2.0, "campaign.chunk_size": 128, "evaluation.settle_s": 0.3,
         "space.t_start_s": [0.2, 0.8], "space.duration_s": [0.3, 1.0], "space.hold_s": [0.2, 0.6]}
ALARMING = {"fdd.loe.tau": 0.03, "fdd.loe.detection_tau": 0.03, "fdd.loe.detection_contrast": 0.0,
            "fdd.loe.confirm_s": 0.0,
            "fdd.loe.excitation_floor_deg": 0.005, "fdd.loe.excitation_noise_factor": 0.2}
N_SHORT = 320


def cli_flags(overrides: dict) -> list[str]:
    return [a for k, v in overrides.items() for a in ("--set", f"{k}={json.dumps(v)}")]


@pytest.fixture(scope="module")
def in_memory():
    """The script of issue 12: only ``import mcfdd``; two runs differing in fdd.loe.tau, one compilation."""
    first = mcfdd.run_campaign(mcfdd.load_config(FAULT_FREE, overrides=SHORT), progress=False)
    runs = []
    count = compiles(lambda: runs.append(mcfdd.run_campaign(mcfdd.load_config(FAULT_FREE, overrides={
        **SHORT, **ALARMING}), progress=False)))
    return first, runs[0], count


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """``mcfdd campaign`` of the second in-memory run, 3 chunks."""
    out = tmp_path_factory.mktemp("campaign") / "a"
    assert run_cli("campaign", FAULT_FREE, "--out", out, *cli_flags({**SHORT, **ALARMING})) == 0
    return out


def test_script_reruns_with_new_tau_without_compiling_and_matches_the_cli(in_memory, cli_run):
    first, second, compiles = in_memory
    assert compiles == 0
    assert len(second.scenarios) == N_SHORT and second.simulated == N_SHORT
    pd.testing.assert_frame_equal(second.scenarios, scenario_table(cli_run))
    assert len(list((cli_run / "scenarios").glob("part-*.parquet"))) == 3
    assert second.overall()["false_alarms_any"] > first.overall()["false_alarms_any"], "a lower tau alarms more often"


def test_save_writes_exactly_the_cli_files(in_memory, cli_run, tmp_path):
    _, second, _ = in_memory
    saved = {p.relative_to(tmp_path / "s") for p in second.save(tmp_path / "s")}
    assert saved == {p.relative_to(cli_run) for p in cli_run.rglob("*") if p.is_file() and p.name != io.LOCK_NAME}
    for name in ("summary.parquet", "gaps.parquet", "confusion.parquet"):
        a, b = pd.read_parquet(tmp_path / "s" / name), pd.read_parquet(cli_run / name)
        if name == "gaps.parquet":  # the replay commands name each campaign's own folder
            for column in ("tau_f_replay", "tau_d_replay"):
                a[column] = a[column].str.replace(str(tmp_path / "s"), str(cli_run), regex=False)
        pd.testing.assert_frame_equal(a, b)
    fig = second.plot("rates_by_manoeuvre")
    assert fig.axes and fig.axes[0].has_data()
    with pytest.raises(ValueError, match="plot"):
        second.plot("nothing")


def test_chunk_size_does_not_change_the_table(in_memory):
    _, second, _ = in_memory
    chunks = []
    cfg = mcfdd.load_config(FAULT_FREE, overrides={**SHORT, **ALARMING, "campaign.chunk_size": 256})
    other = mcfdd.run_campaign(cfg, progress=False, on_chunk=chunks.append)
    assert [len(c) for c in chunks] == [160, 160]
    pd.testing.assert_frame_equal(second.scenarios, other.scenarios)


def test_chunks_are_evened_out_and_padded_only_to_whole_lanes(tmp_path, capsys):
    """The shipped fault-free campaign (2,560 scenarios, chunk size 2,048) runs two chunks of 1,280 on four
    devices, not 4,096 scenarios; ten scenarios run one chunk of 16 on one device; the status line says so."""
    from mcfdd.workflows import campaign as runner

    assert runner.LANE_BLOCK == 16
    shipped = mcfdd.load_config(FAULT_FREE)
    assert (shipped.campaign.scenarios, shipped.campaign.chunk_size) == (2560, 2048)
    assert runner.chunk_size(2048, 2560, devices=4) == 1280
    assert runner.chunk_size(2048, 10, devices=4) == 16 and runner.chunk_devices(16, 4) == 1
    for n in (1, 10, 100, 2560, 16384):
        for requested in (1, 64, 1000, 2048):
            for devices in (1, 2, 4, 6):
                size = runner.chunk_size(requested, n, devices)
                chunks, fewest = -(-n // size), -(-n // min(requested, n))
                used = runner.chunk_devices(size, devices)
                assert size % (used * runner.LANE_BLOCK) == 0 and used == min(devices, size // runner.LANE_BLOCK)
                assert chunks <= fewest  # no more chunks than the requested size makes
                assert chunks * size - n < fewest * used * runner.LANE_BLOCK  # less than a lane block per device
    ten = cli_flags({**SHORT, "campaign.scenarios": 10})
    assert run_cli("campaign", FAULT_FREE, "--out", tmp_path / "ten", *ten) == 0
    assert "10 to run in 1 chunk(s) of 16 (1 device(s) x 16; 6 padding scenarios)" in capsys.readouterr().err


def test_interrupted_campaign_resumes_the_missing_scenarios_to_the_same_table(in_memory, tmp_path):
    _, second, _ = in_memory
    cfg = mcfdd.load_config(FAULT_FREE, overrides={**SHORT, **ALARMING})
    out = tmp_path / "c"

    def interrupt_after_first_chunk(ids):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        mcfdd.run_campaign(cfg, out=out, progress=False, on_chunk=interrupt_after_first_chunk)
    assert [p.name for p in (out / "scenarios").glob("part-*.parquet")] == ["part-00000000.parquet"]
    with pytest.raises(mcfdd.OutputFolderError, match="out: .* not empty"):
        mcfdd.run_campaign(cfg, out=out, progress=False)
    other = mcfdd.load_config(FAULT_FREE, overrides={**SHORT, "campaign.seed": 3})
    with pytest.raises(mcfdd.OutputFolderError, match="resume: the configuration differs"):
        mcfdd.run_campaign(other, out=out, resume=True, progress=False)
    resumed_ids = []
    resumed = mcfdd.run_campaign(cfg, out=out, resume=True, progress=False, on_chunk=resumed_ids.append)
    assert resumed.simulated == N_SHORT - 128
    np.testing.assert_array_equal(np.concatenate(resumed_ids), np.arange(128, N_SHORT))
    pd.testing.assert_frame_equal(second.scenarios, resumed.scenarios)
    pd.testing.assert_frame_equal(second.scenarios, scenario_table(out))


def test_executor_chunks_give_the_same_table(in_memory):
    _, second, _ = in_memory
    cfg = mcfdd.load_config(FAULT_FREE, overrides={**SHORT, **ALARMING})
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        pooled = mcfdd.run_campaign(cfg, progress=False, executor=pool)
    pd.testing.assert_frame_equal(second.scenarios, pooled.scenarios)


def test_outputs_carry_provenance_and_the_far_counts_alarms(cli_run):
    out = cli_run
    for name in ("summary.parquet", "confusion.parquet", "gaps.parquet", "detectability.parquet",
                 "scenarios/part-00000000.parquet"):
        meta = io.read_metadata(out / name)
        assert json.loads(meta["config"])["campaign"]["seed"] == 21
        assert meta["seed"] == "21" and meta["version"] and meta["git_revision"]
    summ = pd.read_parquet(out / "summary.parquet")
    overall = summ[summ["stratum"] == "overall"].iloc[0]
    table = scenario_table(out)
    assert overall["runs"] == len(table) == N_SHORT
    # fault-free runs: a run alarms if its LOE decision or its eta = 1 outside stall loads has a time
    ok = table["status"].to_numpy() == int(mcfdd.Status.OK)
    alarm_times = np.fmin(table["false_alarm_time_s"].to_numpy(), np.nan_to_num(
        table["eta_false_signal_time_s"].to_numpy(), nan=np.inf))
    alarms = int((ok & np.isfinite(alarm_times)).sum())
    assert 0 < alarms < N_SHORT, "the low tau_m should alarm in some runs, not all"
    assert overall["fault_free_runs"] == N_SHORT and overall["false_alarms_any"] == alarms
    ref = binomtest(alarms, N_SHORT).proportion_ci(confidence_level=0.95, method="exact")
    assert overall["far_any"] == pytest.approx(alarms / N_SHORT)
    assert (overall["far_any_lo"], overall["far_any_hi"]) == pytest.approx((ref.low, ref.high), abs=1e-12)
    assert (out / "summary.md").read_text().startswith("# Campaign fault_free")
    assert "## Detectability under the campaign's uncertainty" in (out / "summary.md").read_text()
    assert {"peak_load_fraction", "peak_deflection_deg", "qbar_kpa", "fault_distance", "uncertainty_distance",
            "separable", "missed", "jam_taken_for_stall", "jam_taken_for_stall_time_s"} <= set(table.columns)
    for png in ("rates_by_fault.png", "rates_by_envelope.png", "rates_by_manoeuvre.png", "confusion.png"):
        assert (out / png).stat().st_size > 0
    # no faulty runs: no detection times and no detectability cells to draw; summary.md says so
    text = (out / "summary.md").read_text()
    for png in ("detection_times.png", "detectability.png"):
        assert not (out / png).exists()
        assert f"- `{png}` left out: no" in text
    assert (out / "stall_latency.png").exists() == (overall["stall_events"] > 0)
    assert "(false alarms only: no faulty runs, so no MDR panel)" in text
    assert set(summ["stratum"]) == {"overall", "fault", "envelope", "manoeuvre", "turbulence"}
    assert "group" not in summ.columns


def test_status_codes_carry_their_meaning():
    assert [int(s) for s in mcfdd.Status] == [0, 1]
    assert "non-finite" in mcfdd.Status.NON_FINITE.meaning and mcfdd.Status(0) is mcfdd.Status.OK


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
    axes = [scenarios.Axis("amplitude", "range", lo=-1.0, hi=1.0),
            scenarios.Axis("t_start_s", "range", lo=0.0, hi=10.0),
            scenarios.Axis("kd_scale", "range", lo=0.7, hi=1.3)]
    n = 97
    cols, rows = scenarios.design_table(axes, n, "lhs", seed=3)
    assert rows == n
    for a in axes:
        u = (np.asarray(cols[a.name]) - a.lo) / (a.hi - a.lo)
        assert sorted(np.floor(u * n).astype(int)) == list(range(n))


def test_designs_respect_the_mach_limit_and_grid_axes():
    axes = [scenarios.Axis("vcas_kt", "range", lo=150.0, hi=420.0),
            scenarios.Axis("altitude_m", "range", lo=0.0, hi=12000.0),
            scenarios.Axis("fault_kind", "choices", ("none", "leakage"))]
    cols, n = scenarios.design_table(axes, 64, "sobol", seed=1, grid_axes=("fault_kind",), max_mach=0.82)
    assert n == 128
    assert list(cols["fault_kind"][:64]) == ["none"] * 64
    mach = np.asarray(scenarios.atmosphere.mach(cols["vcas_kt"] * scenarios.atmosphere.KT_TO_M_S, cols["altitude_m"]))
    assert mach.max() <= 0.82 + 1e-9
    grid = [scenarios.Axis("vcas_kt", "range", lo=150.0, hi=420.0, n=4),
            scenarios.Axis("altitude_m", "values", (0.0, 12000.0))]
    cols, n = scenarios.design_table(grid, 1, "grid", seed=0, max_mach=0.82)
    assert n < 8 and set(cols["altitude_m"]) == {0.0, 12000.0}


def test_design_does_not_depend_on_the_jax_precision(tmp_path):
    """The design (Mach limit included) is NumPy float64: the same columns whatever JAX's precision,
    so a resumed campaign's parts are checked against it without the campaign's precision context."""
    cfg = mcfdd.load_config(small_config(tmp_path, n=80), "campaign",
                            overrides={"space.vcas_kt": [200.0, 420.0], "space.altitude_m": [0.0, 12000.0]})
    ids = np.arange(0, 80, 3)
    with precision("float32"):
        single = build.design_chunk(cfg, build.design_plan(cfg), ids)
    with precision("float64"):
        double = build.design_chunk(cfg, build.design_plan(cfg), ids)
    capped = scenarios.mach_limit_speed_kt(single["altitude_m"], cfg.plant.aircraft.max_mach) < 420.0
    assert capped.sum() > len(ids) // 2  # rows whose speed range the Mach limit cuts
    for column, values in single.items():
        np.testing.assert_array_equal(values, double[column], err_msg=column)


SETUP_COMPILES = """
import sys
import numpy as np
import mcfdd
from mcfdd.workflows import campaign as runner
from mcfdd.workflows.common import CompileCounter, precision

with CompileCounter() as counter:
    cfg = mcfdd.load_config(sys.argv[1], "campaign")
    with precision(cfg.campaign.precision):
        setup = runner.campaign_setup(cfg)
        size = runner.chunk_size(cfg.campaign.chunk_size, setup.n)
        runner.chunk_inputs(setup, cfg.campaign.seed, np.arange(min(size, setup.n)), size)
print(counter.count)
"""


@pytest.mark.parametrize("name", ["loe_campaign.toml", "rcam_campaign.toml"])
def test_campaign_setup_compiles_one_program(name):
    """From the config to the first chunk's inputs (validation, plant, hinge table, bank, design plan with its
    Mach limit, scenarios, run keys), a fresh process compiles one program: the run keys' (about 85 before)."""
    out = subprocess.run([sys.executable, "-c", SETUP_COMPILES, str(CONFIGS / name)], capture_output=True,
                         text=True, check=True)
    assert int(out.stdout) == 1


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
    path = small_config(tmp_path, extra=extra)
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
    path = small_config(tmp_path, n=4)
    assert run_cli("campaign", path, "--out", tmp_path / "x", "--chunk-size", 0) == 2
    assert "--chunk-size" in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "y", "--scenarios", -3) == 2
    assert "--scenarios" in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "z", "--resume") == 2
    assert "resume: " in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "w", "--set", "campaign.scenarios") == 2
    assert "--set" in capsys.readouterr().err
    assert run_cli("campaign", path, "--out", tmp_path / "v", "--set", "campaign.scenarioz=3") == 2
    assert "campaign.scenarioz: unknown key" in capsys.readouterr().err


def test_schema_command_validates_the_campaign_configs_and_rejects_a_typo(capsys):
    assert run_cli("schema", "campaign") == 0
    validator = jsonschema.Draft202012Validator(json.loads(capsys.readouterr().out))
    folder = Path(__file__).resolve().parent.parent / "configs"
    campaigns = [p for p in sorted(folder.glob("*.toml")) if mcfdd.config.infer_kind(
        tomllib.loads(p.read_text())) == "campaign"]
    assert {p.name for p in campaigns} >= {"loe_campaign.toml", "stall_campaign.toml", "fault_free.toml"}
    for path in campaigns:
        data = tomllib.loads(path.read_text())
        validator.validate(data)
        data["campaign"]["scenarioz"] = data["campaign"].pop("scenarios")
        assert not validator.is_valid(data), path.name

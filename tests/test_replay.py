"""Replay of named campaign scenarios: outcome columns equal to the campaign's rows bit for bit (scenarios of
several chunks, a campaign run on another number of devices, both aircraft models), histories of the same
runs, the replay commands of summary.md and gaps.parquet, and one-line errors."""

import os
import shlex
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import mcfdd
from helpers import SMALL
from mcfdd import cli, config
from mcfdd.workflows import replay as replay_wf

N = 160  # three chunks of 64 on one device


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory):
    """The SMALL campaign of N scenarios in 3 s runs, run by the command on one JAX host device in chunks of 64
    (this process has several devices: a replay here runs on another layout and another chunk size)."""
    folder = tmp_path_factory.mktemp("replay")
    cfg = folder / "small.toml"
    cfg.write_text(SMALL.format(n=N).replace("duration_s = 4.0", "duration_s = 3.0"))
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=1"}
    out = folder / "campaign"
    proc = subprocess.run([sys.executable, "-m", "mcfdd.cli", "campaign", str(cfg), "--out", str(out)], env=env,
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "3 chunk(s) of 64" in proc.stderr
    return out


def _equal_rows(result):
    assert result.differences() == []
    pd.testing.assert_frame_equal(result.rows, result.outcomes[list(result.rows.columns)], check_exact=True)


def test_replayed_outcomes_equal_the_rows_of_a_campaign_run_in_other_chunks_on_another_device_count(campaign_dir):
    import jax

    assert jax.device_count() > 1
    ids = [150, 3, 70]  # one of each chunk, not in order
    result = mcfdd.replay(campaign_dir, ids, progress=False)
    assert result.ids == ids and result.rows["scenario_id"].tolist() == ids
    _equal_rows(result)
    frame = result.to_pandas()
    assert sorted(set(frame["run"])) == sorted(f"scenario-{i}" for i in ids)
    # the histories are the same runs: the fault-free filter's largest ratio while excited, settled, before the
    # fault and away from stall loads, recomputed from the samples (float64 here, float32 in the campaign)
    checked = 0
    for _, row in result.rows.iterrows():
        g = frame[frame["run"] == f"scenario-{row['scenario_id']}"]
        if row["stall_seen"] or not np.isfinite(row["loe_ratio0_max_pre"]):
            continue
        onset = np.inf if row["fault_kind"] == "none" else row["fault_onset_s"]
        quiet = (g["t_s"] >= 0.5) & (g["t_s"] < onset) & g["excited"]
        np.testing.assert_allclose(g.loc[quiet, "ratio_0"].max(), row["loe_ratio0_max_pre"], rtol=1e-5)
        checked += 1
    assert checked >= 1


def test_a_replay_with_another_seed_differs(campaign_dir):
    """The equality above can fail: the same scenario ids of the campaign at another seed are other runs."""
    cfg, table, _ = replay_wf.stored_campaign(campaign_dir)
    other = config.replace(cfg, {"campaign.seed": 8})
    result = replay_wf.replay_rows(other, table, [3, 70], progress=False)
    assert "loe_ratio0_max_pre" in result.differences() or "peak_deflection_deg" in result.differences()


def test_the_commands_of_summary_and_gaps_replay_the_witnesses(campaign_dir, tmp_path, capsys):
    gaps = pd.read_parquet(campaign_dir / "gaps.parquet")
    witnesses = gaps["tau_f_scenario_id"].tolist()
    assert all(c == f"mcfdd replay {campaign_dir} --scenarios {i}"
               for c, i in zip(gaps["tau_f_replay"], witnesses) if i >= 0)
    summary = (campaign_dir / "summary.md").read_text()
    line = next(s for s in summary.splitlines() if s.startswith("Replay these scenarios"))
    command = shlex.split(line.split("`")[1])
    assert command[:3] == ["mcfdd", "replay", str(campaign_dir)]
    assert {int(i) for i in command[4].split(",")} == set(gaps[["tau_f_scenario_id", "tau_d_scenario_id"]]
                                                         .to_numpy().ravel()) - {-1}
    drivers = summary.split("## What drives")[1]
    assert f"`mcfdd replay {campaign_dir} --scenarios " in drivers or "No false alarm and no miss" in drivers
    out = tmp_path / "replayed"
    assert cli.main([*command[1:], "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "all " in printed and "equal the campaign's rows bit for bit" in printed
    replayed = pd.read_parquet(out / "outcomes.parquet")
    assert replayed["scenario_id"].tolist() == [int(i) for i in command[4].split(",")]
    for i in replayed["scenario_id"]:
        assert (out / f"scenario-{i}.png").stat().st_size > 10_000


@pytest.mark.parametrize("args, message", [
    (["{missing}", "--scenarios", "1"], "does not exist"),
    (["{empty}", "--scenarios", "1"], "holds no campaign (campaign.json missing)"),
    (["{campaign}", "--scenarios", "1,x"], "--scenarios: 'x' is not a scenario id"),
    (["{campaign}", "--scenarios", f"2,{N}"], f"--scenarios: scenario {N} is not in the campaign"),
    (["{campaign}", "--scenarios", "2,2"], "--scenarios: scenario 2 is named twice"),
])
def test_bad_folders_and_ids_are_one_line_errors(campaign_dir, tmp_path, capsys, args, message):
    (tmp_path / "empty").mkdir()
    paths = {"missing": tmp_path / "nowhere", "empty": tmp_path / "empty", "campaign": campaign_dir}
    assert cli.main(["replay", *(a.format(**paths) for a in args)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_an_interrupted_campaign_replays_the_rows_it_has(campaign_dir, tmp_path, capsys):
    partial = tmp_path / "partial"
    (partial / "scenarios").mkdir(parents=True)
    (partial / "campaign.json").write_text((campaign_dir / "campaign.json").read_text())
    first = sorted((campaign_dir / "scenarios").glob("part-*.parquet"))[1]
    (partial / "scenarios" / first.name).write_bytes(first.read_bytes())
    _equal_rows(mcfdd.replay(partial, [64, 127], progress=False))
    assert cli.main(["replay", str(partial), "--scenarios", "3"]) == 2
    assert "holds 64 scenario rows with ids 64..127" in capsys.readouterr().err


def test_the_full_aircraft_replays_its_campaign_rows():
    cfg = mcfdd.load_config({
        "campaign": {"scenarios": 4, "duration_s": 3.0, "design": "random", "seed": 3},
        "evaluation": {"settle_s": 0.5}, "plant": {"aircraft": {"model": "rcam"}},
        "space": {"vcas_kt": [180.0, 240.0], "altitude_m": [500.0, 4000.0], "turbulence": "moderate",
                  "manoeuvre_kind": ["coordinated_turn", "doublet"], "bank_deg": 30.0, "amplitude": 1.0,
                  "t_start_s": 0.5, "fault_kind": ["none", "leakage"], "leakage_size": [0.1, 0.3],
                  "fault_onset_s": 1.0}}, "campaign")
    campaign = mcfdd.run_campaign(cfg, progress=False)
    result = campaign.replay([3, 1], progress=False)
    _equal_rows(result)
    frame = result.to_pandas()
    assert {"alpha_deg", "nz_g", "ratio_0"} <= set(frame.columns)
    # the flight point of the replayed histories is the campaign's (its measured Vcas range, kt)
    for _, row in result.rows.iterrows():
        g = frame[frame["run"] == f"scenario-{row['scenario_id']}"]
        np.testing.assert_allclose([g["vcas_kt"].min(), g["vcas_kt"].max()], [row["vcas_min_kt"], row["vcas_max_kt"]],
                                   rtol=1e-5)

"""Mistakes a user can make end with one line naming the flag, key or file and exit status 2.

The command runs in process (``mcfdd.cli.main``) except where a process must be killed. The
campaign is ``helpers.SMALL`` (384 scenarios of 4 s: several chunks).
"""

import errno
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

import mcfdd
from helpers import CONFIGS, interrupted, refused, scenario_table, small_config
from mcfdd import cli, console, io, report
from mcfdd.analysis import build
from mcfdd.workflows import campaign as campaign_workflow

N = 384


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return small_config(tmp_path_factory.mktemp("config"), N)


@pytest.fixture(scope="module")
def clean_result(small):
    """The campaign from an uninterrupted in-memory run."""
    return mcfdd.run_campaign(small, progress=False)


@pytest.fixture(scope="module")
def clean(clean_result):
    """The campaign's table from an uninterrupted in-memory run."""
    return clean_result.scenarios


@pytest.fixture(scope="module")
def finished(small, tmp_path_factory):
    """A folder holding the whole campaign, written by the command."""
    out = tmp_path_factory.mktemp("finished") / "c"
    assert cli.main(["campaign", str(small), "--out", str(out)]) == 0
    return out


def _binary(tmp_path, small):
    path = tmp_path / "binary.toml"
    path.write_bytes(bytes(range(256)) * 4)
    return [path], [str(path), "not a text file"]


def _latin1(tmp_path, small):
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"[campaign]\nscenarios = 8 # caf\xe9\n")
    return [path], [str(path), "UTF-8"]


def _missing(tmp_path, small):
    return [tmp_path / "nothing.toml"], ["nothing.toml", "no such configuration file"]


def _out_onto_file(tmp_path, small):
    target = tmp_path / "a-file"
    target.write_text("keep me")
    return [small, "--out", target], ["--out", str(target), "not a folder"]


def _seed(tmp_path, small):
    return [small, "--seed", 99999999999999999999], ["--seed", "99999999999999999999", "[0, 4294967295]"]


def _scenarios(tmp_path, small):
    return [small, "--scenarios", 20000000], ["--scenarios", "20000000", "[1, 10000000]"]


def _chunk_size(tmp_path, small):
    return [small, "--chunk-size", 0], ["--chunk-size", "[1, 1000000]"]


def _not_a_multiple(tmp_path, small):
    return [small, "--scenarios", 322, "--set", 'campaign.grid=["fault_kind"]'], [
        "campaign.scenarios", "322 is not a multiple of the 5 grid cells of fault_kind"]


def _settle(tmp_path, small):
    return [small, "--set", "evaluation.settle_s=4.0"], ["evaluation.settle_s", "not below the runs' duration (4.0 s)"]


def _manoeuvre_window(tmp_path, small):
    return [small, "--set", "campaign.duration_s=60.0", "--set", "space.t_start_s=[20.0, 90.0]"], [
        "space.t_start_s", "manoeuvres up to 90.0 s start at or after the end of the runs (60.0 s)"]


def _onset(tmp_path, small):
    return [small, "--set", "space.fault_onset_s=[1.0, 5.0]"], ["space.fault_onset_s", "up to 5.0 s"]


def _empty_space(tmp_path, small):
    path = tmp_path / "empty_space.toml"
    path.write_text("[campaign]\nscenarios = 8\nduration_s = 4.0\n")
    return [path], [str(path), "space: nothing varies"]


def _bad_fdd_file(tmp_path, small):
    path = tmp_path / "fdd.toml"
    path.write_bytes(b"\xff\xfe[fdd]\n")
    return [small, "--fdd", path], [str(path), "not a text file"]


def _tls_without_scheduler(tmp_path, small):
    return [small, "--tls-cert", tmp_path / "cert.pem"], ["--tls-cert", "only used with --scheduler"]


def _tls_with_local_workers(tmp_path, small):
    return [small, "--workers", 2, "--tls-ca-file", tmp_path / "ca.pem"], ["--tls-ca-file",
                                                                           "only used with --scheduler"]


def _read_only(tmp_path, small, monkeypatch):
    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(pathlib.Path, "mkdir", read_only)
    return [small], [str(tmp_path / "out"), os.strerror(errno.EROFS)]


def _nested(tmp_path, small):
    path = tmp_path / "nested.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    return [path], [str(path), "nested too deeply"]


def _folder_as_config(tmp_path, small):
    return [tmp_path], [str(tmp_path), "a folder, not a configuration file"]


def _device_as_config(tmp_path, small):
    return [os.devnull], [os.devnull, "not a regular file, not a configuration file"]


def _nested_set(tmp_path, small):
    return [small, "--set", "fdd.loe.tau=" + "[" * 5000 + "]" * 5000], ["--set", "nested too deeply"]


def _compile_cache(tmp_path, small):
    return [small, "--compile-cache", os.devnull + "/cache"], ["--compile-cache", os.devnull]


CASES = {f.__name__[1:]: f for f in (_binary, _latin1, _missing, _out_onto_file, _seed, _scenarios, _chunk_size,
                                     _not_a_multiple, _settle, _manoeuvre_window, _onset, _empty_space,
                                     _bad_fdd_file, _tls_without_scheduler, _tls_with_local_workers, _nested,
                                     _folder_as_config, _device_as_config, _nested_set, _compile_cache)}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_is_refused_naming_it_before_any_folder_is_made(case, small, tmp_path, capsys):
    args, named = CASES[case](tmp_path, small)
    out = tmp_path / "out"
    if "--out" not in args:
        args = [*args, "--out", out]
    line = refused(capsys, "campaign", *args)
    for text in named:
        assert text in line
    assert not out.exists()


def test_every_refusal_of_an_option_names_it_as_the_command_does(small, finished, tmp_path, capsys):
    """One convention: an option is named as its flag (--out, --resume, --workers, --compile-cache, --scheduler),
    whether the command or the library refused it; folder and machine limits are not called configuration errors."""
    target = tmp_path / "a-file"
    target.write_text("keep me")
    cases = [(["--out", target], "mcfdd: --out: "), (["--out", finished], "mcfdd: --out: "),
             (["--out", tmp_path / "none", "--resume"], "mcfdd: --resume: "),
             (["--out", tmp_path / "w", "--workers", 100000], "mcfdd: --workers: "),
             (["--out", tmp_path / "c", "--compile-cache", target], "mcfdd: configuration error: --compile-cache: "),
             (["--out", tmp_path / "s", "--scheduler", "tcp://127.0.0.1"], "mcfdd: --scheduler: ")]
    for args, start in cases:
        line = refused(capsys, "campaign", small, *args)
        assert line.startswith(start), line
    for call, start in ((lambda: mcfdd.run_campaign(small, out=target), "--out: "),
                        (lambda: mcfdd.run_campaign(small, out=tmp_path / "none", resume=True), "--resume: ")):
        with pytest.raises(mcfdd.OutputFolderError) as err:
            call()
        assert str(err.value).startswith(start)


def test_simulate_refuses_a_manoeuvre_or_fault_after_the_end_of_the_run(tmp_path, capsys):
    path = tmp_path / "late.toml"
    for run, key in (('manoeuvre = { kind = "doublet", t_start_s = 25.0 }', "runs[1].manoeuvre.t_start_s"),
                     ('fault = { kind = "leakage", size = 0.2, onset_s = 20.0 }', "runs[1].fault.onset_s")):
        path.write_text('[simulation]\nduration_s = 20.0\n[[runs]]\nname = "ok"\n'
                        f'[[runs]]\nname = "late"\n{run}\n')
        line = refused(capsys, "simulate", path, "--out", tmp_path / "s")
        assert f"{key}: the" in line and "at or after the end of the run (20.0 s, simulation.duration_s)" in line
    assert not (tmp_path / "s").exists()


def test_read_only_output_folder_is_named(small, tmp_path, capsys, monkeypatch):
    args, named = _read_only(tmp_path, small, monkeypatch)
    line = refused(capsys, "campaign", *args, "--out", tmp_path / "out", "--compile-cache", "off")
    for text in named:
        assert text in line


def test_an_in_process_campaign_prints_no_workers_line(small, tmp_path, capsys):
    assert cli.main(["campaign", str(small), "--out", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert f"{N} scenarios (" in out and "false alarms per fault-free run: LOE " in out and "summary: " in out
    assert "workers:" not in out


def test_simulate_out_onto_a_file_is_refused_before_simulating(tmp_path, capsys):
    target = tmp_path / "a-file"
    target.write_text("keep me")
    line = refused(capsys, "simulate", CONFIGS / "fig5.toml", "--out", target)
    assert "--out" in line and str(target) in line
    assert target.read_text() == "keep me"


def test_full_disk_mid_run_is_named_and_resume_completes_the_table(small, clean, tmp_path, capsys, monkeypatch):
    out = tmp_path / "c"
    write_table, calls = io.write_table, []

    def disk_full_at_second_part(df, path, meta):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return write_table(df, path, meta)

    monkeypatch.setattr(io, "write_table", disk_full_at_second_part)
    line = refused(capsys, "campaign", small, "--out", out)
    assert str(calls[1]) in line and os.strerror(errno.ENOSPC) in line and "--resume" in line
    assert line.startswith("mcfdd: --out: cannot write")  # a full disk is not a configuration error
    monkeypatch.setattr(io, "write_table", write_table)
    assert [p.name for p in (out / "scenarios").glob("*.parquet")] == [calls[0].name]
    assert cli.main(["campaign", str(small), "--out", str(out), "--resume"]) == 0
    pd.testing.assert_frame_equal(scenario_table(out), clean, check_exact=True)


def test_changed_config_on_resume_names_every_differing_key(small, finished, capsys):
    line = refused(capsys, "campaign", small, "--out", finished, "--resume", "--seed", 3, "--set",
                   "fdd.loe.tau=0.2")
    assert "campaign.seed was 7, now 3" in line and "fdd.loe.tau was 0.1, now 0.2" in line


def test_folder_in_use_is_refused_naming_it(small, finished, capsys):
    lock = io.lock_folder(finished)
    try:
        for extra in ([], ["--resume"]):
            line = refused(capsys, "campaign", small, "--out", finished, *extra)
            assert str(finished) in line and "in use" in line
    finally:
        lock.release()
    again = io.lock_folder(finished)
    assert again is not None
    again.release()


@pytest.mark.parametrize("damage", ["truncated", "corrupted bytes"])
def test_damaged_part_is_named_and_run_again_on_resume(damage, small, clean, finished, tmp_path, capsys):
    out = tmp_path / "c"
    shutil.copytree(finished, out)
    parts = sorted((out / "scenarios").glob("part-*.parquet"))
    assert len(parts) > 1
    victim = parts[1]
    data = bytearray(victim.read_bytes())
    if damage == "truncated":
        data = data[:len(data) // 2]
    else:
        data[len(data) // 3:len(data) // 3 + 16] = bytes(16)
    victim.write_bytes(bytes(data))
    simulated = []
    result = mcfdd.run_campaign(small, out=out, resume=True, progress=False, on_chunk=simulated.append)
    err = capsys.readouterr().err
    assert f"{victim} is damaged" in err
    assert (out / "scenarios" / (victim.name + ".damaged")).is_file()
    rows = pd.read_parquet(finished / "scenarios" / victim.name)["scenario_id"].to_numpy()
    assert len(simulated) == 1 and list(simulated[0]) == list(rows)
    pd.testing.assert_frame_equal(result.scenarios, clean, check_exact=True)
    pd.testing.assert_frame_equal(scenario_table(out), clean, check_exact=True)


def test_sigkill_between_chunks_then_resume_gives_the_clean_table(small, clean, tmp_path):
    out = tmp_path / "killed"
    log = tmp_path / "killed.log"
    with log.open("w") as stderr:
        proc = subprocess.Popen([sys.executable, "-m", "mcfdd.cli", "campaign", str(small), "--out", str(out)],
                                stdout=subprocess.DEVNULL, stderr=stderr)
        deadline = time.monotonic() + 600
        while not list((out / "scenarios").glob("part-*.parquet")) and proc.poll() is None:
            assert time.monotonic() < deadline, "no part written in 600 s"
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, log.read_text()
    written = list((out / "scenarios").glob("part-*.parquet"))
    assert 0 < len(written) and sum(len(pd.read_parquet(p)) for p in written) < N
    assert (out / io.LOCK_NAME).is_file()  # the lock file stays; its OS lock died with the process
    resumed = mcfdd.run_campaign(small, out=out, resume=True, progress=False)
    assert 0 < resumed.simulated < N
    pd.testing.assert_frame_equal(scenario_table(out), clean, check_exact=True)
    assert json.loads((out / "campaign.json").read_text())["campaign"]["seed"] == 7


def test_scenarios_is_the_total_split_evenly_over_the_grid_cells():
    cfg = mcfdd.load_config(CONFIGS / "loe_campaign.toml")
    cols, n = build.design(cfg)
    assert n == cfg.campaign.scenarios == 16384
    assert pd.Series(cols["fault_kind"]).value_counts().to_dict() == {
        k: 4096 for k in ("none", "leakage", "surface_damage", "disconnection")}
    assert campaign_workflow.design_line(cfg, n) == "16384 scenarios = 4096 samples x 4 cells of fault_kind"
    stall = mcfdd.load_config(CONFIGS / "stall_campaign.toml", overrides={"campaign.scenarios": 512})
    assert build.design(stall)[1] == 512
    assert campaign_workflow.design_line(stall, 512) == (
        "512 scenarios = 64 samples x 8 cells of fault_kind x manoeuvre_kind")


def test_printed_text_says_n_a_where_a_value_does_not_exist(clean):
    free = clean[(clean["fault_kind"] == "none") & (clean["stall_events"] == 0)]
    summ = report.summary(free)
    text = report.markdown("fault-free", summ, report.confusion(free, ["a"] * 6), report.gaps(free, 1.0), {})
    text += report.stall_scoring_markdown(free)
    assert "nan" not in text and "n/a" in text
    assert "stall events" not in text and "worst" not in text  # no stall columns without a stall load
    overall = summ[summ["stratum"] == "overall"].iloc[0].to_dict()
    assert console.rate_text(overall, "mdr") == "n/a"
    assert console.rate_text(overall, "far_loe").startswith(f"{overall['far_loe']:.4g} [")
    assert console.decisions_text({"pressure-loss-27": 21.740000000000002}) == "pressure-loss-27 at 21.74 s"
    assert console.decisions_text({}) == "none"
    assert console.value_text(float("nan"), ".2f", " s") == "n/a" and console.value_text(1.234, ".2f", " s") == "1.23 s"


STARTUP = """
import sys
from mcfdd import cli
try:
    code = cli.main(sys.argv[1:])
except SystemExit as exit:
    code = exit.code
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib", "numpy", "pandas", "pyarrow", "pydantic",
                                                            "matplotlib", "distributed")
               or m.startswith("mcfdd.") and m not in ("mcfdd.cli", "mcfdd.arguments", "mcfdd.devices"))
print(code, heavy)
"""


@pytest.mark.parametrize("argv", [["--help"], ["campaign", "--help"], ["schema", "--help"], ["nothing"],
                                  ["campaign", "x.toml", "--bogus"], ["campaign", "x.toml", "--scenarios", "many"],
                                  ["campaign", "x.toml", "--workers", "2", "--scheduler", "tls://h:1"]])
def test_help_and_argument_errors_load_neither_jax_nor_the_workflows(argv):
    """The command parses its arguments before it imports what it runs (start-up in a fraction of a second)."""
    proc = subprocess.run([sys.executable, "-c", STARTUP, *argv], capture_output=True, text=True, check=True)
    code, heavy = proc.stdout.splitlines()[-1].split(" ", 1)
    assert code == ("0" if "--help" in argv else "2"), proc.stderr
    assert heavy.strip() == "[]", heavy


def test_the_public_names_import_on_first_use():
    """``import mcfdd`` is light; each public name resolves to the object of the module that holds it."""
    code = ("import sys, mcfdd; light = 'jax' not in sys.modules; from mcfdd.workflows import campaign; "
            "print(light, mcfdd.run_campaign is campaign.run_campaign, sorted(set(mcfdd.__all__) - set(dir(mcfdd))))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.split() == ["True", "True", "[]"], proc.stdout + proc.stderr


def test_schema_help_names_every_config_kind(capsys):
    with pytest.raises(SystemExit):
        cli.main(["schema", "--help"])
    helped = " ".join(capsys.readouterr().out.split())
    assert all(kind in helped for kind in mcfdd.config.KINDS)
    line = refused(capsys, "schema", "nothing")
    assert "kind: 'nothing'" in line


@pytest.mark.parametrize("delay_s", [0.5, 2.0, 4.0, 6.0])
def test_ctrl_c_while_compiling_exits_with_130(small, tmp_path, delay_s):
    """SIGINT while XLA compiles the chunk program (compilation cache off: about 15 s here): status 130 and
    the one line, never a crash of the runtime's teardown under a compilation still running."""
    code, err = interrupted(small, tmp_path / "c", "campaign: ", delay_s)
    assert code == 130, err
    assert "Traceback" not in err
    assert "mcfdd: interrupted" in err, err


@pytest.mark.parametrize("delay_s", [0.5, 1.0, 1.5, 2.5])
def test_ctrl_c_while_starting_exits_with_130(small, tmp_path, delay_s):
    """SIGINT before the campaign starts (imports, configuration): status 130, one line, no folder made. While
    JAX is imported, the interrupt often lands in its garbage-collection callback, where Python ignores it."""
    code, err = interrupted(small, tmp_path / "c", None, delay_s)
    assert code == 130 and "Traceback" not in err and "Exception ignored" not in err, err
    assert "mcfdd: interrupted" in err
    assert not (tmp_path / "c").exists() or "continue with --resume" in err


def _files(folder) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_save_never_merges_into_another_campaign(small, finished, tmp_path):
    """Saving a result of another configuration into a campaign's folder is refused and changes nothing."""
    other = mcfdd.run_campaign(mcfdd.load_config(small, overrides={"campaign.seed": 8}), progress=False)
    target = tmp_path / "d"
    shutil.copytree(finished, target)
    before = _files(target)
    with pytest.raises(mcfdd.OutputFolderError, match=f"--out: {target} exists and is not empty"):
        other.save(target)
    assert _files(target) == before
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "notes.txt").write_text("mine")
    with pytest.raises(mcfdd.OutputFolderError, match="not empty"):
        other.save(tmp_path / "e")
    assert [p.name for p in (tmp_path / "e").iterdir()] == ["notes.txt"]


def test_save_onto_a_file_is_the_one_line_error(clean_result, tmp_path):
    target = tmp_path / "a-file"
    target.write_text("keep me")
    with pytest.raises(mcfdd.OutputFolderError, match=f"--out: {target} exists and is not a folder"):
        clean_result.save(target)
    assert target.read_text() == "keep me"


def test_save_completes_its_own_campaign_but_not_other_chunks_of_it(small, clean_result, finished, tmp_path):
    """The same campaign may be saved into its folder (the same parts, bit for bit); parts of another chunking
    would make a table with repeated scenarios, so that is refused."""
    target = tmp_path / "same"
    shutil.copytree(finished, target)
    before = _files(target)
    clean_result.save(target)
    after = _files(target)
    parts = {k: v for k, v in before.items() if k.parts[0] == "scenarios"}
    assert {k: after[k] for k in parts} == parts
    rechunked = mcfdd.run_campaign(mcfdd.load_config(small, overrides={"campaign.chunk_size": 256}), progress=False)
    with pytest.raises(mcfdd.OutputFolderError, match="parts of this campaign in other chunks"):
        rechunked.save(target)
    busy = io.lock_folder(target)
    try:
        with pytest.raises(mcfdd.OutputFolderError, match="in use"):
            clean_result.save(target)
    finally:
        busy.release()


def test_a_deleted_campaign_json_is_rebuilt_on_resume(small, clean, finished, tmp_path, capsys):
    """The parts carry the resolved configuration: ``--resume`` rebuilds campaign.json from it, still refuses a
    changed configuration naming the key, and completes the table."""
    out = tmp_path / "c"
    shutil.copytree(finished, out)
    original = (out / "campaign.json").read_text()
    parts = sorted((out / "scenarios").glob("part-*.parquet"))
    parts[-1].unlink()
    (out / "campaign.json").unlink()
    line = refused(capsys, "campaign", small, "--out", out, "--resume", "--seed", 3)
    assert "campaign.seed was 7, now 3" in line
    assert (out / "campaign.json").read_text() == original
    (out / "campaign.json").unlink()
    assert cli.main(["campaign", str(small), "--out", str(out), "--resume"]) == 0
    assert "rebuilt from the configuration the parts carry" in capsys.readouterr().err
    assert (out / "campaign.json").read_text() == original
    pd.testing.assert_frame_equal(scenario_table(out), clean, check_exact=True)


def test_resume_without_anything_to_rebuild_from_says_how(small, tmp_path, capsys):
    (tmp_path / "c").mkdir()
    line = refused(capsys, "campaign", small, "--out", tmp_path / "c", "--resume")
    assert "campaign.json missing and no scenario part to rebuild it from" in line and "without --resume" in line


def test_false_alarms_are_counted_per_fault_free_run_loe_and_any_apart(small, tmp_path, capsys):
    """A faulty run can false-alarm only before its onset: the rates count the fault-free runs alone (LOE
    detection, any alarm, false identification), per run and per hour of scored time, in the table, the printed
    lines and summary.md."""
    alarming = {"fdd.loe.tau": 0.03, "fdd.loe.detection_tau": 0.03, "fdd.loe.detection_contrast": 0.0,
                "fdd.loe.confirm_s": 0.0, "fdd.loe.excitation_floor_deg": 0.005, "fdd.loe.excitation_noise_factor": 0.0,
                "fdd.loe.load_gate": "fault_free"}
    out = tmp_path / "c"
    assert cli.main(["campaign", str(small), "--out", str(out),
                     *[a for k, v in alarming.items() for a in ("--set", f"{k}={v}")]]) == 0
    printed = capsys.readouterr().out
    table = pd.read_parquet(out / "scenarios")
    ok = table["status"] == 0
    free = table[ok & (table["fault_kind"] == "none")]
    before_onset = table[ok & (table["fault_kind"] != "none") & table["false_alarm"]]
    assert len(before_onset) > 0, "faulty runs that alarm before their onset (so pooling would change the rate)"
    loe, any_alarm = int(free["false_alarm"].sum()), int((free["false_alarm"] | free["eta_false_signal"]).sum())
    identifications = int(free["false_identification"].sum())
    overall = pd.read_parquet(out / "summary.parquet").query("stratum == 'overall'").iloc[0]
    hours = len(free) * (4.0 - 0.5) / 3600.0
    assert (overall["fault_free_runs"], overall["false_alarms_loe"], overall["false_alarms_any"],
            overall["false_identifications"]) == (len(free), loe, any_alarm, identifications)
    assert overall["far_loe"] == pytest.approx(loe / len(free)) and overall["far_any"] == pytest.approx(
        any_alarm / len(free))
    assert overall["scored_fault_free_h"] == pytest.approx(hours) and overall["far_loe_per_h"] == pytest.approx(
        loe / hours)
    assert not {"far", "far_lo", "far_hi", "loe_far", "false_alarms", "loe_false_alarms"} & set(overall.index)
    assert f"false alarms per fault-free run: LOE {loe}/{len(free)} = " in printed
    assert f"any alarm (LOE or stall identification) {any_alarm}/{len(free)} = " in printed
    assert f"false identifications {identifications}/{len(free)}" in printed
    text = (out / "summary.md").read_text()
    assert "| fault-free runs | LOE false alarms | any false alarm | false identifications |" in text
    assert f"| all | {len(table)} | {len(free)} | {loe}/{len(free)} = " in text

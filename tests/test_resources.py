"""Bounded resources: worker processes, memory of campaigns and histories, long chunks announced.

Memory limits are simulated by replacing ``resources.available_bytes``; the estimates themselves are
checked against the peak resident memory of real runs in subprocesses.
"""

import pandas as pd
import pytest

import mcfdd
from helpers import interrupted, refused, small_config
from mcfdd import cli
from mcfdd.workflows import resources
from mcfdd.workflows.common import precision

N = 384  # the small campaign's scenarios, as in test_cli_errors: several chunks


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return small_config(tmp_path_factory.mktemp("config"), N)


def test_workers_beyond_the_cores_are_refused_before_a_cluster_starts(small, tmp_path, capsys):
    cores = resources.cores()
    code = cli.main(["campaign", str(small), "--workers", str(cores + 1), "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"mcfdd: --workers: {cores + 1} is more than this machine's {cores} cores; at most " \
           f"{cores}" in err
    assert not (tmp_path / "a").exists()


def test_workers_beyond_the_memory_are_refused_naming_the_footprint(small, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(resources, "available_bytes", lambda: 0.5 * resources.RUNTIME_BYTES)
    line = refused(capsys, "campaign", small, "--workers", 1, "--out", tmp_path / "a")
    assert "--workers: 1 workers need about 1 GiB (1 GiB each with JAX and the compiled program), more than the " \
           "0.5 GiB available; at most 0" in line
    with pytest.raises(mcfdd.ConfigError, match="--workers: 1 workers need"):
        with mcfdd.dask_cluster(workers=1):
            pass


def test_ctrl_c_while_the_local_cluster_starts_ends_it_and_exits_with_130(small, tmp_path):
    import psutil

    children = []
    code, err = interrupted(small, tmp_path / "c", "campaign: starting a local Dask cluster", 1.0, "--workers", "2",
                            children=children)
    assert code == 130 and "Traceback" not in err, err
    assert err.splitlines()[-1].startswith("mcfdd: interrupted"), err
    gone, alive = psutil.wait_procs(children, timeout=60)
    assert not alive, alive


def test_a_chunk_too_large_for_the_memory_is_split_with_the_same_table(small, tmp_path, capsys, monkeypatch):
    """Room for chunks of about 40 scenarios: the campaign runs chunks of 32 (2 devices x 16) and says why."""
    from mcfdd.workflows import campaign as runner

    clean = mcfdd.run_campaign(small, progress=False).scenarios

    cfg = mcfdd.load_config(small)
    with precision(cfg.campaign.precision):
        setup = runner.campaign_setup(cfg)
    per = runner.scenario_bytes(setup)
    room = resources.chunk_bytes(40, per)
    monkeypatch.setattr(resources, "available_bytes", lambda: resources.table_bytes(N) + room)
    chunks = []
    result = mcfdd.run_campaign(small, progress=False, on_chunk=chunks.append)
    assert "campaign: chunks of 64 scenarios would need about" in capsys.readouterr().err
    assert {len(c) for c in chunks} == {32}
    pd.testing.assert_frame_equal(result.scenarios, clean, check_exact=True)


@pytest.mark.parametrize("room, key", [(0.5, "campaign.scenarios: the table of"),
                                       (1.0, "campaign.chunk_size: even a chunk of 16 scenarios needs about")])
def test_a_campaign_that_cannot_fit_is_refused_before_any_folder(small, tmp_path, capsys, monkeypatch, room, key):
    """No room for the table (0.5 runtimes in all), or for the table and a process but not one lane of scenarios."""
    available = room * resources.RUNTIME_BYTES + (resources.table_bytes(N) if room >= 1 else 0)
    monkeypatch.setattr(resources, "available_bytes", lambda: available)
    line = refused(capsys, "campaign", small, "--out", tmp_path / "c")
    assert key in line and "GiB" in line
    assert not (tmp_path / "c").exists()


def test_a_long_chunk_is_announced_before_it_starts(small, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(resources, "CAUTIOUS_RATE", 100.0)
    assert cli.main(["campaign", str(small), "--out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err
    announced = err.index("campaign: a chunk of 64 scenarios x 400 steps may take up to")
    assert announced < err.index("scenarios:") and "a smaller --chunk-size" in err


def test_simulate_refuses_histories_that_do_not_fit_naming_the_number(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(resources, "available_bytes", lambda: 4 * resources.GIB)
    path = tmp_path / "long.toml"
    path.write_text("[simulation]\nduration_s = 3600.0\n" + "".join(
        f'[[runs]]\nname = "r{i}"\nmanoeuvre = {{ kind = "doublet", amplitude = 0.5, t_start_s = 1.0 }}\n'
        for i in range(40)))
    line = refused(capsys, "simulate", path, "--out", tmp_path / "s")
    assert "simulation.duration_s: 40 run(s) x 360000 steps x" in line and "more than the 4 GiB available" in line
    assert not (tmp_path / "s").exists()


def _memory_guard():
    """``benchmarks/memory_guard.py``, whose ``measure`` runs a command in a fresh process and returns the estimate
    its guard used and the process's peak resident memory (bytes)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "memory_guard.py"
    spec = importlib.util.spec_from_file_location("memory_guard", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("kind, size", [("campaign", 64), ("simulate", 40)])
def test_the_estimate_bounds_the_measured_peak(kind, size):
    """A campaign chunk of 64 scenarios, and 40 runs of 300 s of histories: the guard's estimate is above the
    measured peak, and not by more than three times."""
    m = _memory_guard().measure(kind, size)
    assert m["peak"] <= m["estimate"] <= 3 * m["peak"], m

"""Campaigns and probability estimates on Dask distributed: same tables as one process, worker deaths, Ctrl-C,
addresses and loopback.

Also the design rows built by index (what lets a worker rebuild its chunk from the ids alone) and
the persistent compilation cache. Every cluster and process started here is closed or killed in
its fixture's teardown.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest
import tomli_w

import mcfdd
from mcfdd import cli
from mcfdd.analysis import build, scenarios
from mcfdd.devices import DEVICES_PER_CORE
from mcfdd.workflows import cluster as dask_cluster, common

distributed = pytest.importorskip("distributed")

SPACE = {"vcas_kt": [150.0, 350.0], "altitude_m": [0.0, 9000.0], "fault_kind": ["none", "leakage"],
         "leakage_size": [0.1, 0.4], "manoeuvre_kind": ["quiet", "doublet"], "fault_onset_s": 0.2, "t_start_s": 0.1}
EVALUATION = {"settle_s": 0.0}
CAMPAIGN = {"scenarios": 384, "duration_s": 0.5, "chunk_size": 128, "seed": 5, "design": "sobol"}
CFG = mcfdd.load_config({"campaign": CAMPAIGN, "space": SPACE, "evaluation": EVALUATION}, "campaign")
LOE_CAMPAIGN = str(Path(__file__).resolve().parent.parent / "configs" / "loe_campaign.toml")


@pytest.fixture(scope="module")
def reference():
    """The scenario table of CFG run in this process."""
    return mcfdd.run_campaign(CFG, progress=False).scenarios


@pytest.fixture(scope="module")
def local():
    """A client of a local cluster of two worker processes (one thread each), closed at the end."""
    with mcfdd.dask_cluster(workers=2) as client:
        client.wait_for_workers(2, timeout=60)
        yield client


def _same(reference, table):
    pd.testing.assert_frame_equal(reference, table, check_exact=True)


@pytest.mark.filterwarnings("ignore:The balance properties of Sobol")
def test_design_rows_built_by_index_are_the_rows_of_the_whole_design():
    rng = np.random.default_rng(0)
    for design in ("random", "sobol", "lhs"):
        whole = scenarios.unit_sample(design, 3, 200, seed=4)
        draws = rng.integers(0, 200, 50)
        assert np.array_equal(scenarios.unit_rows(design, 3, draws, 4, whole if design == "lhs" else None),
                              whole[draws]), design
    grid_mach = {"vcas_kt": {"values": [250.0, 420.0]}, "altitude_m": [0.0, 11000.0], "kd_scale": [0.8, 1.2]}
    for campaign, space in (({"design": "lhs", "grid": ["fault_kind"]}, SPACE), ({"design": "random"}, SPACE),
                            ({"design": "sobol", "grid": ["vcas_kt"]}, grid_mach)):
        cfg = mcfdd.load_config({"campaign": {"scenarios": 60, "seed": 2, **campaign}, "space": space,
                                 "evaluation": EVALUATION}, "campaign")
        cols, n = build.design(cfg)
        plan = build.design_plan(cfg)
        ids = rng.permutation(n)[:17]  # not consecutive, any order
        chunk = build.design_chunk(cfg, plan, ids)
        assert plan.n == n and list(chunk) == list(cols)
        assert (plan.rows is None) == (space is not grid_mach), "grid rows above the Mach limit are dropped"
        for name in cols:
            assert np.array_equal(np.asarray(cols[name])[ids], chunk[name]), (campaign, name)


def test_two_local_workers_give_the_in_process_table(local, reference):
    result = mcfdd.run_campaign(CFG, progress=False, executor=local)
    _same(reference, result.scenarios)
    assert result.workers["scenarios"].sum() == CAMPAIGN["scenarios"]
    assert len(result.workers) == 2 and (result.workers["scenario_steps_per_s"] > 0).all()


def test_probability_on_two_local_workers_is_the_in_process_result(local):
    """Two strata (turbulence), two airframe corners (kci_scale), two runs each: every table and point to the bit."""
    cfg = mcfdd.load_config({
        "campaign": {"duration_s": 1.2, "seed": 3},
        "evaluation": {"settle_s": 0.5},
        "fdd": {"loe": {"detection_tau": 0.004, "detection_contrast": 0.0, "detection_confirm_s": 0.0,
                        "confirm_s": 0.2, "load_gate": "fault_free", "excitation_floor_deg": 0.15,
                        "excitation_noise_factor": 0.0}},
        "space": {"vcas_kt": [200.0, 360.0], "kci_scale": [0.9, 1.1], "turbulence": ["light", "moderate"],
                  "fault_kind": "none", "manoeuvre_kind": "doublet", "t_start_s": [0.2, 1.0]},
        "probability": {"samples": 100, "chunk": 50, "repeats": 2, "budget": 100,
                        "airframe": {"axes": ["kci_scale"], "view": "corner"}}}, "campaign")
    here = mcfdd.probability(cfg, progress=False)
    there = mcfdd.probability(cfg, progress=False, executor=local)
    for name in ("strata", "runs", "levels", "failures", "airframes"):
        pd.testing.assert_frame_equal(getattr(here, name), getattr(there, name), check_exact=True)
    assert len(here.runs) == 4 and len(here.airframes) == 4 and (here.runs["hits"] > 0).any()
    np.testing.assert_array_equal(here.failure_points, there.failure_points)
    assert (here.overall.estimate, here.overall.cov, here.overall.interval) == (
        there.overall.estimate, there.overall.cov, there.overall.interval)


@pytest.mark.filterwarnings("ignore:The balance properties of Sobol")
def test_a_campaign_run_on_dask_workers_replays_its_rows_bit_for_bit(local, tmp_path):
    mcfdd.run_campaign(CFG, out=tmp_path, progress=False, executor=local)
    result = mcfdd.replay(tmp_path, [383, 0, 200], progress=False)  # three chunks of 128
    assert result.differences() == []
    pd.testing.assert_frame_equal(result.rows, result.outcomes[list(result.rows.columns)], check_exact=True)


def test_local_workers_get_their_share_of_the_cores(local):
    def devices():
        import jax  # on the worker: the function is sent to it, the test module's names are not

        return jax.device_count()

    assert set(local.run(devices).values()) == {DEVICES_PER_CORE * max(1, os.cpu_count() // 2)}


LOOPBACK_HEX = {"0100007F", "00000000000000000000000001000000", "0000000000000000FFFF00000100007F"}


def _listening(pids) -> list[str]:
    """Local addresses (hex IP of /proc/net/tcp*) of the TCP sockets in LISTEN state held by processes ``pids``."""
    inodes = set()
    for pid in pids:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(OSError):
                link = os.readlink(fd)
                if link.startswith("socket:["):
                    inodes.add(link[len("socket:["):-1])
    return [fields[1].split(":")[0] for table in ("/proc/net/tcp", "/proc/net/tcp6")
            for fields in (line.split() for line in Path(table).read_text().splitlines()[1:])
            if fields[3] == "0A" and fields[9] in inodes]


def test_local_cluster_listens_on_loopback_only(local):
    info = local.scheduler_info(n_workers=-1)
    addresses = [info["address"]] + list(info["workers"]) + [w["nanny"] for w in info["workers"].values()]
    assert len(addresses) == 1 + 2 * 2
    assert all(a.startswith("tcp://127.0.0.1:") for a in addresses), addresses
    # Every listening socket of the driver (scheduler, nannies, the scheduler's HTTP routes) and of the workers.
    sockets = _listening({os.getpid(), *local.run(os.getpid).values()})
    assert len(sockets) >= len(addresses) + 1 and set(sockets) <= LOOPBACK_HEX, sockets


def test_a_worker_killed_with_a_chunk_in_hand_leaves_the_table_identical(local):
    cfg = mcfdd.load_config({"campaign": {**CAMPAIGN, "scenarios": 640}, "space": SPACE, "evaluation": EVALUATION},
                            "campaign")  # 5 chunks
    reference = mcfdd.run_campaign(cfg, progress=False).scenarios
    pids = local.run(os.getpid)
    killed = []

    def kill_once(ids):
        if not killed:  # after the first chunk: both workers hold one of the four left
            victim = next(a for a, keys in local.processing().items() if keys and a in pids)
            os.kill(pids[victim], signal.SIGKILL)
            killed.append(victim)

    result = mcfdd.run_campaign(cfg, progress=False, executor=local, on_chunk=kill_once)
    assert killed
    _same(reference, result.scenarios)


def test_ctrl_c_cancels_the_tasks_and_resume_finishes_in_process(local, reference, tmp_path):
    def interrupt(ids):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        mcfdd.run_campaign(CFG, out=tmp_path, progress=False, executor=local, on_chunk=interrupt)
    assert len(list((tmp_path / "scenarios").glob("part-*.parquet"))) == 1
    deadline = time.monotonic() + 30
    while any(local.processing().values()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(local.processing().values()), "the remaining chunks were cancelled"
    resumed = mcfdd.run_campaign(CFG, out=tmp_path, resume=True, progress=False)
    assert resumed.simulated == CAMPAIGN["scenarios"] - 128
    _same(reference, resumed.scenarios)


@pytest.fixture
def hand_started(tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, as a user starts them; killed at the end."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # the workers' device count is mcfdd's choice
    dask = [sys.executable, "-m", "dask"]
    file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                      "--scheduler-file", str(file)], env=env, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        for _ in range(2):
            procs.append(subprocess.Popen(dask + ["worker", "--scheduler-file", str(file), "--nthreads", "1",
                                                  "--host", "127.0.0.1", "--no-dashboard"], env=env,
                                          stderr=subprocess.DEVNULL))
        address = json.loads(file.read_text())["address"]
        with distributed.Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            proc.kill()
            proc.wait(timeout=30)


def test_scheduler_and_workers_started_by_hand_give_the_in_process_table(hand_started, reference, tmp_path, capsys):
    config_file = tmp_path / "campaign.toml"
    config_file.write_text(tomli_w.dumps({"campaign": CAMPAIGN, "space": SPACE, "evaluation": EVALUATION}))
    out = tmp_path / "out"
    assert cli.main(["campaign", str(config_file), "--out", str(out), "--scheduler", hand_started]) == 0
    assert "workers: " in capsys.readouterr().out
    _same(reference, pd.concat([pd.read_parquet(p) for p in sorted((out / "scenarios").glob("*.parquet"))],
                               ignore_index=True))
    with distributed.Client(hand_started, timeout=30) as client:
        def devices():
            import jax  # on the worker: the function is sent to it, the test module's names are not

            return jax.device_count()

        expected = {DEVICES_PER_CORE * max(1, os.cpu_count() // 2)}
        assert set(client.run(devices).values()) == expected, "the plugin shared the cores"


@pytest.fixture
def no_workers():
    """A scheduler on 127.0.0.1 without any worker."""
    with distributed.LocalCluster(n_workers=0, host="127.0.0.1", scheduler_kwargs={"dashboard": False}) as empty:
        yield empty.scheduler_address


@pytest.mark.parametrize("address, message", [
    ("127.0.0.1:8786", "is not an address"), ("udp://127.0.0.1:8786", "is not an address"),
    ("tcp://127.0.0.1", "is not an address"), ("tcp://127.0.0.1:9", "cannot reach"),
])
def test_bad_or_unreachable_schedulers_are_one_line_errors_within_the_timeout(address, message, capsys):
    start = time.monotonic()
    assert cli.main(["campaign", LOE_CAMPAIGN, "--scheduler", address, "--connect-timeout", "2"]) == 2
    assert time.monotonic() - start < 15
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err and address in err, err


def test_a_scheduler_without_workers_is_a_one_line_error_within_the_timeout(no_workers, capsys, tmp_path):
    start = time.monotonic()
    assert cli.main(["campaign", LOE_CAMPAIGN, "--out", str(tmp_path / "x"), "--scheduler", no_workers,
                     "--connect-timeout", "2"]) == 2
    assert time.monotonic() - start < 15
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "has no workers after 2 s" in err, err
    assert not (tmp_path / "x").exists()


def test_the_command_prints_the_plain_tcp_warning_as_one_line():
    command = [sys.executable, "-m", "mcfdd.cli", "campaign", LOE_CAMPAIGN, "--scheduler", "tcp://192.0.2.7:8786",
               "--connect-timeout", "1"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    warning, error = done.stderr.strip().splitlines()
    assert warning.startswith("mcfdd: warning: scheduler tcp://192.0.2.7:8786: plain tcp:// to another host")
    assert error.startswith("mcfdd: --scheduler: cannot reach tcp://192.0.2.7:8786 within 1 s")


def test_plain_tcp_to_another_host_warns_and_tls_or_loopback_do_not():
    with pytest.warns(UserWarning, match="plain tcp:// to another host"):
        dask_cluster.check_address("tcp://192.0.2.7:8786")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dask_cluster.check_address("tls://192.0.2.7:8786")
        dask_cluster.check_address("tcp://127.0.0.1:8786")


def test_tls_files_come_together_and_must_exist(tmp_path):
    with pytest.raises(mcfdd.ConfigError, match="--tls-key: missing"):
        dask_cluster.security(tmp_path / "ca.pem", tmp_path / "cert.pem")
    with pytest.raises(mcfdd.ConfigError, match="--tls-ca-file: .* is not a file"):
        dask_cluster.security(tmp_path / "ca.pem", tmp_path / "cert.pem", tmp_path / "key.pem")


def test_tls_set_up_faults_say_so_rather_than_cannot_reach(tmp_path, capsys):
    """A tls:// scheduler without TLS settings, and TLS files that hold no certificate, are named as TLS faults."""
    assert cli.main(["campaign", LOE_CAMPAIGN, "--scheduler", "tls://127.0.0.1:9", "--connect-timeout", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mcfdd: --scheduler: tls://127.0.0.1:9 is a tls:// address but no TLS settings") and \
        "cannot reach" not in err, err
    bad = tmp_path / "bad.pem"
    bad.write_text("not a certificate")
    assert cli.main(["campaign", LOE_CAMPAIGN, "--scheduler", "tls://127.0.0.1:9", "--connect-timeout", "2",
                     "--tls-ca-file", str(bad), "--tls-cert", str(bad), "--tls-key", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mcfdd: --tls-ca-file/--tls-cert/--tls-key: the TLS set-up for tls://127.0.0.1:9 failed") \
        and "\n" not in err, err


RUN_WITH_CACHE = """
import json, sys
import jax.monitoring
import mcfdd
hits = []
jax.monitoring.register_event_listener(lambda event, **kw: hits.append(event) if event.endswith("cache_hits") else None)
cfg = mcfdd.load_config(json.loads(sys.argv[1]), "campaign")
mcfdd.run_campaign(cfg, out=sys.argv[2], progress=False, compile_cache=sys.argv[3])
print(len(hits))
"""


def test_a_second_process_loads_the_compiled_program_from_the_cache_with_the_same_table(tmp_path):
    small = {"campaign": {**CAMPAIGN, "scenarios": 128}, "space": SPACE, "evaluation": EVALUATION}
    reference = mcfdd.run_campaign(mcfdd.load_config(small, "campaign"), progress=False, compile_cache="off")
    folder = tmp_path / "cache"
    one_device = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=1"}  # one compile, not two
    hits = []
    for run in ("cold", "warm"):
        command = [sys.executable, "-c", RUN_WITH_CACHE, json.dumps(small), str(tmp_path / run), str(folder)]
        done = subprocess.run(command, capture_output=True, text=True, check=True, env=one_device)
        hits.append(int(done.stdout.split()[-1]))
        table = pd.read_parquet(tmp_path / run / "scenarios" / "part-00000000.parquet")
        _same(reference.scenarios, table)
    assert any(p.name.startswith("jit_device_batch") for p in folder.iterdir())
    assert hits[0] == 0 and hits[1] >= 1, hits
    assert json.loads((tmp_path / "warm" / "campaign.json").read_text()) == json.loads(
        (tmp_path / "cold" / "campaign.json").read_text()), "the cache is not part of the resolved config"


def test_compile_cache_off_and_back_on():
    try:
        assert common.compile_cache("off") is None and not jax.config.jax_enable_compilation_cache
    finally:
        assert common.compile_cache(None) == common.default_compile_cache()
    assert jax.config.jax_enable_compilation_cache
    assert jax.config.jax_compilation_cache_dir == str(common.default_compile_cache())

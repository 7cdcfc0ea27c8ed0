"""Throughput of the full campaign pipeline (plant + both FDD systems + online reductions) in float32.

What is timed is :func:`mcfdd.analysis.campaign.run_batch` run the way ``mcfdd campaign`` runs it
(:func:`mcfdd.run_campaign`): the scenarios of a realistic mixed space (``SPACE`` below: four fault
kinds on a grid, four closed-loop manoeuvre families, turbulence, uncertainties, Latin hypercube
over the rest) are split into chunks of
``--chunk-size`` padded to a multiple of ``LANE_BLOCK`` scenarios per device, and each chunk's
outcomes are brought back to host arrays. Scoring (``metrics.outcomes``) and Parquet writing are
not timed. Every measurement runs in its own subprocess, so its peak resident memory
(``ru_maxrss``) is its own.

Rows, for 60 s at 100 Hz (6,000 steps), 1,000 / 10,000 / 100,000 scenarios, and 1,000 scenarios
at 120 s (memory must not grow with the horizon: the scan carries reductions only):

- compile (s): first call on the first chunk minus a timed second call on the same chunk
  (``block_until_ready``);
- run (s): the best of ``--repeats`` timed passes over all chunks, compilation excluded;
- scenario-steps/s: real (unpadded) scenarios x steps / run;
- peak RSS (MB): ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` of the measuring process.

Peer, in the same run: the same pipeline as a Python ``for`` loop over time around ONE jitted,
vmapped step (plant step + FDD step + reduction step over all scenarios), the state carried
between steps in NumPy host arrays. Its outcomes are checked against ``run_batch`` on the same
scenarios and steps.

Breakdown, in the same run: one chunk of 20 s with the scan cut after each stage of the step
(random numbers, + plant, + both FDD systems, + online reductions = the campaign's scan), so the
differences between rows are what each stage costs.

    python benchmarks/campaign_throughput.py            # full run (about 7 min on 2 idle cores)
    python benchmarks/campaign_throughput.py --quick    # 1,000 scenarios at 60 s and 120 s, peer

On a shared machine, ``--wait-quiet 600`` waits (up to 600 s) before each measurement until both
cores have been idle for 10 s. The CPU/wall column (CPU time of the measuring process per second
of wall time) shows whether a measurement had the cores to itself: 2.0 on two idle cores.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import time
from functools import partial

import mcfdd  # first: one JAX CPU device per core, before JAX creates its backend

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import AxisType  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

from mcfdd import config, io  # noqa: E402
from mcfdd.analysis import campaign, simulate  # noqa: E402
from mcfdd.fdd import system  # noqa: E402
from mcfdd.plant import closed_loop  # noqa: E402
from mcfdd.workflows import campaign as campaign_runner  # noqa: E402

SPACE = {
    "vcas_kt": [160.0, 350.0], "altitude_m": [0.0, 10000.0], "turbulence": ["light", "moderate"],
    "supply_pressure_scale": [0.95, 1.05], "kci_scale": [0.9, 1.1], "kd_scale": [0.7, 1.3],
    "hinge_scale": [0.8, 1.2], "roll_inertia_scale": [0.9, 1.1], "noise_std_mm": [0.03, 0.07],
    "fault_kind": ["none", "leakage", "surface_damage", "disconnection"], "leakage_size": [0.1, 0.3],
    "surface_damage_size": [0.3, 1.0], "fault_onset_s": [10.0, 30.0],
    "manoeuvre_kind": ["doublet", "bank_to_bank", "roll_protection", "sideslip"], "amplitude": [0.3, 1.0],
    "t_start_s": [5.0, 25.0], "duration_s": [1.0, 3.0], "hold_s": [1.0, 4.0], "sideslip_deg": [-6.0, 6.0],
}
GRID_CELLS = len(SPACE["fault_kind"])  # fault_kind is gridded: scenarios / 4 samples per fault kind


def campaign_config(n_scenarios: int, duration_s: float, chunk_size: int) -> config.CampaignConfig:
    if n_scenarios % GRID_CELLS:
        raise SystemExit(f"scenario counts must be multiples of {GRID_CELLS} (fault kinds on a grid)")
    return mcfdd.load_config({
        "campaign": {"scenarios": n_scenarios, "design": "lhs", "grid": ["fault_kind"], "seed": 1,
                     "chunk_size": chunk_size, "duration_s": duration_s, "precision": "float32"},
        "space": SPACE,
    }, "campaign")


class Problem:
    """The campaign of :func:`campaign_config` set up as ``run_campaign`` sets it up, and its chunks."""

    def __init__(self, n_scenarios: int, duration_s: float, chunk_size: int):
        cfg = campaign_config(n_scenarios, duration_s, chunk_size)
        self.c = cfg.campaign
        start = time.perf_counter()
        self.setup = campaign_runner.campaign_setup(cfg)
        self.setup_s = time.perf_counter() - start
        self.n = self.setup.n
        assert self.n == n_scenarios, (self.n, n_scenarios)
        self.size = campaign_runner.chunk_size(self.c.chunk_size, self.n)
        self.chunks = [np.arange(i, min(i + self.size, self.n)) for i in range(0, self.n, self.size)]

    def inputs(self, ids):
        """Padded scenarios, truths and keys of a chunk, as ``run_campaign`` builds them."""
        return campaign_runner.chunk_inputs(self.setup, self.c.seed, ids, self.size)

    def run_chunk(self, ids, n_steps=None):
        """One chunk as ``run_campaign`` runs it: gather, pad, run_batch, outcomes back to host arrays."""
        s, c = self.setup, self.c
        raw = campaign.run_batch(s.model, s.fdd_params, s.settings, *self.inputs(ids), n_steps or c.n_steps, c.dt_s,
                                 c.substeps, s.kinds)
        return {k: np.asarray(v)[:len(ids)] for k, v in jax.block_until_ready(raw).items()}


def source_digest() -> str:
    """Short digest of the package's Python sources: which code a measurement ran."""
    from pathlib import Path

    digest = hashlib.sha1()
    root = Path(mcfdd.__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + path.read_bytes())
    return digest.hexdigest()[:10]


def _cpu_s():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def measure_pipeline(n_scenarios: int, duration_s: float, chunk_size: int, repeats: int) -> dict:
    p = Problem(n_scenarios, duration_s, chunk_size)
    rss_before = _peak_rss_mb()
    start = time.perf_counter()
    p.run_chunk(p.chunks[0])
    first = time.perf_counter() - start
    start = time.perf_counter()
    p.run_chunk(p.chunks[0])
    second = time.perf_counter() - start
    passes = []
    for _ in range(repeats):
        chunk_times = []
        cpu0, start = _cpu_s(), time.perf_counter()
        for ids in p.chunks:
            t0 = time.perf_counter()
            p.run_chunk(ids)
            chunk_times.append(time.perf_counter() - t0)
        wall = time.perf_counter() - start
        passes.append({"run_s": wall, "chunk_s": chunk_times, "cpu_per_wall": (_cpu_s() - cpu0) / wall})
    best = min(passes, key=lambda r: r["run_s"])
    steps = p.c.n_steps
    fastest = max(len(ids) / t for r in passes for ids, t in zip(p.chunks, r["chunk_s"])) * steps
    return {
        "kind": "pipeline", "scenarios": p.n, "duration_s": duration_s, "steps": steps, "devices": jax.device_count(),
        "chunk": p.size, "chunks": len(p.chunks), "setup_s": p.setup_s, "first_call_s": first,
        "compile_s": first - second, "run_s": best["run_s"], "all_runs_s": [r["run_s"] for r in passes],
        "chunk_s_mean": float(np.mean(best["chunk_s"])), "cpu_per_wall": best["cpu_per_wall"],
        "throughput": p.n * steps / best["run_s"], "fastest_chunk_throughput": fastest,
        "rss_before_mb": rss_before, "peak_rss_mb": _peak_rss_mb(),
    }


def split(fn, specs):
    """``jit`` of ``fn`` (vmapped over scenarios) split over all devices with ``shard_map`` (the peer's way).

    ``run_batch`` instead runs the single-device program on each device's share
    (``campaign.on_devices``), which keeps results independent of the device count.
    """
    mesh = jax.make_mesh((jax.device_count(),), ("batch",), axis_types=(AxisType.Auto,))
    return jax.jit(jax.shard_map(fn, mesh=mesh, in_specs=specs, out_specs=P("batch"), check_vma=False))


def peer_functions(p: Problem, n_steps: int):
    """Jitted pieces of the Python-loop peer: init, one batched step, a noise block, finalize.

    The step is ``campaign.step_one``, the body of ``campaign.run_one``, vmapped over scenarios
    and, with several devices, split over them with ``shard_map`` inside the step's jit.
    """
    s = p.setup
    model, fdd_params, settings, kinds = s.model, s.fdd_params, s.settings, s.kinds
    dt_s, substeps = p.c.dt_s, p.c.substeps

    def init_one(scenario, key):
        return campaign.init_one(model, fdd_params, scenario, key, dt_s)

    def step_one(params, scenario, truth, carry, k, noise):
        return campaign.step_one(params, fdd_params, settings, scenario, truth, carry, k, noise, dt_s, substeps,
                                 kinds)[0]

    def noise_one(key, b):
        return jax.random.normal(jax.random.fold_in(key, b), (simulate.NOISE_BLOCK, closed_loop.NOISE_DIM))

    def finalize_one(red):
        return campaign.finalize(settings, red, n_steps * dt_s)

    b = P("batch")
    init = split(jax.vmap(init_one), (b, b))
    step = split(jax.vmap(step_one, in_axes=(0, 0, 0, 0, None, 0)), (b, b, b, b, P(), b))
    noise = split(jax.vmap(noise_one, in_axes=(0, None)), (b, P()))
    finalize = split(jax.vmap(finalize_one), (b,))
    return init, step, noise, finalize


def run_peer(p: Problem, fns, ids, n_steps: int, host_state: bool = True):
    """Python loop over time; the state goes back to NumPy arrays after every step if ``host_state``."""
    init, step, noise, finalize = fns
    scen, truth, keys = p.inputs(ids)
    params, carry = init(scen, keys)
    to_host = (lambda tree: jax.tree.map(np.asarray, tree)) if host_state else (lambda tree: tree)
    carry = to_host(carry)
    block = None
    for k in range(n_steps):
        j = k % simulate.NOISE_BLOCK
        if j == 0:
            block = np.asarray(noise(keys, np.uint32(k // simulate.NOISE_BLOCK)))
        carry = to_host(step(params, scen, truth, carry, np.int32(k), block[:, j]))
    out = finalize(carry[2])
    return {k: np.asarray(v)[:len(ids)] for k, v in out.items()}


def compare(a: dict, b: dict) -> dict:
    """Scenarios whose outcomes differ between two runs (floats to 1e-4 relative, ints exactly)."""
    differ = np.zeros(len(a["status"]), dtype=bool)
    worst = 0.0
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if np.issubdtype(x.dtype, np.floating):
            same = (x == y) | np.isclose(x, y, rtol=1e-4, atol=1e-9)
            finite = np.isfinite(x) & np.isfinite(y)
            if finite.any():
                worst = max(worst, float(np.max(np.abs(x - y)[finite] / np.maximum(np.abs(x[finite]), 1e-12))))
        else:
            same = x == y
        differ |= ~same.reshape(len(differ), -1).all(axis=1)
    return {"scenarios_differing": int(differ.sum()), "max_rel_diff": worst}


def measure_peer(n_scenarios: int, n_steps: int, repeats: int) -> dict:
    p = Problem(n_scenarios, n_steps * 0.01, n_scenarios)
    ids = p.chunks[0]
    fns = peer_functions(p, n_steps)
    result = {"kind": "peer", "scenarios": p.n, "steps": n_steps, "devices": jax.device_count(), "chunk": p.size}
    for label, host in (("host", True), ("device", False)):
        start = time.perf_counter()
        run_peer(p, fns, ids, 1, host)  # compiles init, step, noise and finalize
        first_one_step = time.perf_counter() - start
        start = time.perf_counter()
        run_peer(p, fns, ids, 1, host)
        one_step = time.perf_counter() - start
        runs = []
        for _ in range(repeats):
            cpu0, start = _cpu_s(), time.perf_counter()
            out = run_peer(p, fns, ids, n_steps, host)
            wall = time.perf_counter() - start
            runs.append((wall, (_cpu_s() - cpu0) / wall))
        wall, cpu = min(runs)
        result[label] = {"compile_s": first_one_step - one_step, "run_s": wall, "all_runs_s": [r[0] for r in runs],
                         "cpu_per_wall": cpu, "throughput": p.n * n_steps / wall, "step_ms": 1e3 * wall / n_steps}
        if host:
            peer_out = out
    reference = p.run_chunk(ids, n_steps)
    result["check"] = compare(reference, peer_out)
    result["peak_rss_mb"] = _peak_rss_mb()
    return result


STAGES = ("random numbers", "+ plant", "+ both FDD systems", "+ online reductions (the campaign)")


def measure_breakdown(n_scenarios: int, duration_s: float, repeats: int) -> dict:
    """Run time of the campaign scan cut after each stage of its step, on one chunk.

    Each cut keeps a cheap running sum of the last stage's outputs in the carry so that XLA cannot
    drop the stage; the last row is ``run_batch`` itself. The differences between rows are what
    each stage adds.
    """
    p = Problem(n_scenarios, duration_s, n_scenarios)
    s, c = p.setup, p.c
    scen, truth, keys = p.inputs(p.chunks[0])

    def cut(stage, scenario, key):
        params, (plant_state, fdd_state, _) = campaign.init_one(s.model, s.fdd_params, scenario, key, c.dt_s)

        def body(state, k, noise):
            plant_state, fdd_state, acc = state
            if stage == 0:
                return (plant_state, fdd_state, acc + noise.sum()), None
            t = k * c.dt_s
            plant_state, out = closed_loop.step(params, plant_state, t, noise, c.dt_s, c.substeps, s.kinds)
            if stage == 1:
                return (plant_state, fdd_state, acc + out.u_m), None
            fdd_state, fo = system.step(s.fdd_params, fdd_state, out.u_c_m, out.u_m, scenario.vcas_m_s,
                                        scenario.altitude_m, t, c.dt_s)
            sink = fo.theta.sum() + fo.theta_stall + fo.detected + fo.eta_signal + fo.eta_model
            return (plant_state, fdd_state, acc + sink), None

        zero = jnp.zeros((), params.qbar_pa.dtype)
        return simulate.scan_steps(body, (plant_state, fdd_state, zero), key, c.n_steps, closed_loop.NOISE_DIM)[0][2]

    runs = [partial(campaign.on_devices, jax.jit(jax.vmap(partial(cut, stage))), scen, keys, batched=(True, True))
            for stage in range(3)]
    runs.append(partial(campaign.run_batch, s.model, s.fdd_params, s.settings, scen, truth, keys, c.n_steps, c.dt_s,
                        c.substeps, s.kinds))
    rows = []
    for name, run in zip(STAGES, runs):
        jax.block_until_ready(run())
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            jax.block_until_ready(run())
            times.append(time.perf_counter() - start)
        rows.append({"stage": name, "run_s": min(times), "throughput": p.size * c.n_steps / min(times)})
    return {"kind": "breakdown", "scenarios": p.size, "steps": c.n_steps, "devices": jax.device_count(), "rows": rows}


def worker(spec: dict) -> dict:
    assert not jax.config.jax_enable_x64, "the benchmark measures float32"
    digest = source_digest()
    if spec["kind"] == "pipeline":
        result = measure_pipeline(spec["scenarios"], spec["duration_s"], spec["chunk_size"], spec["repeats"])
    elif spec["kind"] == "breakdown":
        result = measure_breakdown(spec["scenarios"], spec["duration_s"], spec["repeats"])
    else:
        result = measure_peer(spec["scenarios"], spec["steps"], spec["repeats"])
    return {**result, "source": digest}


def _idle_fraction(seconds: float) -> float:
    """Share of CPU time spent idle over the next ``seconds`` (Linux /proc/stat)."""
    def sample():
        with open("/proc/stat") as f:
            values = [int(v) for v in f.readline().split()[1:]]
        return values[3] + values[4], sum(values)

    idle0, total0 = sample()
    time.sleep(seconds)
    idle1, total1 = sample()
    return (idle1 - idle0) / max(total1 - total0, 1)


def wait_quiet(max_wait_s: float):
    """Wait until the cores have been at least 90 % idle over 10 s, at most ``max_wait_s``."""
    if max_wait_s <= 0 or not os.path.exists("/proc/stat"):
        return
    start = time.perf_counter()
    while True:
        idle = _idle_fraction(10.0)
        if idle >= 0.9:
            return
        if time.perf_counter() - start > max_wait_s:
            print(f"  (machine still busy after {max_wait_s:.0f} s, {100 * idle:.0f} % idle: measuring anyway)",
                  flush=True)
            return


def spawn(spec: dict, max_wait_s: float = 0.0) -> dict:
    """Run one measurement in a fresh process (so ru_maxrss is its own); returns its result."""
    wait_quiet(max_wait_s)
    load = os.getloadavg()
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(spec)], capture_output=True, text=True,
                          check=False)
    if proc.returncode:
        sys.stderr.write(proc.stderr)
        raise SystemExit(f"measurement {spec} failed")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["load_before"] = load
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1,000 scenarios only (60 s and 120 s) and the peer")
    parser.add_argument("--sizes", type=int, nargs="+", help="scenario counts at 60 s (default 1000 10000 100000)")
    parser.add_argument("--chunk-size", type=int, default=2048, help="scenarios per chunk, as campaign.chunk_size")
    parser.add_argument("--repeats", type=int, default=2, help="timed passes per measurement; the best is reported")
    parser.add_argument("--peer-scenarios", type=int, default=1000)
    parser.add_argument("--peer-steps", type=int, default=600)
    parser.add_argument("--wait-quiet", type=float, default=0.0, metavar="S",
                        help="before each measurement wait up to S seconds for idle cores (shared machines)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))), flush=True)
        return
    sizes = args.sizes or ([1000] if args.quick else [1000, 10000, 100000])
    print(f"jax {jax.__version__}, {jax.device_count()} {jax.devices()[0].platform} device(s) "
          f"({os.cpu_count()} cores, XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}), "
          f"{platform.processor() or platform.machine()}, float32, dt 0.01 s, 4 actuator sub-steps, "
          f"chunks of {args.chunk_size} padded to {campaign_runner.LANE_BLOCK} x devices, best of {args.repeats}")
    print(f"mcfdd {io.git_revision()}, sources {source_digest()}")
    print(f"load average before start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    specs = [{"kind": "pipeline", "scenarios": n, "duration_s": 60.0, "chunk_size": args.chunk_size,
              "repeats": args.repeats} for n in sizes]
    specs.append({"kind": "pipeline", "scenarios": sizes[0], "duration_s": 120.0, "chunk_size": args.chunk_size,
                  "repeats": args.repeats})
    rows = []
    for spec in specs:
        r = spawn(spec, args.wait_quiet)
        rows.append(r)
        print(f"  {r['scenarios']:,} x {r['steps']:,}: compile {r['compile_s']:.1f} s, runs "
              f"{', '.join(f'{t:.2f}' for t in r['all_runs_s'])} s ({r['chunks']} chunk(s) of {r['chunk']}, "
              f"{r['chunk_s_mean']:.2f} s each, fastest chunk {r['fastest_chunk_throughput']:.3g} scenario-steps/s), "
              f"CPU/wall {r['cpu_per_wall']:.2f}, setup {r['setup_s']:.1f} s, "
              f"RSS before run {r['rss_before_mb']:.0f} MB, load before {r['load_before'][0]:.2f}", flush=True)
    peer = spawn({"kind": "peer", "scenarios": args.peer_scenarios, "steps": args.peer_steps,
                  "repeats": args.repeats}, args.wait_quiet)
    parts = spawn({"kind": "breakdown", "scenarios": args.chunk_size, "duration_s": 20.0, "repeats": args.repeats + 1},
                  args.wait_quiet)
    print()
    print("| scenarios | horizon | steps | devices | compile (s) | run (s) | scenario-steps/s | CPU/wall | "
          "peak RSS (MB) |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scenarios']:,} | {r['duration_s']:.0f} s | {r['steps']:,} | {r['devices']} | "
              f"{r['compile_s']:.1f} | {r['run_s']:.2f} | {r['throughput']:.3g} | {r['cpu_per_wall']:.2f} | "
              f"{r['peak_rss_mb']:.0f} |")
    print()
    for label, name in (("host", "python loop over time, jitted vectorised step, state in NumPy host arrays"),
                        ("device", "same loop, state left in device arrays")):
        q = peer[label]
        print(f"peer ({name}): {peer['scenarios']:,} scenarios x {peer['steps']:,} steps on {peer['devices']} "
              f"device(s): compile {q['compile_s']:.1f} s, run {q['run_s']:.2f} s ({q['step_ms']:.2f} ms per step), "
              f"{q['throughput']:.3g} scenario-steps/s, CPU/wall {q['cpu_per_wall']:.2f}")
    chk = peer["check"]
    print(f"peer outcomes vs run_batch on the same {peer['scenarios']:,} scenarios x {peer['steps']} steps: "
          f"{chk['scenarios_differing']} scenario(s) differ, largest relative difference {chk['max_rel_diff']:.2g}")
    print()
    print(f"where the time goes ({parts['scenarios']:,} scenarios x {parts['steps']:,} steps, the scan cut after "
          f"each stage of the step):")
    print("| stage | run (s) | scenario-steps/s |")
    print("|---|---:|---:|")
    for r in parts["rows"]:
        print(f"| {r['stage']} | {r['run_s']:.3f} | {r['throughput']:.3g} |")
    base = rows[0]["throughput"]
    print(f"pipeline / peer (host state): {base / peer['host']['throughput']:.0f}x;  aim 3e7 scenario-steps/s: "
          f"{max(r['throughput'] for r in rows) / 3e7:.2f} of it")
    digests = {r["source"] for r in rows + [peer, parts]}
    if len(digests) > 1:
        print(f"WARNING: the package sources changed during the run ({', '.join(sorted(digests))})")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()

"""Campaign throughput on Dask distributed: 1 and 2 local worker processes against one process, in one run.

The campaign is :mod:`campaign_throughput`'s mixed space (four fault kinds on a grid, four
closed-loop manoeuvre families, turbulence, uncertainties, Latin hypercube) in float32, run
through :func:`mcfdd.run_campaign` in memory:

- in process: the driver runs every chunk itself, one JAX device per core;
- N local workers: ``mcfdd.dask_cluster(workers=N)`` (N processes of one thread, each with
  cores // N JAX devices); the driver only builds the design plan and collects the tables.

Each mode first runs a warm-up campaign of one chunk per worker, so every process has compiled (or
loaded from the compile cache) its program; the timed campaign then measures chunks only, with
the driver's scheduling, transfers and table building included. Rows: wall time, scenario-steps
per second, ratio to in process; the tables of all modes are checked to be identical.

Then the time from the start of a process to its first finished chunk, with an empty compile
cache (cold) and with the cache the cold run filled (warm), each in a fresh Python process:
what ``mcfdd campaign`` costs before the first part is written.

    python benchmarks/distributed_throughput.py                      # 2,048 scenarios of 30 s
    python benchmarks/distributed_throughput.py --scenarios 512 --duration 10
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mcfdd  # first: one JAX CPU device per core, before JAX creates its backend

# isort: split

import pandas as pd  # noqa: E402

from mcfdd import io  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from campaign_throughput import campaign_config  # noqa: E402

FIRST_CHUNK = """
import sys, time
import mcfdd
sys.path.insert(0, {bench!r})
from campaign_throughput import campaign_config
cfg = campaign_config({n}, {duration}, {chunk})
def first(ids):
    print(time.time(), flush=True)
    raise KeyboardInterrupt
try:
    mcfdd.run_campaign(cfg, progress=False, on_chunk=first, compile_cache={cache!r})
except KeyboardInterrupt:
    pass
"""


def timed(cfg, executor, cache):
    start = time.perf_counter()
    result = mcfdd.run_campaign(cfg, progress=False, executor=executor, compile_cache=cache)
    return time.perf_counter() - start, result


def measure_modes(args, cache) -> list[dict]:
    cfg = campaign_config(args.scenarios, args.duration, args.chunk_size)
    steps = cfg.campaign.n_steps
    rows, tables, results = [], {}, []
    for workers in (None, 1, 2):
        warm_cfg = campaign_config(args.chunk_size * (workers or 1), args.duration, args.chunk_size)
        if workers is None:
            timed(warm_cfg, None, cache)
            wall, result = timed(cfg, None, cache)
        else:
            with mcfdd.dask_cluster(workers=workers) as client:
                client.wait_for_workers(workers, timeout=120)
                timed(warm_cfg, client, cache)
                wall, result = timed(cfg, client, cache)
        label = "in process" if workers is None else f"{workers} local worker(s)"
        tables[label] = result.scenarios
        results.append(result)
        rows.append({"mode": label, "scenarios": args.scenarios, "steps": steps, "chunks": int(
            result.workers["chunks"].sum()), "wall_s": wall, "throughput": args.scenarios * steps / wall,
            "busy_per_worker": result.workers["busy_s"].round(2).tolist()})
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    base = rows[0]["throughput"]
    for row in rows:
        row["ratio"] = row["throughput"] / base
    first = next(iter(tables.values()))
    for label, table in tables.items():
        pd.testing.assert_frame_equal(first, table, check_exact=True, obj=label)
    return rows, results[0]


def driver_part_s(result, rows: int, folder: Path) -> float:
    """Seconds the driver spends on one finished chunk of ``rows`` scenarios: its DataFrame and Parquet part."""
    chunk = {name: result.scenarios[name].to_numpy()[:rows] for name in result.scenarios.columns}
    start = time.perf_counter()
    for i in range(5):
        io.write_table(pd.DataFrame(chunk), folder / f"part-{i}.parquet", result.meta)
    return (time.perf_counter() - start) / 5


def first_chunk_s(args, cache) -> float:
    """Seconds from a fresh Python process's start to its first finished chunk (one chunk of the campaign)."""
    code = FIRST_CHUNK.format(bench=str(Path(__file__).parent), n=args.chunk_size, duration=args.duration,
                              chunk=args.chunk_size, cache=str(cache))
    start = time.time()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1]) - start


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", type=int, default=2048, help="scenarios (a multiple of 4)")
    p.add_argument("--duration", type=float, default=30.0, help="seconds simulated per scenario")
    p.add_argument("--chunk-size", type=int, default=256)
    args = p.parse_args()
    print(f"cores {os.cpu_count()}, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        cold, warm = first_chunk_s(args, Path(tmp) / "c"), first_chunk_s(args, Path(tmp) / "c")
        rows, result = measure_modes(args, Path(tmp) / "modes")
        part_s = driver_part_s(result, min(args.scenarios, 4096), Path(tmp) / "parts")
    print("| mode | scenarios | steps | chunks | wall (s) | scenario-steps/s | ratio to in process |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['mode']} | {r['scenarios']:,} | {r['steps']:,} | {r['chunks']} | {r['wall_s']:.1f} | "
              f"{r['throughput']:.3g} | {r['ratio']:.2f} |")
    print(f"\nfirst chunk of {args.chunk_size} scenarios from process start: cold cache {cold:.1f} s, "
          f"warm {warm:.1f} s")
    print(f"driver per finished chunk of {min(args.scenarios, 4096)} scenarios ({result.scenarios.shape[1]} columns): "
          f"{1e3 * part_s:.0f} ms for its DataFrame and Parquet part")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()

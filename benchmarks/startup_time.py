"""Time from process start to the first finished chunk of a campaign, cold and warm compilation cache.

Each measurement is a fresh Python process running ``mcfdd.run_campaign`` in memory (as ``mcfdd
campaign`` does, without the files) and stopping after its first chunk: imports, configuration
(validation included), set-up (plant, hinge table, bank, design plan), the first chunk's inputs,
compilation or loading of the campaign program, and the chunk's run. The process reports the
seconds to the end of the set-up, the XLA compilations until then, and the seconds to the first
chunk.

Modes, in this order per checkout: ``off`` (no persistent compilation cache), ``cold`` (an empty
cache folder) and ``warm`` (the folder the cold run filled). ``--baseline PATH`` measures another
checkout of mcfdd (a git worktree) in the same run, after this one.

    python benchmarks/startup_time.py --baseline /work/base-1a28f41           # loe_campaign, first chunk 512 x 60 s
    python benchmarks/startup_time.py --config configs/fault_free.toml --chunk-size 256
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
WORKER = """
import time
START = time.time()
import json, sys
import mcfdd
from mcfdd.workflows import campaign as runner
from mcfdd.workflows.common import CompileCounter, precision

config, scenarios, chunk, cache = sys.argv[1:5]
first = {}


def stop(ids):
    first["s"] = time.time() - START
    raise KeyboardInterrupt


with CompileCounter() as counter:
    cfg = mcfdd.load_config(config, "campaign", overrides={"campaign.scenarios": int(scenarios),
                                                            "campaign.chunk_size": int(chunk)})
    with precision(cfg.campaign.precision):
        runner._setup_of(cfg)  # the process's set-up cache: run_campaign uses this one
    setup_s, setup_compiles = time.time() - START, counter.count
try:
    mcfdd.run_campaign(cfg, progress=False, on_chunk=stop, compile_cache=cache)
except KeyboardInterrupt:
    pass
print(json.dumps({"setup_s": setup_s, "setup_compiles": setup_compiles, "first_chunk_s": first["s"]}))
"""


def measure(checkout: Path, args, cache: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    proc = subprocess.run([sys.executable, "-c", WORKER, str((HERE / args.config).resolve()), str(args.scenarios),
                           str(args.chunk_size), cache], env=env, cwd=checkout, capture_output=True, text=True)
    if proc.returncode:
        sys.stderr.write(proc.stderr)
        raise SystemExit(f"measurement of {checkout} ({cache}) failed")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/loe_campaign.toml")
    parser.add_argument("--scenarios", type=int, default=2048, help="campaign.scenarios")
    parser.add_argument("--chunk-size", type=int, default=512, help="campaign.chunk_size: the first chunk's size")
    parser.add_argument("--baseline", type=Path, help="another checkout of mcfdd, measured in the same run")
    args = parser.parse_args(argv)
    checkouts = [("this", HERE)] + ([("baseline", args.baseline.resolve())] if args.baseline else [])
    print(f"{args.config}, {args.scenarios} scenarios, first chunk of {args.chunk_size}; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for label, checkout in checkouts:
            cache = str(Path(work) / label)
            for mode, folder in (("off", "off"), ("cold", cache), ("warm", cache)):
                r = measure(checkout, args, folder)
                rows.append((label, mode, r))
                print(f"  {label} {mode}: {r}", flush=True)
    print("| checkout | compile cache | start to set-up done (s) | compiles in config + set-up | "
          "start to first chunk (s) |")
    print("|---|---|---:|---:|---:|")
    for label, mode, r in rows:
        print(f"| {label} | {mode} | {r['setup_s']:.1f} | {r['setup_compiles']} | {r['first_chunk_s']:.1f} |")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()

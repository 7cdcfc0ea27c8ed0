"""Memory estimates of the guards (``mcfdd.workflows.resources``) against the measured peak resident memory.

Each measurement is a fresh process (its peak, ``VmHWM`` on Linux, is its own): a campaign of one chunk
of ``--chunk-sizes`` scenarios (the test suite's space, runs of 4 s, one JAX device) and ``simulate``
of ``--runs`` runs of 300 s. Printed: the estimate the guard uses, the measured peak and their ratio.

    python benchmarks/memory_guard.py --chunk-sizes 64,16384,65536,262144 --runs 40,200
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

WORKER = """
import json, os, resource, sys
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"
import mcfdd
from mcfdd.workflows import resources

kind, size = sys.argv[1], int(sys.argv[2])
estimates = []
for name in ("chunk_bytes", "history_bytes"):
    def recorded(*args, _f=getattr(resources, name)):
        estimates.append(_f(*args))
        return estimates[-1]
    setattr(resources, name, recorded)
doublet = {"kind": "doublet", "amplitude": 0.5, "t_start_s": 1.0}
if kind == "campaign":
    space = {"vcas_kt": [200.0, 360.0], "altitude_m": [0.0, 6000.0], "hinge_scale": [0.9, 1.4],
             "fault_kind": ["none", "leakage", "surface_damage", "disconnection", "jamming"],
             "fault_onset_s": [1.0, 2.0], "manoeuvre_kind": ["doublet", "ol_doublet", "sideslip"],
             "t_start_s": [0.2, 1.0], "duration_s": [0.5, 1.0], "sideslip_deg": [8.0, 14.0]}
    cfg = {"campaign": {"scenarios": size, "chunk_size": size, "duration_s": 4.0, "design": "lhs"},
           "evaluation": {"settle_s": 0.5}, "space": space}
    mcfdd.run_campaign(cfg, progress=False)
    estimate = estimates[-1] + resources.table_bytes(size)
else:
    runs = [{"name": f"r{i}", "manoeuvre": doublet} for i in range(size)]
    mcfdd.simulate({"simulation": {"duration_s": 300.0}, "runs": runs}, progress=False).to_pandas()
    estimate = estimates[-1]
try:  # this process's own peak: ru_maxrss keeps the peak of the process that started it (kept across exec)
    with open("/proc/self/status") as status:
        peak = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))
except OSError:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"estimate": estimate, "peak": peak}))
"""


def measure(kind: str, size: int) -> dict:
    proc = subprocess.run([sys.executable, "-c", WORKER, kind, str(size)], capture_output=True, text=True, check=True,
                          env={**os.environ})
    return json.loads(proc.stdout.splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chunk-sizes", default="64,16384,65536")
    parser.add_argument("--runs", default="40,200")
    args = parser.parse_args()
    for kind, sizes in (("campaign", args.chunk_sizes), ("simulate", args.runs)):
        for size in (int(s) for s in sizes.split(",") if s):
            m = measure(kind, size)
            what = f"one chunk of {size} scenarios x 400 steps" if kind == "campaign" else f"{size} runs x 30000 steps"
            print(f"{kind:8s} {what:40s} estimate {m['estimate'] / 2**30:6.2f} GiB, measured peak "
                  f"{m['peak'] / 2**30:6.2f} GiB, ratio {m['estimate'] / m['peak']:.2f}", flush=True)


if __name__ == "__main__":
    main()

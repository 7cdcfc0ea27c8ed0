"""Which per-device batch sizes give a scenario the same bits: the measurement behind ``LANE_BLOCK``.

One JAX device; a small mixed campaign (the test suite's space, runs of 2 s). Each size in
``--sizes`` runs the chunk program on that many scenarios (from scenario 0 and from scenario 5) and
compares every floating-point outcome with a reference batch of ``--reference`` scenarios, bit for
bit. Each size compiles its own program (tens of seconds each).

    python benchmarks/lane_remainders.py --precision float32 --sizes 1,2,3,5,9,16,17,63,65,100,129,250
    python benchmarks/lane_remainders.py --precision float64 --sizes 1,2,3,5,9,17,31,33
"""

from __future__ import annotations

import argparse
import os

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"

import numpy as np  # noqa: E402

import mcfdd  # noqa: E402
from mcfdd.workflows import campaign as runner  # noqa: E402

SPACE = {"vcas_kt": [200.0, 360.0], "altitude_m": [0.0, 6000.0], "noise_std_mm": [0.03, 0.07],
         "hinge_scale": [0.9, 1.4], "fault_kind": ["none", "leakage", "surface_damage", "disconnection", "jamming"],
         "leakage_size": [0.1, 0.3], "surface_damage_size": [0.3, 1.0], "fault_onset_s": [0.5, 1.5],
         "manoeuvre_kind": ["doublet", "ol_doublet", "sideslip"], "amplitude": [0.5, 1.0], "t_start_s": [0.2, 0.8],
         "duration_s": [0.3, 0.6], "sideslip_deg": [8.0, 14.0]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--precision", default="float32", choices=["float32", "float64"])
    parser.add_argument("--sizes", default="1,2,3,5,9,16,17,63,65,100")
    parser.add_argument("--reference", type=int, default=256)
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    cfg = mcfdd.load_config({"campaign": {"scenarios": max(args.reference, max(sizes) + 5), "design": "lhs", "seed": 7,
                                          "duration_s": 2.0, "precision": args.precision},
                             "evaluation": {"settle_s": 0.3}, "space": SPACE}, "campaign")
    reference = runner.run_chunk(cfg, np.arange(args.reference), args.reference)
    columns = [k for k, v in reference.items() if np.asarray(v).dtype.kind == "f"]
    for size in sizes:
        for start in (0, 5):
            ids = np.arange(start, start + size)
            table = runner.run_chunk(cfg, ids, size)
            differ = [c for c in columns if not np.array_equal(np.asarray(reference[c])[ids], table[c], equal_nan=True)]
            print(f"{args.precision} share {size:4d} from scenario {start}: {len(differ)} of {len(columns)} columns "
                  f"differ from the reference {differ[:3]}", flush=True)


if __name__ == "__main__":
    main()

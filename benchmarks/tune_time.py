"""Time of the LOE detection-level tuner (``tune.level = "detection"``) on a training set, by phase.

Phases, each with its XLA compilations counted: the training set (plant histories simulated once,
:func:`mcfdd.workflows.tune.training_set`), the hard columns that give the must-detect runs, one
gradient evaluation of the smooth gap (compilation included) and then ``--repeats`` more (steady
state, the cost of one tuning iteration), and a threshold scan of ``--candidates`` factors (one
FDD pass per candidate). A tuning run costs about plant + iterations x gradient + 2 x scan, plus
the held-out campaigns (``benchmarks/campaign_throughput.py``).

    python benchmarks/tune_time.py                                  # tune_validation.toml's space, 256 runs
    python benchmarks/tune_time.py --scenarios 512 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from mcfdd import config
from mcfdd.analysis import build, detection_tuning as dt, metrics
from mcfdd.workflows.common import CompileCounter, dtype_of, load_bank, precision
from mcfdd.workflows.tune import training_set

HERE = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(HERE / "configs" / "tune_validation.toml"))
    ap.add_argument("--scenarios", type=int, default=256, help="training runs (the config's duration)")
    ap.add_argument("--repeats", type=int, default=2, help="gradient evaluations timed after the first")
    ap.add_argument("--candidates", type=int, default=8, help="thresholds in the scan")
    args = ap.parse_args()
    cfg = config.replace(config.load(config.TuneConfig, args.config), {"training.scenarios": args.scenarios})
    ts, tr = cfg.tune, cfg.training
    times, compiles = {}, {}

    def timed(name, fn):
        with CompileCounter() as counter:
            start = time.perf_counter()
            out = jax.block_until_ready(fn())
            times[name] = time.perf_counter() - start
        compiles[name] = counter.count
        return out

    with precision(tr.precision):
        dtype = dtype_of(tr.precision)
        model = build.plant_model(cfg.plant)
        bank, _ = load_bank(cfg.fdd, dtype)
        params = build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m)
        settings = build.settings(cfg.evaluation, model.actuator.r_arm_m)
        train = cfg.campaign("training")
        data, n = timed("plant", lambda: training_set(train, model, bank, dtype))
        hard = jax.device_get(timed("columns", lambda: dt.evaluate_columns(params, settings, data, tr.dt_s)))
        design, _ = build.design(train)
        must = dt.must_detect_mask(hard, design, metrics.uncertainty_ranges(design), ts.must_detect,
                                   ts.must_detect_kinds, ts.min_peak_load_fraction)
        theta = dt.initial(params, dt.names(params.loe, ts.tune_pole, ts.tune_confirmation))

        def grad():
            return dt.gap_and_grad(theta, params, settings, data, must, ts.temperature, tr.dt_s)

        timed("gradient_first", grad)
        timed("gradient_steady", lambda: [grad() for _ in range(args.repeats)])
        times["gradient_steady"] /= args.repeats
        scales = np.asarray(np.geomspace(*ts.scan_scales, args.candidates), dtype)
        timed("scan", lambda: dt.scan(theta, params, settings, data, must, scales, tr.dt_s))
    print(json.dumps({"runs": n, "duration_s": tr.duration_s, "must_detect": int(must.sum()),
                      "candidates": args.candidates, "seconds": {k: round(v, 2) for k, v in times.items()},
                      "compilations": compiles}, indent=1))


if __name__ == "__main__":
    main()

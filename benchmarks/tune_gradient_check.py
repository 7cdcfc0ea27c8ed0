"""The detection tuner's gradient against central finite differences on a tune config's training space.

Builds the training set of a ``level = "detection"`` tune config (``--scenarios`` runs of
``--duration`` s, float64), its must-detect mask, and the tuner's parameters at the config's start
(logarithms, :mod:`mcfdd.analysis.detection_tuning`), then prints per parameter the gradient of the
smooth gap tau_d - tau_f as the tuner gets it (``gap_and_grad``: non-finite components set to 0),
the same gradient unmasked (``jax.grad``), and central differences of the smooth gap at each
``--steps`` (in the logarithms). The gap is piecewise smooth (a min of terms, the confirmation), so
differences over a step that crosses a kink differ from the derivative: compare at small steps.

    python benchmarks/tune_gradient_check.py configs/tune_validation.toml --scenarios 64
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from mcfdd import config
from mcfdd.analysis import build, detection_tuning as dt, metrics
from mcfdd.workflows.common import load_bank, precision
from mcfdd.workflows.tune import training_set


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--scenarios", type=int, default=64, help="training runs (default 64)")
    ap.add_argument("--duration", type=float, help="training run length in s (default the config's)")
    ap.add_argument("--steps", type=float, nargs="+", default=[1e-2, 1e-3, 1e-4, 1e-5, 1e-6],
                    help="difference steps in the logarithms")
    args = ap.parse_args()
    changes = {"training.scenarios": args.scenarios, "training.precision": "float64",
               "validation.precision": "float64"}
    if args.duration:
        changes["training.duration_s"] = args.duration
    with precision("float64"):
        cfg = config.replace(config.load(config.TuneConfig, args.config), changes)
        ts, tr = cfg.tune, cfg.training
        model = build.plant_model(cfg.plant)
        r_arm = model.actuator.r_arm_m
        bank, _ = load_bank(cfg.fdd, np.float64)
        params, settings = build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm)
        train = cfg.campaign("training")
        data, n = training_set(train, model, bank, np.float64)
        design, _ = build.design(train)
        hard = jax.device_get(dt.evaluate_columns(params, settings, data, tr.dt_s))
        must = dt.must_detect_mask(hard, design, metrics.uncertainty_ranges(design), ts.must_detect,
                                   ts.must_detect_kinds, ts.min_peak_load_fraction)
        theta = dt.initial(params, dt.names(params.loe, ts.tune_pole, ts.tune_confirmation))

        def gap(theta, params, settings, data, must):
            b = dt.bounds(dt.apply(params, theta), settings, data, must, ts.temperature, tr.dt_s)
            return b["soft_detect"] - b["soft_free"]

        value, b, grad = jax.device_get(dt.gap_and_grad(theta, params, settings, data, must, ts.temperature,
                                                        tr.dt_s))
        raw = jax.device_get(jax.jit(jax.grad(gap))(theta, params, settings, data, must))
        at = jax.jit(gap)
        print(f"{args.config}: {n} training runs of {tr.duration_s} s (seed {tr.seed}), {int(must.sum())} must be "
              f"detected, temperature {ts.temperature}; smooth gap {float(value):.6g} (hard tau_f {b['tau_f']:.5g}, "
              f"tau_d {b['tau_d']:.5g})")
        print("| parameter (log) | tuner's gradient | jax.grad | " + " | ".join(f"FD {h:g}" for h in args.steps) + " |")
        print("|---|---:|---:|" + "---:|" * len(args.steps))
        for name in theta:
            fd = []
            for h in args.steps:
                up, down = dict(theta), dict(theta)
                up[name], down[name] = theta[name] + h, theta[name] - h
                diff = at(up, params, settings, data, must) - at(down, params, settings, data, must)
                fd.append(float(diff) / (2 * h))
            print(f"| {name} | {float(grad[name]):.5g} | {float(raw[name]):.5g} | " + " | ".join(f"{x:.5g}" for x in fd)
                  + " |", flush=True)


if __name__ == "__main__":
    main()

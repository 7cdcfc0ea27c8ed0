"""P(false alarm) of the validation FDD by subset simulation, and a lowered threshold against plain Monte Carlo.

1. ``--check``: the validation space with the FDD's thresholds lowered (``--lowered KEY=VALUE``, by
   default ``fdd.loe.detection_contrast=0.03``), where a false alarm is common enough for plain Monte
   Carlo, estimated by subset simulation and by plain Monte Carlo of ``--mc`` runs; both estimates,
   both intervals and whether each holds the other.
2. Otherwise the validation FDD as configured: subset simulation per stratum to the target c.o.v.
   or the budget, for each of ``--seeds``; the simulations spent against the runs plain Monte Carlo
   would need for the same c.o.v., (1 - p) / (p cov^2).

Horizons, strata and budgets are reduced by flags (``--duration``, ``--manoeuvre``, ``--turbulence``)
so a run takes minutes on a laptop; every number printed says what was run.

    nice -n 10 python benchmarks/probability_validation.py [--duration 20] [--manoeuvre doublet]
        [--turbulence moderate] [--samples 500] [--budget 20000] [--seeds 5 6]
        [--check --lowered fdd.loe.detection_contrast=0.03 --mc 4000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import mcfdd
from mcfdd import config

ROOT = Path(__file__).resolve().parent.parent


def reduced(args, **extra) -> config.CampaignConfig:
    cfg = mcfdd.load_config(ROOT / "configs" / "validation.toml", "campaign")
    changes = {"campaign.duration_s": args.duration, "probability.samples": args.samples,
               "probability.budget": args.budget, "probability.target_cov": args.target_cov,
               "probability.chunk": args.chunk, "probability.seed": args.seeds[0]}
    if args.manoeuvre:
        changes["space.manoeuvre_kind"] = args.manoeuvre
    if args.turbulence:
        changes["space.turbulence"] = args.turbulence
    return config.replace(cfg, {**changes, **extra})


def show(label: str, result, seconds: float):
    o = result.overall
    sims = int(result.strata["simulations"].sum())
    print(f"{label}: p = {o.estimate:.3g}, c.o.v. {o.cov:.2f}, 95 % [{o.interval[0]:.3g}, {o.interval[1]:.3g}], "
          f"{sims} simulations, {seconds:.0f} s (compilation included)")
    if result.rate is not None:
        r = result.rate
        print(f"  per flight hour {r.estimate:.3g} [{r.interval[0]:.3g}, {r.interval[1]:.3g}]")
    for row in result.strata.itertuples(index=False):
        print(f"  stratum {row.stratum}: p = {row.estimate:.3g}, c.o.v. {row.cov:.2f}, {row.simulations} simulations, "
              f"{row.levels} levels")
    if o.estimate > 0 and o.cov > 0:
        need = (1.0 - o.estimate) / (o.estimate * o.cov ** 2)
        print(f"  plain Monte Carlo to the same c.o.v.: {need:.3g} runs ({need / max(sims, 1):.3g} x)")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=20.0, help="run length (s); manoeuvres start up to 16 s")
    p.add_argument("--manoeuvre", nargs="*", default=["doublet"])
    p.add_argument("--turbulence", nargs="*", default=["moderate"])
    p.add_argument("--samples", type=int, default=500)
    p.add_argument("--budget", type=int, default=20000)
    p.add_argument("--target-cov", type=float, default=0.3)
    p.add_argument("--chunk", type=int, default=250)
    p.add_argument("--seeds", type=int, nargs="+", default=[5])
    p.add_argument("--check", action="store_true", help="also the lowered threshold against plain Monte Carlo")
    p.add_argument("--lowered", nargs="+", default=["fdd.loe.detection_contrast=0.03"], metavar="KEY=VALUE",
                   help="the FDD keys lowered for the check")
    p.add_argument("--mc", type=int, default=20000, help="plain Monte Carlo runs of the check")
    args = p.parse_args()
    if args.check:
        lowered = {k: float(v) for k, v in (item.split("=") for item in args.lowered)}
        start = time.perf_counter()
        subset = mcfdd.probability(reduced(args, **lowered), progress=False)
        show(f"lowered {lowered}, subset simulation", subset, time.perf_counter() - start)
        start = time.perf_counter()
        mc = mcfdd.probability(reduced(args, **lowered, **{"probability.method": "mc", "probability.samples": args.mc,
                                                             "probability.budget": args.mc}), progress=False)
        show(f"lowered {lowered}, plain Monte Carlo", mc, time.perf_counter() - start)
        a, b = subset.overall, mc.overall
        print(f"  subset estimate in the Monte Carlo interval: {b.interval[0] <= a.estimate <= b.interval[1]}; "
              f"Monte Carlo estimate in the subset interval: {a.interval[0] <= b.estimate <= a.interval[1]}")
        return
    for seed in args.seeds:
        start = time.perf_counter()
        result = mcfdd.probability(reduced(args, **{"probability.seed": seed}), progress=True)
        show(f"validation FDD, subset simulation, seed {seed}", result, time.perf_counter() - start)

if __name__ == "__main__":
    main()

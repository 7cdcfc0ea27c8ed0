"""P(false alarm) of the validation FDD by subset simulation, and a lowered threshold against plain Monte Carlo.

1. ``--check``: the validation space with the FDD's thresholds lowered (``--lowered KEY=VALUE``, by
   default ``fdd.loe.detection_contrast=0.03``), where a false alarm is common enough for plain Monte
   Carlo: plain Monte Carlo of ``--mc`` runs in printed batches (``--mc-only``: that alone), then
   subset simulation for each of ``--seeds`` (``--subset-only``: that alone).
2. Otherwise the validation FDD as configured: the estimator (``--method``, subset simulation by default;
   importance sampling's keys by ``--set``) per stratum (``--repeats`` runs,
   then more to the target c.o.v. within the budget), for each of ``--seeds``; the simulations spent
   against the runs plain Monte Carlo would need for the same c.o.v., (1 - p) / (p cov^2).

With several seeds, the spread of ln p_hat over the runs and over the seeds' pooled estimates is
printed beside the stated c.o.v. (as s = sqrt(ln(1 + cov^2))). Horizons, strata and budgets are
reduced by flags (``--duration``, ``--manoeuvre``, ``--turbulence``) so a run takes minutes; every
number printed says what was run. The per-airframe view is off here.

    nice -n 10 python benchmarks/probability_validation.py [--duration 20] [--manoeuvre doublet]
        [--turbulence moderate] [--samples 400] [--p0 0.1] [--repeats 4] [--budget 20000] [--seeds 11 12 13]
        [--method importance --set probability.starts_from=subset probability.spread=1.5]
        [--check [--mc-only | --subset-only] --lowered fdd.loe.detection_contrast=0.03 --mc 100000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

import mcfdd
from mcfdd import config
from mcfdd.analysis import probability as normal_space, rare
from mcfdd.analysis.metrics import clopper_pearson
from mcfdd.flags import set_overrides
from mcfdd.workflows.common import dtype_of, precision
from mcfdd.workflows.probability import problem_of

ROOT = Path(__file__).resolve().parent.parent


def reduced(args, **extra) -> config.CampaignConfig:
    cfg = mcfdd.load_config(ROOT / "configs" / "validation.toml", "campaign")
    changes = {"campaign.duration_s": args.duration, "probability.samples": args.samples,
               "probability.budget": args.budget, "probability.target_cov": args.target_cov,
               "probability.chunk": args.chunk, "probability.seed": args.seeds[0], "probability.p0": args.p0,
               "probability.max_levels": args.max_levels,
               "probability.repeats": args.repeats, "probability.airframe.view": "none"}
    if args.manoeuvre:
        changes["space.manoeuvre_kind"] = args.manoeuvre
    if args.turbulence:
        changes["space.turbulence"] = args.turbulence
    changes["probability.method"] = args.method
    return config.replace(cfg, {**changes, **set_overrides(args.set), **extra})


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


def plain_monte_carlo(cfg: config.CampaignConfig, runs: int, batch: int, seed: int):
    """Plain Monte Carlo of the (one-stratum) space in batches of ``batch`` runs under one compiled program,
    the running hits printed after each batch (a cut run keeps what it printed)."""
    with precision(cfg.campaign.precision):
        problem, _ = problem_of(cfg)
        (stratum,) = normal_space.strata(cfg.space.axes, ("none",))
        args = normal_space.stratum_args(cfg.space.axes, stratum, dtype_of(cfg.campaign.precision))
        g = normal_space.limit_state(problem)
        hits = n = 0
        key = jax.random.key(seed)
        for i in range(runs // batch):
            e = rare.monte_carlo(g, problem.space.d, jax.random.fold_in(key, i), n=batch,
                                 batch=min(batch, cfg.probability.chunk), args=(args,))
            hits, n = hits + e.hits, n + batch
            lo, hi = clopper_pearson(hits, n, 0.95)
            print(f"  plain Monte Carlo: {hits} hits in {n} runs, p = {hits / n:.3g}, 95 % [{lo:.3g}, {hi:.3g}]",
                  flush=True)
    return hits, n


def spread(results) -> None:
    """Over the seeds: the spread of ln p_hat against the stated c.o.v., for single runs and pooled estimates."""
    def s_of(cov):
        return np.sqrt(np.log1p(np.asarray(cov) ** 2))

    runs = pd.concat([r.runs for r in results])
    pooled = np.array([[r.overall.estimate, r.overall.cov] for r in results])
    print(f"single runs ({len(runs)}): sd of ln p_hat {np.std(np.log(runs['estimate']), ddof=1):.2f}, stated s "
          f"(mean of sqrt(ln(1 + cov^2))) {np.mean(s_of(runs['cov'])):.2f}; median lineages at the final level "
          f"{np.median(runs['lineages']):.0f}")
    print(f"pooled estimates ({len(results)} seeds, {len(runs) / len(results):.1f} runs each): sd of ln p_hat "
          f"{np.std(np.log(pooled[:, 0]), ddof=1):.2f}, stated s {np.mean(s_of(pooled[:, 1])):.2f}; geometric mean "
          f"{np.exp(np.mean(np.log(pooled[:, 0]))):.3g}, mean {np.mean(pooled[:, 0]):.3g}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=20.0, help="run length (s); manoeuvres start up to 16 s")
    p.add_argument("--manoeuvre", nargs="*", default=["doublet"])
    p.add_argument("--turbulence", nargs="*", default=["moderate"])
    p.add_argument("--samples", type=int, default=500)
    p.add_argument("--p0", type=float, default=0.1)
    p.add_argument("--max-levels", type=int, default=12)
    p.add_argument("--repeats", type=int, default=4, help="estimator runs per stratum at least")
    p.add_argument("--budget", type=int, default=20000)
    p.add_argument("--target-cov", type=float, default=0.3)
    p.add_argument("--chunk", type=int, default=250)
    p.add_argument("--seeds", type=int, nargs="+", default=[5])
    p.add_argument("--check", action="store_true", help="the lowered threshold against plain Monte Carlo")
    p.add_argument("--lowered", nargs="+", default=["fdd.loe.detection_contrast=0.03"], metavar="KEY=VALUE",
                   help="the FDD keys lowered for the check")
    p.add_argument("--mc", type=int, default=20000, help="plain Monte Carlo runs of the check")
    p.add_argument("--mc-batch", type=int, default=5000, help="plain Monte Carlo runs per printed batch")
    p.add_argument("--mc-only", action="store_true", help="the check's plain Monte Carlo alone")
    p.add_argument("--subset-only", action="store_true", help="the check's estimator alone (subset or --method)")
    p.add_argument("--method", default="subset", choices=("subset", "importance"), help="the estimator")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="more config keys, e.g. probability.starts_from=subset probability.spread=1.5")
    args = p.parse_args()
    lowered = set_overrides(args.lowered) if args.check else {}
    label = f"lowered {lowered}" if args.check else "validation FDD"
    if not args.subset_only and args.check:
        plain_monte_carlo(reduced(args, **lowered), args.mc, args.mc_batch, args.seeds[0])
    if args.mc_only:
        return
    results = []
    for seed in args.seeds:  # the Monte Carlo's seed is reused: the estimators' keys are not its keys
        start = time.perf_counter()
        result = mcfdd.probability(reduced(args, **lowered, **{"probability.seed": seed}), progress=True)
        show(f"{label}, {args.method}, seed {seed}", result, time.perf_counter() - start)
        for row in result.runs.itertuples(index=False):
            print(f"    run {row.run}: p = {row.estimate:.3g}, c.o.v. {row.cov:.2f}, {row.simulations} simulations, "
                  f"{row.levels} levels, {row.lineages} lineages at the final level", flush=True)
        results.append(result)
    if len(results) > 1:
        spread(results)


if __name__ == "__main__":
    main()

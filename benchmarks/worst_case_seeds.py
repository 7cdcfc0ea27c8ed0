"""The worst-case search against Monte Carlo on several seeds (README "Worst cases and tuning").

Runs ``mcfdd.worst_case`` on each config and seed (``simulation.seed``: the screening's Sobol
scrambling and run keys; Monte Carlo draws from seed + 1), each with the search and both Monte
Carlo comparisons in one run, saves each run's files under ``--out/<config>-seed<S>`` and prints
one table row per run: the screening alone, the gradient search, Monte Carlo with the same number
of simulations and with the same run time (its runs in brackets), the starts replaced, and the
number of Monte Carlo runs (in the order they were drawn) needed to reach the search's bound
(``-`` if the equal-time runs did not reach it). ``--set KEY=VALUE`` overrides a config key for
every run (e.g. to try a setting on the tuning seed).

    python benchmarks/worst_case_seeds.py configs/worst_case_stall_detect.toml --seeds 1 2
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import mcfdd
from mcfdd.search_report import fmt

COLUMNS = ("Sobol screening alone", "gradient search (Sobol screening + projected gradient)",
           "Monte Carlo, equal number of simulations", "Monte Carlo, equal run time")


def to_match(points, value: str, bound: str, target: float) -> str:
    """Monte Carlo runs, in drawing order, until one is as bad as ``target``; '-' if none is."""
    mc = points[points["method"].isin(("monte_carlo", "monte_carlo_extra"))].sort_values("run_index")[value]
    reached = (mc >= target) if bound == "free" else (mc <= target)
    return str(int(np.argmax(reached.to_numpy())) + 1) if reached.any() else "-"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="+")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", default="results/worst-case-seeds")
    args = parser.parse_args()
    overrides = {k: json.loads(v) for k, v in (s.split("=", 1) for s in args.set)}
    print("| config | seed | screening alone | gradient search | Monte Carlo, same simulations | "
          "Monte Carlo, equal run time (runs) | starts replaced | Monte Carlo runs to reach the search |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.configs:
        for seed in args.seeds:
            cfg = mcfdd.load_config(path, "worst-case", overrides={**overrides, "simulation.seed": seed})
            result = mcfdd.worst_case(cfg, progress=False)
            name = Path(path).stem
            result.save(Path(args.out) / f"{name}-seed{seed}", f"Worst case {name}, seed {seed}")
            by = result.summary.set_index("method")
            grad = result.points[result.points["method"] == "gradient"]
            replaced = grad["start"].nunique() - cfg.search.starts
            v = [by.loc[m, result.value] for m in COLUMNS]
            print(f"| {name} | {seed} | {fmt(v[0], 4)} | {fmt(v[1], 4)} | {fmt(v[2], 4)} "
                  f"({by.loc[COLUMNS[2], 'simulations']:,}) | {fmt(v[3], 4)} ({by.loc[COLUMNS[3], 'simulations']:,}) "
                  f"| {replaced} | {to_match(result.points, result.value, result.bound, v[1])} |", flush=True)


if __name__ == "__main__":
    main()

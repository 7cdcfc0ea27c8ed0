"""Compare the campaign of one config run by two checkouts of mcfdd: same table, or rates within each other's intervals.

Runs ``mcfdd campaign CONFIG --scenarios N`` once with this checkout (or ``--checkout``) and once
with the checkout at ``--baseline`` (its package imported first through ``PYTHONPATH``), each into its own folder
under ``--work``, then compares the scenario tables row by row (same scenario ids): every column
of the baseline's table must be in this one (columns only this one has are listed as additions),
integer, boolean and text columns must be equal, floats within ``--rtol`` relative (non-finite
values must match; ``--rtol 0``: bit for bit). With ``--rates`` it instead compares the overall and
per-stratum rates of the two summaries: each rate must lie inside the other run's Clopper-Pearson
95 % interval (for a change of the random numbers, which changes draws but must not change what the campaign concludes).

    python benchmarks/compare_campaigns.py --baseline /work/base-a96c20f                  # tables
    python benchmarks/compare_campaigns.py --baseline /work/base-a96c20f --rates          # rates
    python benchmarks/compare_campaigns.py --baseline /work/base-a96c20f --reuse          # compare folders again

Exit status 1 when the comparison fails.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent.parent
RATES = ("far_loe", "far_any", "false_identification_rate", "mdr", "identification", "stall_rate_signal",
         "stall_rate_model")  # those named in both summaries are compared (bd337dd pooled "far" and "loe_far")


def run(checkout: Path, config: str, scenarios: int, out: Path) -> float:
    """``mcfdd campaign`` of ``checkout``'s package into ``out``; returns the wall time (s)."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [sys.executable, "-c", "import mcfdd.cli, sys; print(mcfdd.__file__, file=sys.stderr); "
           "sys.exit(mcfdd.cli.main())", "campaign", str((HERE / config).resolve()), "--scenarios", str(scenarios),
           "--out", str(out)]
    start = time.perf_counter()
    # run from the checkout, so that its package is the one imported whatever sys.path[0] is
    subprocess.run(cmd, env=env, check=True, cwd=checkout, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def table(out: Path) -> pd.DataFrame:
    parts = sorted((out / "scenarios").glob("part-*.parquet"))
    df = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    return df.sort_values("scenario_id").reset_index(drop=True)


def compare_tables(a: pd.DataFrame, b: pd.DataFrame, rtol: float) -> list[str]:
    """Lines describing each column of the baseline ``b`` that differs in ``a`` (empty: the tables agree)."""
    problems = []
    missing = [c for c in b.columns if c not in a.columns]
    if missing or len(a) != len(b):
        return [f"rows {len(a)} and {len(b)}, baseline columns missing here: {missing}"]
    added = [c for c in a.columns if c not in b.columns]
    print(f"{len(b.columns)} columns compared; added here: {', '.join(added) if added else 'none'}")
    worst = 0.0
    for col in b.columns:
        x, y = a[col].to_numpy(), b[col].to_numpy()
        if np.issubdtype(x.dtype, np.floating):
            finite = np.isfinite(x) & np.isfinite(y)
            same_nonfinite = np.array_equal(np.isfinite(x), np.isfinite(y)) and np.array_equal(x[~finite], y[~finite],
                                                                                                equal_nan=True)
            rel = np.abs(x[finite] - y[finite]) / np.maximum(np.abs(x[finite]), 1e-30)
            largest = float(rel.max()) if rel.size else 0.0
            worst = max(worst, largest)
            if not same_nonfinite or largest > rtol:
                problems.append(f"{col}: {int((rel > rtol).sum())} rows beyond rtol (largest {largest:.2g}), "
                                f"non-finite pattern {'same' if same_nonfinite else 'differs'}")
        elif not np.array_equal(x, y):
            problems.append(f"{col}: {int((x != y).sum())} rows differ")
    print(f"largest relative difference of a float column: {worst:.2g}")
    return problems


def compare_rates(a: pd.DataFrame, b: pd.DataFrame) -> list[str]:
    problems, checked = [], 0
    rates = [r for r in RATES if all(f"{r}{end}" in t.columns for end in ("", "_lo", "_hi") for t in (a, b))]
    merged = a.merge(b, on=["stratum", "label"], suffixes=("_a", "_b"))
    for _, row in merged.iterrows():
        for rate in rates:
            if not np.isfinite(row[f"{rate}_a"]) or not np.isfinite(row[f"{rate}_b"]):
                continue
            checked += 1
            ra, rb = row[f"{rate}_a"], row[f"{rate}_b"]
            inside = (row[f"{rate}_lo_b"] <= ra <= row[f"{rate}_hi_b"]
                      and row[f"{rate}_lo_a"] <= rb <= row[f"{rate}_hi_a"])
            if not inside:
                problems.append(f"{row['stratum']} {row['label']} {rate}: {ra:.4g} [{row[f'{rate}_lo_a']:.4g}, "
                                f"{row[f'{rate}_hi_a']:.4g}] vs {rb:.4g} [{row[f'{rate}_lo_b']:.4g}, "
                                f"{row[f'{rate}_hi_b']:.4g}]")
    overall = merged[merged["stratum"] == "overall"].iloc[0]
    for rate in rates:
        print(f"overall {rate}: this {overall[f'{rate}_a']:.4g} [{overall[f'{rate}_lo_a']:.4g}, "
              f"{overall[f'{rate}_hi_a']:.4g}], baseline {overall[f'{rate}_b']:.4g} "
              f"[{overall[f'{rate}_lo_b']:.4g}, {overall[f'{rate}_hi_b']:.4g}]")
    print(f"{checked} rates compared over {len(merged)} strata")
    return problems


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, type=Path, help="another checkout of mcfdd (a git worktree)")
    parser.add_argument("--checkout", type=Path, default=HERE, help="the checkout compared with it (default: this one)")
    parser.add_argument("--config", default="configs/loe_campaign.toml")
    parser.add_argument("--scenarios", type=int, default=2048, help="campaign.scenarios of both runs")
    parser.add_argument("--work", type=Path, default=Path("results/compare_campaigns"),
                        help="folder of the two runs (its 'this' and 'baseline' folders are replaced)")
    parser.add_argument("--rtol", type=float, default=1e-4, help="relative tolerance of float columns")
    parser.add_argument("--rates", action="store_true", help="compare the summaries' rates and intervals instead")
    parser.add_argument("--reuse", action="store_true", help="compare the folders of an earlier run, run nothing")
    args = parser.parse_args(argv)
    for flag, path in (("--baseline", args.baseline), ("--checkout", args.checkout)):
        if not (path / "mcfdd" / "__init__.py").is_file():
            raise SystemExit(f"{flag}: {path} holds no mcfdd package")
    outs = {"this": args.work / "this", "baseline": args.work / "baseline"}
    if not args.reuse:
        for name, checkout in (("this", args.checkout.resolve()), ("baseline", args.baseline.resolve())):
            if outs[name].exists():
                shutil.rmtree(outs[name])
            print(f"{name} ({checkout}): {run(checkout, args.config, args.scenarios, outs[name].resolve()):.0f} s",
                  flush=True)
    if args.rates:
        problems = compare_rates(pd.read_parquet(outs["this"] / "summary.parquet"),
                                 pd.read_parquet(outs["baseline"] / "summary.parquet"))
    else:
        problems = compare_tables(table(outs["this"]), table(outs["baseline"]), args.rtol)
    print("\n".join(problems) if problems else "the two campaigns agree")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

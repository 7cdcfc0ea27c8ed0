"""Simulations and wall time to a c.o.v. of 0.3 at P = 1e-6, against plain Monte Carlo; interval coverage.

The problems are the closed-form linear limit states g(u) = a.u - beta, ||a|| = 1, beta = 4.753
(P = Phi(-beta) = 1e-6) in d = 2 and d = 10,000 (a noise path of 6,000 steps x 2 channels is about that
size), and the union of two half-planes (two design points, P = 7.6e-7). For each estimator and
sample size, ``--repeats`` seeds give the empirical c.o.v. sd(p_hat) / P (the number that
matters), the mean stated c.o.v., the coverage of the 95 % intervals, the simulations per run, and
the wall time per run after compilation (``block_until_ready``: the results are NumPy) and the
first run's time with compilation. Plain Monte Carlo would need (1 - P) / (cov^2 P) = 1.1e7 runs
for a c.o.v. of 0.3 at 1e-6.

``--coverage N`` also runs subset simulation on N seeds in d = 2, 100 and 1000 and compares the
coverage of its interval with that of Au and Beck's independent-level c.o.v. (see
:mod:`mcfdd.analysis.rare.subset`).

    python benchmarks/rare_event.py [--repeats 20] [--coverage 200] [--problems linear-2 linear-10000 union]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from scipy.stats import multivariate_normal, norm

from mcfdd.analysis import rare
from mcfdd.analysis.rare.estimate import interval

jax.config.update("jax_enable_x64", True)
BETA = float(-norm.ppf(1e-6))
TARGET_COV = 0.3


class Linear:
    def __init__(self, d):
        self.d, self.a, self.truth = d, np.ones(d) / np.sqrt(d), float(norm.sf(BETA))

    def __call__(self, u):
        return u @ self.a - BETA


class Union:
    d, a1, a2, b1, b2 = 2, np.array([1.0, 0.0]), np.array([0.6, 0.8]), 4.9, 5.0

    def __init__(self):
        both = multivariate_normal([0, 0], [[1, 0.6], [0.6, 1]]).cdf([-self.b1, -self.b2])
        self.truth = float(norm.sf(self.b1) + norm.sf(self.b2) - both)

    def __call__(self, u):
        import jax.numpy as jnp

        return jnp.maximum(u @ self.a1 - self.b1, u @ self.a2 - self.b2)


def estimators(n):
    return {"subset": lambda g, d, k: rare.subset_simulation(g, d, k, n=n),
            "importance": lambda g, d, k: rare.importance_sampling(g, d, k, n=n, starts=4, screening=64,
                                                                   iterations=8)}


def study(problem, method, n, repeats):
    fn = estimators(n)[method]
    start = time.perf_counter()
    first = fn(problem, problem.d, jax.random.key(0))
    with_compile = time.perf_counter() - start
    start = time.perf_counter()
    runs = [first] + [fn(problem, problem.d, jax.random.key(s)) for s in range(1, repeats)]
    per_run = (time.perf_counter() - start) / (repeats - 1)
    values = np.array([r.estimate for r in runs])
    return dict(n=n, sims=np.mean([r.n_simulations for r in runs]), emp_cov=values.std(ddof=1) / problem.truth,
                stated=np.mean([r.cov for r in runs]), cover=np.mean([r.covers(problem.truth) for r in runs]),
                first_s=with_compile, run_s=per_run)


PROBLEMS = {"linear-2": lambda: Linear(2), "linear-10000": lambda: Linear(10_000), "union": Union}


def efficiency(repeats, names):
    problems = {name: PROBLEMS[name]() for name in names}
    ladders = {"subset": (250, 500, 1000, 2000, 4000), "importance": (50, 100, 200, 400)}
    print(f"{'problem':16} {'method':10} {'n':>5} {'simulations':>11} {'emp. cov':>8} {'stated':>7} "
          f"{'cover':>6} {'run s':>7} {'1st s':>7}  MC runs for this cov")
    for name, problem in problems.items():
        for method, ladder in ladders.items():
            for n in ladder:
                r = study(problem, method, n, repeats)
                mc = (1 - problem.truth) / (r["emp_cov"] ** 2 * problem.truth)
                print(f"{name:16} {method:10} {n:5d} {r['sims']:11.0f} {r['emp_cov']:8.3f} {r['stated']:7.3f} "
                      f"{r['cover']:6.2f} {r['run_s']:7.3f} {r['first_s']:7.2f}  {mc:.2e}", flush=True)
                if r["emp_cov"] <= TARGET_COV:
                    break


def coverage(seeds):
    print(f"\nsubset simulation, n = 1000, P = 1e-6, {seeds} seeds: coverage of the 95 % interval")
    print(f"{'d':>5} {'sd ln p':>8} {'lineage s':>9} {'AB s':>6} {'cover':>6} {'cover AB':>8} {'lineages':>8}")
    for d in (2, 100, 1000):
        problem = Linear(d)
        runs = [rare.subset_simulation(problem, d, jax.random.key(10_000 + s), n=1000) for s in range(seeds)]
        ab = [np.sqrt(sum(level.cov ** 2 for level in r.levels)) for r in runs]
        ab_cover = np.mean([lo <= problem.truth <= hi for lo, hi in
                            (interval(r.estimate, c, 0.95, "lognormal") for r, c in zip(runs, ab))])
        stated = np.sqrt(np.mean(np.log1p([r.cov ** 2 for r in runs])))
        cover = np.mean([r.covers(problem.truth) for r in runs])
        print(f"{d:5d} {np.std(np.log([r.estimate for r in runs])):8.3f} {stated:9.3f} "
              f"{np.sqrt(np.mean(np.log1p(np.square(ab)))):6.3f} {cover:6.3f} {ab_cover:8.3f} "
              f"{np.median([r.levels[-1].lineages for r in runs]):8.0f}", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=20, help="seeds per estimator and size")
    parser.add_argument("--coverage", type=int, default=0, help="seeds of the coverage study (0: skip)")
    parser.add_argument("--problems", nargs="+", choices=list(PROBLEMS), default=list(PROBLEMS))
    args = parser.parse_args()
    efficiency(args.repeats, args.problems)
    if args.coverage:
        coverage(args.coverage)


if __name__ == "__main__":
    main()

"""Subset simulation (Au and Beck 2001) with adaptive conditional sampling (Papaioannou et al. 2015).

S.-K. Au and J. L. Beck, "Estimation of small failure probabilities in high dimensions by subset
simulation", Probabilistic Engineering Mechanics 16(4), 263-277, 2001 (AB);
I. Papaioannou, W. Betz, K. Zwirglmaier and D. Straub, "MCMC algorithms for subset simulation",
Probabilistic Engineering Mechanics 41, 89-103, 2015 (PBZS); S. L. Cotter, G. O. Roberts,
A. M. Stuart and D. White, "MCMC methods for functions: modifying old algorithms to make them
faster", Statistical Science 28(3), 424-446, 2013 (the preconditioned Crank-Nicolson move).

The event F = {g(u) > 0}, u ~ N(0, I_d), is reached through nested events
F_j = {g(u) > b_j}, b_1 < b_2 < ... < 0, so that (AB eq. 2)

    P(F) = P(F_1) prod_{j=2}^{L} P(F_j | F_{j-1}) * P(F | F_L) = p0^L * P(F | F_L).

Level 0 draws n independent samples. At each level, b_j is the (1 - p0) sample quantile of g
(the midpoint between the n_c-th and (n_c + 1)-th largest values, n_c = p0 n), so P(F_j | F_{j-1})
is p0 by construction; the n_c samples above it are the seeds of n_c Markov chains of n_s = 1/p0
states each (the seed the first), which give the n samples of the next level, conditional on
F_j. The final level is the first whose samples have at least n_c in F (or the level cap L_max):
P(F | F_L) = k / n with k the samples in F. Simulations: n + L (n - n_c).

Chains (PBZS, "adaptive conditional sampling", Algorithm 5): each component is moved by the
conditional-normal (pCN) proposal

    v_i = rho_i u_i + sigma_i xi_i,   xi_i ~ N(0, 1),   sigma_i = min(lambda s_i, 1),   rho_i = sqrt(1 - sigma_i^2),

with s_i the seeds' sample standard deviation in component i. The proposal is reversible with
respect to N(0, 1) in each component, hence N(0, I_d) is invariant in any dimension (Cotter et
al. 2013: no Metropolis ratio and no acceptance collapse as d grows; with s_i = 1 it is
pCN with beta = lambda), and the candidate is accepted exactly when g(v) > b_j. The per-component
scale s_i shrinks the move in the few coordinates (e.g. the uncertain parameters) where the
seeds concentrate and leaves it wide in the many (e.g. a noise path) where they do not. The scale
lambda (1 at level 0 per PBZS, here ``scale0``) is adapted to the target acceptance rate
a* = 0.44: after chain step t of a level, over all chains at once,
ln lambda <- ln lambda + (a_t - a*) / sqrt(t), and the last value carries to the next level. All
chains advance together as one batch of n_c candidates per step (``lax.scan`` over n_s - 1
steps, ``lax.while_loop`` over levels, one compiled program per run).

Coefficient of variation. Per level, AB eqs. 27-29: for level j with conditional probability
p_j and the indicators I_{c,l} = [g(u_{c,l}) > b_j] of chain c's l-th state,

    delta_j^2 = (1 - p_j) / (n p_j) (1 + gamma_j),   gamma_j = 2 sum_{k=1}^{n_s-1} (1 - k/n_s) rho_j(k),
    rho_j(k) = R_j(k) / R_j(0),   R_j(k) = 1 / (n - k n_c) sum_c sum_{l=1}^{n_s-k} I_{c,l} I_{c,l+k} - p_j^2,

gamma_0 = 0 (independent samples); these are reported per level. AB's total, sum_j delta_j^2,
takes the chains of a level as independent and the levels as uncorrelated. Neither holds: seeds
taken from one chain (repeated states included) start correlated chains, and a lineage that
went deep at one level seeds the next. On linear limit states at P = 1e-6 (n = 1000, d = 2,
100, 1000; ``benchmarks/rare_event.py --coverage 200``), sqrt(ln(1 + sum_j delta_j^2)) is 0.34
where the standard deviation of ln p_hat over 200 seeds is 0.39 to 0.43, and the log-normal
interval built on it covers 88 to 92 % instead of 95 %. The total variance is therefore taken
from the genealogy, as for sequential Monte Carlo (subset simulation is one: F. Cerou,
P. Del Moral, T. Furon and A. Guyader, "Sequential Monte Carlo for rare event estimation",
Statistics and Computing 22(3), 2012; the estimator after H. P. Chan and T. L. Lai, Annals of
Statistics 41(6), 2013, and A. Lee and N. Whiteley, "Variance estimation in the particle
filter", Biometrika 105(3), 2018): to first order
ln p_hat - ln P = sum_j sum_i (I_{j,i} - p_j) / (n p_j), and grouping the terms of every level by
the level-0 sample k that sample i descends from (its root lineage) gives sums psi_k that are
uncorrelated across lineages, so

    s^2 = var(ln p_hat) = n / (n - 1) sum_k psi_k^2,   (at least ln(1 + sum_j delta_j^2)),

delta = sqrt(exp(s^2) - 1), and the log-normal interval uses Student's t with (lineages at the
final level - 1) degrees of freedom, since only that many lineages carry the deep levels
(``Level.lineages``; a median of 13 of n = 1000 at P = 1e-6). There s is 0.38 to 0.40 and the
interval covers 94 to 98 %. The estimate's bias is O(1/n) (AB).

When the cap is reached with no sample in F, the result is ``reached=False``: with b_L < 0 the
last threshold, F is inside F_L, so P(F) <= P(F_L), estimated by p0^L; that is the estimate
reported, with the interval (0, upper end of p0^L's), as an upper bound statement.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis.rare.estimate import Estimate, Level, interval
from mcfdd.analysis.rare.sampling import check_problem, evaluate, failure_arrays, float_dtype

TARGET_ACCEPTANCE = 0.44  # PBZS section 4: the optimal acceptance rate of a one-dimensional move


class _Run(NamedTuple):
    level: jax.Array  # intermediate levels done
    u: jax.Array  # (n, d) samples of the current level, row = chain step * n_c + chain
    gu: jax.Array  # (n,) g at the samples
    key: jax.Array
    scale: jax.Array  # lambda
    roots: jax.Array  # (n_c,) the level-0 sample each current chain's lineage descends from
    influence: jax.Array  # (n,) psi_k summed over the levels done
    # per level j (the last slot: the final level): b_j, gamma_j, lineages, and the acceptance and
    # lambda of the chains that produced level j's samples
    thresholds: jax.Array
    gammas: jax.Array
    lineages: jax.Array
    acceptance: jax.Array
    scales: jax.Array


def gamma_factor(indicators):
    """AB's gamma (eq. 29) from the indicators (n_s, n_c) of n_c chains of n_s states (0 if constant)."""
    ind = indicators.astype(jnp.result_type(float))
    ns, nc = ind.shape
    p = jnp.mean(ind)
    r0 = p - p * p
    gamma = 0.0
    for k in range(1, ns):
        rk = jnp.sum(ind[: ns - k] * ind[k:]) / (nc * (ns - k)) - p * p
        gamma = gamma + 2.0 * (1.0 - k / ns) * rk / jnp.where(r0 > 0, r0, 1.0)
    return jnp.where(r0 > 0, gamma, 0.0)


def lineage_terms(above, level, roots):
    """(n,) the terms (I_i - p) / (n p) of one level's samples summed per root lineage, and the lineage count.

    ``above`` (n,) are the indicators, row = chain step * n_c + chain; at level 0 every sample is
    its own lineage.
    """
    n, nc = above.shape[0], roots.shape[0]
    ind = above.astype(jnp.result_type(float))
    p = jnp.mean(ind)
    terms = (ind - p) / (n * jnp.where(p > 0, p, 1.0))
    owner = jnp.where(level > 0, jnp.tile(roots, n // nc), jnp.arange(n))
    count = jnp.where(level > 0, jnp.sum(jax.ops.segment_sum(jnp.ones(nc), roots, n) > 0), n).astype(jnp.int32)
    return jax.ops.segment_sum(terms, owner, n), count


def conditional_move(g, u, gu, threshold, sigma, key, chunk=None, args=()):
    """One adaptive-conditional-sampling move of every chain (module docstring).

    Args:
        u: (m, d) chain states, all with g > threshold; gu: (m,) g there.
        sigma: (d,) or (m, d) proposal standard deviations, each in [0, 1].
    Returns:
        (u', gu', accepted (m,) bool): N(0, I_d) restricted to {g > threshold} is invariant.
    """
    sigma = jnp.asarray(sigma, u.dtype)
    v = jnp.sqrt(1.0 - sigma * sigma) * u + sigma * jax.random.normal(key, u.shape, u.dtype)
    gv = evaluate(g, v, chunk, args)
    accept = gv > threshold
    return jnp.where(accept[:, None], v, u), jnp.where(accept, gv, gu), accept


def _record(run: _Run, j, threshold, above, ns, nc) -> _Run:
    """Level j's threshold, gamma, lineage count and its samples' terms psi (added to the influence)."""
    terms, count = lineage_terms(above, run.level, run.roots)
    gamma = jnp.where(run.level > 0, gamma_factor(above.reshape(ns, nc)), 0.0)
    return run._replace(influence=run.influence + terms, thresholds=run.thresholds.at[j].set(threshold),
                        gammas=run.gammas.at[j].set(gamma), lineages=run.lineages.at[j].set(count))


def _level(g, run: _Run, nc, ns, chunk, args, target) -> _Run:
    """One intermediate level: threshold and records of the current samples, chains from the seeds."""
    order = jnp.argsort(-run.gu)
    b = 0.5 * (run.gu[order[nc - 1]] + run.gu[order[nc]])
    j = run.level
    run = _record(run, j, b, run.gu > b, ns, nc)
    seeds, gseeds = run.u[order[:nc]], run.gu[order[:nc]]
    roots = jnp.where(j > 0, run.roots[order[:nc] % nc], order[:nc])
    spread = jnp.std(seeds, axis=0)
    key, sub = jax.random.split(run.key)

    def step(carry, t):
        u, gu, scale = carry
        sigma = jnp.minimum(scale * spread, 1.0)
        u, gu, accept = conditional_move(g, u, gu, b, sigma, jax.random.fold_in(sub, t), chunk, args)
        rate = jnp.mean(accept.astype(scale.dtype))
        scale = jnp.exp(jnp.log(scale) + (rate - target) / jnp.sqrt((t + 1).astype(scale.dtype)))
        return (u, gu, scale), (u, gu, rate)

    (_, _, scale), (us, gus, rates) = jax.lax.scan(step, (seeds, gseeds, run.scale), jnp.arange(ns - 1))
    d = run.u.shape[1]
    return run._replace(level=j + 1, u=jnp.concatenate([seeds[None], us]).reshape(ns * nc, d),
                        gu=jnp.concatenate([gseeds[None], gus]).reshape(-1), key=key, scale=scale, roots=roots,
                        acceptance=run.acceptance.at[j + 1].set(jnp.mean(rates)),
                        scales=run.scales.at[j + 1].set(scale))


@partial(jax.jit, static_argnames=("g", "d", "n", "nc", "max_levels", "chunk", "keep", "dtype", "target"))
def _subset(g, d, key, args, scale0, n, nc, max_levels, chunk, keep, dtype, target):
    ns = n // nc
    key, sub = jax.random.split(key)
    u = jax.random.normal(sub, (n, d), dtype)
    slots = jnp.full(max_levels + 1, jnp.nan, dtype)
    run = _Run(level=jnp.asarray(0), u=u, gu=evaluate(g, u, chunk, args), key=key, scale=jnp.asarray(scale0, dtype),
               roots=jnp.arange(nc), influence=jnp.zeros(n, dtype), thresholds=slots, gammas=slots,
               lineages=jnp.zeros(max_levels + 1, jnp.int32), acceptance=slots, scales=slots)

    def more(r):
        return (jnp.sum(r.gu > 0) < nc) & (r.level < max_levels)

    run = jax.lax.while_loop(more, lambda r: _level(g, r, nc, ns, chunk, args, target), run)
    hit = run.gu > 0
    run = _record(run, run.level, jnp.asarray(0.0, dtype), hit, ns, nc)
    score = jnp.where(hit, -jnp.sum(run.u * run.u, axis=1), -jnp.inf)
    best, idx = jax.lax.top_k(score, keep)
    records = {name: getattr(run, name) for name in ("level", "thresholds", "gammas", "lineages", "acceptance",
                                                      "scales")}
    return dict(records, var_log=n / (n - 1.0) * jnp.sum(run.influence ** 2), hits=jnp.sum(hit),
                points=run.u[idx], margins=run.gu[idx], score=best)


def subset_simulation(g, d: int, key, *, n: int = 1000, p0: float = 0.1, max_levels: int = 20,
                      scale0: float = 1.0, target_acceptance: float = TARGET_ACCEPTANCE, chunk: int | None = None,
                      keep: int = 16, confidence: float = 0.95, dtype=None, args=()) -> Estimate:
    """Subset simulation estimate of P(g(u) > 0), u ~ N(0, I_d) (module docstring).

    Args:
        g: batched limit state ``g(u, *args)``, (m, d) -> (m,), JAX-traceable; g > 0 is the event.
            Called on n rows at level 0 and n_c = p0 n rows per chain step.
        d: dimension of u (any: the chains keep N(0, I_d) invariant).
        key: a ``jax.random`` key; the same key gives the same estimate to the last bit.
        n: samples per level; p0 n must be an integer >= 2 dividing n.
        p0: conditional probability of the intermediate levels (0.1: AB, PBZS).
        max_levels: cap on the intermediate levels (the smallest probability reachable before the
            final level is p0^max_levels).
        scale0: the proposal scale lambda at the first level.
        target_acceptance: a* of the scale adaptation.
        chunk: rows of u that g sees at once (None: all); memory is about 3 n d numbers for the
            samples plus g's working memory for ``chunk`` rows.
        keep: failure points returned (the most probable of the last level's).
        confidence: of the log-normal interval.
        dtype: of u (default: JAX's default float).
        args: traced arrays passed to g after u (no recompilation when they change).

    Returns:
        :class:`Estimate` with ``kind="lognormal"``, the levels (the final one last), the
        simulations n + L (n - n_c), and ``reached=False`` for an upper bound (module docstring).
    """
    if not 0.0 < p0 <= 0.5:
        raise ValueError(f"p0 must lie in (0, 0.5], got {p0}")
    nc = int(round(p0 * n))
    if nc < 2 or abs(nc - p0 * n) > 1e-9 * n or n % nc:
        raise ValueError(f"p0 * n must be an integer >= 2 dividing n: p0={p0}, n={n}")
    if not isinstance(max_levels, int) or max_levels < 1:
        raise ValueError(f"max_levels must be a positive integer, got {max_levels!r}")
    check_problem(g, d, n, chunk, dtype, args)
    run = jax.device_get(_subset(g, d, key, tuple(args), scale0, n, nc, max_levels, chunk, min(keep, n),
                                 float_dtype(dtype), target_acceptance))
    done, hits = int(run["level"]), int(run["hits"])
    reached = hits > 0
    probabilities = [nc / n] * done + ([hits / n] if reached else [])
    levels = tuple(Level(threshold=float(run["thresholds"][j]), probability=p,
                         cov=float(np.sqrt((1.0 - p) / (n * p) * (1.0 + run["gammas"][j]))),  # AB eq. 27
                         gamma=float(run["gammas"][j]), lineages=int(run["lineages"][j]),
                         acceptance=float(run["acceptance"][j]), scale=float(run["scales"][j]))
                   for j, p in enumerate(probabilities))
    estimate = float(np.prod(probabilities))
    # s^2 = var(ln p_hat): the lineage estimate, never below AB's independent-level sum
    s2 = max(float(run["var_log"]), float(np.log1p(sum(level.cov ** 2 for level in levels))))
    cov = float(np.sqrt(np.expm1(s2)))
    dof = float(run["lineages"][done] - 1) if done else float("inf")
    lo, hi = interval(estimate, cov, confidence, "lognormal", dof)
    points, margins = failure_arrays(run["points"], run["margins"], run["score"])
    return Estimate(method="subset", estimate=estimate, cov=cov, interval=(lo if reached else 0.0, hi),
                    confidence=confidence, kind="lognormal", n_simulations=n + done * (n - nc), hits=hits,
                    reached=reached, dof=dof, levels=levels, failure_points=points, failure_margins=margins)

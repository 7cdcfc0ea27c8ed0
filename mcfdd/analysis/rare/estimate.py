"""What every rare-event estimator returns, its intervals, and estimates combined over strata.

An estimate p_hat of P(F) carries its coefficient of variation delta = sd(p_hat) / p_hat and a
two-sided interval at a stated confidence c (z = Phi^-1((1 + c) / 2)), of one of three kinds:

- ``"lognormal"`` (subset simulation): ln p_hat taken as normal with variance
  s^2 = ln(1 + delta^2) and mean ln P - s^2 / 2 (so that p_hat is unbiased), giving
  ``[p_hat exp(s^2/2 - z s), p_hat exp(s^2/2 + z s)]``: positive, and skewed as the product of
  the levels' conditional probabilities is; when s^2 is itself estimated from few independent
  groups (``dof`` finite), z is Student's t quantile with ``dof`` degrees of freedom;
- ``"normal"`` (importance sampling): the central limit interval ``p_hat (1 -+ z delta)``, its
  lower end clipped at 0;
- ``"clopper-pearson"`` (plain Monte Carlo): the exact binomial interval of k hits in n runs
  (:func:`mcfdd.analysis.metrics.clopper_pearson`), which with k = 0 still bounds P from above
  (about 3 / n at 95 %).

A linear combination of independent estimates, ``P = sum_s c_s p_s`` (strata with weights
c_s = w_s, or a rate per flight hour with c_s = w_s 3600 / T_s), has the variance
``sum_s c_s^2 (delta_s p_s)^2`` (the delta method; exact for a linear map of independent
estimates). Its interval is either ``"delta"``: lognormal from the combined c.o.v., or ``"union"``:
``[sum_s c_s lo_s, sum_s c_s hi_s]`` with each stratum's interval at confidence 1 - (1 - c) / S
(Bonferroni: it covers whenever every stratum's interval does, which happens with probability at
least c whatever the strata's laws; wider, and the one to use when a stratum has no hit).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
from scipy.stats import norm, t as student_t

from mcfdd.analysis.metrics import clopper_pearson

INTERVALS = ("lognormal", "normal", "clopper-pearson", "delta", "union")


class Level(NamedTuple):
    """One level of subset simulation: F_j = {g(u) > threshold}, P(F_j | F_{j-1}) = probability.

    ``cov`` is the level's c.o.v. and ``gamma`` its chain-correlation factor (Au and Beck 2001,
    eqs. 27-29), ``lineages`` the number of level-0 samples the level's samples descend from,
    ``acceptance`` the mean acceptance rate of the chain moves that produced the level's samples
    and ``scale`` the proposal scale lambda they ended with (nan for the Monte Carlo level 0).
    """

    threshold: float
    probability: float
    cov: float
    gamma: float
    lineages: int
    acceptance: float
    scale: float


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A probability (or a rate) with its coefficient of variation and interval.

    Attributes:
        method: ``"subset"``, ``"importance"``, ``"monte_carlo"`` or ``"combined"``.
        estimate: p_hat (a probability; a rate per flight hour for a per-hour combination).
        cov: delta = sd(p_hat) / p_hat (inf when nothing was hit).
        interval: (lo, hi) at ``confidence``.
        confidence: two-sided confidence of ``interval``.
        kind: how the interval is computed (see the module docstring).
        n_simulations: evaluations of g spent (a gradient counted as one evaluation).
        hits: failure samples (g > 0) among the last level's, the importance or the Monte Carlo samples.
        dof: degrees of freedom of the variance estimate behind ``interval`` (inf: z is normal).
        reached: False when subset simulation stopped at its level cap without a sample in F: then
            ``estimate`` is p0^L = P(g > b_L) for the last threshold b_L < 0, an upper bound of P(F)
            (an estimate of one), and ``interval`` is (0, its upper end).
        levels: subset simulation's levels, the final one last.
        failure_points: (k, d) failure samples found, most probable (smallest ||u||) first.
        failure_margins: (k,) g at those points.
        design_points: (m, d) distinct design points (importance sampling), smallest beta first.
        components: for ``"combined"``: the estimates combined and their coefficients.
        coefficients: (S,) the c_s of a combination.
    """

    method: str
    estimate: float
    cov: float
    interval: tuple[float, float]
    confidence: float
    kind: str
    n_simulations: int
    hits: int
    dof: float = float("inf")
    reached: bool = True
    levels: tuple[Level, ...] = ()
    failure_points: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    failure_margins: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    design_points: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0)))
    components: tuple[Estimate, ...] = ()
    coefficients: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def interval_at(self, confidence: float) -> tuple[float, float]:
        """The interval of the same kind at another confidence level."""
        if self.kind == "clopper-pearson":
            lo, hi = clopper_pearson(self.hits, self.n_simulations, confidence)
            return float(lo), float(hi)
        if self.kind in ("delta", "union"):
            return combined_interval(self.components, self.coefficients, confidence, self.kind)
        lo, hi = interval(self.estimate, self.cov, confidence, self.kind, self.dof)
        return (0.0, hi) if not self.reached else (lo, hi)

    def covers(self, truth: float) -> bool:
        """Whether ``interval`` contains ``truth``."""
        return bool(self.interval[0] <= truth <= self.interval[1])


def z_value(confidence: float, dof: float = float("inf")) -> float:
    """The half-width in standard deviations of a two-sided interval: Phi^-1((1 + c) / 2), or Student's t."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    q = 0.5 + confidence / 2.0
    return float(norm.ppf(q) if np.isinf(dof) else student_t.ppf(q, max(dof, 1.0)))


def interval(estimate: float, cov: float, confidence: float, kind: str,
             dof: float = float("inf")) -> tuple[float, float]:
    """(lo, hi) of a ``"lognormal"`` or ``"normal"`` interval from p_hat and its c.o.v."""
    z = z_value(confidence, dof)
    if not np.isfinite(cov) or estimate <= 0.0:
        return 0.0, float("inf")
    if kind == "lognormal":
        s = np.sqrt(np.log1p(cov ** 2))
        return float(estimate * np.exp(s * s / 2 - z * s)), float(estimate * np.exp(s * s / 2 + z * s))
    if kind == "normal":
        return float(max(estimate * (1.0 - z * cov), 0.0)), float(estimate * (1.0 + z * cov))
    raise ValueError(f"interval kind must be 'lognormal' or 'normal', got {kind!r}")


def combined_interval(components, coefficients, confidence: float, kind: str) -> tuple[float, float]:
    """(lo, hi) of ``sum_s c_s p_s`` by the ``"delta"`` or ``"union"`` rule (module docstring)."""
    coefficients = np.asarray(coefficients, float)
    if kind == "union":
        per = 1.0 - (1.0 - confidence) / len(components)
        bounds = np.array([e.interval_at(per) for e in components])
        return float(coefficients @ bounds[:, 0]), float(coefficients @ bounds[:, 1])
    if kind != "delta":
        raise ValueError(f"a combined interval is 'delta' or 'union', got {kind!r}")
    estimate, cov = _combined_moments(components, coefficients)
    return interval(estimate, cov, confidence, "lognormal")


def _combined_moments(components, coefficients):
    values = np.array([e.estimate for e in components])
    sds = np.array([e.cov * e.estimate if e.estimate > 0 else 0.0 for e in components])
    estimate = float(coefficients @ values)
    sd = float(np.sqrt(np.sum((coefficients * sds) ** 2)))
    return estimate, (sd / estimate if estimate > 0 else float("inf"))


def combine(estimates, coefficients, confidence: float = 0.95, interval_kind: str = "delta") -> Estimate:
    """``sum_s c_s p_s`` of independent estimates (one per stratum), with its c.o.v. and interval.

    Args:
        estimates: S :class:`Estimate` (independent: separate keys).
        coefficients: (S,) non-negative c_s.
        confidence: of the combined interval.
        interval_kind: ``"delta"`` (every stratum must have a hit: a stratum with none has no
            variance to combine) or ``"union"`` (see the module docstring).

    Raises:
        ValueError: on mismatched lengths, negative coefficients, an unknown kind, or a stratum
            without hits under ``"delta"``.
    """
    estimates = tuple(estimates)
    coefficients = np.asarray(coefficients, float)
    if coefficients.shape != (len(estimates),) or not estimates:
        raise ValueError(f"need one coefficient per estimate: {len(estimates)} estimates, "
                         f"coefficients of shape {coefficients.shape}")
    if np.any(coefficients < 0) or not np.all(np.isfinite(coefficients)):
        raise ValueError(f"coefficients must be finite and non-negative, got {coefficients}")
    if interval_kind == "delta":
        empty = [s for s, e in enumerate(estimates) if not (e.reached and e.hits > 0 and np.isfinite(e.cov))]
        if empty:
            raise ValueError(f"stratum {empty[0]} has no failure sample, so no variance for the delta "
                             f"interval: use interval_kind='union'")
    estimate, cov = _combined_moments(estimates, coefficients)
    lo, hi = combined_interval(estimates, coefficients, confidence, interval_kind)
    return Estimate(method="combined", estimate=estimate, cov=cov, interval=(lo, hi), confidence=confidence,
                    kind=interval_kind, n_simulations=sum(e.n_simulations for e in estimates),
                    hits=sum(e.hits for e in estimates), reached=all(e.reached for e in estimates),
                    components=estimates, coefficients=coefficients)


def repeated(estimates, confidence: float = 0.95) -> Estimate:
    """The mean of R independent runs of one estimator on one problem, with a c.o.v. the runs' spread checks.

    Plain Monte Carlo runs pool exactly: k = sum k_r hits in n = sum n_r runs, Clopper-Pearson.
    Otherwise p_hat = mean_r p_r, and its c.o.v. is the larger of the delta method's
    sqrt(sum_r (delta_r p_r)^2) / (R p_hat), which trusts each run's own c.o.v., and, from R = 3 on
    with every run hit, the one the runs' spread gives: with s^2 the sample variance of ln p_r
    (p_r taken as log-normal), delta = sqrt((exp(s^2) - 1) / R). When the spread's is the larger, the
    log-normal interval uses Student's t with R - 1 degrees of freedom (its upper end at most 1: the
    runs estimate a probability). A within-run c.o.v. that
    understates (subset simulation's chains mixing slowly in a large d) is thus replaced by what the
    repeats show; the levels and failure points are the run's with most hits, all runs' points kept.
    """
    runs = tuple(estimates)
    if not runs:
        raise ValueError("no estimator run to pool")
    if len(runs) == 1:
        return runs[0]
    points = np.concatenate([r.failure_points for r in runs])
    margins = np.concatenate([r.failure_margins for r in runs])
    best = max(runs, key=lambda r: r.hits)
    if all(r.kind == "clopper-pearson" for r in runs):
        n, k = sum(r.n_simulations for r in runs), sum(r.hits for r in runs)
        lo, hi = clopper_pearson(k, n, confidence)
        return dataclasses.replace(best, estimate=k / n, cov=float(np.sqrt((1.0 - k / n) / k)) if k else float("inf"),
                                   interval=(float(lo), float(hi)), confidence=confidence, n_simulations=n, hits=k,
                                   failure_points=points, failure_margins=margins)
    hit = all(r.reached and r.hits > 0 and np.isfinite(r.cov) and r.estimate > 0 for r in runs)
    mean = combine(runs, np.full(len(runs), 1.0 / len(runs)), confidence, "delta" if hit else "union")
    mean = dataclasses.replace(mean, method=runs[0].method, levels=best.levels, failure_points=points,
                               failure_margins=margins, design_points=best.design_points)
    if not hit or len(runs) < 3:
        return mean
    spread = float(np.sqrt(np.expm1(np.var(np.log([r.estimate for r in runs]), ddof=1)) / len(runs)))
    cov, dof = (spread, len(runs) - 1.0) if spread > mean.cov else (mean.cov, float("inf"))
    lo, hi = interval(mean.estimate, cov, confidence, "lognormal", dof)
    return dataclasses.replace(mean, cov=cov, dof=dof, kind="lognormal", interval=(lo, min(hi, 1.0)))


def stratified(estimates, weights, confidence: float = 0.95, interval_kind: str = "delta") -> Estimate:
    """P = sum_s w_s p_s over strata with probabilities w_s (non-negative, summing to 1)."""
    weights = np.asarray(weights, float)
    if weights.ndim != 1 or abs(weights.sum() - 1.0) > 1e-9:
        raise ValueError(f"stratum weights must be a vector summing to 1, got {weights} (sum {weights.sum()})")
    return combine(estimates, weights, confidence, interval_kind)

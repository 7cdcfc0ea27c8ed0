"""From per-run probabilities to rates per flight hour, certification classes and the per-airframe view.

Per flight hour (DESIGN.md section 5c): a run scores T_s seconds of flight in stratum s (a
manoeuvre family, turbulence level, envelope region), and w_s is the fraction of flight time spent
in stratum s (sum_s w_s = 1). An hour holds 3600 w_s / T_s scored windows of stratum s, each with
an event with probability p_s, so the expected number of events per flight hour is

    lambda = sum_s w_s p_s 3600 / T_s,

a linear combination of the per-stratum estimates, with the delta-method variance or the
conservative union interval of :func:`mcfdd.analysis.rare.estimate.combine`. It reads as a
probability per flight hour while lambda << 1, and assumes windows (and flights) independent:
parameters fixed per airframe break that, hence the per-airframe view below.

Certification classes: EASA CS-25 Book 2, AMC 25.1309 ("System Design and Analysis"), the
quantitative probability terms per flight hour: Remote <= 1e-5, Extremely Remote <= 1e-7,
Extremely Improbable <= 1e-9, required of Major, Hazardous and Catastrophic failure conditions.

Per airframe: with u = (theta, v), theta the k standard-normal coordinates of the parameters an
aircraft keeps for life (e.g. the servo-valve gain Kci) and v the rest (noise and turbulence
paths), an airframe's rate is P(F | theta) = P(g(theta, v) > 0), v ~ N(0, I_{d-k}). It is
estimated at given theta (one estimator run each, theta traced: one compilation for all), and
reported at its worst corner (the largest over the 2^k corners theta in {-r, r}^k: for a
parameter p = F^-1(Phi(theta)), the corner r stands for its quantiles Phi(-r) and Phi(r)), or as
a quantile over airframes: with theta_1..theta_m drawn from N(0, I_k), the q-quantile of
P(F | theta) is estimated by the order statistic of the estimates, and its distribution-free
interval takes the ranks r < s with P(r <= B < s) >= c, B ~ Binomial(m, q), and the r-th
smallest lower and s-th smallest upper per-airframe interval ends (it covers when the ranks
bracket the quantile and the per-airframe intervals cover).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import binom

from mcfdd.analysis.rare.estimate import Estimate, combine
from mcfdd.analysis.rare.subset import subset_simulation

SECONDS_PER_HOUR = 3600.0
# AMC 25.1309 (EASA CS-25 Book 2): largest average probability per flight hour of a failure condition
MAJOR = 1e-5  # Remote
HAZARDOUS = 1e-7  # Extremely Remote
CATASTROPHIC = 1e-9  # Extremely Improbable
CLASSES = {"major": MAJOR, "hazardous": HAZARDOUS, "catastrophic": CATASTROPHIC}
SOURCE = "EASA CS-25 Book 2, AMC 25.1309 System Design and Analysis (quantitative probability terms)"


def per_flight_hour(estimates, weights, scored_s, confidence: float = 0.95, interval_kind: str = "delta") -> Estimate:
    """lambda = sum_s w_s p_s 3600 / T_s, per flight hour, with its interval (module docstring).

    Args:
        estimates: S per-run :class:`Estimate`, one per stratum (independent keys).
        weights: (S,) fractions of flight time, non-negative, summing to 1.
        scored_s: T_s, the scored seconds of a run: a number or (S,) per stratum.
        confidence, interval_kind: as :func:`mcfdd.analysis.rare.estimate.combine`.

    Returns:
        :class:`Estimate` with ``method="per_flight_hour"``, in events per flight hour.
    """
    weights = np.asarray(weights, float)
    scored = np.broadcast_to(np.asarray(scored_s, float), weights.shape)
    if weights.ndim != 1 or np.any(weights < 0) or abs(weights.sum() - 1.0) > 1e-9:
        raise ValueError(f"exposure weights are fractions of flight time: non-negative, summing to 1; got {weights}")
    if np.any(~np.isfinite(scored)) or np.any(scored <= 0):
        raise ValueError(f"the scored seconds of a run must be positive, got {scored_s}")
    rate = combine(estimates, weights * SECONDS_PER_HOUR / scored, confidence, interval_kind)
    return dataclasses.replace(rate, method="per_flight_hour")


def certification_class(rate: Estimate) -> str | None:
    """The most severe AMC 25.1309 class whose limit the upper end of ``rate``'s interval meets.

    ``"catastrophic"``, ``"hazardous"``, ``"major"``, or None when the upper end exceeds 1e-5
    per flight hour (only a Minor failure condition may be that probable).
    """
    for name in ("catastrophic", "hazardous", "major"):
        if rate.interval[1] <= CLASSES[name]:
            return name
    return None


@dataclasses.dataclass(frozen=True)
class Conditional:
    """g with the coordinates ``index`` fixed: ``Conditional(g, index)(v, theta, *args)``.

    v (n, d - k) the free coordinates in their order, theta (k,) the fixed ones (coordinate
    ``index[j]`` of u is theta[j]); equal objects hash alike, so estimators compile once for every theta.
    """

    g: Callable
    index: tuple[int, ...]

    def __call__(self, v, theta, *args):
        k = len(self.index)
        d = k + v.shape[1]
        fixed = jnp.broadcast_to(jnp.asarray(theta, v.dtype), (v.shape[0], k))
        order = np.argsort(np.concatenate([np.asarray(self.index, int), np.setdiff1d(np.arange(d), self.index)]))
        return self.g(jnp.concatenate([fixed, v], axis=1)[:, order], *args)


class Airframes(NamedTuple):
    """P(F | theta) at parameter points theta (m, k).

    Attributes:
        points: (m, k) the parameter coordinates.
        estimates: m :class:`Estimate`, one per point.
        worst: index of the largest estimate.
        quantile: q of ``value`` (nan when not asked).
        value: the q-quantile over the points of the estimates (nan when not asked).
        interval: its distribution-free interval (module docstring).
    """

    points: np.ndarray
    estimates: tuple[Estimate, ...]
    worst: int
    quantile: float
    value: float
    interval: tuple[float, float]


def corners(parameters: int, radius: float) -> np.ndarray:
    """The 2^k corners {-radius, radius}^k of the parameter block, (2^k, k)."""
    if not 1 <= parameters <= 12:
        raise ValueError(f"corners of 1 to 12 parameters (2^k estimator runs), got {parameters}")
    return radius * np.array(list(itertools.product((-1.0, 1.0), repeat=parameters)))


def quantile_ranks(m: int, q: float, confidence: float) -> tuple[int, int]:
    """1-based ranks r < s of m draws with P(r <= B < s) >= confidence, B ~ Binomial(m, q), central."""
    alpha = 1.0 - confidence
    r = int(binom.ppf(alpha / 2, m, q))
    s = int(binom.ppf(1 - alpha / 2, m, q)) + 1
    if r < 1 or s > m:
        raise ValueError(f"{m} parameter points cannot bracket the {q} quantile at confidence {confidence}")
    return r, s


def parameter_index(parameters, d: int) -> tuple[int, ...]:
    """The fixed coordinates: the first ``parameters`` (an int) or the given indices, distinct, in [0, d)."""
    index = tuple(range(parameters)) if isinstance(parameters, (int, np.integer)) else tuple(int(i) for i in parameters)
    if not index or len(set(index)) != len(index) or min(index) < 0 or max(index) >= d or len(index) >= d:
        raise ValueError(f"the fixed parameters must be 1 to d - 1 distinct coordinates of u (d = {d}), got "
                         f"{parameters!r}")
    return index


def summarise(points, estimates, quantile: float | None = None, confidence: float = 0.95) -> Airframes:
    """:class:`Airframes` of per-point estimates: the worst point, and the q-quantile with its interval."""
    values = np.array([e.estimate for e in estimates])
    value, bounds = float("nan"), (float("nan"), float("nan"))
    if quantile is not None:
        r, s = quantile_ranks(len(points), quantile, confidence)
        lows = np.sort([e.interval[0] for e in estimates])
        highs = np.sort([e.interval[1] for e in estimates])
        value = float(np.quantile(values, quantile, method="inverted_cdf"))
        bounds = (float(lows[r - 1]), float(highs[s - 1]))
    return Airframes(np.asarray(points, float), tuple(estimates), int(np.argmax(values)),
                     float("nan") if quantile is None else quantile, value, bounds)


def airframes(g, d: int, parameters, points, key, *, estimator=subset_simulation, quantile: float | None = None,
              confidence: float = 0.95, args=(), **options) -> Airframes:
    """P(g(theta, v) > 0 | theta) at each parameter point (module docstring).

    Args:
        g: batched limit state on the full u = (theta, v), (n, d) -> (n,).
        d: dimension of u.
        parameters: the fixed coordinates theta: an int k (the first k) or their indices in u.
        points: (m, k) standard-normal parameter coordinates (:func:`corners`, or draws
            from N(0, I_k) for a quantile).
        key: point i uses ``fold_in(key, i)``.
        estimator: :func:`subset_simulation` (default) or another estimator of this package.
        quantile: q to report over the points (they must then be draws of N(0, I_k)).
        confidence: of the estimators' and the quantile's intervals.
        args: traced arrays passed to g after u; options: the estimator's keywords.
    """
    index = parameter_index(parameters, d)
    points = np.asarray(points, float)
    if points.ndim != 2 or points.shape[1] != len(index):
        raise ValueError(f"parameter points must be (m, {len(index)}), got shape {points.shape}")
    cond = Conditional(g, index)
    estimates = tuple(estimator(cond, d - len(index), jax.random.fold_in(key, i), confidence=confidence,
                                args=(theta, *args), **options) for i, theta in enumerate(points))
    return summarise(points, estimates, quantile, confidence)

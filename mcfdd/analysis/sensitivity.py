"""Global sensitivity of an outcome to independent inputs: variance-based indices, gradient screen, regional.

Three measures on arrays (no files, no tables); :mod:`mcfdd.workflows.sensitivity` runs them on
campaign designs.

- Variance-based indices (Sobol'): first order S_i = V[E(Y | X_i)] / V(Y) and total
  S_Ti = E[V(Y | X_~i)] / V(Y), by pick-freeze. Two matrices A and B of N points in the unit cube
  are the two halves of one scrambled Sobol' sequence of 2 d dimensions; A_B^(i) is A with
  column i taken from B (Saltelli et al. 2010, Comput. Phys. Commun. 181, sec. 5), N (d + 2) runs.
  Estimators of Saltelli et al. (2010), Table 2: (b) for S_i,
  ``mean(f(B) (f(A_B^i) - f(A))) / V`` and (f) (Jansen 1999) for S_Ti,
  ``mean((f(A) - f(A_B^i))^2) / (2 V)``, with V the variance of f(A) and f(B) together and every
  value centred on their mean (Sobol' and Levitan 1999). These are the estimators of
  ``scipy.stats.sobol_indices``, against which the tests check them. A coordinate need not be a
  number: one that only says whether a run takes A's or B's copy of something (a random-number
  path) makes that thing one factor.
  Library choice: ``scipy.stats.sobol_indices`` takes precomputed evaluations (``func`` as a dict
  of f_A, f_B, f_AB), so campaign runs could feed it, but its ``bootstrap`` takes no seed (the
  intervals would change from call to call) and it draws its own A and B; SALib would be a new
  dependency with normal-approximation intervals and its own sample ordering. So the design and
  the two estimators (two lines of the paper's Table 2) are written here, and the intervals are
  ``scipy.stats.bootstrap`` (BCa, seeded) over the N base rows, each resample taking A, B and all
  A_B^(i) rows of the same base points.
- Gradient screen (DGSM, Sobol' and Kucherenko 2009): nu_i = E[(dY/du_i)^2] over the unit cube;
  for inputs uniform on [0, 1], S_Ti <= nu_i / (pi^2 V) (Lamboni et al. 2013, the Poincare
  constant of the unit interval). The bound ranks like S_Ti where Y is close to additive and
  monotonic in each input, and can rank otherwise: for the Ishigami function nu ranks x2 > x3 > x1
  while S_T ranks x1 > x2 > x3 (both analytic). Through a simulation, gradients of a smooth
  statistic miss what acts only through jumps of the hard one (a sample entering a gate), and
  steep local slopes (the timing of a command's edges) weigh heavily in nu: a screen, not a ranking.
- Regional sensitivity for a binary event (Hornberger and Spear 1981): per input, its values in the
  runs with the event against the others: the two-sample Kolmogorov-Smirnov distance D with its
  p-value (``scipy.stats.ks_2samp``) and Cliff's delta ``2 P(X_event > X_other) + P(=) - 1``
  (the Mann-Whitney common-language effect rescaled to [-1, 1]) with a percentile bootstrap
  interval, resampling both groups; for a categorical input the total-variation distance between
  the level distributions of the two groups (the categorical analogue of D, so the two rank
  together), Fisher's exact test (two levels) or the chi-square test of the contingency table, and
  the event rate per level.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import stats
from scipy.stats import qmc

# Bootstrap statistics are evaluated on at most about this many numbers at once.
_BATCH_ELEMENTS = 4_000_000


def check_samples(n: int):
    """Base sample size of a pick-freeze design: a power of 2 (Sobol' balance), at least 8."""
    if n < 8 or n & (n - 1):
        raise ValueError(f"{n} base samples: expected a power of 2, at least 8 (Sobol' points are balanced "
                         f"in powers of 2 and the bootstrap needs a few)")


def saltelli_matrices(n: int, dim: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A and B, each (n, dim) in [0, 1): the halves of one scrambled Sobol' sequence of 2 dim dimensions."""
    check_samples(n)
    points = qmc.Sobol(2 * dim, scramble=True, seed=seed).random(n)
    return points[:, :dim], points[:, dim:]


def pick_freeze(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the pick-freeze design: blocks A, B, A_B^(1), ..., A_B^(dim), each of n rows.

    Returns (points (n (dim + 2), dim), from_b (n (dim + 2), dim) true where a coordinate is B's).
    Row ``block * n + j`` belongs to base point j.
    """
    n, dim = a.shape
    from_b = np.zeros((dim + 2, n, dim), dtype=bool)
    from_b[1] = True
    from_b[2 + np.arange(dim), :, np.arange(dim)] = True
    points = np.where(from_b, b[None], a[None])
    return points.reshape(-1, dim), from_b.reshape(-1, dim)


def split_blocks(y, n: int):
    """Outcomes of a pick-freeze design's rows (..., n (dim + 2)) as f_A (..., n), f_B (..., n), f_AB (dim, ..., n)."""
    y = np.asarray(y, dtype=float)
    blocks = np.moveaxis(y.reshape(*y.shape[:-1], -1, n), -2, 0)
    return blocks[0], blocks[1], blocks[2:]


def sobol_estimates(f_a, f_b, f_ab) -> tuple[np.ndarray, np.ndarray]:
    """First-order (Saltelli 2010) and total (Jansen) indices of centred f_A, f_B (..., n) and f_AB (dim, ..., n).

    Returns (first, total), each (dim, ...).
    """
    var = np.var(np.concatenate([f_a, f_b], axis=-1), axis=-1)
    first = np.mean(f_b * (f_ab - f_a), axis=-1) / var
    total = 0.5 * np.mean((f_a - f_ab) ** 2, axis=-1) / var
    return first, total


def _bootstrap(statistic, n: int, per_resample: int, resamples: int, confidence: float, seed: int, method: str):
    """``scipy.stats.bootstrap`` over n row indices: (low, high) per output of ``statistic(idx (batch, n))``.

    Where every resample gives the same value (an input without effect) the interval is that value.
    """
    def stat(idx, axis=-1):
        return statistic(np.asarray(idx))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = stats.bootstrap((np.arange(n),), stat, vectorized=True, n_resamples=resamples,
                              batch=max(1, _BATCH_ELEMENTS // max(per_resample, 1)), confidence_level=confidence,
                              method=method, rng=np.random.default_rng(seed))
    dist = res.bootstrap_distribution
    flat = np.ptp(dist, axis=-1) == 0
    low = np.where(flat, dist[..., 0], res.confidence_interval.low)
    high = np.where(flat, dist[..., 0], res.confidence_interval.high)
    return low, high


def sobol_indices(f_a, f_b, f_ab, resamples: int = 1000, confidence: float = 0.95, seed: int = 0) -> dict:
    """First-order and total indices with BCa bootstrap intervals over the base rows.

    Args:
        f_a, f_b: (n,) outcomes of the runs of A and B.
        f_ab: (dim, n) outcomes of the runs of A_B^(i).
        resamples: bootstrap resamples; seed: their random numbers.

    Returns:
        dict of (dim,) arrays: first, first_lo, first_hi, total, total_lo, total_hi, and the
        outcome's mean and variance (floats). Raises ValueError if the outcome does not vary.
    """
    f_a, f_b, f_ab = (np.asarray(v, dtype=float) for v in (f_a, f_b, f_ab))
    mean = np.mean(np.concatenate([f_a, f_b]))
    var = np.var(np.concatenate([f_a, f_b]))
    if not var > 0:
        raise ValueError("the outcome does not vary over the design's A and B runs")
    f_a, f_b, f_ab = f_a - mean, f_b - mean, f_ab - mean
    first, total = sobol_estimates(f_a, f_b, f_ab)
    dim, n = f_ab.shape

    def statistic(idx):
        return np.concatenate(sobol_estimates(f_a[idx], f_b[idx], f_ab[:, idx]))

    low, high = _bootstrap(statistic, n, (dim + 2) * n, resamples, confidence, seed, "BCa")
    return {"first": first, "first_lo": low[:dim], "first_hi": high[:dim], "total": total, "total_lo": low[dim:],
            "total_hi": high[dim:], "mean": float(mean), "variance": float(var)}


def dgsm(gradients, values, resamples: int = 1000, confidence: float = 0.95, seed: int = 0) -> dict:
    """Derivative-based measures nu_i = E[(dY/du_i)^2] and the bound nu_i / (pi^2 V) on S_Ti, with intervals.

    Args:
        gradients: (n, dim) dY/du at n points drawn uniformly over the unit cube.
        values: (n,) Y at the same points (their variance V normalises the bound).

    Returns:
        dict of (dim,) arrays nu, nu_lo, nu_hi, bound, bound_lo, bound_hi (BCa bootstrap over the
        points, the bound's interval resampling V with the gradients).
    """
    g2 = np.asarray(gradients, dtype=float) ** 2
    y = np.asarray(values, dtype=float)
    n, dim = g2.shape
    if not np.var(y) > 0:
        raise ValueError("the outcome does not vary over the screened points")

    def statistic(idx):
        nu = np.moveaxis(np.mean(g2[idx], axis=-2), -1, 0)
        return np.concatenate([nu, nu / (np.pi ** 2 * np.var(y[idx], axis=-1))])

    nu = g2.mean(axis=0)
    low, high = _bootstrap(statistic, n, 2 * n * dim, resamples, confidence, seed, "BCa")
    return {"nu": nu, "nu_lo": low[:dim], "nu_hi": high[:dim], "bound": nu / (np.pi ** 2 * np.var(y)),
            "bound_lo": low[dim:], "bound_hi": high[dim:]}


def _resampled_counts(rng, counts, b: int) -> np.ndarray:
    """(b, cells) counts per cell of b resamples with replacement of a sample with ``counts`` points per cell.

    Multinomial draws where the cells are few against the points, else the points themselves are
    drawn (both are the same law; each is the faster in its case).
    """
    n = int(counts.sum())
    if 4 * len(counts) < n:
        return rng.multinomial(n, counts / n, size=b)
    labels = np.repeat(np.arange(len(counts)), counts)[rng.integers(0, n, (b, n))]
    return np.bincount((labels + np.arange(b)[:, None] * len(counts)).ravel(), minlength=b * len(counts)).reshape(b, -1)


def cliffs_delta(x_event, x_other, resamples: int = 1000, confidence: float = 0.95, seed: int = 0) -> tuple:
    """Cliff's delta of two samples with a percentile bootstrap interval resampling each sample.

    delta = 2 A - 1 with A = P(X_event > X_other) + P(X_event = X_other) / 2. The bootstrap
    resamples both samples with replacement, drawn in law rather than point by point: with S the
    smaller sample and v its m distinct values, a resample of the larger one enters A only through
    its counts below, at and between the v (2 m + 1 cells, multinomial with the sample's cell
    shares), and a resample of S through its counts at the v.

    Returns (delta, low, high).
    """
    x_e, x_o = np.asarray(x_event, dtype=float), np.asarray(x_other, dtype=float)
    swap = len(x_e) > len(x_o)
    small, large = (x_o, x_e) if swap else (x_e, x_o)
    values, multiplicity = np.unique(small, return_counts=True)
    m = len(values)
    left, right = np.searchsorted(values, large, "left"), np.searchsorted(values, large, "right")
    cells = np.bincount(2 * left + (right > left), minlength=2 * m + 1)  # below v_0, at v_0, between, ..., above
    below_at = np.cumsum(cells)[0:2 * m:2] + 0.5 * cells[1::2]  # per distinct value: larger ones below, half at it
    a = np.sum(multiplicity * below_at) / (len(small) * len(large))
    sign = -1.0 if swap else 1.0
    rng = np.random.default_rng(seed)
    batch = max(1, _BATCH_ELEMENTS // (3 * m + len(x_e) + len(x_o)))
    deltas = []
    for start in range(0, resamples, batch):
        b = min(batch, resamples - start)
        drawn = _resampled_counts(rng, cells, b)
        score = np.cumsum(drawn, axis=1)[:, 0:2 * m:2] + 0.5 * drawn[:, 1::2]
        weights = _resampled_counts(rng, multiplicity, b)
        deltas.append(sign * (2.0 * np.sum(weights * score, axis=1) / (len(small) * len(large)) - 1.0))
    deltas = np.concatenate(deltas)
    tail = 50.0 * (1.0 - confidence)
    return sign * (2.0 * a - 1.0), float(np.percentile(deltas, tail)), float(np.percentile(deltas, 100.0 - tail))


def regional_continuous(x, event, resamples: int = 1000, confidence: float = 0.95, seed: int = 0) -> dict:
    """Values of a continuous input in runs with the event against the others.

    Args:
        x: (n,) input values; event: (n,) bool. Both groups must be non-empty.

    Returns:
        dict: statistic (Kolmogorov-Smirnov D), p_value, effect (Cliff's delta, > 0 when the
        events sit at larger values), effect_lo, effect_hi, median_event, median_other.
    """
    x, event = np.asarray(x, dtype=float), np.asarray(event, dtype=bool)
    ks = stats.ks_2samp(x[event], x[~event])
    delta, low, high = cliffs_delta(x[event], x[~event], resamples, confidence, seed)
    return {"statistic": float(ks.statistic), "p_value": float(ks.pvalue), "effect": delta, "effect_lo": low,
            "effect_hi": high, "median_event": float(np.median(x[event])), "median_other": float(np.median(x[~event]))}


def regional_categorical(levels, event) -> dict:
    """Levels of a categorical input in runs with the event against the others.

    Returns:
        dict: statistic (total-variation distance between the level distributions of the two
        groups), p_value and test ('fisher' for two levels, else 'chi-square'), and rates: per
        level (name, events, runs), sorted by name.
    """
    levels, event = np.asarray(levels), np.asarray(event, dtype=bool)
    names = np.unique(levels)
    table = np.array([[np.sum(event & (levels == v)), np.sum(~event & (levels == v))] for v in names])
    share = table / table.sum(axis=0, keepdims=True)
    distance = 0.5 * float(np.abs(share[:, 0] - share[:, 1]).sum())
    used = table[table.sum(axis=1) > 0]
    if len(used) < 2:
        p, test = 1.0, "none"
    elif len(used) == 2:
        p, test = float(stats.fisher_exact(used).pvalue), "fisher"
    else:
        p, test = float(stats.chi2_contingency(used).pvalue), "chi-square"
    return {"statistic": distance, "p_value": p, "test": test,
            "rates": [(str(v), int(k), int(k + m)) for v, (k, m) in zip(names, table)]}

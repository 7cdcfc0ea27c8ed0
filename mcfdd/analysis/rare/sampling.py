"""Evaluating a limit state in chunks, independent sampling with weights, and plain Monte Carlo.

The event is F = {u : g(u) > 0} with u ~ N(0, I_d). ``g`` is batched and JAX-traceable:
``g(u, *args)`` maps u of shape (n, d) to (n,) (``args``: traced arrays passed through, e.g. the
fixed parameter coordinates of :func:`mcfdd.analysis.rare.exposure.airframe`).

Memory: with ``chunk = m`` g sees at most m rows at a time, so its working memory is what it
needs for m scenarios (for a closed-loop simulation, its scan carry and per-step temporaries for
m scenarios; never m x d x steps), on top of the estimator's own samples (``n x d`` numbers for
subset simulation, ``batch x d`` for the samplers below).

Weighted sampling: ``batch`` rows are drawn at a time from a density q (the standard normal
phi for Monte Carlo, a mixture for importance sampling), each with its log-likelihood ratio
ln(phi(u)/q(u)); a ``lax.fori_loop`` over the n / batch batches accumulates S1 = sum I w and
S2 = sum (I w)^2 (I = [g(u) > 0], w = phi/q), the hits and the ``keep`` most probable failure
points seen (smallest ||u||). Batch i draws from ``fold_in(key, i)``. Then

    p_hat = S1 / n,   var(p_hat) = (S2 - n p_hat^2) / (n (n - 1)),   delta = sd(p_hat) / p_hat.

Plain Monte Carlo (w = 1): k hits in n runs, p_hat = k / n, delta = sqrt((1 - p_hat) / (n p_hat)),
and the exact Clopper-Pearson interval, which with k = 0 is the upper bound 1 - (alpha/2)^(1/n).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis.metrics import clopper_pearson
from mcfdd.analysis.rare.estimate import Estimate


def float_dtype(dtype=None):
    """The dtype of the standard-normal coordinates: ``dtype``, or JAX's default float."""
    return jnp.dtype(dtype) if dtype is not None else jnp.result_type(float)


def evaluate(g, u, chunk, args=()):
    """g(u, *args) for u (n, d), ``chunk`` rows at a time (``lax.map``; None: all at once) -> (n,).

    Rows are padded with zeros up to a multiple of the chunk and the padding is dropped.
    """
    n, d = u.shape
    if chunk is None or chunk >= n:
        return g(u, *args)
    pad = -n % chunk
    blocks = jnp.pad(u, ((0, pad), (0, 0))).reshape(-1, chunk, d)
    return jax.lax.map(lambda b: g(b, *args), blocks).reshape(-1)[:n]


def check_problem(g, d: int, n: int, chunk, dtype, args=()) -> None:
    """Fail early, with one clear message, on a limit state or size an estimator cannot use.

    Traces g once on (rows, d) (``jax.eval_shape``: no compilation) and checks it returns (rows,).
    """
    if not isinstance(d, int) or d < 1:
        raise ValueError(f"the dimension d must be a positive integer, got {d!r}")
    if not isinstance(n, int) or n < 2:
        raise ValueError(f"the number of samples must be an integer >= 2, got {n!r}")
    if chunk is not None and (not isinstance(chunk, int) or chunk < 1):
        raise ValueError(f"chunk must be None or a positive integer, got {chunk!r}")
    rows = min(n, chunk or n)
    spec = jax.ShapeDtypeStruct((rows, d), float_dtype(dtype))
    out = jax.eval_shape(lambda u: g(u, *args), spec)
    if getattr(out, "shape", None) != (rows,):
        raise ValueError(f"g must map u of shape (n, d) to (n,): got {getattr(out, 'shape', out)} "
                         f"for u of shape {(rows, d)}")


class Sums(NamedTuple):
    """Accumulated weighted-sampling statistics (module docstring)."""

    s1: jax.Array
    s2: jax.Array
    hits: jax.Array
    points: jax.Array  # (keep, d) most probable failure samples seen
    margins: jax.Array  # (keep,) g there
    score: jax.Array  # (keep,) -||u||^2 of each, -inf for an empty slot


def _merge(sums: Sums, u, gu, keep: int) -> Sums:
    """Keep the ``keep`` failure samples of smallest norm among those held and the batch ``u``."""
    score = jnp.where(gu > 0, -jnp.sum(u * u, axis=1), -jnp.inf)
    scores = jnp.concatenate([sums.score, score])
    best, idx = jax.lax.top_k(scores, keep)
    points = jnp.concatenate([sums.points, u])[idx]
    margins = jnp.concatenate([sums.margins, gu])[idx]
    return sums._replace(points=points, margins=margins, score=best)


def weighted_sums(g, draw, key, n: int, batch: int, keep: int, d: int, dtype, args=()) -> Sums:
    """Accumulate :class:`Sums` over n samples drawn ``batch`` at a time by ``draw(key, batch)``.

    ``draw`` returns (u (batch, d), log_ratio (batch,)) with log_ratio = ln phi(u) - ln q(u).
    Runs inside the caller's jit; n must be a multiple of ``batch``.
    """
    acc = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    init = Sums(jnp.zeros((), acc), jnp.zeros((), acc), jnp.zeros((), jnp.int32), jnp.zeros((keep, d), dtype),
                jnp.zeros(keep, dtype), jnp.full(keep, -jnp.inf, dtype))

    def body(i, sums):
        u, log_ratio = draw(jax.random.fold_in(key, i), batch)
        gu = g(u, *args)
        hit = gu > 0
        w = jnp.where(hit, jnp.exp(log_ratio.astype(acc)), 0.0)
        sums = sums._replace(s1=sums.s1 + jnp.sum(w), s2=sums.s2 + jnp.sum(w * w),
                             hits=sums.hits + jnp.sum(hit, dtype=jnp.int32))
        return _merge(sums, u, gu, keep)

    return jax.lax.fori_loop(0, n // batch, body, init)


def failure_arrays(points, margins, score):
    """The held failure points (k, d) and margins (k,) as NumPy, empty slots dropped."""
    found = np.isfinite(np.asarray(score))
    return np.asarray(points)[found], np.asarray(margins)[found]


def batches(n: int, batch) -> int:
    """The batch size to use for n samples: ``batch`` (or n), checked to divide n."""
    batch = n if batch is None else batch
    if not isinstance(batch, int) or batch < 1 or n % batch:
        raise ValueError(f"batch must be a positive integer dividing the {n} samples, got {batch!r}")
    return batch


@partial(jax.jit, static_argnames=("g", "d", "n", "batch", "keep", "dtype"))
def _monte_carlo(g, d, key, args, n, batch, keep, dtype):
    def draw(k, m):
        return jax.random.normal(k, (m, d), dtype), jnp.zeros(m, dtype)

    return weighted_sums(g, draw, key, n, batch, keep, d, dtype, args)


def monte_carlo(g, d: int, key, *, n: int = 100_000, batch: int | None = 10_000, keep: int = 16,
                confidence: float = 0.95, dtype=None, args=()) -> Estimate:
    """Plain Monte Carlo estimate of P(g(u) > 0), u ~ N(0, I_d), with its exact interval.

    Args:
        g: batched limit state, (batch, d) -> (batch,), JAX-traceable; g > 0 is the event.
        d: dimension of u.
        key: a ``jax.random`` key; the same key gives the same estimate to the last bit.
        n: samples (simulations); a multiple of ``batch``.
        batch: rows drawn and evaluated at a time (bounds memory: batch x d numbers and g's
            working memory for ``batch`` rows); None: all n at once.
        keep: failure points kept (the most probable ones).
        confidence: of the Clopper-Pearson interval.
        dtype: of u (default: JAX's default float).
        args: traced arrays passed to g after u.

    Returns:
        :class:`Estimate` with ``kind="clopper-pearson"``.
    """
    batch = batches(n, batch if batch is None else min(batch, n))
    check_problem(g, d, n, batch, dtype, args)
    sums = _monte_carlo(g, d, key, tuple(args), n, batch, keep, float_dtype(dtype))
    k = int(sums.hits)
    lo, hi = clopper_pearson(k, n, confidence)
    p = k / n
    cov = float(np.sqrt((1.0 - p) / (n * p))) if k else float("inf")
    points, margins = failure_arrays(sums.points, sums.margins, sums.score)
    return Estimate(method="monte_carlo", estimate=p, cov=cov, interval=(float(lo), float(hi)),
                    confidence=confidence, kind="clopper-pearson", n_simulations=n, hits=k,
                    failure_points=points, failure_margins=margins)

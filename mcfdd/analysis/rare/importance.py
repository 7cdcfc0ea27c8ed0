"""Design points by gradient (improved HLRF) and importance sampling around them.

A design point (most probable failure point) of F = {g(u) > 0}, u ~ N(0, I_d), is a local
solution of ``min ||u|| s.t. g(u) >= 0``; beta = ||u*|| is its reliability index and Phi(-beta)
the first-order (FORM) probability of its half-space. At u* the gradient of g is parallel to u*
and points away from the origin. A first passage over time has several: one per time of
crossing, each the smallest noise path that crosses then.

Search: the HLRF iteration (Hasofer and Lind 1974; Rackwitz and Fiessler 1978), written for
g > 0 as the event,

    u_HLRF = [(grad g(u) . u - g(u)) / ||grad g(u)||^2] grad g(u),

exact in one step for a linear g, is damped by a line search on the merit function
m(u) = ||u||^2 / 2 + c |g(u)|, c = 2 ||u|| / ||grad g(u)|| + 1 (the "improved HLRF" of Zhang and
Der Kiureghian 1995, which needs c > ||u|| / ||grad g||): u <- u + s (u_HLRF - u) with s the step
of smallest merit among 1, 1/2, ..., 2^-5. The gradient is JAX's reverse mode through g. All
starts move as one batch; the starts are the ``starts`` samples of largest g among ``screening``
standard-normal draws (so that different starts sit in the basins of different crossings).
A point has converged when its distance to the limit surface |g| / ||grad g|| and the angle
between u and grad g (1 - cos) are both below ``tol``; converged points closer than
0.01 max(1, beta) to one of smaller beta are duplicates.

A start inside F (g >= 0: a failure point of a subset simulation) moves by feasible steps instead:
of the same trial points, the one of smallest ||u|| that stays in F (g >= -tol ||grad g||), or none.
Linearised, the damped step keeps g at (1 - s) g(u) >= 0, so on a near-linear g it is the damped
HLRF; on a first passage of a closed-loop simulation the linearisation at a failure point of the
standard-normal shell (||u|| near sqrt(d)) is far off, and the merit function's step would leave
F for the origin's neighbourhood, where g is flat. Only converged points are centres: an
unconverged end (in F, but far from the most probable failure point) is a poor centre whose
estimate, unbiased but heavy-tailed, states a c.o.v. far below its spread (measured on the
validation FDD and a reduced FDD space: benchmarks/RESULTS.md, importance sampling on the FDD).

Importance sampling: the density is the mixture q(u) = sum_k w_k q_k(u) of normals centred on the
m distinct design points, w_k proportional to Phi(-beta_k), component k with covariance
I + (s^2 - 1) a_k a_k^T, a_k = u*_k / beta_k: unit covariance (s = 1, the default) or widened
(tempered, s > 1) along the design direction only. The likelihood ratio depends on u only through
its projections t_k = a_k . u on the design directions, so it does not degenerate as d grows (a
covariance s^2 I with s != 1 would: its ratio carries ||u||^2 (1 - 1/s^2) / 2 over all d
coordinates):

    ln(phi(u) / q(u)) = -ln sum_k w_k exp(t_k^2 / 2 - (t_k - beta_k)^2 / (2 s^2) - ln s),

which for s = 1 is -ln sum_k w_k exp(u . u*_k - ||u*_k||^2 / 2). A wider component puts more
samples past the design point's tangent plane, where a first passage's other crossings and a
curved limit surface lie. Then p_hat, its c.o.v. and its normal (central limit) interval follow
from the weighted samples (:mod:`mcfdd.analysis.rare.sampling`). q is positive everywhere, so the
estimate is unbiased whatever design points were found; but a part of F the mixture misses shows
only as rare large weights: a large c.o.v. when one is drawn, and when none is among the n
samples, a low estimate with a small stated c.o.v. (repeated runs,
:func:`mcfdd.analysis.rare.repeated`, show the spread). With no converged design point the
samples are drawn from phi itself (plain Monte Carlo), and the result says so
(``reached=False``).

Simulations: screening + starts (is the start in F) + iterations x starts x (1 gradient + 6
line-search evaluations) + starts (the final check) + n. A gradient (one forward and one reverse
pass) counts as one.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import log_ndtr, logsumexp

from mcfdd.analysis.rare.estimate import Estimate, interval
from mcfdd.analysis.rare.sampling import batches, check_problem, failure_arrays, float_dtype, weighted_sums

STEPS = 2.0 ** -np.arange(6)  # line-search steps of the damped HLRF iteration
DUPLICATE = 0.01  # converged points closer than DUPLICATE max(1, beta) are one design point


class DesignPoints(NamedTuple):
    """Design points from a batch of starts (k = number of starts), smallest beta first.

    Attributes:
        points: (k, d) end points of the search.
        beta: (k,) ||u*||.
        margin: (k,) g at the points (0 at a design point).
        converged: (k,) the convergence test held.
        distinct: (k,) converged and not a duplicate of one of smaller beta: the mixture's centres.
    """

    points: jax.Array
    beta: jax.Array
    margin: jax.Array
    converged: jax.Array
    distinct: jax.Array


def _value_and_grad(g, u, args):
    """g (k,) and its gradient (k, d) at k points (the rows of a batched g are independent)."""
    def total(x):
        gx = g(x, *args)
        return jnp.sum(gx), gx

    grad, gu = jax.grad(total, has_aux=True)(u)
    return gu, grad


def search(g, starts, iterations: int, tol: float, args=()) -> DesignPoints:
    """Damped HLRF from every start at once (module docstring); runs inside the caller's jit."""
    steps = jnp.asarray(STEPS, starts.dtype)

    def merit(u, gu, c):
        return 0.5 * jnp.sum(u * u, axis=-1) + c * jnp.abs(gu)

    def direction(u, gu, grad):
        norm2 = jnp.sum(grad * grad, axis=1)
        safe = jnp.where(norm2 > 0, norm2, 1.0)
        target = ((jnp.sum(grad * u, axis=1) - gu) / safe)[:, None] * grad
        c = 2.0 * jnp.linalg.norm(u, axis=1) / jnp.sqrt(safe) + 1.0
        return jnp.where(norm2[:, None] > 0, target - u, 0.0), c

    k, d = starts.shape
    inside = g(starts, *args) >= 0  # (k,) these starts take feasible steps (module docstring)

    def iterate(_, u):
        gu, grad = _value_and_grad(g, u, args)
        dirn, c = direction(u, gu, grad)
        trial = u[None] + steps[:, None, None] * dirn[None]  # (steps, k, d)
        gt = g(trial.reshape(-1, d), *args).reshape(len(STEPS), k)
        best = jnp.argmin(merit(trial, gt, c[None]), axis=0)
        ok = (gt >= -tol * jnp.linalg.norm(grad, axis=1)[None]) & jnp.all(jnp.isfinite(trial), axis=2)
        norms = jnp.where(ok, jnp.sum(trial * trial, axis=2), jnp.inf)
        feasible = jnp.argmin(norms, axis=0)
        moved = trial[jnp.where(inside, feasible, best), jnp.arange(k)]
        return jnp.where((inside & ~jnp.any(ok, axis=0))[:, None], u, moved)

    u = jax.lax.fori_loop(0, iterations, iterate, starts)
    gu, grad = _value_and_grad(g, u, args)
    norm_u, norm_g = jnp.linalg.norm(u, axis=1), jnp.linalg.norm(grad, axis=1)
    distance = jnp.abs(gu) / jnp.where(norm_g > 0, norm_g, jnp.inf)
    cosine = jnp.sum(u * grad, axis=1) / jnp.where(norm_u * norm_g > 0, norm_u * norm_g, jnp.inf)
    finite = jnp.all(jnp.isfinite(u), axis=1)
    converged = (distance < tol) & (1.0 - cosine < tol) & finite
    order = jnp.argsort(jnp.where(converged, norm_u, jnp.inf))
    u, gu, norm_u, converged = u[order], gu[order], norm_u[order], converged[order]
    gap = jnp.linalg.norm(u[:, None] - u[None], axis=-1)
    earlier = jnp.tril(jnp.ones(gap.shape, bool), -1)
    duplicate = jnp.any(earlier & converged[None] & (gap < DUPLICATE * jnp.maximum(1.0, norm_u)[:, None]), axis=1)
    return DesignPoints(u, norm_u, gu, converged, converged & ~duplicate)


def screened_starts(g, d, key, starts: int, screening: int, dtype, args=()):
    """The ``starts`` draws of largest g among ``screening`` standard normals, (starts, d)."""
    u = jax.random.normal(key, (screening, d), dtype)
    _, idx = jax.lax.top_k(g(u, *args), starts)
    return u[idx]


@partial(jax.jit, static_argnames=("g", "d", "starts", "screening", "iterations", "tol", "dtype"))
def _design_points(g, d, key, args, starts, screening, iterations, tol, dtype):
    return search(g, screened_starts(g, d, key, starts, screening, dtype, args), iterations, tol, args)


def design_points(g, d: int, key, *, starts: int = 8, screening: int = 256, iterations: int = 20,
                  tol: float = 1e-3, dtype=None, args=()) -> DesignPoints:
    """Design points of {g(u) > 0} by damped HLRF from screened starts (module docstring).

    Returns :class:`DesignPoints` as NumPy arrays, smallest beta first.
    """
    _check_search(starts, screening, iterations)
    check_problem(g, d, screening, None, dtype, args)
    return jax.device_get(_design_points(g, d, key, tuple(args), starts, screening, iterations, tol,
                                         float_dtype(dtype)))


def _check_search(starts, screening, iterations):
    if not (isinstance(starts, int) and isinstance(screening, int) and 1 <= starts <= screening):
        raise ValueError(f"need integers 1 <= starts <= screening, got starts={starts!r}, screening={screening!r}")
    if not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be a positive integer, got {iterations!r}")


def mixture_draw(points, usable, dtype, spread=1.0):
    """``draw(key, m)`` for the mixture around the usable design points (phi itself if none), each
    component's standard deviation ``spread`` along its design direction and 1 across it."""
    any_usable = jnp.any(usable)
    centres = jnp.where(any_usable, points, 0.0)
    beta = jnp.linalg.norm(centres, axis=1)
    axes = centres / jnp.where(beta > 0, beta, 1.0)[:, None]  # (k, d) unit design directions (0 for phi)
    s = jnp.where(any_usable, jnp.asarray(spread, dtype), 1.0)
    log_w = jnp.where(usable, log_ndtr(-beta), -jnp.inf)
    log_w = jnp.where(any_usable, log_w - logsumexp(log_w), jnp.where(jnp.arange(len(points)) == 0, 0.0, -jnp.inf))

    def draw(key, m):
        k1, k2 = jax.random.split(key)
        comp = jax.random.categorical(k1, log_w, shape=(m,))
        z = jax.random.normal(k2, (m, points.shape[1]), dtype)
        a = axes[comp]
        u = centres[comp] + z + ((s - 1.0) * jnp.sum(a * z, axis=1))[:, None] * a
        t = u @ axes.T  # (m, k) projections on the design directions
        log_q = 0.5 * t * t - 0.5 * ((t - beta[None]) / s) ** 2 - jnp.log(s)  # ln q_k(u) - ln phi(u)
        return u, -logsumexp(log_w[None] + log_q, axis=1)

    return draw


def _sample(g, d, key, args, found, n, batch, keep, spread, dtype):
    return found, weighted_sums(g, mixture_draw(found.points, found.distinct, dtype, spread), key, n, batch, keep, d,
                                dtype, args)


@partial(jax.jit, static_argnames=("g", "d", "n", "batch", "keep", "starts", "screening", "iterations", "tol",
                                   "dtype"))
def _importance_screened(g, d, key, args, spread, n, batch, keep, starts, screening, iterations, tol, dtype):
    k_search, k_sample = jax.random.split(key)
    found = _design_points(g, d, k_search, args, starts, screening, iterations, tol, dtype)
    return _sample(g, d, k_sample, args, found, n, batch, keep, spread, dtype)


@partial(jax.jit, static_argnames=("g", "d", "n", "batch", "keep", "iterations", "tol", "dtype"))
def _importance_from(g, d, key, args, spread, starts, n, batch, keep, iterations, tol, dtype):
    found = search(g, starts.astype(dtype), iterations, tol, args)
    return _sample(g, d, jax.random.split(key)[1], args, found, n, batch, keep, spread, dtype)


def importance_sampling(g, d: int, key, *, n: int = 1000, batch: int | None = None, starts=8,
                        screening: int = 256, iterations: int = 20, tol: float = 1e-3, spread: float = 1.0,
                        keep: int = 16, confidence: float = 0.95, dtype=None, args=()) -> Estimate:
    """Importance sampling estimate of P(g(u) > 0) around the design points (module docstring).

    Args:
        g: batched limit state ``g(u, *args)``, (m, d) -> (m,), JAX-traceable and differentiable
            in u almost everywhere; g > 0 is the event.
        d: dimension of u.
        key: a ``jax.random`` key; the same key gives the same estimate to the last bit.
        n: importance samples (a multiple of ``batch``).
        batch: rows drawn and evaluated at a time (None: all n); memory about batch x d numbers
            plus g's working memory for ``batch`` rows (and for the starts x 6 line-search rows).
        starts: the number of search starts, screened as in :func:`design_points`, or the start
            points themselves, an array (k, d) (e.g. failure points of a subset simulation, or
            one per time of crossing), then with no screening.
        screening, iterations, tol: the design-point search (:func:`design_points`).
        spread: standard deviation of each mixture component along its design direction (1: unit
            covariance; > 1 tempered, module docstring); a traced value (a new one compiles nothing).
        keep: failure points returned (the most probable ones sampled).
        confidence: of the normal interval.
        dtype: of u (default: JAX's default float).
        args: traced arrays passed to g after u.

    Returns:
        :class:`Estimate` with ``kind="normal"`` and ``design_points`` (distinct, smallest beta
        first); ``reached=False`` when no design point converged (then the samples were plain
        Monte Carlo).
    """
    batch = batches(n, batch)
    check_problem(g, d, n, batch, dtype, args)
    dtype = float_dtype(dtype)
    if not spread > 0:
        raise ValueError(f"spread must be positive, got {spread!r}")
    spread = jnp.asarray(spread, dtype)
    if isinstance(starts, int):
        _check_search(starts, screening, iterations)
        found, sums = jax.device_get(_importance_screened(g, d, key, tuple(args), spread, n, batch, keep, starts,
                                                          screening, iterations, tol, dtype))
    else:
        starts = np.asarray(starts)
        if starts.ndim != 2 or starts.shape[1] != d or len(starts) < 1:
            raise ValueError(f"start points must be an array (k, {d}), got shape {starts.shape}")
        _check_search(len(starts), len(starts), iterations)
        screening = 0
        found, sums = jax.device_get(_importance_from(g, d, key, tuple(args), spread, starts, n, batch, keep,
                                                      iterations, tol, dtype))
    p = float(sums.s1) / n
    var = max(float(sums.s2) - n * p * p, 0.0) / (n * (n - 1.0))
    cov = float(np.sqrt(var) / p) if p > 0 else float("inf")
    lo, hi = interval(p, cov, confidence, "normal")
    points, margins = failure_arrays(sums.points, sums.margins, sums.score)
    k = len(found.points)
    n_sim = screening + k + iterations * k * (1 + len(STEPS)) + k + n
    return Estimate(method="importance", estimate=p, cov=cov, interval=(lo, hi), confidence=confidence,
                    kind="normal", n_simulations=n_sim, hits=int(sums.hits), reached=bool(np.any(found.distinct)),
                    failure_points=points, failure_margins=margins,
                    design_points=np.asarray(found.points)[np.asarray(found.distinct)])

"""The one optimiser loop of the gradient tools (optax): the LPV fit, the tuner and the worst-case search.

:func:`run` evaluates ``fn(params) -> (value, aux, gradient)`` (a jitted simulation and its
gradient), hands the gradient to an optax transformation, applies its updates and, optionally,
projects the parameters back onto their feasible set; every evaluation is kept. The tools differ
only in the transformation: Adam with an exponentially decaying step for the LPV fit
(:func:`mcfdd.analysis.lpv_fit.fit`), plain Adam for the tuner, and Adam with the backtracking of
:func:`backtracking` for the multi-start worst-case search, whose score is -inf at an infeasible
point. A multi-start run can also replace a start that reaches an infeasible point by the next
point of a reserve (:class:`Restarts`: the worst-case search's next best screened point that has
the event), with its optimiser state fresh.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax


class Trace(NamedTuple):
    """Every evaluation of a run: the parameters, the value and the aux of ``fn`` (lists, in order), and
    the parameters after the last update."""

    params: list
    values: list
    aux: list
    final: object


def run(fn: Callable, params, optimiser: optax.GradientTransformation, iterations: int, *, maximize: bool = False,
        evaluate_last: bool = True, project: Callable | None = None, callback: Callable | None = None,
        restarts: Restarts | None = None) -> Trace:
    """``iterations`` updates of ``params`` by ``optimiser`` on the gradients of ``fn``.

    Args:
        fn: ``fn(params) -> (value, aux, gradient)``, the gradient of ``value`` in ``params``.
        optimiser: an optax transformation; its ``update`` gets the value too (``value=``), for
            transformations that need it (:func:`backtracking`).
        maximize: ascend ``value`` (the gradient's sign is flipped for the optimiser).
        evaluate_last: evaluate the parameters after the last update too (iterations + 1
            evaluations; else ``iterations``).
        project: applied to the parameters after each update (a projection onto the feasible set).
        callback: ``callback(i, value, aux)`` after each evaluation.
        restarts: for S starts at once (parameters (S, d), value (S,)): after each update, the
            starts whose value was -inf move to the next reserve points (:meth:`Restarts.replace`)
            and their rows of the optimiser state (every state leaf with a leading axis S) start
            afresh; ``fn`` reads :attr:`Restarts.slots` to know which point each start is.
    """
    optimiser = _standard_promotion(optax.with_extra_args_support(optimiser))
    state = optimiser.init(params)
    trace = Trace([], [], [], None)
    for i in range(iterations + evaluate_last):
        value, aux, grad = fn(params)
        trace.params.append(params)
        trace.values.append(value)
        trace.aux.append(aux)
        if callback is not None:
            callback(i, value, aux)
        if i == iterations:
            break
        if maximize:
            grad = jax.tree.map(jnp.negative, grad)
        updates, state = optimiser.update(grad, state, params, value=value)
        params = optax.apply_updates(params, updates)
        if project is not None:
            params = project(params)
        if restarts is not None:
            params, replaced = restarts.replace(params, value)
            if replaced.any():
                state = _fresh_rows(optimiser.init(params), state, jnp.asarray(replaced))
    return trace._replace(final=params)


class Restarts:
    """The points of a multi-start run: S starts, then a reserve taken in order (``pool`` (P, d), P >= S).

    ``slots`` (S,) is the pool index each start is at (0 .. S - 1 at first); a start whose value is
    -inf ``patience`` evaluations in a row moves to the next unused pool point while any is left; before
    that (and once the pool is used up) it only backtracks (:func:`backtracking`), so a start whose
    extreme lies at the edge of the feasible set approaches it with ever shorter steps.
    """

    def __init__(self, pool, starts: int, patience: int = 1):
        self.pool = jnp.asarray(pool)
        if not 1 <= starts <= self.pool.shape[0]:
            raise ValueError(f"restarts: {starts} starts need 1 to {self.pool.shape[0]} pool points")
        if patience < 1:
            raise ValueError(f"restarts: patience {patience} must be at least 1")
        self.slots = np.arange(starts)
        self.next = starts
        self.patience = patience
        self.misses = np.zeros(starts, int)  # infeasible evaluations in a row, per start

    def replace(self, params, value):
        """(params with the starts infeasible ``patience`` times in a row at their new pool points, the
        replaced starts (S,) bool)."""
        infeasible = ~np.isfinite(np.asarray(value))
        self.misses = np.where(infeasible, self.misses + 1, 0)
        replaced = np.zeros(len(self.slots), bool)
        for s in np.flatnonzero(self.misses >= self.patience):
            if self.next == self.pool.shape[0]:
                break
            self.slots[s], self.next, replaced[s], self.misses[s] = self.next, self.next + 1, True, 0
        if replaced.any():
            params = jnp.where(jnp.asarray(replaced)[:, None], self.pool[self.slots].astype(params.dtype), params)
        return params, replaced


def _fresh_rows(fresh, state, rows):
    """``state`` with the rows (leading axis S) of ``rows`` (S,) taken from ``fresh``."""
    def pick(new, old):
        if jnp.ndim(old) == 0 or jnp.shape(old)[0] != rows.shape[0]:
            return old
        return jnp.where(rows.reshape((-1,) + (1,) * (jnp.ndim(old) - 1)), new, old)

    return jax.tree.map(pick, fresh, state)


def _standard_promotion(tx: optax.GradientTransformationExtraArgs) -> optax.GradientTransformationExtraArgs:
    """``tx`` with its ``init`` and ``update`` traced under JAX's standard dtype promotion.

    optax's Adam raises its decay rates to the power of an int32 step count (bias correction), an
    implicit int -> float promotion that strict promotion (under which the test suite runs the
    package) refuses; the package's own code promotes nothing implicitly. Values do not change.
    """

    def init(params):
        with jax.numpy_dtype_promotion("standard"):
            return tx.init(params)

    def update(updates, state, params=None, **extra):
        with jax.numpy_dtype_promotion("standard"):
            return tx.update(updates, state, params, **extra)

    return optax.GradientTransformationExtraArgs(init, update)


class BacktrackingState(NamedTuple):
    inner: optax.OptState
    best_params: jnp.ndarray  # (S, d) best feasible point of each start so far
    best: jnp.ndarray  # (S,) its value
    step: jnp.ndarray  # (S,) step scale


def backtracking(learning_rate: float) -> optax.GradientTransformationExtraArgs:
    """Adam for S starts at once (parameters (S, d), value (S,)), one per start, that backtracks from
    infeasible points.

    The value is maximised (:func:`run` with ``maximize=True``); a value of -inf marks an infeasible
    point (e.g. no stall event left to measure): that start returns to its best feasible point and
    halves its step, which grows back by half after each feasible one (up to the Adam step).
    """
    adam = optax.adam(learning_rate)  # one per start (its own step count), so a start can begin afresh

    def init(params):
        n = params.shape[0]
        return BacktrackingState(jax.vmap(adam.init)(params), params, jnp.full(n, -jnp.inf, params.dtype),
                                 jnp.ones(n, params.dtype))

    def update(updates, state: BacktrackingState, params, value=None, **extra):
        feasible = jnp.isfinite(value)
        better = feasible & (value > state.best)
        best_params = jnp.where(better[:, None], params, state.best_params)
        step = jnp.where(feasible, jnp.minimum(1.0, 1.5 * state.step), 0.5 * state.step)
        moves, inner = jax.vmap(adam.update)(updates, state.inner, params)
        moves = step[:, None] * moves
        moves = jnp.where(feasible[:, None], moves, (best_params - params) + moves)
        return moves, BacktrackingState(inner, best_params, jnp.where(better, value, state.best), step)

    return optax.GradientTransformationExtraArgs(init, update)

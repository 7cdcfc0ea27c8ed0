"""Smooth extremes for the gradient tools: the online log-sum-exp every monitor's smooth version is built from.

The hard extremes of the monitors (a maximum over the samples of a window, a minimum over stall
events) have no useful gradient; their smooth versions replace max by the log-sum-exp
``T log sum exp(x_i / T)`` at a temperature T, which tends to the maximum as T -> 0. It is carried
through the scan online (:class:`SoftMax`, :func:`softmax_step`) with a running shift, the largest
value so far, held out of the gradient: stable, and the value does not depend on the shift.
:func:`soft_max` and :func:`soft_min` are the same over an axis of an array.

Statistics of eqs. (26)-(27) (theta of the stall detector, theta_i / ||u|| of the LOE bank) are
smoothed on their logarithm (:func:`log_stat`), so T is relative there (0.05: about 5 %) and the
same for every detector; the monitors' signed margins are relative already and are smoothed as
they are.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

LOG_FLOOR = 1e-20  # statistics are floored here before the logarithm


class SoftMax(NamedTuple):
    """Online log-sum-exp: ``value = shift + T log(total)``, ``total = sum exp((x_i - shift) / T)``.

    ``shift`` is the running maximum, held out of the gradient (the value does not depend on it).
    """

    shift: jnp.ndarray
    total: jnp.ndarray


def softmax_init(dtype) -> SoftMax:
    return SoftMax(jnp.asarray(-jnp.inf, dtype), jnp.asarray(0.0, dtype))


def softmax_step(temperature, acc: SoftMax, x, mask) -> SoftMax:
    """Fold ``x`` into the accumulator where ``mask`` holds."""
    x_in = jnp.where(mask, x, -jnp.inf)
    shift = jax.lax.stop_gradient(jnp.maximum(acc.shift, x_in))
    ref = jnp.where(jnp.isfinite(shift), shift, 0.0)
    rescale = jnp.exp(jnp.where(jnp.isfinite(acc.shift), acc.shift - ref, -jnp.inf) / temperature)
    term = jnp.where(mask, jnp.exp((jnp.where(mask, x, ref) - ref) / temperature), 0.0)
    return SoftMax(shift, acc.total * rescale + term)


def softmax_merge(temperature, acc: SoftMax, other: SoftMax, mask) -> SoftMax:
    """The accumulator of both sets of values where ``mask`` holds, ``acc`` elsewhere."""
    shift = jax.lax.stop_gradient(jnp.maximum(acc.shift, jnp.where(mask, other.shift, -jnp.inf)))
    ref = jnp.where(jnp.isfinite(shift), shift, 0.0)

    def rescaled(a: SoftMax):
        return a.total * jnp.exp(jnp.where(jnp.isfinite(a.shift), a.shift - ref, -jnp.inf) / temperature)

    return SoftMax(shift, rescaled(acc) + jnp.where(mask, rescaled(other), 0.0))


def softmax_value(temperature, acc: SoftMax):
    """Smooth maximum of the folded values; -inf if none was folded."""
    some = acc.total > 0.0
    return jnp.where(some, acc.shift + temperature * jnp.log(jnp.where(some, acc.total, 1.0)), -jnp.inf)


def reset(acc: SoftMax, mask) -> SoftMax:
    """An empty accumulator where ``mask`` holds."""
    return jax.tree.map(lambda fresh, old: jnp.where(mask, fresh, old), softmax_init(acc.total.dtype), acc)


def soft_max(x, mask, temperature, axis=-1):
    """Smooth maximum over ``axis`` of the masked ``x`` (-inf where nothing is masked in)."""
    shift = jax.lax.stop_gradient(jnp.max(jnp.where(mask, x, -jnp.inf), axis=axis, keepdims=True))
    ref = jnp.where(jnp.isfinite(shift), shift, 0.0)
    total = jnp.sum(jnp.where(mask, jnp.exp((jnp.where(mask, x, ref) - ref) / temperature), 0.0), axis=axis)
    return softmax_value(temperature, SoftMax(jnp.squeeze(ref, axis), total))


def soft_min(x, mask, temperature, axis=-1):
    """Smooth minimum, ``-soft_max(-x)`` (+inf where nothing is masked in)."""
    return -soft_max(-x, mask, temperature, axis)


def log_stat(value):
    """log of a non-negative statistic, floored at LOG_FLOOR."""
    return jnp.log(jnp.maximum(value, LOG_FLOOR))

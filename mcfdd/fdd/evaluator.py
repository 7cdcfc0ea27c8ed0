"""Narendra residual evaluator, eqs. (13)-(14), discretised exactly for |r| held over a sample.

    theta = xi + alpha |r|,   xi+ = exp(-gamma T) xi + beta (1 - exp(-gamma T)) / gamma |r|

alpha >= 0 weighs the instantaneous value, beta >= 0 the exponentially forgotten integral and
gamma > 0 is the forgetting factor (1/s). Parameters broadcast: a bank evaluates all its
residuals at once.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class NarendraParams(NamedTuple):
    alpha: float
    beta: float
    gamma: float


def init(like):
    return jnp.zeros_like(like)


def step(params: NarendraParams, xi, r, dt_s: float):
    """Returns (new xi, theta at the start of the step)."""
    magnitude = jnp.abs(r)
    decay = jnp.exp(-params.gamma * dt_s)
    theta = xi + params.alpha * magnitude
    return decay * xi + params.beta * (1.0 - decay) / params.gamma * magnitude, theta

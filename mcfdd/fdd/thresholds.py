"""H-inf distances between first-order models and the thresholds of eq. (16).

For ``G_i = k_i / (s + k_i)`` the difference ``G_j - G_i = (k_j - k_i) s / ((s + k_i)(s + k_j))``
peaks at ``w = sqrt(k_i k_j)`` with

    ||G_j - G_i||_inf = |k_j - k_i| / (k_i + k_j).

Eq. (16) takes, for filter i, the infimum of this distance over the other models and over the
scheduling parameters; the bank's gains are evaluated on a grid of the envelope (Vcas, h),
deflection and both motion directions, all at once.

Scheduled thresholds: the same distance evaluated online at the current scheduling point, in the
units of the bank's decision theta_i / ||u|| (filter i on model j gives a ratio of about
``|k_j - k_i| / k0_i``, i.e. the distance times ``(k_i + k_j) / k0_i``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcfdd.fdd import lpv


def hinf_distance(k_i, k_j):
    """||G_j - G_i||_inf of two first-order models (broadcasts)."""
    return jnp.abs(k_j - k_i) / (k_i + k_j)


def peak_frequency(k_i, k_j):
    """Frequency (rad/s) where |G_j - G_i| peaks."""
    return jnp.sqrt(k_i * k_j)


def gain_grid(bank: lpv.GainBank, vcas_m_s, altitude_m, x_m):
    """Gains of all models on the grid: shape (N, n_vcas, n_alt, n_x, 2), last axis s = -1, +1."""
    def at(v, h, x, s):
        return lpv.gains(bank, x, s, v, h)

    f = jax.vmap(at, in_axes=(None, None, None, 0), out_axes=-1)
    f = jax.vmap(f, in_axes=(None, None, 0, None), out_axes=-2)
    f = jax.vmap(f, in_axes=(None, 0, None, None), out_axes=-3)
    f = jax.vmap(f, in_axes=(0, None, None, None), out_axes=-4)
    return f(jnp.asarray(vcas_m_s), jnp.asarray(altitude_m), jnp.asarray(x_m), jnp.array([-1.0, 1.0]))


def pairwise_distances(bank: lpv.GainBank, vcas_m_s, altitude_m, x_m):
    """Distances of every model pair at every grid point: shape (N, N, n_vcas, n_alt, n_x, 2).

    Both models are evaluated at the same rho (same flight point, deflection and direction).
    """
    k = gain_grid(bank, vcas_m_s, altitude_m, x_m)
    return hinf_distance(k[:, None], k[None, :])


def minimum_distances(distances, mask=None):
    """Infimum over the grid of each pair's distance, (N, N); ``mask`` drops grid points (e.g. Mach)."""
    if mask is not None:
        distances = jnp.where(mask, distances, jnp.inf)
    return jnp.min(distances.reshape(distances.shape[:2] + (-1,)), axis=-1)


def thresholds(min_distances):
    """tau_i of eq. (16): the smallest distance from model i to any other model, (N,)."""
    n = min_distances.shape[0]
    return jnp.min(jnp.where(jnp.eye(n, dtype=bool), jnp.inf, min_distances), axis=1)


def nearest_ratio(k, k0):
    """Distance (16) of each model to its nearest other model at one scheduling point, in ratio units.

    ``k`` (N,) are the models' gains at the current point, ``k0`` (N,) their nominal gains; returns
    (N,) ``min_{j != i} |k_j - k_i| / k0_i``, the ratio theta_i / ||u|| filter i shows on model j.
    """
    n = k.shape[0]
    gap = jnp.where(jnp.eye(n, dtype=bool), jnp.inf, jnp.abs(k[None, :] - k[:, None]))
    return jnp.min(gap, axis=1) / k0

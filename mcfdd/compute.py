"""Compute once: a quantity of a step evaluated once per step by XLA CPU (DESIGN.md section 2).

XLA's CPU backend has no multi-output fusion. Every array a step carries or returns is the root
of its own loop fusion, and the cheap elementwise work several roots depend on (pilot inputs,
control law, scheduled gains, ...) is duplicated into each of them: the campaign step compiled
to about 90 fusions that executed three times the element-ops of its jaxpr. XLA does not
duplicate an operation it counts as expensive, and a floating-point division is one; so
:func:`once` divides a shared quantity by a 1.0 that is known only at run time (a leaf of the
parameters, an argument of the jitted function, so XLA can neither fold nor simplify it). The
quantity is then computed in one fusion, stored, and read by every user. The division is exact
(x / 1 == x for every float, inf and nan included): results do not change.

``jax.lax.optimization_barrier`` would express the same intent, but XLA's CPU pipeline removes
it before fusion, so it has no effect there (``benchmarks/campaign_throughput.py --barrier-check``).
A boolean mask goes the same way as a float 0/1 (:func:`once_mask`): the mask is computed in the
one fusion of the division, and each user only compares the stored float with 0.

When the 1.0 is a compile-time constant (parameters closed over instead of passed) XLA folds the
division away: results are the same, only the duplication returns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

ONE = 1.0  # the default of the ``one`` leaves of the parameters (PlantModel, FddParams)


def once(tree, one):
    """``tree`` with its floating-point leaves divided by ``one`` (a runtime 1.0): computed once.

    Integer and boolean leaves pass unchanged (XLA duplicates a mask's conversion to float and
    back as readily as the mask itself). ``one`` is a scalar leaf of the step's parameters.
    """
    def leaf(x):
        x = jnp.asarray(x)
        return x / one.astype(x.dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x

    one = jnp.asarray(one)
    return jax.tree.map(leaf, tree)


def once_mask(mask, one):
    """A boolean ``mask`` computed once: stored as a float 0/1 divided by ``one``, each user compares it.

    XLA duplicates the comparisons and logic a mask is made of into every fusion it gates (the
    reductions' masks gated 10-26 fusions each); the float costs one comparison per user instead.
    """
    one = jnp.asarray(one)
    return once(jnp.where(mask, jnp.ones((), one.dtype), jnp.zeros((), one.dtype)), one) > 0.0

"""Compute once: a quantity of a step evaluated once per step by XLA CPU (DESIGN.md section 2).

XLA's CPU backend has no multi-output fusion. Every array a step carries or returns is the root
of its own loop fusion, and the cheap elementwise work several roots depend on (pilot inputs,
control law, scheduled gains, ...) is duplicated into each of them: the campaign step compiled
to about 90 fusions that executed three times the element-ops of its jaxpr. XLA does not
duplicate an operation it counts as expensive, and a floating-point division is one; so
:func:`once` divides a shared quantity by a 1.0 that is known only at run time (a leaf of the
parameters, an argument of the jitted function, so XLA can neither fold nor simplify it). The
quantity is then computed in one fusion, stored, and read by every user. The division is exact
(x / 1 == x for every float, inf and nan included; subnormals are flushed to zero by XLA CPU in
every operation, this one too): results do not change.

``jax.lax.optimization_barrier`` would express the same intent, but XLA's CPU pipeline removes
it before fusion, so it has no effect there (``benchmarks/campaign_throughput.py --barrier-check``).
Boolean and integer leaves go the same way through a float (a mask as 0/1, a model id or count
as its value, exact below 2**24): the leaf is computed in the one fusion of the division, and each
user only converts or compares the stored float (one operation instead of the whole mask).

A stored quantity read as a divisor is not stored: XLA's algebraic simplifier rewrites
``a / (b / one)`` as ``(a * one) / b``, and ``b`` is recomputed in every reader (a toy scan step
whose three readers divide by the shared value: 33 element-ops per step against 15 when they
multiply). Store the quotient itself, or the reciprocal where a change of rounding is acceptable.

When the 1.0 is a compile-time constant (parameters closed over instead of passed) XLA folds the
division away: results are the same, only the duplication returns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

ONE = 1.0  # the default of the ``one`` leaves of the parameters (PlantModel, FddParams)


def once(tree, one):
    """``tree`` with its leaves computed once: divided by ``one`` (a runtime 1.0 of the step's parameters).

    Floating-point leaves are divided as they are; boolean and integer leaves are divided as
    floats in ``one``'s dtype and turned back (``> 0`` for a mask, a conversion for an integer,
    exact for integers below 2**24 in magnitude). Values, dtypes and gradients are unchanged.
    """
    one = jnp.asarray(one)

    def leaf(x):
        x = jnp.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.floating):
            return x / one.astype(x.dtype)
        if x.dtype == jnp.bool_:
            return jnp.where(x, jnp.ones((), one.dtype), jnp.zeros((), one.dtype)) / one > 0.0
        return (x.astype(one.dtype) / one).astype(x.dtype)

    return jax.tree.map(leaf, tree)


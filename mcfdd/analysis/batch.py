"""Batches of scenarios: stacking per-run pytrees into arrays with a leading batch axis."""

from __future__ import annotations

import jax
import numpy as np


def stack(trees, dtype=np.float32):
    """Stack a list of pytrees of Python numbers into one pytree of arrays (batch axis first).

    Integer leaves (manoeuvre family codes) become int32, the others ``dtype``.
    """
    def leaf(*xs):
        integer = all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in xs)
        return np.asarray(xs, dtype=np.int32 if integer else dtype)

    return jax.tree.map(leaf, *trees)


def kinds_in(codes) -> tuple[int, ...]:
    """The static tuple of manoeuvre family codes present in a batch."""
    return tuple(sorted({int(c) for c in np.asarray(codes).ravel()}))

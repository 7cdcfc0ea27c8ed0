"""Host or traced: the array module a formula shared by the step and the set-up computes with.

A formula of the plant (atmosphere, trim, hinge table) runs traced inside the step and in NumPy on
host arrays at set-up, where every eager ``jax.numpy`` operation would compile a program of its
own (about 50 per command before this). Importing this module does not import JAX, so the
configuration can check flight points with the same formulas without starting JAX.
"""

from __future__ import annotations

import importlib
import sys

import numpy as np


def array_module(*values):
    """``jax.numpy`` if any of ``values`` is a JAX array (a tracer included), else ``numpy``."""
    jax = sys.modules.get("jax")  # no value is a JAX array before JAX is imported
    if jax is not None and any(isinstance(v, jax.Array) for v in values):
        return importlib.import_module("jax.numpy")
    return np

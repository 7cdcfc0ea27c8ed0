"""Shared test set-up: float64 everywhere, since the tests check numerics."""

import jax

jax.config.update("jax_enable_x64", True)

"""Test set-up for the whole repository (tests and doctests): two JAX host devices, float64 numerics,
strict dtype promotion.

The device count is fixed before JAX starts, so the sharded campaign path is tested whatever the
machine or the test order; ``tests/test_layout.py`` compares runs on 1, 2 and 3 devices.

Dtype promotion is "strict", as the JAX libraries run their tests: an operation between arrays of
different dtypes is an error instead of an implicit promotion (Python scalars stay weakly typed),
so the package states every conversion. The environment variable carries the setting into the
commands the tests run in subprocesses.
"""

import os
import re

import pytest

FLAG = "--xla_force_host_platform_device_count"
TEST_DEVICES = 2
os.environ["XLA_FLAGS"] = (re.sub(rf"{FLAG}=\d+", "", os.environ.get("XLA_FLAGS", "")) +
                           f" {FLAG}={TEST_DEVICES}").strip()
os.environ["JAX_NUMPY_DTYPE_PROMOTION"] = "strict"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


@pytest.fixture(autouse=True, scope="module")
def _compiled_programs_freed_after_each_module():
    """One process runs the whole suite: JAX's caches of traced and compiled programs are emptied after each
    test module, so their memory does not grow with the number of modules (a module that counts compilations
    counts within itself)."""
    yield
    jax.clear_caches()

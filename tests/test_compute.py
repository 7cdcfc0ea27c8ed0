"""mcfdd.compute.once: exact for every dtype, transparent to gradients, and computed once by XLA CPU."""

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.compute import once


def test_once_returns_every_leaf_unchanged():
    """Floats (inf, nan, -0, the largest and smallest normal), masks and integers up to 2**24 in magnitude: same
    values and dtypes, with ``one`` a runtime argument as in the step."""
    floats = np.array([0.0, -0.0, 1.5, -1.2e-38, np.inf, -np.inf, np.nan, 3.4e38], np.float32)
    mask = np.array([True, False, True, True, False])
    ints = np.array([-1, 0, 5, -(2 ** 24), 2 ** 24], np.int32)
    tree = {"f": floats, "b": mask, "i": ints, "pair": (floats[:3], mask[:2])}
    out = jax.jit(once)(tree, np.float32(1.0))
    for got, want in zip(jax.tree.leaves(out), jax.tree.leaves(tree)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(np.asarray(got), want)
    assert np.signbit(np.asarray(out["f"])[1])


def test_once_is_transparent_to_gradients():
    x = jnp.array([0.3, -2.0, 4.0])
    grad = jax.grad(lambda v, one: jnp.sum(jnp.sin(once(v, one)) * v))(x, 1.0)
    np.testing.assert_allclose(grad, np.cos(x) * x + np.sin(x), rtol=1e-6)


def _fusions_with(use_once: bool, op: str) -> int:
    """Fused computations of a toy scan step containing ``op``: three carried values share a cheap
    expression (a clamp) and a mask (a comparison) that XLA would duplicate into each of their loops."""
    def run(x, one):
        def body(c, _):
            a, b, d = c
            shared = jnp.clip(a * 1.1 + b * 0.3, -1.0, 1.0) * (a - b)
            mask = (a > b) & (jnp.abs(b) < 0.75)
            if use_once:
                shared, mask = once((shared, mask), one)
            return (a + jnp.where(mask, 0.01, 0.02) * shared, b - jnp.where(mask, 0.03, 0.0) * shared,
                    jnp.where(mask, jnp.maximum(d, shared), d)), None
        return jax.lax.scan(body, (x, 0.5 * x, x), None, length=10)[0]

    text = jax.jit(jax.vmap(run, in_axes=(0, None))).lower(jnp.linspace(-1.0, 1.0, 64), 1.0).compile().as_text()
    blocks = text.split("\n\n")
    return sum(1 for b in blocks if b.lstrip().startswith("%fused") and f" {op}(" in b)


def test_once_makes_xla_compute_a_shared_value_and_mask_in_one_fusion():
    assert _fusions_with(False, "clamp") >= 3 and _fusions_with(False, "and") >= 3
    assert _fusions_with(True, "clamp") == 1 and _fusions_with(True, "and") == 1

"""Counter-based standard normals keyed by (seed, scenario, step).

Step k of a run draws its normals from a hash of (run key, k, j), j = 0 .. dim - 1, so a run's
numbers depend on its seed, its scenario id and the step alone, never on the batch, the chunk,
the horizon or the device it runs on, and nothing is carried between steps. The run key is the
threefry key ``fold_in(key(seed), scenario)`` (:func:`mcfdd.analysis.simulate.run_keys`); its
two 32-bit words key the hash.

Bits: the counter ``k dim + j`` goes through two rounds of a 32-bit integer mixer, one keyed
by each key word. The mixer is C. Wellons' "lowbias32" (xor-shift-multiply, constants
0x7feb352d and 0x846ca68b, found by his hash-prospector search), whose every output bit flips
with probability close to 1/2 when any input bit flips.

Normals: the top 23 bits m give ``v = (2 m + 1) 2^-23 - 1``, exactly, in (-1, 1), symmetric
about 0 and never 0 or +-1, and ``z = sqrt(2) erfinv(v)``: the inverse-CDF transform, with
XLA's float32 ``erf_inv`` (M. Giles, "Approximating the erfinv function", GPU Computing Gems
Jade Edition, 2011: two polynomials in ``w = -log(1 - v^2)``). ``|z|`` reaches 5.3 at most,
beyond which a normal has probability 1.2e-7. The compiled cost is about 65 element-ops per
normal (hash and transform; ``benchmarks/campaign_throughput.py``), where threefry normals drawn
in blocks cost about 245.

Box-Muller (``method="box_muller"``, the full aircraft's per-step noise): n = ceil(dim / 2) pairs
need 2 n uniforms of 23 bits. The same hash gives 3 t words of step k, t = ceil(n / 2) (counter
``k 3 t + j``), read as t triples (a, b, c) of 96 bits: the top 23 bits of a, b and c are three
uniforms' m, and a fourth is a's low 9 bits, b's low 9 bits and c's low 5 bits side by side, so no
bit serves twice. The first n of the 4 t give ``u = (2 m + 1) 2^-24`` in (0, 1) as above, the next
n give ``theta = 2 pi m 2^-23`` in [0, 2 pi), and each pair ``sqrt(-2 ln u) (cos theta, sin
theta)`` is two independent standard normals exactly for uniform u and theta (G. E. P. Box and M.
E. Muller, "A note on the generation of random normal deviates", Ann. Math. Statist. 29, 1958).
The radius reaches sqrt(48 ln 2) = 5.77 at most. Compiled, the full aircraft's 7 normals (4 pairs
from 6 words) cost about 180 element-ops (6 hashes, the bit splicing, 4 logs, square roots and
cosines, 3 sines), 26 a normal against the inverse-CDF's 65. The roll axis keeps the inverse-CDF
transform (its tables stay as they are).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)
_MANTISSA_BITS = 23


def _mix(x):
    """lowbias32: a bijective 32-bit integer mixer (uint32 in, uint32 out)."""
    x = x ^ (x >> 16)
    x = x * _M1
    x = x ^ (x >> 15)
    x = x * _M2
    return x ^ (x >> 16)


def key_words(key):
    """The two uint32 words of a threefry key (typed or raw), shape (2,) for one key."""
    if jnp.issubdtype(jnp.asarray(key).dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return jnp.asarray(key, jnp.uint32)


def bits(words, step, dim: int):
    """(dim,) uint32 hash bits of step ``step`` for key words (2,)."""
    counter = jnp.asarray(step).astype(jnp.uint32) * np.uint32(dim) + jnp.arange(dim, dtype=jnp.uint32)
    return _mix(_mix(counter ^ words[0]) + words[1])


def to_normal(b, dtype=jnp.float32):
    """Standard normals from uint32 bits by the inverse-CDF transform (see the module docstring)."""
    m = (b >> (32 - _MANTISSA_BITS)).astype(jnp.int32)
    v = (2 * m + 1).astype(dtype) * jnp.asarray(2.0 ** -_MANTISSA_BITS, dtype) - jnp.asarray(1.0, dtype)
    return jnp.asarray(np.sqrt(2.0), dtype) * jax.lax.erf_inv(v)


def uniform_bits(b):
    """4 t uniform 23-bit integers (int32) from 3 t uint32 words read as t triples (a, b, c) = (b[i], b[t + i],
    b[2 t + i]): the top 23 bits of every word, then a's low 9, b's low 9 and c's low 5 bits of each triple."""
    t = b.shape[0] // 3
    a, bb, c = b[:t], b[t:2 * t], b[2 * t:]
    spliced = ((a & np.uint32(0x1FF)) << 14) | ((bb & np.uint32(0x1FF)) << 5) | (c & np.uint32(0x1F))
    return jnp.concatenate([b >> (32 - _MANTISSA_BITS), spliced]).astype(jnp.int32)


def box_muller(m, dim: int, dtype=jnp.float32):
    """``dim`` standard normals from at least 2 n uniform 23-bit integers m, n = ceil(dim / 2), by the Box-Muller
    transform (see the module docstring): the n radii from m[:n], the n angles from m[n:2 n]; the n cosine
    terms first, then the first dim - n sine terms (an odd dim leaves the last sine unused)."""
    n = -(-dim // 2)
    u = m[:n].astype(dtype) * jnp.asarray(2.0 ** -_MANTISSA_BITS, dtype) + jnp.asarray(2.0 ** -(_MANTISSA_BITS + 1),
                                                                                  dtype)  # (2 m + 1) 2^-24 exactly
    radius = jnp.sqrt(jnp.asarray(-2.0, dtype) * jnp.log(u))
    angle = m[n:2 * n].astype(dtype) * jnp.asarray(2.0 * np.pi * 2.0 ** -_MANTISSA_BITS, dtype)
    return jnp.concatenate([radius * jnp.cos(angle), radius[:dim - n] * jnp.sin(angle[:dim - n])])


def box_muller_words(dim: int) -> int:
    """Hash words a step of ``dim`` Box-Muller normals reads: 3 t, t = ceil(ceil(dim / 2) / 2)."""
    pairs = -(-dim // 2)
    return 3 * -(-pairs // 2)


METHODS = ("inverse_cdf", "box_muller")


def normals(words, step, dim: int, dtype=jnp.float32, method: str = "inverse_cdf"):
    """(dim,) standard normals of step ``step`` of the run keyed by ``words`` (:func:`key_words`), by ``method``
    (:data:`METHODS`: the inverse-CDF transform of ``dim`` hashes, or Box-Muller pairs of :func:`box_muller_words`)."""
    if method == "inverse_cdf":
        return to_normal(bits(words, step, dim), dtype)
    if method == "box_muller":
        return box_muller(uniform_bits(bits(words, step, box_muller_words(dim))), dim, dtype)
    raise ValueError(f"unknown normal generator {method!r}: one of {', '.join(METHODS)}")

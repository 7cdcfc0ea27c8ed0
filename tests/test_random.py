"""Counter-based normals (mcfdd.analysis.noise): distribution, independence, keying by (seed, scenario, step),
for both transforms (the roll axis's inverse CDF, the full aircraft's Box-Muller pairs)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special
import scipy.stats

from mcfdd.analysis import noise, probability, simulate
from mcfdd.plant import closed_loop, manoeuvres, rcam_loop

N_SCENARIOS, N_STEPS = 256, 200
DIMS = {"inverse_cdf": closed_loop.NOISE_DIM, "box_muller": rcam_loop.NOISE_DIM}  # 4 and 7 (an odd count)


@pytest.fixture(scope="module", params=noise.METHODS)
def draws(request):
    """(scenarios, steps, dim) float32 normals of seed 3, as a campaign's steps draw them, by each method."""
    keys = simulate.run_keys(3, np.arange(N_SCENARIOS))
    method = request.param

    def run(key):
        words = noise.key_words(key)
        return jax.vmap(lambda k: noise.normals(words, k, DIMS[method], jnp.float32, method))(jnp.arange(N_STEPS))

    out = np.asarray(jax.jit(jax.vmap(run))(keys))
    assert out.dtype == np.float32
    return out


def test_moments_are_those_of_a_standard_normal(draws):
    z = draws.astype(np.float64).ravel()
    n = z.size
    assert abs(z.mean()) < 4.0 / np.sqrt(n)
    assert abs(z.var() - 1.0) < 4.0 * np.sqrt(2.0 / n)
    assert abs(scipy.stats.skew(z)) < 4.0 * np.sqrt(6.0 / n)
    assert abs(scipy.stats.kurtosis(z)) < 4.0 * np.sqrt(24.0 / n)


@pytest.mark.parametrize("level", [1.0, 2.0, 3.0, 4.0])
def test_tail_frequencies_match_the_normal(draws, level):
    z = draws.ravel()
    expected = 2.0 * scipy.stats.norm.sf(level)
    count = int((np.abs(z) > level).sum())
    lo, hi = scipy.stats.binom.interval(1.0 - 1e-6, z.size, expected)
    assert lo <= count <= hi, (level, count, expected * z.size)


def test_kolmogorov_smirnov_against_the_normal(draws):
    assert scipy.stats.kstest(draws.ravel(), "norm").pvalue > 1e-3
    for j in range(draws.shape[-1]):  # every component of a step on its own
        assert scipy.stats.kstest(draws[:, :, j].ravel(), "norm").pvalue > 1e-3


def test_no_correlation_between_neighbouring_scenarios_steps_and_components(draws):
    def corr(a, b):
        return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])

    bound = 4.5 / np.sqrt(draws[1:].size)
    assert abs(corr(draws[1:], draws[:-1])) < bound  # scenario s and s + 1, same step
    assert abs(corr(draws[:, 1:], draws[:, :-1])) < bound  # step k and k + 1, same scenario
    assert abs(corr(draws[..., 1:], draws[..., :-1])) < bound  # component j and j + 1
    assert abs(corr(draws[:, 1:, 0], draws[:, :-1, -1])) < bound  # last of step k, first of step k + 1
    assert abs(corr(draws[1:, :, 0] ** 2, draws[:-1, :, 0] ** 2)) < bound  # nor in magnitude
    pair_bound = 4.5 / np.sqrt(draws[..., 0].size)
    for j in range(draws.shape[-1] - 1):  # every pair of components, in magnitude too (a Box-Muller pair
        for i in range(j + 1, draws.shape[-1]):  # shares its radius: uncorrelated squares, as independence needs)
            assert abs(corr(draws[..., i], draws[..., j])) < pair_bound
            assert abs(corr(draws[..., i] ** 2, draws[..., j] ** 2)) < pair_bound


@pytest.mark.parametrize("method", noise.METHODS)
def test_a_scenarios_numbers_depend_on_seed_scenario_and_step_only(method):
    def normals(seed, ids, steps):
        keys = simulate.run_keys(seed, ids)
        return np.asarray(jax.vmap(lambda key: jax.vmap(
            lambda k: noise.normals(noise.key_words(key), k, DIMS[method], jnp.float32, method))(
                jnp.asarray(steps)))(keys))

    whole = normals(5, np.arange(64), np.arange(50))
    alone = normals(5, np.array([17]), np.arange(50))
    np.testing.assert_array_equal(alone[0], whole[17])  # the batch it is in does not matter
    np.testing.assert_array_equal(normals(5, np.array([17]), np.arange(20, 50))[0], whole[17, 20:])  # nor the start
    assert not np.any(normals(6, np.array([17]), np.arange(50))[0] == whole[17])  # another seed: other numbers


@pytest.mark.parametrize("method", noise.METHODS)
def test_scan_steps_feeds_step_k_its_own_normals(method):
    key = simulate.run_keys(2, [9])[0]

    def body(c, k, z):
        return c, (k, z)

    _, (ks, zs) = simulate.scan_steps(body, 0.0, key, 30, DIMS[method], method=method)
    expected = np.stack([np.asarray(noise.normals(noise.key_words(key), k, DIMS[method], zs.dtype, method))
                         for k in range(30)])
    np.testing.assert_array_equal(np.asarray(ks), np.arange(30))
    np.testing.assert_array_equal(np.asarray(zs), expected)


def test_transform_is_the_normal_quantile_to_float32_accuracy():
    bits = np.concatenate([np.array([0, 1, 2**31 - 1, 2**31, 2**32 - 1], dtype=np.uint32),
                           np.random.default_rng(0).integers(0, 2**32, 100_000, dtype=np.uint32)])
    z = np.asarray(noise.to_normal(jnp.asarray(bits), jnp.float32)).astype(np.float64)
    m = (bits >> 9).astype(np.float64)
    reference = scipy.special.ndtri((2.0 * m + 1.0) / 2.0**24)  # the quantile of the midpoint of cell m
    assert np.all(np.isfinite(z))
    np.testing.assert_allclose(z, reference, rtol=2e-5, atol=2e-6)
    assert z[0] == -z[4] and abs(z[0]) < 5.4  # symmetric; the largest normal it can give
    assert np.all(z != 0.0)


def test_box_muller_is_the_pair_transform_of_the_step_bits():
    """An independent NumPy Box-Muller of the hash words (float64) against the float32 normals of a step."""
    words = noise.key_words(simulate.run_keys(4, [11])[0])
    for step in (0, 1, 977):
        w = [int(x) for x in np.asarray(noise.bits(words, step, 6))]  # 7 normals: 4 pairs of 23-bit uniforms
        m = [x >> 9 for x in w] + [(w[i] % 512) * 2**14 + (w[2 + i] % 512) * 2**5 + w[4 + i] % 32 for i in range(2)]
        m = np.asarray(m, dtype=np.float64)
        radius = np.sqrt(-2.0 * np.log((2.0 * m[:4] + 1.0) / 2.0**24))
        angle = 2.0 * np.pi * m[4:] / 2.0**23
        reference = np.concatenate([radius * np.cos(angle), radius[:3] * np.sin(angle[:3])])
        z = np.asarray(noise.normals(words, step, 7, jnp.float32, "box_muller")).astype(np.float64)
        np.testing.assert_allclose(z, reference, rtol=1e-5, atol=1e-6)


def test_box_muller_uses_every_bit_of_its_words_once():
    """Each of the 4 t uniforms of 3 t words flips with its own bits only, and 4 t x 23 of the 96 t bits serve."""
    rng = np.random.default_rng(1)
    b = rng.integers(0, 2**32, 6, dtype=np.uint32)
    base = np.asarray(noise.uniform_bits(jnp.asarray(b)))
    owners = {}
    for word in range(6):
        for bit in range(32):
            flipped = b.copy()
            flipped[word] ^= np.uint32(1 << bit)
            changed = np.flatnonzero(np.asarray(noise.uniform_bits(jnp.asarray(flipped))) != base)
            assert len(changed) <= 1, (word, bit)
            if len(changed):
                owners.setdefault(int(changed[0]), []).append((word, bit))
    assert sorted(owners) == list(range(8)) and all(len(v) == 23 for v in owners.values())
    assert base.min() >= 0 and base.max() < 2**23


def test_box_muller_extremes_and_an_unknown_method():
    m = jnp.asarray(np.array([0, 2**23 - 1, 0, 2**22], dtype=np.int32))
    z = np.asarray(noise.box_muller(m, 4, jnp.float32)).astype(np.float64)
    largest = np.sqrt(-2.0 * np.log(2.0**-24))  # the smallest u, (2 0 + 1) 2^-24
    np.testing.assert_allclose(z, [largest, -np.sqrt(-2.0 * np.log(1.0 - 2.0**-24)), 0.0, 0.0], rtol=1e-5, atol=1e-6)
    assert abs(largest - 5.77) < 0.01
    with pytest.raises(ValueError, match="unknown normal generator 'polar'"):
        noise.normals(noise.key_words(simulate.run_keys(0, [0])[0]), 0, 7, jnp.float32, "polar")


def test_a_full_aircraft_run_is_the_run_of_the_normals_its_key_draws():
    """The full aircraft's campaign runs draw Box-Muller normals: given them (probability.campaign_normals with
    the plant's method), run_normals is the key's run to the bit, as issue 23's standard-normal space needs."""
    model = closed_loop.build_model(aircraft_model="rcam")
    plant = closed_loop.loop(model)
    assert plant.normals == "box_muller" and closed_loop.loop(closed_loop.build_model()).normals == "inverse_cdf"
    scenario = jax.tree.map(jnp.asarray, closed_loop.Scenario(turbulence_level=2.0))
    key, n_steps, kinds = simulate.run_keys(7, [3])[0], 40, (manoeuvres.KIND_CODE["doublet"],)
    ref = simulate.run(model, None, scenario, key, n_steps, 0.01, 2, kinds)[1]
    init, steps = probability.campaign_normals(key, n_steps, probability.noise_dims(model), plant.normals)
    got = simulate.run_normals(model, None, scenario, init, steps, 0.01, 2, kinds)[1]
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(ref)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    inverse = probability.campaign_normals(key, n_steps, probability.noise_dims(model))[1]
    assert not np.any(np.asarray(inverse) == np.asarray(steps))  # the other method: other numbers

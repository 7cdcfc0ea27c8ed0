"""Rare-event estimators (mcfdd.analysis.rare) against closed forms and independent references.

Problems with known probabilities near 1e-6: linear limit states g = a.u - beta, P = Phi(-beta), in
d = 2, 100 and 1000; the union of two linear limit states (two design points), P by
inclusion-exclusion with scipy's bivariate normal CDF; the first passage of an AR(1) path over a
level, P by the recursion of the killed density on a grid written here (checked against scipy's
multivariate normal CDF where that is accurate). Over 40 seeds each estimator's interval covers
the truth as often as its confidence says (a one-sided binomial test at 1 %, which a biased
estimator fails, shown), and the mean estimate is within three standard errors of the truth.
Also: the chains' invariant law, design points against closed forms, bit-for-bit determinism,
one compilation per run, combinations over strata and per flight hour, the per-airframe view,
and clear errors on bad input.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import binomtest, kstest, multivariate_normal, norm, t as student_t, truncnorm

from mcfdd.analysis import rare
from mcfdd.analysis.rare.estimate import interval
from mcfdd.workflows.common import CompileCounter
from rare_problems import PROBLEMS, FirstPassage, Linear, killed_density_crossing

SEEDS = 40
CONFIDENCE = 0.95


# importance sampling settings: a first passage has one design point per step, so more starts
IS_OPTIONS = {"first-passage": dict(n=2000, starts=64, screening=2048, iterations=8)}
IS_DEFAULT = dict(n=500, starts=8, screening=128, iterations=10)


def run(method, name, seed):
    problem = PROBLEMS[name]
    if method == "subset":
        return rare.subset_simulation(problem, problem.d, jax.random.key(seed), n=1000)
    return rare.importance_sampling(problem, problem.d, jax.random.key(seed), **IS_OPTIONS.get(name, IS_DEFAULT))


def coverage_consistent(covered: int, runs: int, confidence: float) -> bool:
    """A one-sided binomial test at 1 %: too few covering intervals for the stated confidence fail."""
    return binomtest(covered, runs, confidence, alternative="less").pvalue > 0.01


def consistent(estimates, intervals, truth) -> bool:
    """Estimates over seeds are right: intervals cover at their confidence, mean within 3 standard errors."""
    estimates = np.asarray(estimates)
    covered = sum(lo <= truth <= hi for lo, hi in intervals)
    unbiased = abs(estimates.mean() - truth) < 3.0 * estimates.std(ddof=1) / np.sqrt(len(estimates))
    return coverage_consistent(covered, len(estimates), CONFIDENCE) and unbiased


# --------------------------------------------------------------------------------------------
# References


def test_first_passage_reference_against_the_multivariate_normal_cdf():
    """The killed-density recursion against 1 - P(all x_t <= level) (scipy, at a level where that is accurate)."""
    fp = FirstPassage(sigmas=2.0)
    cov = fp.paths @ fp.paths.T
    mvn = 1.0 - multivariate_normal(np.zeros(fp.d), cov, seed=0).cdf(np.full(fp.d, fp.level))  # abseps 1e-5
    assert fp.truth == pytest.approx(mvn, rel=2e-4)
    # and the grid has converged at the 1e-6 level used below
    rare_fp = PROBLEMS["first-passage"]
    coarse = killed_density_crossing(rare_fp.phi, rare_fp.s, rare_fp.d, rare_fp.level, m=1000)
    assert rare_fp.truth == pytest.approx(coarse, rel=1e-4)
    assert 3e-7 < rare_fp.truth < 3e-6


def test_union_reference_by_quadrature():
    from scipy.integrate import quad

    union = PROBLEMS["union"]
    rho = float(union.a1 @ union.a2)
    both = quad(lambda x: norm.pdf(x) * norm.sf((union.b2 - rho * x) / np.sqrt(1 - rho * rho)), union.b1, np.inf,
                epsabs=0.0, epsrel=1e-12)[0]
    assert union.truth == pytest.approx(norm.sf(union.b1) + norm.sf(union.b2) - both, rel=1e-8)


# --------------------------------------------------------------------------------------------
# Coverage over seeds


@pytest.mark.parametrize("method", ["subset", "importance"])
@pytest.mark.parametrize("name", list(PROBLEMS))
def test_estimates_cover_the_truth_at_their_confidence(method, name):
    truth = PROBLEMS[name].truth
    results = [run(method, name, seed) for seed in range(SEEDS)]
    values = np.array([r.estimate for r in results])
    covered = sum(r.covers(truth) for r in results)
    assert all(r.reached and r.confidence == CONFIDENCE for r in results)
    assert consistent(values, [r.interval for r in results], truth), \
        f"{covered}/{SEEDS} intervals cover {truth:.3e}, mean {values.mean():.3e}"
    # the stated c.o.v. is the spread seen over seeds, within a factor 1.6
    assert 1 / 1.6 < np.mean([r.cov for r in results]) / (values.std(ddof=1) / truth) < 1.6
    if method == "subset":
        assert all(r.n_simulations <= 1000 + 7 * 900 for r in results)


@pytest.mark.parametrize("name", ["linear-1000", "union"])
def test_widened_mixture_covers_the_truth_and_keeps_its_weights_in_high_dimension(name):
    """Components widened along their design directions (spread 1.5): unbiased, covering at their confidence
    over seeds, and in d = 1000 the weights stay as tame as in d = 2 (the ratio sees the projections only)."""
    problem = PROBLEMS[name]
    results = [rare.importance_sampling(problem, problem.d, jax.random.key(seed), spread=1.5, **IS_DEFAULT)
               for seed in range(SEEDS)]
    values = np.array([r.estimate for r in results])
    assert all(r.reached for r in results)
    assert consistent(values, [r.interval for r in results], problem.truth)
    assert 1 / 1.6 < np.mean([r.cov for r in results]) / (values.std(ddof=1) / problem.truth) < 1.6
    assert np.mean([r.cov for r in results]) < 0.2  # 500 samples: a working proposal, not a degenerate one


def test_mixture_density_against_scipy_and_its_draws_against_their_law():
    """ln(phi / q) of the mixture against scipy's multivariate normal densities with the covariances
    I + (s^2 - 1) a a^T; draws of one component: a.u ~ N(beta, s^2), the orthogonal part N(0, I)."""
    from mcfdd.analysis.rare.importance import mixture_draw

    points = np.array([[3.0, 0.5, -1.0], [0.0, 2.5, 2.0], [9.0, 9.0, 9.0]])
    usable = np.array([True, True, False])
    s = 1.7
    u, log_ratio = mixture_draw(jnp.asarray(points), jnp.asarray(usable), jnp.float64, s)(jax.random.key(4), 4000)
    u, log_ratio = np.asarray(u), np.asarray(log_ratio)
    beta = np.linalg.norm(points[:2], axis=1)
    w = norm.sf(beta) / norm.sf(beta).sum()
    q = sum(wk * multivariate_normal(c, np.eye(3) + (s * s - 1) * np.outer(c, c) / (c @ c)).pdf(u)
            for wk, c in zip(w, points[:2]))
    np.testing.assert_allclose(log_ratio, multivariate_normal(np.zeros(3), np.eye(3)).logpdf(u) - np.log(q),
                               rtol=1e-9, atol=1e-9)
    one, _ = mixture_draw(jnp.asarray(points[:1]), jnp.asarray([True]), jnp.float64, s)(jax.random.key(5), 4000)
    a = points[0] / beta[0]
    t = np.asarray(one) @ a
    assert kstest(t, norm(beta[0], s).cdf).pvalue > 1e-3
    across = np.asarray(one) - np.outer(t, a)
    assert kstest(across @ np.array([0.5, -3.0, 0.0]) / np.sqrt(9.25), "norm").pvalue > 1e-3


@pytest.mark.parametrize("bias", [1.5, 2.0])
def test_the_check_rejects_a_biased_estimator(bias):
    """Subset simulation's estimates scaled by 1.5 or 2, with intervals of their stated c.o.v., fail the check."""
    truth = PROBLEMS["linear-100"].truth
    results = [run("subset", "linear-100", seed) for seed in range(SEEDS)]
    assert consistent([r.estimate for r in results], [r.interval for r in results], truth)
    biased = [bias * r.estimate for r in results]
    intervals = [interval(b, r.cov, CONFIDENCE, "lognormal", r.dof) for b, r in zip(biased, results)]
    assert not consistent(biased, intervals, truth)
    if bias == 2.0:  # coverage alone already fails
        assert not coverage_consistent(sum(lo <= truth <= hi for lo, hi in intervals), SEEDS, CONFIDENCE)


def test_monte_carlo_intervals_cover_and_bound_with_no_hit():
    problem = Linear(3, beta=2.0)
    results = [rare.monte_carlo(problem, 3, jax.random.key(s), n=4000, batch=1000) for s in range(SEEDS)]
    assert coverage_consistent(sum(r.covers(problem.truth) for r in results), SEEDS, CONFIDENCE)
    assert all(r.hits == round(r.estimate * 4000) and r.n_simulations == 4000 for r in results)
    assert all(np.all(r.failure_margins > 0) and len(r.failure_points) == 16 for r in results)
    none = rare.monte_carlo(Linear(3, beta=9.0), 3, jax.random.key(0), n=4000, batch=1000)
    assert none.hits == 0 and none.estimate == 0.0 and none.cov == np.inf
    assert none.interval == pytest.approx((0.0, 1.0 - 0.025 ** (1 / 4000)), rel=1e-9)  # Clopper-Pearson, k = 0
    assert none.failure_points.shape == (0, 3)


# --------------------------------------------------------------------------------------------
# The pieces


def test_conditional_moves_keep_the_standard_normal_law():
    """In d = 500: free moves keep N(0, 1) marginals; conditioned on a.u > b, a.u stays truncated normal.

    The conditioned chains start off the law (a.u folded and shifted above b) and must reach it.
    """
    d, m, b = 500, 2000, 1.0
    key = jax.random.key(3)
    u = jax.random.normal(key, (m, d))
    a = np.ones(d) / np.sqrt(d)

    def g(x):
        return x @ a

    @jax.jit
    def chains(x, y):
        def move(carry, t):
            x, gx, y, gy = carry
            x, gx, _ = rare.conditional_move(g, x, gx, -jnp.inf, 0.6, jax.random.fold_in(key, 2 * t + 1))
            y, gy, _ = rare.conditional_move(g, y, gy, b, 0.6, jax.random.fold_in(key, 2 * t + 2))
            return (x, gx, y, gy), None

        return jax.lax.scan(move, (x, g(x), y, g(y)), jnp.arange(60))[0]

    start = u + (jnp.abs(u @ a) + b - u @ a)[:, None] * a
    x, _, y, gy = chains(u, start)
    assert kstest(np.asarray(x[:, :5]).ravel(), "norm").pvalue > 1e-3
    assert np.all(np.asarray(gy) > b)
    assert kstest(np.asarray(gy), truncnorm(b, np.inf).cdf).pvalue > 1e-3
    orth = np.asarray(y[:, 1] - y[:, 0]) / np.sqrt(2.0)  # a direction orthogonal to a
    assert kstest(orth, "norm").pvalue > 1e-3


@pytest.mark.parametrize("name", list(PROBLEMS))
def test_design_points_against_closed_forms(name):
    problem = PROBLEMS[name]
    starts, screening = (64, 2048) if name == "first-passage" else (8, 128)
    found = rare.design_points(problem, problem.d, jax.random.key(0), starts=starts, screening=screening)
    points = found.points[found.distinct]
    assert np.all(np.abs(found.margin[found.converged]) < 1e-8)
    for p in points:  # every point found is one of the closed-form design points
        assert min(np.linalg.norm(p - q) for q in problem.design) < 1e-5
    truth = np.array(sorted(problem.design, key=np.linalg.norm))
    wanted = truth if name != "first-passage" else truth[:8]  # the crossings that matter most
    for q in wanted:
        assert min(np.linalg.norm(p - q) for p in points) < 1e-5
    assert np.allclose(found.beta[found.distinct], np.linalg.norm(points, axis=1))


def test_same_key_same_estimate_to_the_last_bit():
    moderate = Linear(2, beta=2.0)
    for problem, estimator, options in ((PROBLEMS["union"], rare.subset_simulation, dict(n=500)),
                                        (PROBLEMS["union"], rare.importance_sampling, IS_DEFAULT),
                                        (moderate, rare.monte_carlo, dict(n=2000, batch=500))):
        one = estimator(problem, 2, jax.random.key(7), **options)
        two = estimator(problem, 2, jax.random.key(7), **options)
        other = estimator(problem, 2, jax.random.key(8), **options)
        assert (one.estimate, one.cov, one.interval) == (two.estimate, two.cov, two.interval)
        np.testing.assert_array_equal(np.array(one.levels), np.array(two.levels))  # nan where nan
        np.testing.assert_array_equal(one.failure_points, two.failure_points)
        assert other.estimate != one.estimate


@pytest.mark.parametrize("estimator", ["subset", "importance", "monte_carlo"])
def test_one_compilation_per_run_and_none_for_a_new_key(estimator):
    problem = Linear(5, beta=3.0)  # a new g: nothing cached
    fn = {"subset": lambda k: rare.subset_simulation(problem, 5, k, n=200, chunk=50),
          "importance": lambda k: rare.importance_sampling(problem, 5, k, n=200, batch=50, starts=4, screening=32),
          "monte_carlo": lambda k: rare.monte_carlo(problem, 5, k, n=1000, batch=250)}[estimator]
    keys = jax.random.key(0), jax.random.key(1)
    with CompileCounter() as first:
        fn(keys[0])
    with CompileCounter() as second:
        fn(keys[1])
    assert (first.count, second.count) == (1, 0)


def test_chunks_do_not_change_the_estimate():
    problem = PROBLEMS["linear-100"]
    whole = rare.subset_simulation(problem, 100, jax.random.key(2), n=1000)  # compiled by the coverage test
    chunked = rare.subset_simulation(problem, 100, jax.random.key(2), n=1000, chunk=64)
    assert whole.estimate == chunked.estimate
    np.testing.assert_array_equal(np.array(whole.levels), np.array(chunked.levels))


def test_level_cap_gives_an_upper_bound():
    problem = Linear(4, beta=6.0)  # P = 9.9e-10, out of reach of two levels
    capped = rare.subset_simulation(problem, 4, jax.random.key(0), n=500, max_levels=2)
    assert not capped.reached and capped.hits == 0 and capped.estimate == pytest.approx(1e-2)
    assert capped.interval[0] == 0.0 and capped.interval[1] > problem.truth
    assert len(capped.levels) == 2 and capped.levels[-1].threshold < 0
    assert capped.n_simulations == 500 + 2 * 450


# --------------------------------------------------------------------------------------------
# Strata, flight hours, airframes


def test_strata_and_per_flight_hour():
    """Three strata g = u_0 - beta_s (beta traced: one compilation): combined against sum w_s Phi(-beta_s)."""
    betas, weights, scored = np.array([3.5, 4.0, 4.5]), np.array([0.5, 0.3, 0.2]), 50.0

    def g(u, beta):
        return u[:, 0] - beta

    truth = float(weights @ norm.sf(betas))
    covered_delta = covered_union = 0
    for seed in range(20):
        keys = jax.random.split(jax.random.key(seed), 3)
        per = [rare.subset_simulation(g, 3, k, n=500, args=(b,)) for k, b in zip(keys, betas)]
        combined = rare.stratified(per, weights)
        union = rare.stratified(per, weights, interval_kind="union")
        assert combined.estimate == pytest.approx(sum(w * e.estimate for w, e in zip(weights, per)))
        sd = np.sqrt(sum((w * e.cov * e.estimate) ** 2 for w, e in zip(weights, per)))
        assert combined.cov == pytest.approx(sd / combined.estimate)
        assert union.interval[0] <= combined.interval[0] and union.interval[1] >= combined.interval[1]
        covered_delta += combined.covers(truth)
        covered_union += union.covers(truth)
        rate = rare.per_flight_hour(per, weights, scored)
        assert rate.estimate == pytest.approx(combined.estimate * 3600 / scored)
        assert rate.interval == pytest.approx(tuple(x * 3600 / scored for x in combined.interval))
    assert coverage_consistent(covered_delta, 20, CONFIDENCE) and covered_union >= 19


def test_certification_classes_and_bad_weights():
    assert (rare.MAJOR, rare.HAZARDOUS, rare.CATASTROPHIC) == (1e-5, 1e-7, 1e-9)
    mc = rare.monte_carlo(Linear(2, beta=9.0), 2, jax.random.key(0), n=10_000, batch=10_000)
    rate = rare.per_flight_hour([mc], [1.0], 60.0, interval_kind="union")
    assert rate.interval[1] == pytest.approx(mc.interval[1] * 60.0)  # 3/n per run: 0.02 per hour
    assert rare.certification_class(rate) is None
    tiny = rare.per_flight_hour([run("subset", "linear-2", 0)], [1.0], 3600.0)
    assert rare.certification_class(tiny) == "major"
    with pytest.raises(ValueError, match="summing to 1"):
        rare.per_flight_hour([mc, mc], [0.5, 0.6], 60.0)
    with pytest.raises(ValueError, match="interval_kind='union'"):
        rare.per_flight_hour([mc], [1.0], 60.0)
    with pytest.raises(ValueError, match="scored seconds"):
        rare.per_flight_hour([mc], [1.0], 0.0)


def test_per_airframe_probability_worst_corner_and_quantile():
    """g = theta + (v_0 + v_1) / sqrt(2) - c: P(F | theta) = Phi(theta - c)."""
    c = 5.0

    def g(u):
        return u[:, 0] + (u[:, 1] + u[:, 2]) / np.sqrt(2.0) - c

    corners = rare.corners(1, 0.5)
    view = rare.airframes(g, 3, 1, corners, jax.random.key(0), n=1000)
    assert corners.tolist() == [[-0.5], [0.5]] and view.worst == 1
    for theta, est in zip(corners[:, 0], view.estimates):
        assert est.covers(norm.cdf(theta - c))
    draws = np.asarray(jax.random.normal(jax.random.key(1), (30, 1)))
    with CompileCounter() as compiles:
        spread = rare.airframes(g, 3, 1, draws, jax.random.key(2), quantile=0.5, n=1000)
    assert compiles.count == 0  # the same conditional problem as above: theta is traced
    assert spread.interval[0] <= norm.cdf(0.0 - c) <= spread.interval[1]
    assert spread.interval[0] <= spread.value <= spread.interval[1]


def test_conditional_fixes_the_named_coordinates_anywhere_in_u():
    def g(u):
        return u @ jnp.arange(1.0, 6.0) + u[:, 0] * u[:, 3]

    u = np.asarray(jax.random.normal(jax.random.key(3), (7, 5)))
    index, free = (3, 1), [0, 2, 4]
    cond = rare.exposure.Conditional(g, index)
    for row in u:  # theta (the coordinates 3 and 1 in that order) set, the rest from v
        np.testing.assert_array_equal(cond(jnp.asarray(u[:, free]), row[list(index)]),
                                      g(jnp.asarray(np.where(np.isin(np.arange(5), index), row, u))))
    with pytest.raises(ValueError, match="distinct coordinates"):
        rare.airframes(g, 5, (1, 1), np.zeros((2, 2)), jax.random.key(0))


def _estimate(p, cov, method="subset", kind="lognormal"):
    return rare.Estimate(method, p, cov, (p / 2, p * 2), 0.95, kind, 1000, 10, failure_points=np.zeros((1, 2)),
                         failure_margins=np.ones(1))


def test_repeated_runs_take_the_larger_of_their_own_and_their_spreads_cov():
    """Closed forms: Monte Carlo runs pool their hits exactly; runs that understate their c.o.v. get the spread's."""
    mc = [rare.monte_carlo(Linear(2, beta=2.0), 2, jax.random.key(i), n=2000, batch=2000) for i in range(3)]
    pooled = rare.repeated(mc)
    hits = sum(e.hits for e in mc)
    assert (pooled.hits, pooled.n_simulations, pooled.estimate) == (hits, 6000, hits / 6000)
    ci = binomtest(hits, 6000).proportion_ci(0.95)
    assert pooled.interval == pytest.approx((ci.low, ci.high))
    values = np.array([1e-6, 4e-6, 2e-7, 8e-7])
    tight = rare.repeated([_estimate(v, 0.1) for v in values])
    s2 = np.var(np.log(values), ddof=1)
    assert tight.estimate == pytest.approx(values.mean())
    assert tight.cov == pytest.approx(np.sqrt(np.expm1(s2) / 4)) and tight.dof == 3
    z = student_t.ppf(0.975, 3)
    s = np.sqrt(np.log1p(tight.cov ** 2))
    mean = values.mean()
    assert tight.interval == pytest.approx((mean * np.exp(s * s / 2 - z * s), mean * np.exp(s * s / 2 + z * s)))
    honest = rare.repeated([_estimate(v, 3.0) for v in values])  # their own c.o.v. is the larger: the delta method
    assert honest.cov == pytest.approx(np.sqrt(np.sum((3.0 * values) ** 2)) / 4 / mean) and np.isinf(honest.dof)
    two = rare.repeated([_estimate(v, 0.1) for v in values[:2]])  # too few runs for a spread
    assert two.cov == pytest.approx(np.sqrt(np.sum((0.1 * values[:2]) ** 2)) / 2 / values[:2].mean())


def test_repeated_subset_runs_cover_the_truth_at_their_confidence():
    """40 seeds x 4 runs of n = 500 on the linear limit state at P = 1e-4 (d = 50)."""
    beta = 3.719
    truth = float(norm.sf(beta))
    problem = Linear(50, beta=beta)
    covered, logs, stated = 0, [], []
    for seed in range(40):
        runs = [rare.subset_simulation(problem, 50, jax.random.fold_in(jax.random.key(seed), r), n=500)
                for r in range(4)]
        pooled = rare.repeated(runs)
        covered += pooled.covers(truth)
        logs.append(np.log(pooled.estimate))
        stated.append(np.sqrt(np.log1p(pooled.cov ** 2)))
    assert coverage_consistent(covered, 40, CONFIDENCE)
    assert 0.7 < np.std(logs, ddof=1) / np.mean(stated) < 1.4


def test_bad_input_gets_a_clear_error():
    problem = Linear(3)
    with pytest.raises(ValueError, match=r"g must map u of shape \(n, d\) to \(n,\)"):
        rare.subset_simulation(lambda u: u, 3, jax.random.key(0))
    with pytest.raises(ValueError, match="p0 \\* n must be an integer"):
        rare.subset_simulation(problem, 3, jax.random.key(0), n=1005)
    with pytest.raises(ValueError, match="dimension d"):
        rare.monte_carlo(problem, 0, jax.random.key(0))
    with pytest.raises(ValueError, match="batch must"):
        rare.monte_carlo(problem, 3, jax.random.key(0), n=1000, batch=300)
    with pytest.raises(ValueError, match="spread must be positive"):
        rare.importance_sampling(problem, 3, jax.random.key(0), spread=0.0)
    with pytest.raises(ValueError, match=r"start points must be an array \(k, 3\)"):
        rare.importance_sampling(problem, 3, jax.random.key(0), starts=np.zeros((2, 4)))
    with pytest.raises(ValueError, match="bracket"):
        rare.exposure.quantile_ranks(5, 0.99, 0.95)

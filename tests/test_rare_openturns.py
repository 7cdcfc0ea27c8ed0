"""The rare-event estimators against OpenTURNS on the same limit states (an independent implementation).

OpenTURNS' ``SubsetSampling`` (its own Markov chains and levels) and its FORM (``AbdoRackwitz``)
followed by ``ProbabilitySimulationAlgorithm`` with an ``ImportanceSamplingExperiment`` around its
design points (a Gaussian mixture when there are two) run on the linear limit states in d = 2 and
100, the union of two half-planes and the AR(1) first passage of ``test_rare``. Each pair of
estimates agrees: the intervals overlap, the log-ratio of the two estimates is within 2.58
combined standard deviations, and ours contains the closed-form probability (OpenTURNS' need not:
its subset sampling interval is normal and, like ours, one draw of a random interval). OpenTURNS'
FORM design points equal ours.
"""

import jax
import numpy as np
import openturns as ot
import pytest
from scipy.stats import norm

from mcfdd.analysis import rare
from rare_problems import PROBLEMS


def ot_event(problem):
    """OpenTURNS' event {g(X) > 0}, X ~ N(0, I_d), g evaluated on whole samples through NumPy."""
    d = problem.d

    def g_sample(x):
        return np.asarray(problem(np.asarray(x)))[:, None]

    model = ot.PythonFunction(d, 1, func_sample=g_sample)
    model.setGradient(ot.CenteredFiniteDifferenceGradient(1e-6, model.getEvaluation()))
    output = ot.CompositeRandomVector(model, ot.RandomVector(ot.Normal(d)))
    return ot.ThresholdEvent(output, ot.Greater(), 0.0)


def ot_interval(result, confidence=0.95):
    """Estimate, c.o.v. and the normal interval OpenTURNS' result implies."""
    p, cov = result.getProbabilityEstimate(), result.getCoefficientOfVariation()
    z = norm.ppf(0.5 + confidence / 2)
    return p, cov, (max(p * (1 - z * cov), 0.0), p * (1 + z * cov))


def ot_subset(problem, n, seed):
    ot.RandomGenerator.SetSeed(seed)
    algo = ot.SubsetSampling(ot_event(problem))
    algo.setMaximumOuterSampling(n)
    algo.setBlockSize(1)
    algo.setConditionalProbability(0.1)
    algo.run()
    return ot_interval(algo.getResult())


def ot_design_point(problem, start):
    solver = ot.AbdoRackwitz()
    solver.setStartingPoint(ot.Point(start))
    form = ot.FORM(solver, ot_event(problem))
    form.run()
    return np.array(form.getResult().getStandardSpaceDesignPoint())


def ot_importance(problem, points, n, seed):
    ot.RandomGenerator.SetSeed(seed)
    d = problem.d
    parts = [ot.Normal(ot.Point(p), ot.CovarianceMatrix(d)) for p in points]
    proposal = parts[0] if len(parts) == 1 else ot.Mixture(parts, [norm.sf(np.linalg.norm(p)) for p in points])
    experiment = ot.ImportanceSamplingExperiment(proposal)
    algo = ot.ProbabilitySimulationAlgorithm(ot.StandardEvent(ot_event(problem)), experiment)
    algo.setMaximumOuterSampling(n // 100)
    algo.setBlockSize(100)
    algo.setMaximumCoefficientOfVariation(-1.0)
    algo.run()
    return ot_interval(algo.getResult())


def agree(ours, theirs, truth):
    """The intervals overlap, the estimates differ by < 2.58 combined sds in log, ours holds the truth."""
    p_ot, cov_ot, (lo_ot, hi_ot) = theirs
    print(f"ours {ours.estimate:.3e} ({ours.interval[0]:.3e}, {ours.interval[1]:.3e}), {ours.n_simulations} runs; "
          f"OpenTURNS {p_ot:.3e} ({lo_ot:.3e}, {hi_ot:.3e}); truth {truth:.3e}")
    assert ours.covers(truth)
    assert ours.interval[0] <= hi_ot and lo_ot <= ours.interval[1]
    spread = np.sqrt(np.log1p(ours.cov ** 2) + np.log1p(cov_ot ** 2))
    assert abs(np.log(ours.estimate / p_ot)) < 2.58 * spread


@pytest.mark.parametrize("name", ["linear-2", "linear-100", "union", "first-passage"])
def test_subset_simulation_agrees_with_openturns(name):
    problem = PROBLEMS[name]
    ours = rare.subset_simulation(problem, problem.d, jax.random.key(11), n=2000)
    agree(ours, ot_subset(problem, 2000, 11), problem.truth)


@pytest.mark.parametrize("name", ["linear-2", "linear-100", "union"])
def test_importance_sampling_agrees_with_openturns_form_and_importance_sampling(name):
    problem = PROBLEMS[name]
    ours = rare.importance_sampling(problem, problem.d, jax.random.key(12), n=1000, starts=8, screening=128,
                                    iterations=10)
    # OpenTURNS' FORM from a start near each closed-form design point finds the same points as ours
    theirs_points = [ot_design_point(problem, 0.5 * q) for q in problem.design]
    assert len(ours.design_points) == len(theirs_points)
    for q in theirs_points:
        assert min(np.linalg.norm(p - q) for p in ours.design_points) < 1e-4 * max(1.0, np.linalg.norm(q))
    agree(ours, ot_importance(problem, theirs_points, 1000, 12), problem.truth)

"""Rare-event probabilities of an event g(u) > 0 on a standard-normal space (DESIGN.md section 5c).

Every random input of a run is a deterministic function of standard-normal coordinates
u ~ N(0, I_d), and an event (a false alarm, a missed detection) is F = {g(u) > 0}, with g a signed
margin. The estimators take any batched, JAX-traceable ``g(u, *args)``, (n, d) -> (n,), the
dimension d (a noise path of 6,000 steps of a few channels is d ~ 2e4: the Markov chains keep
N(0, I_d) invariant in any dimension) and a ``jax.random`` key, and return an
:class:`~mcfdd.analysis.rare.estimate.Estimate`: P(F), its coefficient of variation, an interval,
the simulations spent, the levels and the failure points found.

- :func:`subset_simulation` (default; Au and Beck 2001, adaptive conditional sampling of
  Papaioannou et al. 2015, the pCN move of Cotter et al. 2013): about n (1 + 0.9 log10(1/P))
  simulations;
- :func:`importance_sampling` around the design points found by damped HLRF with JAX gradients
  (Rackwitz and Fiessler 1978; Zhang and Der Kiureghian 1995);
- :func:`monte_carlo`, the baseline, with exact intervals;
- :func:`repeated` pools independent runs (its c.o.v. checked by their spread), :func:`stratified` and
  :func:`combine` over strata, :func:`per_flight_hour` and the AMC 25.1309
  classes, :func:`airframes` for P(F | parameters fixed per aircraft).

Each estimator run is one compiled program (``lax`` loops over levels, chain steps and sample
batches; g is a static argument, so a second run with the same g, sizes and options, or new
``args``, compiles nothing) and gives the same estimate to the last bit for the same key.
"""

from mcfdd.analysis.rare.estimate import Estimate, Level, combine, repeated, stratified
from mcfdd.analysis.rare.exposure import (
                                          CATASTROPHIC,
                                          CLASSES,
                                          HAZARDOUS,
                                          MAJOR,
                                          Airframes,
                                          Conditional,
                                          airframes,
                                          certification_class,
                                          corners,
                                          per_flight_hour,
)
from mcfdd.analysis.rare.importance import DesignPoints, design_points, importance_sampling
from mcfdd.analysis.rare.sampling import monte_carlo
from mcfdd.analysis.rare.subset import conditional_move, subset_simulation

__all__ = ["CATASTROPHIC", "CLASSES", "HAZARDOUS", "MAJOR", "Airframes", "Conditional", "DesignPoints", "Estimate",
           "Level", "airframes", "certification_class", "combine", "conditional_move", "corners", "design_points",
           "importance_sampling", "monte_carlo", "per_flight_hour", "repeated", "stratified", "subset_simulation"]

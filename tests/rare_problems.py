"""Rare-event test problems with known probabilities near 1e-6 (shared by the rare-event test modules).

Each problem is a limit state g(u) on standard-normal coordinates with its dimension ``d``, its
true probability ``truth`` from an independent reference (closed form, scipy's bivariate normal
CDF, or the killed-density recursion below) and its design points.
"""

import jax.numpy as jnp
import numpy as np
from scipy.stats import multivariate_normal, norm

BETA_1E6 = float(-norm.ppf(1e-6))


class Linear:
    """g(u) = a.u - beta with a unit vector along the diagonal: P = Phi(-beta)."""

    def __init__(self, d, beta=BETA_1E6):
        self.d, self.beta, self.a = d, beta, np.ones(d) / np.sqrt(d)
        self.truth = float(norm.sf(beta))
        self.design = [beta * self.a]

    def __call__(self, u):
        return u @ self.a - self.beta


class Union:
    """max of two linear limit states in d = 2: P = P1 + P2 - P(both), the last by scipy's bivariate CDF."""

    d = 2
    a1, a2, b1, b2 = np.array([1.0, 0.0]), np.array([0.6, 0.8]), 4.9, 5.0

    def __init__(self):
        rho = float(self.a1 @ self.a2)
        both = multivariate_normal([0.0, 0.0], [[1.0, rho], [rho, 1.0]]).cdf([-self.b1, -self.b2])
        self.truth = float(norm.sf(self.b1) + norm.sf(self.b2) - both)
        self.design = [self.b1 * self.a1, self.b2 * self.a2]

    def __call__(self, u):
        return jnp.maximum(u @ self.a1 - self.b1, u @ self.a2 - self.b2)


def killed_density_crossing(phi, s, steps, level, m=2000):
    """P(max_{t<=steps} x_t > level) for x_0 = 0, x_t = phi x_{t-1} + s xi_t, xi_t ~ N(0, 1).

    Recursion on a trapezoid grid of the density of x_t on paths that have not crossed yet:
    P = sum_t P(first crossing at t) = P(x_1 > level) + sum_{t>=2} int_{x<level} f_{t-1}(x) P(phi x + s xi > level) dx.
    """
    x = np.linspace(-12.0 * s / np.sqrt(1.0 - phi * phi), level, m)
    w = np.full(m, x[1] - x[0])
    w[[0, -1]] /= 2.0
    dens = norm.pdf(x, 0.0, s)
    total = norm.sf(level, 0.0, s)
    for _ in range(steps - 1):
        total += np.sum(w * dens * norm.sf(level, phi * x, s))
        dens = norm.pdf(x[:, None], phi * x[None, :], s) @ (w * dens)
    return float(total)


class FirstPassage:
    """AR(1) path of 16 steps driven by u crossing 5.25 stationary standard deviations."""

    d, phi, s = 16, 0.8, 0.6

    def __init__(self, sigmas=5.25):
        t = np.arange(self.d)
        self.paths = np.where(t[:, None] >= t[None], self.s * self.phi ** (t[:, None] - t[None]), 0.0)
        self.level = sigmas * self.s / np.sqrt(1.0 - self.phi ** 2)
        self.truth = killed_density_crossing(self.phi, self.s, self.d, self.level)
        # the design point of a crossing at step t: the smallest u with (L u)_t = level
        self.design = [self.level * row / (row @ row) for row in self.paths]

    def __call__(self, u):
        return jnp.max(u @ self.paths.T, axis=1) - self.level


PROBLEMS = {"linear-2": Linear(2), "linear-100": Linear(100), "linear-1000": Linear(1000), "union": Union(),
            "first-passage": FirstPassage()}

"""Fitting the LPV gain models of eq. (4) to the nonlinear actuator (Section 3).

The starting point is a gain match: for each fault model nu^(i), the small-error gain of the
nonlinear actuator, ``K = Kci Kp sqrt((nu1 dP - nu2 s F_aero(p, x) / S) / dP_ref)``, sampled over
the envelope (Vcas, h below the Mach limit), the deflection range and both directions, is
fitted by linear least squares with the 12 coefficients of eq. (4).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.fdd import lpv
from mcfdd.plant import actuator, atmosphere, closed_loop, hinge


def envelope_grid(vcas_m_s, altitude_m, max_mach: float):
    """Flight points (Vcas, h) of a grid below the Mach limit, as two flat arrays."""
    v, h = np.meshgrid(np.asarray(vcas_m_s, float), np.asarray(altitude_m, float), indexing="ij")
    keep = np.asarray(atmosphere.mach(v, h)) <= max_mach
    return v[keep], h[keep]


def small_error_gain(model: closed_loop.PlantModel, nu, vcas_m_s, altitude_m, x_m, direction):
    """Gain of the nonlinear actuator for a vanishing error moving in ``direction`` (broadcasts)."""
    act = model.actuator
    at = jnp.vectorize(lambda v, h, d: hinge.interpolate(model.table, v, h, d))
    load = at(vcas_m_s, altitude_m, x_m / act.r_arm_m)
    pressure = actuator.available_pressure(act, nu[0], nu[1], load, direction)
    return act.kci_m_s_a * act.kp_a_m * jnp.sqrt(jnp.maximum(pressure, 0.0) / act.ref_pressure_pa)


def design_matrix(norm: lpv.Normalisation, vcas_m_s, altitude_m, x_m, direction):
    """Rows of the linear map from the 12 coefficients to k(rho), shape (n, 12)."""
    basis = np.asarray(lpv.scheduling(norm, vcas_m_s, altitude_m))
    xn = (np.asarray(x_m) / norm.x_scale_m)[:, None]
    s = np.asarray(direction)[:, None]
    return np.concatenate([basis, s * basis, xn * basis, xn * s * basis], axis=1)


def gain_match(model: closed_loop.PlantModel, nus, vcas_m_s, altitude_m, n_x: int = 21,
               norm: lpv.Normalisation | None = None) -> np.ndarray:
    """Least-squares coefficients (N, 4, 3) of the small-error gains on the given flight points."""
    x_max = model.actuator.r_arm_m * model.actuator.max_deflection_rad
    norm = norm or lpv.Normalisation(x_scale_m=x_max)
    x = np.linspace(-x_max, x_max, n_x)
    pts_v = np.repeat(np.asarray(vcas_m_s, float), n_x * 2)
    pts_h = np.repeat(np.asarray(altitude_m, float), n_x * 2)
    pts_x = np.tile(np.repeat(x, 2), len(vcas_m_s))
    pts_s = np.tile([-1.0, 1.0], len(vcas_m_s) * n_x)
    design = design_matrix(norm, pts_v, pts_h, pts_x, pts_s)
    out = []
    for nu in nus:
        k = np.asarray(jax.jit(small_error_gain)(model, jnp.asarray(nu), pts_v, pts_h, pts_x, pts_s))
        coef, *_ = np.linalg.lstsq(design, k, rcond=None)
        out.append(coef.reshape(4, 3))
    return np.stack(out)


def default_bank(model: closed_loop.PlantModel, max_mach: float = 0.82) -> tuple[lpv.GainBank, tuple[str, ...]]:
    """The six models of Section 6.1 by gain matching over a default envelope grid."""
    v, h = envelope_grid(np.linspace(80.0, 420.0, 18) * atmosphere.KT_TO_M_S, np.linspace(0.0, 12000.0, 13), max_mach)
    names = tuple(name for name, _ in lpv.PAPER_MODELS)
    nus = np.array([nu for _, nu in lpv.PAPER_MODELS])
    x_max = model.actuator.r_arm_m * model.actuator.max_deflection_rad
    norm = lpv.Normalisation(x_scale_m=x_max)
    coef = gain_match(model, nus, v, h, norm=norm)
    return lpv.make_bank(coef, nus, coef[:, 0, 0], norm), names

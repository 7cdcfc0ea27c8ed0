"""LPV gain models of the actuator, eqs. (3)-(4), and the bank of fault models of Section 6.1.

For fault model nu^(i) the actuator is approximated by ``xdot = k^(i)(rho) (u_c - x)`` with

    k(rho) = C0(p) + C1(p) s + xn (C2(p) + C3(p) s),   s = sgn(xdot),   xn = x / x_scale

and each C_j affine in the flight parameters p = (Vcas, h):
``C_j(p) = c_j0 + c_j1 vn + c_j2 hn`` with ``vn = (Vcas - v_ref) / v_scale``,
``hn = (h - h_ref) / h_scale``. The normalisation keeps the 12 coefficients per model of the
order of the gain (1/s). On board, rho is formed from measured signals only: x -> measured u,
s = sgn(u_c - u) (for a first-order model sgn(xdot) = sgn(u_c - x)).

A bank is a pytree (arrays with a leading model axis) plus names; :func:`to_dict` and
:func:`from_dict` give its versioned JSON form (files are read and written by :mod:`mcfdd.io`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

FORMAT = "mcfdd.lpv-bank"
FORMAT_VERSION = 1
COEFFICIENT_NAMES = ("C0", "C1", "C2", "C3")
AFFINE_TERMS = ("const", "vcas", "altitude")

class Normalisation(NamedTuple):
    """Scheduling-variable normalisation: SI reference values and scales."""

    vcas_ref_m_s: float = 130.0
    vcas_scale_m_s: float = 50.0
    altitude_ref_m: float = 5000.0
    altitude_scale_m: float = 5000.0
    x_scale_m: float = 0.0229


class GainBank(NamedTuple):
    """Gain models of N fault models.

    coef: (N, 4, 3) coefficients c_jm (1/s), j over (C0..C3), m over (const, vcas, altitude)
    nu:   (N, 2) fault parameters (nu1, nu2) each model stands for
    k0:   (N,) nominal gain of each model (1/s), the detector scaling of eq. (20)
    """

    coef: jnp.ndarray
    nu: jnp.ndarray
    k0: jnp.ndarray
    norm: Normalisation


def scheduling(norm: Normalisation, vcas_m_s, altitude_m):
    """Affine basis (1, vn, hn) of the flight parameters, shape (..., 3)."""
    vn = (vcas_m_s - norm.vcas_ref_m_s) / norm.vcas_scale_m_s
    hn = (altitude_m - norm.altitude_ref_m) / norm.altitude_scale_m
    return jnp.stack([jnp.ones_like(vn), vn, hn], axis=-1)


def gains(bank: GainBank, x_m, direction, vcas_m_s, altitude_m):
    """k^(i)(rho) for all models, shape (N,), from rod position, sgn(xdot) and flight point."""
    c = bank.coef @ scheduling(bank.norm, vcas_m_s, altitude_m)  # (N, 4)
    xn = x_m / bank.norm.x_scale_m
    return c[:, 0] + c[:, 1] * direction + xn * (c[:, 2] + c[:, 3] * direction)


def constant_coefficients(k_1_s: float) -> np.ndarray:
    """Coefficients (4, 3) of a constant gain, e.g. the exact gain of eq. (36)."""
    coef = np.zeros((4, 3))
    coef[0, 0] = k_1_s
    return coef


def make_bank(coefficients, nu, k0, norm: Normalisation = Normalisation(), dtype=np.float32) -> GainBank:
    arrays = jax.device_put(tuple(np.asarray(a, dtype) for a in (coefficients, nu, k0)))  # no compile, unlike jnp
    return GainBank(*arrays, norm)


def to_dict(bank: GainBank, names, extra: dict | None = None) -> dict:
    """Versioned plain-data form of a bank (JSON-ready)."""
    coef = np.asarray(bank.coef, dtype=float)
    models = []
    for i, name in enumerate(names):
        models.append({
            "name": name,
            "nu": [float(v) for v in np.asarray(bank.nu[i])],
            "k0_1_s": float(bank.k0[i]),
            "coefficients_1_s": {cn: dict(zip(AFFINE_TERMS, map(float, coef[i, j]))) for j, cn in
                                 enumerate(COEFFICIENT_NAMES)},
        })
    out = {"format": FORMAT, "version": FORMAT_VERSION, "normalisation": bank.norm._asdict(), "models": models}
    if extra:
        out.update(extra)
    return out


def from_dict(data: dict, dtype=np.float32) -> tuple[GainBank, tuple[str, ...]]:
    """Inverse of :func:`to_dict`; checks format and version. Returns (bank, model names)."""
    if data.get("format") != FORMAT:
        raise ValueError(f"not an LPV bank: format is {data.get('format')!r}, expected {FORMAT!r}")
    if data.get("version") != FORMAT_VERSION:
        raise ValueError(f"LPV bank version {data.get('version')!r} is not supported (expected {FORMAT_VERSION})")
    models = data["models"]
    if len(models) < 2:
        raise ValueError(f"an LPV bank needs the fault-free model and at least one fault model, not {len(models)}")
    coef = np.array([[[m["coefficients_1_s"][cn][t] for t in AFFINE_TERMS] for cn in COEFFICIENT_NAMES]
                     for m in models])
    nu = np.array([m["nu"] for m in models])
    k0 = np.array([m["k0_1_s"] for m in models])
    norm = Normalisation(**data["normalisation"])
    return make_bank(coef, nu, k0, norm, dtype), tuple(m["name"] for m in models)

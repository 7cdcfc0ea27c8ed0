"""ISA atmosphere and calibrated airspeed to dynamic pressure (DESIGN.md section 3).

The flight parameters p = (Vcas, h) of the paper's eq. (2) enter the hinge load through the
dynamic pressure. Calibrated airspeed is converted with the compressible (subsonic) pitot
relation:

    qc = p0 ((1 + 0.2 (Vcas / a0)^2)^3.5 - 1)
    M  = sqrt(5 ((qc / p + 1)^(2/7) - 1))
    qbar = 0.7 p M^2

All functions take and return SI units (m, m/s, Pa, K) and broadcast over arrays. They compute
with ``jax.numpy`` on JAX arrays (traced in the step) and with NumPy on host numbers (the set-up:
the hinge table, the design's Mach limit, configuration checks), so the set-up compiles nothing.
"""

from __future__ import annotations

import numpy as np

from mcfdd.arrays import array_module

P0_PA = 101325.0
T0_K = 288.15
RHO0_KG_M3 = 1.225
LAPSE_K_M = 0.0065
G0_M_S2 = 9.80665
R_J_KG_K = 287.05287
GAMMA = 1.4
TROPOPAUSE_M = 11000.0
A0_M_S = float((GAMMA * R_J_KG_K * T0_K) ** 0.5)
KT_TO_M_S = 1852.0 / 3600.0
FT_TO_M = 0.3048


def isa_temperature(altitude_m):
    """ISA temperature (K) up to 20 km, shaped like ``altitude_m``."""
    xp = array_module(altitude_m)
    h = xp.asarray(altitude_m)
    return xp.where(h < TROPOPAUSE_M, T0_K - LAPSE_K_M * h, T0_K - LAPSE_K_M * TROPOPAUSE_M)


def isa(altitude_m, temperature_k=None):
    """International Standard Atmosphere up to 20 km.

    Returns (temperature K, pressure Pa, density kg/m^3, speed of sound m/s), each shaped like
    ``altitude_m``. A caller that already holds :func:`isa_temperature` of ``altitude_m`` (a step
    that keeps it once) passes it as ``temperature_k``.
    """
    xp = array_module(altitude_m)
    h = xp.asarray(altitude_m)
    temperature = isa_temperature(h) if temperature_k is None else temperature_k
    t_trop = T0_K - LAPSE_K_M * TROPOPAUSE_M
    exponent = G0_M_S2 / (R_J_KG_K * LAPSE_K_M)
    p_trop = P0_PA * (t_trop / T0_K) ** exponent
    pressure = xp.where(
        h < TROPOPAUSE_M,
        P0_PA * (temperature / T0_K) ** exponent,
        p_trop * xp.exp(-G0_M_S2 * (h - TROPOPAUSE_M) / (R_J_KG_K * t_trop)),
    )
    density = pressure / (R_J_KG_K * temperature)
    sound = xp.sqrt(GAMMA * R_J_KG_K * temperature)
    return temperature, pressure, density, sound


def impact_pressure(vcas_m_s):
    """Pitot impact pressure qc (Pa) of a calibrated airspeed, subsonic."""
    v = array_module(vcas_m_s).asarray(vcas_m_s)
    return P0_PA * ((1.0 + 0.2 * (v / A0_M_S) ** 2) ** 3.5 - 1.0)


def mach(vcas_m_s, altitude_m):
    """Mach number of a calibrated airspeed (m/s) at a pressure altitude (m)."""
    _, pressure, _, _ = isa(altitude_m)
    qc = impact_pressure(vcas_m_s)
    ratio = qc / pressure + 1.0
    return array_module(ratio).sqrt(5.0 * (ratio ** (2.0 / 7.0) - 1.0))


def below_mach(vcas_m_s, altitude_m, max_mach: float):
    """Which points of the grid Vcas (n_v,) x altitude (n_h,) respect the Mach limit, (n_v, n_h) bool."""
    v, h = np.meshgrid(np.asarray(vcas_m_s, float), np.asarray(altitude_m, float), indexing="ij")
    return np.asarray(mach(v, h)) <= max_mach


def calibrated_airspeed(mach_number, altitude_m):
    """Calibrated airspeed (m/s) of a Mach number at an altitude: the pitot relations inverted."""
    return calibrated_airspeed_at_pressure(mach_number, isa(altitude_m)[1])


def calibrated_airspeed_at_pressure(mach_number, pressure_pa):
    """Calibrated airspeed (m/s) of a Mach number at a static pressure (Pa)."""
    xp = array_module(mach_number, pressure_pa)
    qc = pressure_pa * ((1.0 + 0.2 * xp.asarray(mach_number) ** 2) ** 3.5 - 1.0)
    return A0_M_S * xp.sqrt(5.0 * ((qc / P0_PA + 1.0) ** (2.0 / 7.0) - 1.0))


def flight_condition(vcas_m_s, altitude_m):
    """Dynamic pressure (Pa), Mach number and true airspeed (m/s) of a flight point."""
    _, pressure, _, sound = isa(altitude_m)
    m = mach(vcas_m_s, altitude_m)
    return 0.7 * pressure * m**2, m, m * sound


def dynamic_pressure(vcas_m_s, altitude_m):
    """Dynamic pressure qbar (Pa) of a calibrated airspeed (m/s) at an altitude (m)."""
    return flight_condition(vcas_m_s, altitude_m)[0]

"""Aerodynamic hinge load F_aero(p, x) of eq. (2), as a formula and as an on-board style table.

Hinge load of the healthy surface, converted to a rod force through the lever arm r_arm:

    F_aero = -qbar S_a c_a (C_h0 + C_halpha alpha + C_hdelta delta) / r_arm

positive when it opposes a positive deflection (C_hdelta < 0). The fault parameter nu2 is
applied once, in the actuator (DESIGN.md section 3). The paper says F_aero is only available as a
table, so the simulation interpolates a table over (Vcas, h, delta) built from the formula; the
formula stays the reference the table is tested against.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.compute import once
from mcfdd.plant import atmosphere


class HingeSurface(NamedTuple):
    """Control-surface geometry and hinge-moment coefficients (per rad)."""

    area_m2: float = 1.93
    chord_m: float = 0.58
    ch0: float = 0.0
    ch_alpha: float = -0.06
    ch_delta: float = -0.25


class HingeTable(NamedTuple):
    """Rod load F_aero (N) on uniform grids: ``load_n[i, j, k]`` at (vcas[i], altitude[j], delta[k])."""

    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray
    delta_rad: jnp.ndarray
    load_n: jnp.ndarray


def hinge_load(surface: HingeSurface, r_arm_m, qbar_pa, alpha_rad, delta_rad):
    """Rod force (N) of the hinge moment, formula of DESIGN.md section 3. Broadcasts."""
    ch = surface.ch0 + surface.ch_alpha * alpha_rad + surface.ch_delta * delta_rad
    return -qbar_pa * surface.area_m2 * surface.chord_m * ch / r_arm_m


def build_table(surface: HingeSurface, r_arm_m, alpha_of_qbar, vcas_m_s, altitude_m, delta_rad):
    """Tabulate the hinge load on uniform grids.

    ``alpha_of_qbar`` maps dynamic pressure (Pa) to the wing's trim angle of attack (rad); the grids
    are 1-D, uniformly spaced arrays. The table is computed in NumPy float64 (nothing compiled)
    and moved to the device once, at JAX's default float. Returns a :class:`HingeTable`.
    """
    grids = [np.asarray(g, dtype=np.float64) for g in (vcas_m_s, altitude_m, delta_rad)]
    v, h, d = np.meshgrid(*grids, indexing="ij")
    qbar = atmosphere.dynamic_pressure(v, h)
    load = hinge_load(surface, r_arm_m, qbar, alpha_of_qbar(qbar), d)
    return HingeTable(*jax.device_put((*grids, load)))


def _position(grid, value):
    """Position of ``value`` on a uniform grid in cells from its first node, clamped to the grid."""
    return jnp.clip((value - grid[0]) / (grid[1] - grid[0]), 0.0, grid.shape[0] - 1.0)


def _cell(grid, value):
    """Lower cell index and weight of ``value`` on a uniform grid, clamped to the grid."""
    pos = _position(grid, value)
    idx = jnp.minimum(jnp.floor(pos).astype(jnp.int32), grid.shape[0] - 2)
    return idx, pos - idx.astype(pos.dtype)


def flight_point_slice(table: HingeTable, vcas_m_s, altitude_m):
    """Bilinear interpolation of the table at one flight point: load over the delta grid, (nd,).

    The roll-axis simulation keeps the flight point of a run constant, so this is done once per
    scenario and :func:`interpolate_delta` runs in the step.
    """
    i, wv = _cell(table.vcas_m_s, vcas_m_s)
    j, wh = _cell(table.altitude_m, altitude_m)
    lo = table.load_n[i, j] * (1.0 - wh) + table.load_n[i, j + 1] * wh
    hi = table.load_n[i + 1, j] * (1.0 - wh) + table.load_n[i + 1, j + 1] * wh
    return lo * (1.0 - wv) + hi * wv


def interpolate_delta(delta_grid_rad, load_slice_n, delta_rad):
    """Linear interpolation of a flight-point slice at deflection ``delta_rad`` (clamped)."""
    return local_line(delta_grid_rad, load_slice_n, delta_rad)[0]


def local_line(delta_grid_rad, load_slice_n, delta_rad):
    """Interpolated load (N) at ``delta_rad`` and the slope (N/rad) of the table cell it lies in."""
    k, w = _cell(delta_grid_rad, delta_rad)
    lo, hi = load_slice_n[k], load_slice_n[k + 1]
    return lo + (hi - lo) * w, (hi - lo) / (delta_grid_rad[1] - delta_grid_rad[0])


def point_line(table: HingeTable, vcas_m_s, altitude_m, delta_rad, one=1.0):
    """:func:`local_line` of the slice at (Vcas, h), built from the two delta nodes of its cell only.

    The same numbers as ``local_line(table.delta_rad, flight_point_slice(table, vcas, h), delta)``
    for a flight point that moves every sample (the full aircraft): the 2 x 2 x 2 table entries
    around the point (one slice read) instead of the whole delta slice; the cells are computed
    once (``one``: :func:`mcfdd.compute.once`). Returns (load N, slope N/rad).
    """
    grids = (table.vcas_m_s, table.altitude_m, table.delta_rad)
    positions = once(tuple(_position(g, x) for g, x in zip(grids, (vcas_m_s, altitude_m, delta_rad))), one)
    # the lower node as a float (exact), so the index and the weight read the stored position only
    nodes = [jnp.minimum(jnp.floor(pos), g.shape[0] - 2.0) for pos, g in zip(positions, grids)]
    wv, wh, wd = once(tuple(pos - node for pos, node in zip(positions, nodes)), one)
    block = jax.lax.dynamic_slice(table.load_n, tuple(node.astype(jnp.int32) for node in nodes), (2, 2, 2))

    def node(k):  # the slice at the cell's delta node k (each node's four entries only)
        by_h = block[:, 0, k] * (1.0 - wh) + block[:, 1, k] * wh
        return by_h[0] * (1.0 - wv) + by_h[1] * wv

    lo, hi = once((node(0), node(1)), one)  # read by the load and the slope
    return lo + (hi - lo) * wd, (hi - lo) / (table.delta_rad[1] - table.delta_rad[0])


def interpolate(table: HingeTable, vcas_m_s, altitude_m, delta_rad):
    """Trilinear interpolation of the table (N) at one point."""
    return interpolate_delta(table.delta_rad, flight_point_slice(table, vcas_m_s, altitude_m), delta_rad)

"""Figures from tidy tables (the edge of the package). Every function returns a Figure."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure


def _shade(ax, t, mask, **kw):
    """Shade the intervals where ``mask`` is true."""
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    dt = t[1] - t[0] if len(t) > 1 else 0.0
    for i, (start, end) in enumerate(zip(edges[::2], edges[1::2])):
        ax.axvspan(t[start], t[end - 1] + dt, label=kw.pop("label", None) if i == 0 else None, **kw)


def run_timeseries(df: pd.DataFrame, title: str) -> Figure:
    """Command and measured deflection over time, available pressure below, stalls shaded."""
    t = df["t_s"].to_numpy()
    fig = Figure(figsize=(9, 6), constrained_layout=True)
    ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ax1.plot(t, df["u_c_deg"], label="command u_c", color="C0")
    ax1.plot(t, df["u_deg"], label="measured u", color="C1", lw=1.0)
    _shade(ax1, t, df["stall"], color="red", alpha=0.15, label="stall load")
    ax1.set_ylabel("deflection (deg)")
    ax1.legend(loc="upper right")
    ax1.set_title(title)
    ax1.grid(alpha=0.3)
    ax2.plot(t, df["dp_avail_norm"], color="C2")
    ax2.axhline(0.0, color="k", lw=0.8)
    _shade(ax2, t, df["stall"], color="red", alpha=0.15)
    ax2.set_ylabel("available pressure / dP")
    ax2.set_xlabel("time (s)")
    ax2.grid(alpha=0.3)
    return fig

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


def rates_by_stratum(summ: pd.DataFrame, group: str) -> Figure:
    """FAR and MDR with their exact 95 % intervals for each stratum of one grouping."""
    sub = summ[summ["group"] == group]
    fig = Figure(figsize=(9, 1.2 + 0.35 * len(sub)), constrained_layout=True)
    axes = fig.subplots(1, 2, sharey=True)
    y = np.arange(len(sub))
    for ax, (name, lo, hi, title) in zip(axes, (("far", "far_lo", "far_hi", "false-alarm rate"),
                                               ("mdr", "mdr_lo", "mdr_hi", "missed-detection rate"))):
        value = sub[name].to_numpy(dtype=float)
        err = np.vstack([value - sub[lo].to_numpy(dtype=float), sub[hi].to_numpy(dtype=float) - value])
        ax.errorbar(value, y, xerr=np.nan_to_num(err), fmt="o", capsize=3)
        ax.set_xlim(-0.02, 1.02)
        ax.set_title(f"{title} (95 % CI)")
        ax.grid(alpha=0.3)
    axes[0].set_yticks(y, sub["stratum"])
    axes[0].invert_yaxis()
    fig.suptitle(f"by {group}")
    return fig


def detection_times(df: pd.DataFrame, classes: pd.Series) -> Figure:
    """Distribution of detection latency per fault class (detected runs)."""
    detected = df["detected"].to_numpy(dtype=bool)
    labels = sorted(set(classes[detected]))
    fig = Figure(figsize=(9, 1.2 + 0.4 * max(len(labels), 1)), constrained_layout=True)
    ax = fig.subplots()
    data = [df.loc[detected & (classes == c), "detection_latency_s"].to_numpy() for c in labels]
    if data:
        ax.boxplot(data, vert=False, tick_labels=labels, whis=(0, 95))
    ax.set_xlabel("detection time after fault onset (s); whiskers: min and 95th percentile")
    ax.grid(alpha=0.3)
    return fig


def confusion_matrix(conf: pd.DataFrame) -> Figure:
    """Heat map of true against decided model counts."""
    fig = Figure(figsize=(1.8 + 1.1 * conf.shape[1], 1.5 + 0.5 * conf.shape[0]), constrained_layout=True)
    ax = fig.subplots()
    values = conf.to_numpy()
    ax.imshow(values, cmap="Blues")
    ax.set_xticks(range(conf.shape[1]), conf.columns, rotation=30, ha="right")
    ax.set_yticks(range(conf.shape[0]), conf.index)
    for (i, j), v in np.ndenumerate(values):
        ax.text(j, i, str(v), ha="center", va="center", color="white" if v > values.max() / 2 else "black")
    ax.set_xlabel("decided model")
    ax.set_ylabel("true (nearest) model")
    return fig

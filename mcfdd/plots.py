"""Figures from tidy tables (the edge of the package). Every function returns a Figure."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from mcfdd.report import bin_lower_edge


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


def flight_state(df: pd.DataFrame, title: str) -> Figure:
    """Flight of a full-aircraft run: speed and altitude, attitude, aerodynamic angles, load factor."""
    t = df["t_s"].to_numpy()
    fig = Figure(figsize=(9, 8), constrained_layout=True)
    ax1, ax2, ax3, ax4 = fig.subplots(4, 1, sharex=True)
    ax1.plot(t, df["vcas_kt"], color="C0")
    ax1.set_ylabel("Vcas (kt)", color="C0")
    alt = ax1.twinx()
    alt.plot(t, df["altitude_m"], color="C1")
    alt.set_ylabel("altitude (m)", color="C1")
    ax1.set_title(title)
    for name, label in (("phi_deg", "bank phi"), ("theta_deg", "pitch theta"), ("psi_deg", "heading psi")):
        ax2.plot(t, df[name], label=label)
    ax2.set_ylabel("attitude (deg)")
    for name, label in (("alpha_deg", "alpha"), ("beta_deg", "beta")):
        ax3.plot(t, df[name], label=label)
    ax3.set_ylabel("angle (deg)")
    ax4.plot(t, df["nz_g"], color="C3")
    ax4.set_ylabel("load factor nz (g)")
    ax4.set_xlabel("time (s)")
    for ax in (ax2, ax3):
        ax.legend(loc="upper right")
    for ax in (ax1, ax2, ax3, ax4):
        ax.grid(alpha=0.3)
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
        ax.boxplot(data, orientation="horizontal", tick_labels=labels, whis=(0, 95))
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


def lpv_responses(df: pd.DataFrame, model_names) -> Figure:
    """Nonlinear actuator against its LPV models on a few runs (``mcfdd fit-lpv``).

    ``df`` is a time-history table (:func:`mcfdd.io.history_frame`) with columns ``u_c_deg``,
    ``amplitude_deg`` and, for model i, ``x_nonlinear_deg_i`` and ``x_lpv_deg_i``. Left: command
    and responses (nonlinear solid, LPV dashed); right: LPV minus nonlinear in percent of the
    run's amplitude.
    """
    runs = list(dict.fromkeys(df["run"]))
    fig = Figure(figsize=(13, 3.0 * len(runs)), constrained_layout=True)
    axes = np.atleast_2d(fig.subplots(len(runs), 2, sharex=True, gridspec_kw={"width_ratios": [3, 2]}))
    for (ax_x, ax_e), run in zip(axes, runs):
        sub = df[df["run"] == run]
        t = sub["t_s"].to_numpy()
        ax_x.plot(t, sub["u_c_deg"], color="k", lw=1.0, label="command u_c")
        scale = 100.0 / sub["amplitude_deg"].to_numpy()
        for i, name in enumerate(model_names):
            nonlinear, lpv = sub[f"x_nonlinear_deg_{i}"].to_numpy(), sub[f"x_lpv_deg_{i}"].to_numpy()
            ax_x.plot(t, nonlinear, color=f"C{i}", lw=1.2, label=name)
            ax_x.plot(t, lpv, color=f"C{i}", lw=1.2, ls="--")
            ax_e.plot(t, (lpv - nonlinear) * scale, color=f"C{i}", lw=1.0)
        ax_x.set_title(run, fontsize=10)
        ax_x.set_ylabel("deflection (deg)")
        ax_e.set_ylabel("LPV - nonlinear (% of amplitude)")
        for ax in (ax_x, ax_e):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=2, loc="upper right", title="nonlinear solid, LPV dashed", title_fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    return fig


def lpv_gains(df: pd.DataFrame, model_names) -> Figure:
    """Fitted gains k^(i)(rho) over the envelope against the nonlinear actuator's small-error gain.

    ``df`` has one row per (model, vcas_kt, altitude_m, direction) at one deflection
    ``delta_deg``, with ``k_lpv_1_s`` and ``k_nonlinear_1_s`` (NaN above the Mach limit). One
    column of panels per model, one row per direction s = sgn(xdot); a line per altitude (LPV
    solid, nonlinear small-error gain dotted).
    """
    directions = sorted(df["direction"].unique(), reverse=True)
    altitudes = sorted(df["altitude_m"].unique())
    fig = Figure(figsize=(3.0 * len(model_names), 2.8 * len(directions)), constrained_layout=True)
    axes = np.atleast_2d(fig.subplots(len(directions), len(model_names), sharex=True, sharey=True))
    for row, s in zip(axes, directions):
        for ax, name in zip(row, model_names):
            for a, alt in enumerate(altitudes):
                sub = df[(df["model"] == name) & (df["direction"] == s) & (df["altitude_m"] == alt)]
                sub = sub.sort_values("vcas_kt")
                ax.plot(sub["vcas_kt"], sub["k_lpv_1_s"], color=f"C{a}", label=f"{alt:.0f} m")
                ax.plot(sub["vcas_kt"], sub["k_nonlinear_1_s"], color=f"C{a}", ls=":")
            ax.set_title(f"{name}, s = {s:+.0f}", fontsize=10)
            ax.grid(alpha=0.3)
        row[0].set_ylabel("gain k (1/s)")
    for ax in axes[-1]:
        ax.set_xlabel("Vcas (kt)")
    axes[0, 0].legend(fontsize=7, title="LPV solid, nonlinear small-error dotted", title_fontsize=7)
    fig.suptitle(f"gains at {df['delta_deg'].iloc[0]:+.1f} deg deflection")
    return fig


def fig3(df: pd.DataFrame, fault_free: str, faulty: str, onset_s: float) -> Figure:
    """Paper Fig. 3: actuator output of a fault-free and a faulty actuator, and their difference."""
    a = df[df["run"] == fault_free]
    b = df[df["run"] == faulty]
    t = a["t_s"].to_numpy()
    fig = Figure(figsize=(9, 6), constrained_layout=True)
    ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ax1.plot(t, a["u_c_deg"], color="0.6", lw=1.0, label=f"command u_c ({fault_free})")
    ax1.plot(t, a["u_deg"], label=f"u, {fault_free}")
    ax1.plot(t, b["u_deg"], "--", label=f"u, {faulty}")
    ax1.axvline(onset_s, color="r", lw=0.8, label="fault onset")
    ax1.set_ylabel("deflection (deg)")
    ax1.legend(loc="upper right")
    ax1.set_title("Effect of a parametric LOE fault (paper Fig. 3)")
    ax1.grid(alpha=0.3)
    ax2.plot(t, b["delta_deg"].to_numpy() - a["delta_deg"].to_numpy(), color="C3")
    ax2.axvline(onset_s, color="r", lw=0.8)
    ax2.set_ylabel("difference (deg)")
    ax2.set_xlabel("time (s)")
    ax2.grid(alpha=0.3)
    return fig


def fig4(sweep: pd.DataFrame, model_names, grid_values: dict) -> Figure:
    """Paper Fig. 4: decided model against fault size, grid values of the bank as vertical lines."""
    fig = Figure(figsize=(10, 4.5), constrained_layout=True)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (family, label) in zip(axes, (("surface", "loss of surface effectiveness (%)"),
                                         ("leakage", "loss of hydraulic pressure (%)"))):
        sub = sweep[sweep["family"] == family]
        for v in grid_values[family]:
            ax.axvline(100.0 * v, color="0.7", lw=1.0)
        ax.plot(100.0 * sub["fault_size"], sub["detected_model"], "o", mfc="none")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_yticks(range(-1, len(model_names)), ["no decision"] + list(model_names))
    axes[0].set_ylabel("decided model after the onset")
    fig.suptitle("Detected model during fault simulations (paper Fig. 4)")
    return fig


def fig5(run: pd.DataFrame) -> Figure:
    """Paper Fig. 5: command and output, normalised available pressure, stall-detector residual."""
    t = run["t_s"].to_numpy()
    fig = Figure(figsize=(9, 7), constrained_layout=True)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    ax1.plot(t, run["u_c_deg"], label="u_c")
    ax1.plot(t, run["u_deg"], label="u")
    ax1.set_ylabel("deflection (deg)")
    ax1.legend(loc="upper right")
    ax1.set_title("Stall loads during a high-input manoeuvre (paper Fig. 5)")
    ax2.plot(t, run["dp_avail_norm"], color="C2")
    ax2.axhline(0.0, color="k", lw=0.8)
    ax2.set_ylabel("(dP - sgn(xdot) F/S) / dP")
    ax3.plot(t, run["r_stall_deg"], color="C3")
    ax3.set_ylabel("residual r (deg)")
    ax3.set_xlabel("time (s)")
    for ax in (ax1, ax2, ax3):
        _shade(ax, t, run["stall"], color="red", alpha=0.12)
        ax.grid(alpha=0.3)
    return fig


def fig6(run: pd.DataFrame, max_deflection_deg: float) -> Figure:
    """Paper Fig. 6: stall identification signal eta beside normalised command and output."""
    t = run["t_s"].to_numpy()
    fig = Figure(figsize=(9, 5), constrained_layout=True)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.plot(t, run["u_c_deg"] / max_deflection_deg, label="u_c / max")
    ax1.plot(t, run["u_deg"] / max_deflection_deg, label="u / max")
    ax1.set_ylabel("normalised deflection")
    ax1.legend(loc="upper right")
    ax1.set_title("Stall-load identification signal (paper Fig. 6)")
    ax2.step(t, run["eta_signal"].astype(float), where="post", label="eta, signal-based (32)-(35)")
    ax2.step(t, run["eta_model"].astype(float) * 0.9, where="post", label="eta, model detection (30) (x0.9)")
    ax2.set_ylabel("eta")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right")
    for ax in (ax1, ax2):
        _shade(ax, t, run["stall"], color="red", alpha=0.12)
        ax.grid(alpha=0.3)
    return fig


def search_history(df: pd.DataFrame, value: str, smooth: str, label: str, bound: str) -> Figure:
    """Worst-case search: the bound per gradient iteration for each start (smooth value dashed),
    beside the best of the screening and of Monte Carlo with the same number of simulations.

    ``df`` has one row per simulation with ``method``, ``start``, ``iteration`` and the columns
    ``value`` (hard bound) and ``smooth``; ``label`` names the bound on the axis; ``bound`` is 'free'
    (the worst case is the largest value) or 'detect' (the smallest).
    """
    fig = Figure(figsize=(8, 4.5), constrained_layout=True)
    ax = fig.subplots()
    grad = df[df["method"] == "gradient"]
    for i, (start, g) in enumerate(grad.groupby("start")):
        g = g.sort_values("iteration")
        ax.plot(g["iteration"], g[value], "o-", color=f"C{i % 10}", ms=3, label=f"start {start}")
        ax.plot(g["iteration"], g[smooth], "--", color=f"C{i % 10}", lw=0.8)
    for method, style, name in (("screening", ":", "best of the screening"),
                                ("monte_carlo", "-.", "Monte Carlo, equal simulations")):
        values = df.loc[df["method"] == method, value].to_numpy(dtype=float)
        values = values[np.isfinite(values)]
        if values.size:
            best = values.max() if bound == "free" else values.min()
            ax.axhline(best, color="k", ls=style, lw=1.0, label=name)
    ax.set_xlabel("gradient iteration")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    return fig


def tuning_history(history: pd.DataFrame, units: str) -> Figure:
    """Tuning: normalised detection gap per iteration (hard, and the smooth log gap), the bounds and
    the parameters. ``history`` has one row per iteration."""
    fig = Figure(figsize=(10, 7), constrained_layout=True)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    it = history["iteration"]
    ax1.plot(it, history["normalised_gap"], "o-", ms=3, label="(tau_d - tau_f) / tau_f")
    ax1.plot(it, np.expm1(history["smooth_log_gap"]), "--", label="smooth: exp(log tau_d - log tau_f) - 1")
    ax1.axhline(0.0, color="k", lw=0.8)
    ax1.set_ylabel("normalised gap")
    ax1.legend(fontsize=8)
    ax2.plot(it, history["tau_f"], label="tau_f (26)")
    ax2.plot(it, history["tau_d"], label="tau_d (27)")
    ax2.set_ylabel(f"bound ({units})")
    ax2.set_yscale("log")
    ax2.legend(fontsize=8)
    for name in ("alpha", "beta", "gamma_1_s", "pole_1_s"):
        ax3.plot(it, history[name], label=name)
    ax3.set_yscale("log")
    ax3.set_ylabel("parameter")
    ax3.set_xlabel("iteration")
    ax3.legend(fontsize=8, ncol=4)
    for ax in (ax1, ax2, ax3):
        ax.grid(alpha=0.3)
    return fig


def detectability(det: pd.DataFrame) -> Figure:
    """MDR heat map per fault kind over (dynamic pressure x peak load fraction), separable cells framed.

    ``det`` is :func:`mcfdd.report.detectability`. Each cell shows MDR, missed/runs and the false
    alarms of the fault-free runs in the same cell.
    """
    qbar_bins, load_bins = (sorted(set(det[c]), key=bin_lower_edge) for c in ("qbar_kpa_bin", "load_fraction_bin"))
    kinds = list(dict.fromkeys(det["fault_kind"]))
    fig = Figure(figsize=(1.0 + 0.9 * max(len(qbar_bins), 4) * max(len(kinds), 1), 1.6 + 0.62 * max(len(load_bins), 4)),
                 constrained_layout=True)
    axes = np.atleast_1d(fig.subplots(1, max(len(kinds), 1), sharey=True, squeeze=False)[0])
    image = None
    for ax, kind in zip(axes, kinds):
        sub = det[det["fault_kind"] == kind]
        grid = np.full((len(load_bins), len(qbar_bins)), np.nan)
        for _, r in sub.iterrows():
            i, j = load_bins.index(r["load_fraction_bin"]), qbar_bins.index(r["qbar_kpa_bin"])
            grid[i, j] = r["mdr"]
            ax.text(j, i, f"{r['mdr']:.2f}\n{r['missed']}/{r['faulty_runs']}\nFAR {r['false_alarms']}/"
                    f"{r['fault_free_runs']}", ha="center", va="center", fontsize=6.5,
                    color="white" if r["mdr"] > 0.6 else "black")
            if r["separable"]:
                ax.add_patch(_cell_frame(j, i))
        image = ax.imshow(grid, cmap="Reds", vmin=0.0, vmax=1.0, origin="lower", aspect="auto")
        ax.set_xticks(range(len(qbar_bins)), qbar_bins, rotation=30, ha="right", fontsize=8)
        ax.set_title(f"{kind}: MDR (framed: separable)", fontsize=10)
        ax.set_xlabel("dynamic pressure (kPa)")
    axes[0].set_yticks(range(len(load_bins)), load_bins, fontsize=8)
    axes[0].set_ylabel("peak load fraction |F| / (nu1 dP S)")
    if image is not None:
        fig.colorbar(image, ax=list(axes), label="missed-detection rate", shrink=0.8)
    else:
        axes[0].text(0.5, 0.5, "no parametric faults in this campaign", ha="center", va="center",
                     transform=axes[0].transAxes)
        axes[0].set_axis_off()
    return fig


def _cell_frame(j, i):
    return Rectangle((j - 0.46, i - 0.46), 0.92, 0.92, fill=False, edgecolor="tab:blue", linewidth=2.2)

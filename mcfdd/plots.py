"""Figures from tidy tables (the edge of the package). Every function returns a Figure."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import FuncFormatter

from mcfdd.report import LOAD_FRACTION_BINS, QBAR_BINS_KPA, bin_lower_edge


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


def _event_times(row) -> dict:
    """The campaign's times of a replayed run to mark: label -> (time s, colour), finite ones only."""
    marks = {"fault onset": ("fault_onset_s", "k"), "false alarm": ("false_alarm_time_s", "C3"),
             "detection": ("detection_time_s", "C2"), "identification": ("identification_time_s", "C4")}
    return {label: (float(row[col]), colour) for label, (col, colour) in marks.items()
            if np.isfinite(row[col]) and (label != "fault onset" or row["fault_kind"] != "none")}


def replay_run(df: pd.DataFrame, row, models, detection_tau: float) -> Figure:
    """A replayed campaign run: deflections with stall loads, the LOE ratios theta_i / ||u|| (where excited) against
    the detection threshold, the decisions, the stall detector; the campaign's onset, alarm, detection and
    identification times (``row``, its scenario-table row) marked in every panel."""
    t = df["t_s"].to_numpy()
    fig = Figure(figsize=(10, 9), constrained_layout=True)
    ax1, ax2, ax3, ax4 = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [2, 2, 1.2, 1.2]})
    ax1.plot(t, df["u_c_deg"], label="command u_c", color="C0")
    ax1.plot(t, df["u_deg"], label="measured u", color="C1", lw=1.0)
    _shade(ax1, t, df["stall"], color="red", alpha=0.15, label="stall load")
    ax1.set_ylabel("deflection (deg)")
    size = f" {row['fault_size']:.3g}" if row["fault_kind"] not in ("none", "jamming") else ""
    ax1.set_title(f"scenario {row['scenario_id']}: {row['fault_kind']}{size}, {row['manoeuvre_kind']}, "
                  f"{row['vcas_kt']:.0f} kt, {row['altitude_m']:.0f} m")
    excited = df["excited"].to_numpy(dtype=bool)
    ratios = np.where(excited[:, None], df[[f"ratio_{i}" for i in range(len(models))]].to_numpy(), np.nan)
    for i, name in enumerate(models):
        ax2.plot(t, ratios[:, i], label=name, lw=1.2 if i == 0 else 0.8)
    ax2.axhline(detection_tau, color="k", ls=":", lw=1.0, label=f"detection_tau {detection_tau:g}")
    _shade(ax2, t, ~excited, color="0.85", alpha=0.6, label="not excited")
    if (ratios[np.isfinite(ratios)] > 0).any():
        ax2.set_yscale("log")
    ax2.set_ylabel("theta_i / ||u||")
    ax2.legend(loc="best", fontsize=7, ncol=4, framealpha=0.6)
    ax3.step(t, df["decoded_model"], where="post", color="0.6", lw=0.8, label="decoded (15)")
    ax3.step(t, df["detected_model"], where="post", color="C4", label="identified (confirmed)")
    _shade(ax3, t, df["fault_detected"], color="C2", alpha=0.2, label="fault detected")
    ax3.set_yticks(range(-1, len(models)), ["none", *models], fontsize=7)
    ax3.set_ylabel("decision")
    ax3.legend(loc="upper left", fontsize=7)
    ax4.plot(t, df["theta_stall_deg"], color="C5", label="stall detector theta")
    _shade(ax4, t, df["eta_stall"], color="red", alpha=0.15, label="eta = 1 (stall identified)")
    ax4.set_ylabel("theta (deg)")
    ax4.set_xlabel("time (s)")
    ax4.legend(loc="upper left", fontsize=7)
    for label, (when, colour) in _event_times(row).items():
        for ax in (ax1, ax2, ax3, ax4):
            ax.axvline(when, color=colour, ls="--", lw=1.0, label=label if ax is ax1 else None)
    ax1.legend(loc="upper right", fontsize=7)
    for ax in (ax1, ax2, ax3, ax4):
        ax.grid(alpha=0.3)
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


RATE_PANELS = {"far_loe": ("false_alarms_loe", "fault_free_runs", "LOE false alarms per fault-free run"),
               "far_any": ("false_alarms_any", "fault_free_runs", "any alarm (LOE, stall id.) per fault-free run"),
               "mdr": ("missed", "faulty_runs", "missed-detection rate")}


def rates_by_stratum(summ: pd.DataFrame, stratum: str, rates=("far_loe", "far_any", "mdr")) -> Figure:
    """Rates (``rates``: keys of :data:`RATE_PANELS`) with exact 95 % intervals for each label of one stratum.

    Each panel has its own scale: logarithmic when a rate or bound lies below 0.1 (FAR of a few
    1e-3 stays readable), else linear from 0 to 1. A zero count is drawn as a bar up to its upper
    bound; every row is annotated with k/n.
    """
    sub = summ[summ["stratum"] == stratum]
    y = np.arange(len(sub))
    width = 1.0 + 0.075 * max(len(str(label)) for label in sub["label"])
    fig = Figure(figsize=(width + 4.2 * len(rates), 1.3 + 0.36 * len(sub)), constrained_layout=True)
    axes = np.atleast_1d(fig.subplots(1, len(rates), sharey=True, squeeze=False)[0])
    for ax, name in zip(axes, rates):
        count, total, title = RATE_PANELS[name]
        k, n = sub[count].to_numpy(dtype=int), sub[total].to_numpy(dtype=int)
        value, lo, hi = (sub[c].to_numpy(dtype=float) for c in (name, f"{name}_lo", f"{name}_hi"))
        shown = np.concatenate([lo[(n > 0) & (lo > 0.0)], hi[n > 0]])
        log = shown.size > 0 and shown.min() < 0.1
        left = 10.0 ** np.floor(np.log10(shown.min() / 2.0)) if log else 0.0
        some, zero = (n > 0) & (k > 0), (n > 0) & (k == 0)
        if some.any():
            ax.errorbar(value[some], y[some], xerr=[value[some] - lo[some], hi[some] - value[some]], fmt="o",
                        capsize=3, color="C0", label="rate, 95 % interval")
        if zero.any():
            ax.hlines(y[zero], left, hi[zero], color="C1", lw=2.0)
            ax.plot(hi[zero], y[zero], "|", color="C1", ms=10, mew=2.0, label="0 counted: up to the upper bound")
        for row in range(len(sub)):
            text = f"{k[row]}/{n[row]}" if n[row] > 0 else f"no {total.replace('_', ' ')}"
            ax.annotate(text, (1.0, y[row]), xycoords=("axes fraction", "data"), xytext=(4, 0),
                        textcoords="offset points", va="center", fontsize=7)
        if log:
            ax.set_xscale("log")
        ax.set_xlim(left, 1.0)
        ax.set_xlabel(f"{title} ({'log scale' if log else 'linear scale'})")
        ax.grid(alpha=0.3)
    axes[0].set_yticks(y, sub["label"])
    axes[0].invert_yaxis()
    legend = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    fig.legend(legend.values(), legend.keys(), loc="outside lower center", ncols=2, fontsize=7)
    fig.suptitle(f"by {stratum}: rates with exact Clopper-Pearson 95 % intervals")
    return fig


def detection_times(df: pd.DataFrame, classes: pd.Series) -> Figure:
    """Distribution of detection latency per fault class (detected runs)."""
    detected = df["detected"].to_numpy(dtype=bool)
    labels = sorted(set(classes[detected]))
    fig = Figure(figsize=(9, 1.4 + 0.4 * len(labels)), constrained_layout=True)
    ax = fig.subplots()
    data = [df.loc[detected & (classes == c), "detection_latency_s"].to_numpy() for c in labels]
    ax.boxplot(data, orientation="horizontal", tick_labels=[f"{c} ({len(d)})" for c, d in zip(labels, data)],
               whis=(0, 95))
    ax.set_xlabel("detection time after fault onset (s); whiskers: min and 95th percentile; (detected runs)")
    ax.grid(alpha=0.3)
    return fig


def _heat_map(ax, table: pd.DataFrame, xlabel: str, ylabel: str, scaled=None):
    """Counts of ``table``, each cell coloured by its share of its row over the ``scaled`` columns (default all);
    the other columns are grey with their counts (e.g. "no decision", which would set the scale)."""
    values = table.to_numpy()
    scaled = list(table.columns) if scaled is None else list(scaled)
    inside = np.isin(table.columns, scaled)
    totals = values[:, inside].sum(axis=1, keepdims=True)
    share = np.where(inside & (totals > 0), values / np.maximum(totals, 1), np.nan)
    ax.imshow(np.ma.masked_invalid(share), cmap="Blues", vmin=0.0, vmax=1.0, aspect="auto")
    for j in np.flatnonzero(~inside):
        ax.axvspan(j - 0.5, j + 0.5, color="0.88", zorder=0)
    ax.set_xlim(-0.5, values.shape[1] - 0.5)
    ax.set_ylim(values.shape[0] - 0.5, -0.5)
    ax.set_xticks(range(table.shape[1]), table.columns, rotation=30, ha="right")
    ax.set_yticks(range(table.shape[0]), table.index)
    for (i, j), v in np.ndenumerate(values):
        ax.text(j, i, str(v), ha="center", va="center", color="white" if share[i, j] > 0.5 else "black")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)


def confusion_matrix(conf: pd.DataFrame, stall: pd.DataFrame | None = None) -> Figure:
    """Heat map of true against decided model counts, each cell coloured by its share of the row's identified
    runs ("no decision" in grey, its count only); with ``stall`` (:func:`mcfdd.report.stall_confusion`) a second
    one of stall loads, jammed rods and the other runs against eta = 1, coloured by share of the row."""
    decided = [c for c in conf.columns if c != "no decision"]
    width = max(4.6, 2.6 + 1.0 * conf.shape[1]) + (0.0 if stall is None else 2.6 + 1.2 * stall.shape[1])
    rows = max(conf.shape[0], 0 if stall is None else stall.shape[0])
    fig = Figure(figsize=(width, 3.0 + 0.45 * rows), constrained_layout=True)
    if stall is None:
        left = fig.subplots()
    else:
        left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [conf.shape[1] + 1.5, stall.shape[1] + 1.5]})
        _heat_map(right, stall, "stall identification", "truth")
        right.set_title("stall identification (events; runs)\ncolour: share of the row", fontsize=10)
    _heat_map(left, conf, "decided model (identification)", "true (nearest) model", decided)
    left.set_title("LOE identification (runs)\ncolour: share of the row's identified runs", fontsize=10)
    return fig


def stall_latency(df: pd.DataFrame, window_s: float) -> Figure:
    """Cumulative distribution of each run's worst stall-identification latency, per identification method.

    A run counts once it has identified every one of its relevant stall events; runs with an event
    not identified never reach the curve's end. The vertical line is the stall window (0.5 s in
    the paper's claim).
    """
    runs = df[(df["status"] == 0) & (df["stall_events"] > 0)]
    fig = Figure(figsize=(8, 4.5), constrained_layout=True)
    ax = fig.subplots()
    largest = window_s
    for i, (method, name) in enumerate((("signal", "signal rules (32)-(35)"), ("model", "model detection (30)"))):
        complete = runs[f"stall_identified_{method}"].to_numpy() == runs["stall_events"].to_numpy()
        latency = np.sort(np.where(complete, runs[f"stall_worst_latency_{method}_s"].to_numpy(dtype=float), np.inf))
        finite = latency[np.isfinite(latency)]
        largest = max(largest, float(finite.max()) if finite.size else 0.0)
        within = int((latency <= window_s).sum())
        frac = np.arange(1, len(latency) + 1) / len(latency)
        ax.step(np.concatenate([[0.0], finite]), np.concatenate([[0.0], frac[:finite.size]]), where="post",
                color=f"C{i}", label=f"{name}: {within}/{len(latency)} runs within {window_s:g} s, "
                                     f"{len(latency) - finite.size} with an event not identified")
    ax.axvline(window_s, color="r", ls="--", lw=1.0, label=f"stall window {window_s:g} s")
    ax.set_xlim(0.0, 1.1 * largest)
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("worst identification latency of the run's relevant stall loads: first eta = 1 - onset (s)")
    ax.set_ylabel(f"fraction of the {len(runs)} runs with stall loads")
    ax.set_title("Stall-load identification latency")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
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
    ax2.set_ylabel(f"delta, {faulty}\nminus {fault_free} (deg)")
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


def fig5(run: pd.DataFrame, tau_deg: float) -> Figure:
    """Paper Fig. 5: command and output, normalised available pressure, stall-detector residual with its
    evaluation theta (eq. 14) and the threshold ``tau_deg`` of eq. (25)."""
    t = run["t_s"].to_numpy()
    fig = Figure(figsize=(9, 7), constrained_layout=True)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    ax1.plot(t, run["u_c_deg"], label="u_c")
    ax1.plot(t, run["u_deg"], label="u")
    ax1.set_ylabel("deflection (deg)")
    ax1.set_title("Stall loads during a high-input manoeuvre (paper Fig. 5)")
    ax2.plot(t, run["dp_avail_norm"], color="C2")
    ax2.axhline(0.0, color="k", lw=0.8)
    ax2.set_ylabel("(dP - sgn(xdot) F/S) / dP")
    ax3.plot(t, run["r_stall_deg"], color="C3", label="residual r (20)")
    ax3.plot(t, run["theta_stall_deg"], color="C4", lw=1.0, label="evaluation theta (14)")
    ax3.axhline(tau_deg, color="k", ls="--", lw=1.0, label=f"threshold tau = {tau_deg:g} deg (25)")
    ax3.set_ylabel("residual, evaluation (deg)")
    ax3.set_xlabel("time (s)")
    _shade(ax1, t, run["stall"], color="red", alpha=0.12, label="stall load")
    for ax in (ax2, ax3):
        _shade(ax, t, run["stall"], color="red", alpha=0.12)
    for ax in (ax1, ax2, ax3):
        ax.grid(alpha=0.3)
    ax1.legend(loc="upper right")
    ax3.legend(loc="upper right", fontsize=8)
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
    ax2.set_ylim(-0.05, 1.45)
    ax2.legend(loc="upper center", ncols=2, fontsize=8)
    for ax in (ax1, ax2):
        _shade(ax, t, run["stall"], color="red", alpha=0.12)
        ax.grid(alpha=0.3)
    return fig


def search_history(df: pd.DataFrame, value: str, smooth: str, label: str, bound: str) -> Figure:
    """Worst-case search: the bound per gradient iteration for each start (its smooth value dashed),
    beside the best of the screening and of Monte Carlo with the same number of simulations and with
    the same run time.

    ``df`` has one row per simulation with ``method``, ``start``, ``iteration`` and the columns
    ``value`` (hard bound) and ``smooth``; ``label`` names the bound on the axis; ``bound`` is 'free'
    (the worst case is the largest value) or 'detect' (the smallest).
    """
    fig = Figure(figsize=(9, 5), constrained_layout=True)
    ax = fig.subplots()
    grad = df[df["method"] == "gradient"]
    for i, (start, g) in enumerate(grad.groupby("start")):
        g = g.sort_values("iteration")
        ax.plot(g["iteration"], g[value], "o-", color=f"C{i % 10}", ms=3, label=f"start {start}: bound")
        ax.plot(g["iteration"], g[smooth], "--", color=f"C{i % 10}", lw=0.8,
                label=f"start {start}: smooth bound the gradient follows")
    for methods, style, color, name in (
            (("screening",), ":", "k", "best of the screening"),
            (("monte_carlo",), "-.", "k", "Monte Carlo, equal number of simulations"),
            (("monte_carlo", "monte_carlo_extra"), "-.", "C7", "Monte Carlo, equal run time")):
        runs = df.loc[df["method"].isin(methods), value].to_numpy(dtype=float)
        values = runs[np.isfinite(runs)]
        if values.size:
            best = values.max() if bound == "free" else values.min()
            ax.axhline(best, color=color, ls=style, lw=1.2,
                       label=f"{name} ({runs.size:,} runs, {values.size:,} with the bound)")
    ax.set_xlabel("gradient iteration")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
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
    ax2.legend(fontsize=8)
    for name in ("alpha", "beta", "gamma_1_s", "pole_1_s"):
        ax3.plot(it, history[name], label=name)
    ax3.set_ylabel("parameter")
    ax3.set_xlabel("iteration")
    ax3.legend(fontsize=8, ncol=4, loc="upper left", bbox_to_anchor=(0.0, -0.25))
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for ax in (ax2, ax3):
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(plain)
        low, high = ax.get_ylim()
        if high < 10.0 * low:  # within a decade the minor ticks carry the labels: plain numbers, not 2 x 10^0
            ax.yaxis.set_minor_formatter(plain)
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
        ax.set_xticks(range(len(qbar_bins)), [_bin_text(b, QBAR_BINS_KPA) for b in qbar_bins], fontsize=8)
        ax.set_title(f"{kind}: MDR (framed: separable)", fontsize=10)
        ax.set_xlabel("dynamic pressure (kPa)")
    axes[0].set_yticks(range(len(load_bins)), [_bin_text(b, LOAD_FRACTION_BINS) for b in load_bins], fontsize=8)
    axes[0].set_ylabel("peak load fraction |F| / (nu1 dP S)")
    if image is not None:
        fig.colorbar(image, ax=list(axes), label="missed-detection rate", shrink=0.8)
    else:
        axes[0].text(0.5, 0.5, "no parametric faults in this campaign", ha="center", va="center",
                     transform=axes[0].transAxes)
        axes[0].set_axis_off()
    return fig


def _bin_text(label: str, edges) -> str:
    """``[a, b)`` as ``a-b``, the last bin of ``edges`` as ``>= a``; other labels (no motion) as they are."""
    if not label.startswith("["):
        return label
    lo, hi = (float(v) for v in label[1:-1].split(","))
    return f">= {lo:g}" if hi == edges[-1] else f"{lo:g}-{hi:g}"


def _cell_frame(j, i):
    return Rectangle((j - 0.46, i - 0.46), 0.92, 0.92, fill=False, edgecolor="tab:blue", linewidth=2.2)


def ranked_bars(df: pd.DataFrame, series, xlabel: str, top: int = 10, log: bool = False) -> Figure:
    """Ranked horizontal bars with interval whiskers, one panel per (``outcome``, ``stratum``) of a tidy table.

    ``series`` are (column, label) pairs, drawn side by side per ``factor``; a column's interval is
    ``<column>_lo`` to ``<column>_hi`` where the table has them. Rows are drawn in table order
    (ranked by the first series), the ``top`` first of each panel, largest on top; ``log``: a
    logarithmic axis from 1e-4 of the panel's largest value (non-negative values spanning decades).
    """
    groups = list(df.groupby(["outcome", "stratum"], sort=False))
    ncols = min(3, len(groups))
    nrows = -(-len(groups) // ncols)
    rows_shown = max(min(top, len(g)) for _, g in groups)
    fig = Figure(figsize=(4.6 * ncols, (0.32 * rows_shown + 1.3) * nrows), constrained_layout=True)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    width = 0.8 / len(series)
    for ax, ((outcome, stratum), g) in zip(axes.flat, groups):
        g = g.head(top).iloc[::-1]
        y = np.arange(len(g))
        for k, (column, label) in enumerate(series):
            v = g[column].to_numpy(dtype=float)
            pos = y + ((len(series) - 1) / 2 - k) * width
            ax.barh(pos, v, height=width, color=f"C{k}", alpha=1.0 if k == 0 else 0.55, label=label)
            if f"{column}_lo" in g:
                lo, hi = g[f"{column}_lo"].to_numpy(dtype=float), g[f"{column}_hi"].to_numpy(dtype=float)
                err = np.clip([v - lo, hi - v], 0.0, None)
                ax.errorbar(v, pos, xerr=np.nan_to_num(err), fmt="none", ecolor="k", elinewidth=0.8, capsize=2)
        if log:
            ax.set_xscale("log")
            ax.set_xlim(1e-4 * np.nanmax(g[series[0][0]]), None)
        ax.set_yticks(y, g["factor"], fontsize=8)
        ax.set_title(f"{outcome}\n{stratum}" if stratum not in ("", "all") else outcome, fontsize=9)
        if not log:
            ax.axvline(0.0, color="k", lw=0.6)
        ax.grid(axis="x", alpha=0.3)
    for ax in axes.flat[len(groups):]:
        ax.set_visible(False)
    if len(series) > 1:
        axes.flat[0].legend(loc="lower right", fontsize=8)
    fig.supxlabel(xlabel, fontsize=9)
    return fig


def detection_tuning_history(history: pd.DataFrame) -> Figure:
    """Detection-level tuning: the gap tau_d - tau_f per iteration (hard and smooth), the training false alarms
    and missed detections, and the tuned parameters relative to their start. One row of ``history`` per iteration."""
    fig = Figure(figsize=(10, 7), constrained_layout=True)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    it = history["iteration"]
    ax1.plot(it, history["gap"], "o-", ms=3, label="tau_d - tau_f (hard)")
    ax1.plot(it, history["smooth_gap"], "--", label="smooth surrogate")
    ax1.plot(it, history["tau_f"], lw=0.8, label="tau_f: largest false-alarm margin")
    ax1.plot(it, history["tau_d"], lw=0.8, label="tau_d: smallest detection margin (must-detect runs)")
    ax1.axhline(0.0, color="k", lw=0.8)
    ax1.set_ylabel("theta_0 / ||u||")
    ax1.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax2.plot(it, history["false_alarms"], "o-", ms=3, label="false alarms (runs)")
    ax2.plot(it, history["missed"], "s-", ms=3, label="must-detect runs missed")
    ax2.set_ylabel("training runs")
    ax2.legend(fontsize=8)
    skip = {"iteration", "smooth_gap", "tau_f", "tau_d", "gap", "false_alarms", "missed", "detection_time_s"}
    for name in (c for c in history.columns if c not in skip):
        ax3.plot(it, history[name] / history[name].iloc[0], label=name)
    ax3.set_ylabel("parameter / start")
    ax3.set_xlabel("iteration")
    ax3.legend(fontsize=8, ncol=4, loc="upper left", bbox_to_anchor=(0.0, -0.25))
    for ax in (ax1, ax2, ax3):
        ax.grid(alpha=0.3)
    return fig

"""Worst-case search and tuning reports (the edge): ``mcfdd worst-case`` and ``mcfdd tune``.

The worst bound each search method found, the verdict of the gradient search against Monte Carlo,
the held-out campaigns of a tuned FDD side by side (their rates from :func:`mcfdd.report.summary`)
and the Markdown of both commands.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from mcfdd.analysis import metrics
from mcfdd.report import FALSE_ALARM_COLUMNS, NA, fmt, gaps, interval, summary, timing

SEARCH_METHODS = {
    "gradient search (Sobol screening + projected gradient)": ("screening", "gradient"),
    "Sobol screening alone": ("screening",),
    "Monte Carlo, equal number of simulations": ("monte_carlo",),
    "Monte Carlo, equal run time": ("monte_carlo", "monte_carlo_extra"),
}


def search_summary(df: pd.DataFrame, value: str, bound: str, run_time_s: dict) -> pd.DataFrame:
    """Worst bound found by each method with its row (``df`` holds one row per simulation).

    ``bound`` is 'free' (the worst case is the largest value) or 'detect' (the smallest);
    ``run_time_s`` maps the ``method`` labels of ``df`` to their run times (s).
    """
    rows = []
    for name, methods in SEARCH_METHODS.items():
        sub = df[df["method"].isin(methods)]
        best, row = metrics.bound_with_witness(sub[value].to_numpy(), sub.index.to_numpy(),
                                               "sup" if bound == "free" else "inf")
        rows.append({"method": name, "simulations": int(len(sub)),
                     "run_time_s": float(sum(run_time_s.get(m, 0.0) for m in methods)), value: best, "row": row})
    return pd.DataFrame(rows)


def search_verdict(summ: pd.DataFrame, value: str, bound: str, restarted: int, pool_left: int) -> str:
    """Whether the gradient search found a worse bound than Monte Carlo at equal run time, and if not, what the
    search's own record shows (``summ``: :func:`search_summary`; starts replaced and pool points left unused)."""
    by = summ.set_index("method")[value]
    grad, mc = by.iloc[0], by["Monte Carlo, equal run time"]
    name, worse = ("tau_f", "larger") if bound == "free" else ("tau_d", "smaller")
    if not np.isfinite(grad) or not np.isfinite(mc):
        return f"No comparison at equal run time: a method found no run with the bound ({grad}, {mc})."
    if (grad > mc) if bound == "free" else (grad < mc):
        return (f"At equal run time the gradient search's {name} ({fmt(grad, 5)}) is {worse} than Monte Carlo's "
                f"({fmt(mc, 5)}): the search found a worse case.")
    return (f"At equal run time the gradient search's {name} ({fmt(grad, 5)}) is not {worse} than Monte Carlo's "
            f"({fmt(mc, 5)}): the search did not earn its cost here. Its starts were replaced {restarted} times "
            f"({pool_left} screened runs with the event left); a worst case in another categorical cell than the "
            f"starts' (manoeuvre family, turbulence level) or on a plateau of the smooth statistic (no gradient) is "
            f"out of its reach; more starts or screening move it there.")


def worst_case_markdown(title: str, summ: pd.DataFrame, df: pd.DataFrame, value: str, bound: str, parameters, notes,
                        meta: dict) -> str:
    """Report of a worst-case search: methods compared, the worst scenarios, progress per start.

    ``summ`` is :func:`search_summary` of ``df``; ``parameters`` the scenario columns to show.
    """
    lines = [f"# {title}", "", *notes, "", f"seed {meta.get('seed')}, mcfdd {meta.get('version')}, revision "
             f"{meta.get('git_revision')}.", "", f"| method | simulations | run time (s) | worst {value} | row |",
             "|---|---|---|---|---|"]
    for _, r in summ.iterrows():
        lines.append(f"| {r['method']} | {r['simulations']} | {r['run_time_s']:.1f} | {fmt(r[value], 5)} | "
                     f"{r['row']} |")
    rows = [int(r) for r in summ["row"] if r >= 0]
    lines += ["", "## Worst scenarios", "", "| parameter | " + " | ".join(summ["method"][summ["row"] >= 0]) + " |",
              "|---" * (len(rows) + 1) + "|"]
    for name in [*parameters, value]:
        lines.append(f"| {name} | " + " | ".join(fmt(df.loc[r, name], 5) if not isinstance(df.loc[r, name], str)
                                                else df.loc[r, name] for r in rows) + " |")
    grad = df[df["method"] == "gradient"]
    if len(grad):
        lines += ["", "## Gradient search per start", "", "| start (screening row) | at start | after the last step "
                  "| best |", "|---|---|---|---|"]
        worst = max if bound == "free" else min
        for start, g in grad.groupby("start"):
            g = g.sort_values("iteration")
            values = g[value].to_numpy()
            finite = values[np.isfinite(values)]
            lines.append(f"| {start} | {fmt(values[0], 5)} | {fmt(values[-1], 5)} | "
                         f"{fmt(worst(finite), 5) if finite.size else NA} |")
    return "\n".join(lines) + "\n"


def validation_table(frames: dict, deg_per_m: float, identification: str,
                     scored_s: float | None = None) -> pd.DataFrame:
    """Held-out campaign outcomes side by side: one row per FDD setting (e.g. 'before', 'after').

    ``frames`` maps the setting to its campaign scenario table; ``stall_detector_fires`` counts runs
    whose stall detector reached its threshold outside stall loads (``stall_false_detection``),
    ``stall_late_or_missed`` runs with a relevant stall event that the ``identification`` method
    ('signal' or 'model') did not identify within the stall window (``stall_missed_<method>``).
    """
    rows = []
    for label, df in frames.items():
        overall = summary(df, scored_s).query("stratum == 'overall'").iloc[0]
        gap = gaps(df, deg_per_m).set_index("detector")
        row = {"fdd": label, **{k: overall[k] for k in (
            "runs", *FALSE_ALARM_COLUMNS, "eta_false_alarms_signal", "faulty_runs", "missed", "mdr", "mdr_lo",
            "mdr_hi", "identification_accuracy",
            "detection_time_median_s", "detection_time_p95_s", "detection_time_max_s", "stall_events",
            "stall_identified_signal", "stall_identified_model", "stall_worst_latency_signal_s",
            "stall_worst_latency_model_s")}, "stall_detector_fires": int(df["stall_false_detection"].sum()),
            "stall_late_or_missed": int(df[f"stall_missed_{identification}"].sum())}
        for det in gap.index:
            for k in ("tau_f", "tau_d", "gap"):
                row[f"{det}_{k}"] = gap.loc[det, k]
            row[f"{det}_normalised_gap"] = gap.loc[det, "gap"] / gap.loc[det, "tau_f"]
        rows.append(row)
    return pd.DataFrame(rows)


def tuning_markdown(title: str, detector: str, history: pd.DataFrame, best: int, before: dict,
                    parameters: pd.DataFrame, validation: pd.DataFrame, notes, meta: dict,
                    scan: pd.DataFrame | None = None) -> str:
    """Report of a tuning run: parameters and training gap before (``before``: tau_f and tau_d of
    the configured FDD) and after (iteration ``best`` of ``history``), the threshold scan if one
    was made, the held-out campaign side by side."""
    units = "deg" if detector == "stall" else "theta/||u||"
    chosen = history.iloc[best]
    first = {**before, "normalised_gap": (before["tau_d"] - before["tau_f"]) / before["tau_f"]}
    lines = [f"# {title}", "", *notes, "", f"seed {meta.get('seed')}, mcfdd {meta.get('version')}, revision "
             f"{meta.get('git_revision')}.", "", "## Parameters", "", "| parameter | before | after |", "|---|---|---|"]
    for _, r in parameters.iterrows():
        lines.append(f"| {r['parameter']} | {fmt(r['before'], 5)} | {fmt(r['after'], 5)} |")
    lines += ["", f"## Training set (iteration {best} of {len(history) - 1} chosen)", "",
              f"| | tau_f ({units}) | tau_d ({units}) | gap | normalised gap (tau_d - tau_f) / tau_f |",
              "|---|---|---|---|---|"]
    for label, r in (("before", first), ("after", chosen)):
        lines.append(f"| {label} | {fmt(r['tau_f'], 5)} | {fmt(r['tau_d'], 5)} | {fmt(r['tau_d'] - r['tau_f'], 5)} "
                     f"| {fmt(r['normalised_gap'], 4)} |")
    if scan is not None:
        lines += ["", "## Thresholds on the training set (negative gap)", "",
                  "| " + " | ".join(scan.columns) + " |", "|---" * len(scan.columns) + "|"]
        lines += ["| " + " | ".join(fmt(v, 4) if isinstance(v, float) else str(v) for v in r) + " |"
                  for r in scan.itertuples(index=False)]
    lines += ["", "## Held-out campaign", "", "| | " + " | ".join(validation["fdd"]) + " |",
              "|---" * (len(validation) + 1) + "|"]
    for name, cell in (
        ("runs", lambda r: str(r["runs"])),
        ("fault-free runs", lambda r: str(r["fault_free_runs"])),
        ("LOE false alarms (per fault-free run)",
         lambda r: interval(r["false_alarms_loe"], r["fault_free_runs"], r["far_loe_lo"], r["far_loe_hi"])),
        ("any false alarm, incl. eta outside stall (per fault-free run)",
         lambda r: interval(r["false_alarms_any"], r["fault_free_runs"], r["far_any_lo"], r["far_any_hi"])),
        ("false identifications (per fault-free run)",
         lambda r: interval(r["false_identifications"], r["fault_free_runs"], r["false_identification_rate_lo"],
                             r["false_identification_rate_hi"])),
        ("MDR", lambda r: interval(r["missed"], r["faulty_runs"], r["mdr_lo"], r["mdr_hi"])),
        ("correct identification (of identified runs)", lambda r: fmt(r["identification_accuracy"])),
        ("detection time median / p95 / max (s)",
         lambda r: timing(r["detection_time_median_s"], r["detection_time_p95_s"], r["detection_time_max_s"])),
        ("stall detector above tau outside stall loads (runs)", lambda r: str(r["stall_detector_fires"])),
        ("eta = 1 outside stall loads (runs, signal)", lambda r: str(r["eta_false_alarms_signal"])),
        ("stall events identified, signal (worst latency s)", lambda r: f"{r['stall_identified_signal']} / "
         f"{r['stall_events']} ({fmt(r['stall_worst_latency_signal_s'])})"),
        ("stall events identified, model (worst latency s)", lambda r: f"{r['stall_identified_model']} / "
         f"{r['stall_events']} ({fmt(r['stall_worst_latency_model_s'])})"),
        ("runs with a stall load identified late (after the stall window) or not",
         lambda r: str(r["stall_late_or_missed"])),
        (f"{detector} tau_f / tau_d ({units}) / normalised gap", lambda r: " / ".join(
            fmt(r[f"{'stall_detector' if detector == 'stall' else 'loe_bank'}_{k}"], 4)
            for k in ("tau_f", "tau_d", "normalised_gap"))),
    ):
        lines.append(f"| {name} | " + " | ".join(cell(r) for _, r in validation.iterrows()) + " |")
    return "\n".join(lines) + "\n"

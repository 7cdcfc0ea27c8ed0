"""Campaign summaries (the edge): tidy tables of rates, detection times, confusion and gaps.

Input is the scenario table of a campaign (one row per scenario, parameters and the scoring
monitors' outcome columns, :mod:`mcfdd.analysis.scoring`: the definitions live there, the counts,
rates and Markdown here); output are pandas tables and a Markdown report. Rates carry exact
Clopper-Pearson 95 % intervals.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mcfdd.analysis import metrics

FAULT_BANDS = {"leakage": (0.0, 0.1, 0.2, 0.3, 1.0), "surface_damage": (0.0, 0.25, 0.5, 0.75, 1.0)}
VCAS_BINS_KT = (0.0, 200.0, 250.0, 300.0, 1000.0)
ALTITUDE_BINS_M = (-1.0, 3000.0, 7000.0, 20000.0)
QBAR_BINS_KPA = (0.0, 5.0, 10.0, 15.0, 20.0, 100.0)
LOAD_FRACTION_BINS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.6, 10.0)
NO_MOTION = "no motion"
DETECTABILITY_COLUMNS = ("fault_kind", "qbar_kpa_bin", "load_fraction_bin", "faulty_runs", "missed", "mdr", "mdr_lo",
                         "mdr_hi", "separable_runs", "separable", "missed_separable", "fault_distance_median",
                         "uncertainty_distance_median", "fault_free_runs", "false_alarms", "far", "far_lo", "far_hi")


def fault_class(df: pd.DataFrame) -> pd.Series:
    """Fault kind with a size band, e.g. ``leakage 10-20 %``."""
    labels = df["fault_kind"].astype(str).copy()
    for kind, edges in FAULT_BANDS.items():
        rows = df["fault_kind"] == kind
        size = df.loc[rows, "fault_size"].to_numpy()
        band = np.clip(np.searchsorted(edges, size, side="right") - 1, 0, len(edges) - 2)
        labels.loc[rows] = [f"{kind} {edges[b] * 100:.0f}-{edges[b + 1] * 100:.0f} %" for b in band]
    return labels


def _band_labels(edges, unit: str, scale: float = 1.0, below: bool = False) -> list[str]:
    """Readable labels of the bins ``[edges[i], edges[i + 1])`` in ``unit`` (edges / ``scale``): ``a-b``
    (a below 0 shown as 0), the last ``>= a`` and, with ``below``, the first ``< b``."""
    shown = [f"{max(e, 0.0) / scale:g}" for e in edges]
    labels = [f"{lo}-{hi} {unit}" for lo, hi in zip(shown[:-1], shown[1:])]
    if below:
        labels[0] = f"< {shown[1]} {unit}"
    labels[-1] = f">= {shown[-2]} {unit}"
    return labels


def envelope_bin(df: pd.DataFrame) -> pd.Series:
    """Envelope cell of each run, e.g. ``< 200 kt, 0-3 km``; categories ordered by speed, then altitude."""
    v = pd.cut(df["vcas_kt"], VCAS_BINS_KT, right=False, labels=_band_labels(VCAS_BINS_KT, "kt", below=True))
    h = pd.cut(df["altitude_m"], ALTITUDE_BINS_M, right=False, labels=_band_labels(ALTITUDE_BINS_M, "km", 1000.0))
    order = [f"{a}, {b}" for a in v.cat.categories for b in h.cat.categories]
    return pd.Series(pd.Categorical(v.astype(str) + ", " + h.astype(str), categories=order), index=df.index)


# The summary columns scripts read (README lists them). False alarms are counted per fault-free run:
# a faulty run can false-alarm only before its onset, so pooling it would dilute the rate.
FALSE_ALARM_COLUMNS = ("fault_free_runs", "scored_fault_free_h",
                       "false_alarms_loe", "far_loe", "far_loe_lo", "far_loe_hi", "far_loe_per_h", "far_loe_per_h_hi",
                       "false_alarms_any", "far_any", "far_any_lo", "far_any_hi", "far_any_per_h", "far_any_per_h_hi",
                       "false_identifications", "false_identification_rate", "false_identification_rate_lo",
                       "false_identification_rate_hi")


def _false_alarms(free: pd.DataFrame, scored_s: float | None) -> dict:
    """False alarms of the fault-free runs ``free`` (valid, no fault): LOE detection, any alarm (LOE detection or
    eta = 1 outside stall loads), false identification; rates per run with exact intervals, and per hour of scored
    time (``scored_s`` per run: the run after its settling time; the per-hour bound is the per-run bound times the
    runs over the hours)."""
    hours = len(free) * scored_s / 3600.0 if scored_s else float("nan")
    row = {"fault_free_runs": int(len(free)), "scored_fault_free_h": hours}
    for name, flags in (("loe", free["false_alarm"].to_numpy()), ("any", metrics.any_false_alarm(free))):
        r = metrics.rate(int(flags.sum()), len(free))
        row.update({f"false_alarms_{name}": r["k"], f"far_{name}": r["rate"], f"far_{name}_lo": r["lo"],
                    f"far_{name}_hi": r["hi"],
                    f"far_{name}_per_h": r["k"] / hours if hours > 0 else float("nan"),
                    f"far_{name}_per_h_hi": r["hi"] * len(free) / hours if hours > 0 else float("nan")})
    fid = metrics.rate(int(free["false_identification"].sum()), len(free))
    row.update({"false_identifications": fid["k"], "false_identification_rate": fid["rate"],
                "false_identification_rate_lo": fid["lo"],
                "false_identification_rate_hi": fid["hi"]})
    return row


def _rates(group: pd.DataFrame, scored_s: float | None) -> dict:
    ok = group["status"] == 0
    free = group[ok & (group["fault_kind"] == "none")]
    faulty = group["must_detect"]
    mdr = metrics.rate(int(group["missed"].sum()), int(faulty.sum()))
    identified = faulty & (group["identified_model"] >= 0)
    ident = metrics.rate(int((faulty & group["identified_correctly"]).sum()), int(identified.sum()))
    times = metrics.quantiles(group.loc[faulty & group["detected"], "detection_latency_s"])
    id_times = metrics.quantiles(group.loc[identified, "identification_latency_s"])
    events = int(group["stall_events"].sum())
    stall_sig = metrics.rate(int(group["stall_identified_signal"].sum()), events)
    stall_mod = metrics.rate(int(group["stall_identified_model"].sum()), events)
    return {
        "runs": int(len(group)), "runs_failed": int((~ok).sum()), **_false_alarms(free, scored_s),
        "eta_false_alarms_signal": int(free["eta_false_signal"].sum()),
        "eta_false_alarms_model": int(free["eta_false_model"].sum()),
        "faulty_runs": mdr["n"], "missed": mdr["k"], "mdr": mdr["rate"], "mdr_lo": mdr["lo"], "mdr_hi": mdr["hi"],
        "identified": ident["n"], "identified_correctly": ident["k"], "identification_accuracy": ident["rate"],
        "identification_lo": ident["lo"], "identification_hi": ident["hi"],
        "detection_time_median_s": times["median"], "detection_time_p95_s": times["p95"],
        "detection_time_max_s": times["max"], "identification_time_median_s": id_times["median"],
        "identification_time_max_s": id_times["max"],
        "stall_events": events, "stall_identified_signal": stall_sig["k"], "stall_rate_signal": stall_sig["rate"],
        "stall_rate_signal_lo": stall_sig["lo"], "stall_identified_model": stall_mod["k"],
        "stall_rate_model": stall_mod["rate"], "stall_rate_model_lo": stall_mod["lo"],
        "stall_worst_latency_signal_s": float(group["stall_worst_latency_signal_s"].max()),
        "stall_worst_latency_model_s": float(group["stall_worst_latency_model_s"].max()),
        "jammed_runs": int((ok & (group["fault_kind"] == "jamming")).sum()),
        "jam_taken_for_stall": int((ok & group["jam_taken_for_stall"]).sum()),
    }


def summary(df: pd.DataFrame, scored_s: float | None = None) -> pd.DataFrame:
    """Rates per stratum (``overall``, ``fault``, ``envelope``, ``manoeuvre``, ``turbulence``) and, within it,
    per ``label`` (fault class, envelope cell such as ``< 200 kt, 0-3 km``, ...). Tidy.

    False alarms and false identifications count the stratum's fault-free runs (:data:`FALSE_ALARM_COLUMNS`;
    a stratum without any, such as a fault class, has none to count), with the hours of scored fault-free time
    when ``scored_s`` (seconds scored per run: duration minus settling) is given; MDR and detection times its
    faulty runs; eta counts (stall identification outside stall loads) its fault-free runs too."""
    strata = {"overall": pd.Series("all", index=df.index), "fault": fault_class(df), "envelope": envelope_bin(df),
              "manoeuvre": df["manoeuvre_kind"].astype(str), "turbulence": df["turbulence"].astype(str)}
    rows = []
    for stratum, labels in strata.items():
        for label, group in df.groupby(labels, sort=True, observed=True):
            rows.append({"stratum": stratum, "label": str(label), **_rates(group, scored_s)})
    return pd.DataFrame(rows)


def confusion(df: pd.DataFrame, model_names) -> pd.DataFrame:
    """Counts of true (nearest) model against the first identified fault model (-1: none), parametric,
    fault-free (where an identification is a false one) and jammed runs (row ``jamming``: what the bank
    decides on a jammed rod). The identification level, apart from detection."""
    sub = df[df["status"] == 0]
    names = list(model_names)
    true_names = [names[i] if i >= 0 else "jamming" for i in sub["true_model"]]
    decided_names = [names[i] if i >= 0 else "no decision" for i in sub["identified_model"]]
    table = pd.crosstab(pd.Series(true_names, name="true_model"), pd.Series(decided_names, name="decided_model"))
    columns = [n for n in names + ["no decision"] if n in table.columns]
    return table.reindex(index=[n for n in names + ["jamming"] if n in table.index], columns=columns, fill_value=0)


def stall_confusion(df: pd.DataFrame, method: str) -> pd.DataFrame:
    """Stall identification against the truth: relevant stall events (identified by ``method``, 'signal' or
    'model'), jammed runs (eta = 1 of either method on the jammed rod) and the other runs (eta = 1 of
    ``method`` outside stall loads, before any fault). Columns: taken for a stall or not."""
    ok = df[df["status"] == 0]
    jammed = ok["fault_kind"] == "jamming"
    events, found = int(ok["stall_events"].sum()), int(ok[f"stall_identified_{method}"].sum())
    rows = {"relevant stall loads (events)": (found, events - found)}
    if jammed.any():
        taken = int(ok.loc[jammed, "jam_taken_for_stall"].sum())
        rows["jammed rods (runs)"] = (taken, int(jammed.sum()) - taken)
    others = ok.loc[~jammed, f"eta_false_{method}"].to_numpy(dtype=bool)
    rows["other runs, outside stall loads"] = (int(others.sum()), int((~others).sum()))
    return pd.DataFrame(rows.values(), index=list(rows), columns=["eta = 1 (stall)", "eta = 0"])


def gaps(df: pd.DataFrame, deg_per_m: float) -> pd.DataFrame:
    """Detection bounds per detector, eqs. (26)-(27), with the scenario of each extreme.

    LOE bank (units of theta / ||u||): tau_f = sup of the fault-free filter's ratio before any fault
    (no fault model can be decided, and no fault detected, while it is below tau); identification
    (``loe_bank``): tau_d = inf over faulty runs of the peak, within the detection window, of the
    smallest ratio among the filters that must fire; detection (``loe_detection``): tau_d = inf over
    faulty runs of the fault-free filter's peak ratio within the window.
    Stall detector (deg): tau_f = sup of theta over runs without any stall load, before any fault
    (the evaluator remembers a stall for about 1/gamma); tau_d = inf over relevant stall events of
    the peak theta within the stall window after onset.
    """
    ok = df["status"] == 0
    ids = df["scenario_id"].to_numpy()
    faulty = df["must_detect"]
    rows = []
    for name, free, detect, scale in (
        ("loe_bank", df["loe_ratio0_max_pre"].where(ok), df["loe_others_min_peak"].where(faulty), 1.0),
        ("loe_detection", df["loe_ratio0_max_pre"].where(ok), df["loe_ratio0_max_post"].where(faulty), 1.0),
        ("stall_detector", df["stall_theta_max_free"].where(ok & ~df["stall_seen"]),
         df["stall_theta_peak_min"].where(ok), deg_per_m),
    ):
        tau_f, f_id = metrics.bound_with_witness(free.to_numpy() * scale, ids, "sup")
        tau_d, d_id = metrics.bound_with_witness(detect.to_numpy() * scale, ids, "inf")
        rows.append({"detector": name, "tau_f": tau_f, "tau_f_scenario_id": f_id, "tau_d": tau_d,
                     "tau_d_scenario_id": d_id, "gap": tau_d - tau_f,
                     "units": "theta/||u||" if scale == 1.0 else "deg"})
    return pd.DataFrame(rows)


NA = "n/a"  # printed where a value does not exist (a rate of no runs, the time of no detection)


def fmt(v, digits=3):
    """A table cell of a number (``digits`` significant), or n/a for nan."""
    if isinstance(v, float):
        return NA if math.isnan(v) else f"{v:.{digits}g}"
    return str(v)


def timing(*values) -> str:
    """'a / b / c' of durations in s, or n/a when there are none."""
    return NA if all(math.isnan(v) for v in values) else " / ".join(fmt(v) for v in values)


def _stall_cell(identified: int, events: int, worst_s: float) -> str:
    return NA if events == 0 else f"{identified} (worst {fmt(worst_s)} s)"


def interval(k, n, lo, hi):
    """A table cell of a count of n runs: 'k/n = rate [lo, hi]', or n/a without runs."""
    if n == 0:
        return NA
    return f"{k}/{n} = {k / n:.3g} [{lo:.3g}, {hi:.3g}]"


def markdown(title: str, summ: pd.DataFrame, conf: pd.DataFrame, gap: pd.DataFrame, meta: dict,
             replay: str = "") -> str:
    """Human-readable campaign report; ``replay``: the command replaying the bounds' witnesses."""
    overall = summ[summ["stratum"] == "overall"].iloc[0]
    stalls = overall["stall_events"] > 0
    lines = [f"# {title}", "", f"{overall['runs']} scenarios ({overall['runs_failed']} failed numerically); "
             f"seed {meta.get('seed')}, mcfdd {meta.get('version')}, revision {meta.get('git_revision')}.", "",
             "Rates with exact Clopper-Pearson 95 % intervals; n/a where there is nothing to count.", "",
             "Detection (an LOE fault is present: the fault-free model rejected) gives false alarms, MDR and "
             "detection time; identification (the decoded signature, eq. 15) gives the identified runs, their "
             "accuracy and time, false identifications and the confusion matrix. False alarms count per "
             "fault-free run (a faulty run can false-alarm only before its onset): LOE detection, any alarm (LOE "
             "detection or a stall identification outside stall loads) and false identification; the overall "
             f"row adds their rate per hour of scored fault-free time ({fmt(overall['scored_fault_free_h'])} h: "
             "each run after its settling time)."
             + ("" if stalls else " No stall load occurred in any run, so the table has no stall columns."), "",
             f"Overall false alarms: LOE {per_hour_text(overall, 'loe')}, any alarm "
             f"{per_hour_text(overall, 'any')}.", "",
             "| stratum | runs | fault-free runs | LOE false alarms | any false alarm | false identifications "
             "| faulty | MDR | detection time median / p95 / max (s) "
             "| identified: correct / runs | identification time median / max (s) "
             + ("| stall events | identified (signal) | identified (model) |" if stalls else "|"),
             "|---" * (14 if stalls else 11) + "|"]
    for _, r in summ.iterrows():
        label = r["label"] if r["stratum"] == "overall" else f"{r['stratum']}: {r['label']}"
        stall_cells = (
            f" {r['stall_events']} "
            f"| {_stall_cell(r['stall_identified_signal'], r['stall_events'], r['stall_worst_latency_signal_s'])} "
            f"| {_stall_cell(r['stall_identified_model'], r['stall_events'], r['stall_worst_latency_model_s'])} |"
            if stalls else "")
        free, fid = r["fault_free_runs"], (r["false_identification_rate_lo"], r["false_identification_rate_hi"])
        lines.append(
            f"| {label} | {r['runs']} | {free} "
            f"| {interval(r['false_alarms_loe'], free, r['far_loe_lo'], r['far_loe_hi'])} "
            f"| {interval(r['false_alarms_any'], free, r['far_any_lo'], r['far_any_hi'])} "
            f"| {interval(r['false_identifications'], free, *fid)} "
            f"| {r['faulty_runs']} | {interval(r['missed'], r['faulty_runs'], r['mdr_lo'], r['mdr_hi'])} "
            f"| {timing(r['detection_time_median_s'], r['detection_time_p95_s'], r['detection_time_max_s'])} | "
            f"{interval(r['identified_correctly'], r['identified'], r['identification_lo'], r['identification_hi'])} "
            f"| {timing(r['identification_time_median_s'], r['identification_time_max_s'])} |" + stall_cells)
    lines += ["", "## Detection bounds (eqs. 26-27)", "",
              "| detector | tau_f | at scenario | tau_d | at scenario | gap tau_d - tau_f | units |",
              "|---|---|---|---|---|---|---|"]
    for _, r in gap.iterrows():
        lines.append(f"| {r['detector']} | {fmt(r['tau_f'], 4)} | {r['tau_f_scenario_id']} | {fmt(r['tau_d'], 4)} "
                     f"| {r['tau_d_scenario_id']} | {fmt(r['gap'], 4)} | {r['units']} |")
    if replay:
        lines += ["", f"Replay these scenarios (time histories and a figure per run): `{replay}`"]
    lines += ["", "## Confusion: true (nearest) model against first identified fault model", "",
              "| true \\ decided | " + " | ".join(conf.columns) + " |", "|---" * (len(conf.columns) + 1) + "|"]
    for name, row in conf.iterrows():
        lines.append(f"| {name} | " + " | ".join(str(v) for v in row.to_numpy()) + " |")
    return "\n".join(lines) + "\n"


def figures_markdown(drawn: dict, left_out: dict) -> str:
    """Section of summary.md: each figure written (name -> what it shows) and each left out (name -> why)."""
    lines = ["", "## Figures", ""]
    lines += [f"- `{name}.png`: {what}" for name, what in drawn.items()]
    lines += [f"- `{name}.png` left out: {why}." for name, why in left_out.items()]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# Detectability and stall scoring (``mcfdd campaign``)


def _bin_labels(values: pd.Series, edges) -> pd.Series:
    """``[lo, hi)`` labels of ``values`` in ``edges``; nan (the rod never moved) is :data:`NO_MOTION`."""
    labels = pd.cut(values, edges, right=False).astype(str)
    return labels.where(values.notna(), NO_MOTION)


def detectability(df: pd.DataFrame) -> pd.DataFrame:
    """FAR and MDR per fault kind and (dynamic-pressure bin x peak-load-fraction bin), tidy.

    A faulty run counts in the cell of its dynamic pressure and its peak load fraction after the
    onset; fault-free runs (over their settled run) give the FAR of the same cell, repeated for each
    fault kind. MDR counts the ``missed`` column of the scoring monitors. A cell is
    separable when most of its faulty runs are (fault distance above the uncertainty distance).
    """
    cell = ["qbar_kpa_bin", "load_fraction_bin"]
    df = df[df["status"] == 0].assign(qbar_kpa_bin=_bin_labels(df["qbar_kpa"], QBAR_BINS_KPA),
                                      load_fraction_bin=_bin_labels(df["peak_load_fraction"], LOAD_FRACTION_BINS))
    free = df[df["fault_kind"] == "none"]
    free_cells = dict(tuple(free.groupby(cell)))
    rows = []
    for kind in [k for k in ("leakage", "surface_damage", "disconnection") if (df["fault_kind"] == k).any()]:
        faulty = df[(df["fault_kind"] == kind) & df["must_detect"]]
        for key, g in faulty.groupby(cell):
            mdr = metrics.rate(int(g["missed"].sum()), len(g))
            sep = g["separable"].to_numpy(dtype=bool)
            fa = free_cells.get(key, free.iloc[:0])
            far = metrics.rate(int(fa["false_alarm"].sum()), len(fa))
            rows.append({
                "fault_kind": kind, "qbar_kpa_bin": key[0], "load_fraction_bin": key[1],
                "faulty_runs": mdr["n"], "missed": mdr["k"], "mdr": mdr["rate"], "mdr_lo": mdr["lo"],
                "mdr_hi": mdr["hi"], "separable_runs": int(sep.sum()), "separable": bool(sep.mean() > 0.5),
                "missed_separable": int(g["missed"].to_numpy(dtype=bool)[sep].sum()),
                "fault_distance_median": float(g["fault_distance"].median()),
                "uncertainty_distance_median": float(g["uncertainty_distance"].median()),
                "fault_free_runs": far["n"], "false_alarms": far["k"], "far": far["rate"], "far_lo": far["lo"],
                "far_hi": far["hi"]})
    det = pd.DataFrame(rows, columns=list(DETECTABILITY_COLUMNS))
    if det.empty:
        return det
    order = det["fault_kind"].map({"leakage": 0, "surface_damage": 1, "disconnection": 2})
    keys = pd.DataFrame({"kind": order, "qbar": det["qbar_kpa_bin"].map(bin_lower_edge),
                         "load": det["load_fraction_bin"].map(bin_lower_edge)})
    return det.loc[keys.sort_values(list(keys.columns)).index].reset_index(drop=True)


def bin_lower_edge(label: str) -> float:
    """Lower edge of a ``[lo, hi)`` label; :data:`NO_MOTION` sorts last."""
    return float(label[1:].split(",")[0]) if label.startswith("[") else np.inf


def detectability_markdown(det: pd.DataFrame, df: pd.DataFrame) -> str:
    """Section of summary.md: per fault kind, misses where the fault was separable and where it was not."""
    lines = ["", "## Detectability under the campaign's uncertainty", "",
             "Distance (16) |k_j - k_i| / (k_i + k_j) on the plant's small-error gains at each run's peak hinge-load "
             "fraction after the onset (rod moving): fault-free against the true fault, and the largest distance the "
             "uncertainty ranges of the campaign (Kci, supply pressure, hinge load) create on the fault-free gain. "
             "A run is separable when the first exceeds the second; a cell when most of its faulty runs are. "
             "Misses in separable runs are the FDD's; in the others nothing could tell the fault from the "
             "uncertainty.", ""]
    for kind in det["fault_kind"].unique():
        g = df[(df["fault_kind"] == kind) & df["must_detect"]]
        sep = g["separable"].to_numpy(dtype=bool)
        missed = g["missed"].to_numpy(dtype=bool)
        a = metrics.rate(int(missed[sep].sum()), int(sep.sum()))
        b = metrics.rate(int(missed[~sep].sum()), int((~sep).sum()))
        lines.append(f"- {kind}: missed {interval(a['k'], a['n'], a['lo'], a['hi'])} of the separable runs (the FDD "
                     f"misses what it could see), {interval(b['k'], b['n'], b['lo'], b['hi'])} of the runs not "
                     "separable under this uncertainty (nothing could).")
    if det.empty:
        return "\n".join(lines + ["No parametric faults in this campaign."]) + "\n"
    lines += ["", "| fault | qbar (kPa) | peak load fraction | separable | fault / uncertainty distance (median) "
              "| MDR | missed, separable runs | FAR (fault-free runs) |", "|---|---|---|---|---|---|---|---|"]
    for _, r in det.iterrows():
        lines.append(f"| {r['fault_kind']} | {r['qbar_kpa_bin']} | {r['load_fraction_bin']} "
                     f"| {'yes' if r['separable'] else 'no'} ({r['separable_runs']}/{r['faulty_runs']}) "
                     f"| {fmt(r['fault_distance_median'])} / {fmt(r['uncertainty_distance_median'])} "
                     f"| {interval(r['missed'], r['faulty_runs'], r['mdr_lo'], r['mdr_hi'])} "
                     f"| {r['missed_separable']}/{r['separable_runs']} "
                     f"| {interval(r['false_alarms'], r['fault_free_runs'], r['far_lo'], r['far_hi'])} |")
    return "\n".join(lines) + "\n"


def drivers_markdown(regional: pd.DataFrame, witnesses: pd.DataFrame, runs: str = "the campaign's runs",
                     top: int = 3, replay: str = "") -> str:
    """Section of summary.md: the top factors of the false alarms and misses (regional sensitivity of ``runs``,
    :func:`mcfdd.workflows.sensitivity.tables.regional_table`) and the worst witnesses (``replay``: the command
    replaying them)."""
    lines = ["", "## What drives the false alarms and misses", "",
             f"Regional sensitivity of {runs} (no extra simulation): each parameter's values in the runs with the "
             "event against the others, ranked by the distance D (Kolmogorov-Smirnov for ranges, total variation "
             "for lists), with its p-value (not adjusted for the parameters tested); Cliff's delta > 0 where the "
             "events sit at larger values, with its bootstrap interval; event rates per level of a list.", ""]
    for outcome, g in regional.groupby("outcome", sort=False):
        whole = g.loc[g["runs"].idxmax()]  # a fault-size parameter counts within its fault kind's runs only
        few = "; few events: an indication" if whole["events"] < 10 else ""
        lines.append(f"- {outcome.replace('_', ' ')} ({whole['events']} of {whole['runs']} runs{few}): " + "; ".join(
            f"{r.factor} D {r.statistic:.2f} (p {r.p_value:.2g}), " + (
                f"delta {r.effect:+.2f} [{r.effect_lo:+.2f}, {r.effect_hi:+.2f}]" if r.kind == "continuous"
                else r.rates)
            for r in g.head(top).itertuples()) + ".")
    if regional.empty:
        lines.append("- No false alarm and no miss to explain (or every run of its kind has one).")
    for outcome, g in witnesses.groupby("outcome", sort=False):
        lines.append(f"- Worst {outcome.replace('_', ' ')} witnesses: " + ", ".join(
            f"scenario {r.scenario_id} ({r.measure} {r.value:.3g})" for r in g.itertuples()) + ".")
    if replay:
        lines.append(f"- Replay the witnesses (time histories and a figure per run): `{replay}`.")
    return "\n".join(lines) + "\n"


def stall_scoring_markdown(df: pd.DataFrame) -> str:
    """Section of summary.md: jams taken for stalls (eta = 1 on a jammed rod) and LOE false alarms."""
    ok = df["status"] == 0
    jammed = df[ok & (df["fault_kind"] == "jamming")]
    free = df[ok & (df["fault_kind"] == "none")]
    loe = metrics.rate(int(free["false_alarm"].sum()), len(free))
    lines = ["", "## Jams taken for stalls and LOE false alarms", ""]
    if len(jammed):
        taken = jammed["jam_taken_for_stall"].to_numpy(dtype=bool)
        jam = metrics.rate(int(taken.sum()), len(jammed))
        after = (jammed["jam_taken_for_stall_time_s"] - jammed["fault_onset_s"])[taken]
        t = metrics.quantiles(after)
        when = f"; time after the jam onset median {fmt(t['median'])} s, max {fmt(t['max'])} s" if taken.any() else ""
        lines.append(f"- Jammed runs with eta = 1 (either identification method) on the jammed rod: "
                     f"{interval(jam['k'], jam['n'], jam['lo'], jam['hi'])}{when}.")
    else:
        lines.append("- No jammed runs in this campaign.")
    lines.append(f"- LOE false alarms in fault-free runs: {interval(loe['k'], loe['n'], loe['lo'], loe['hi'])}.")
    return "\n".join(lines) + "\n"


def per_hour_text(r: dict, name: str) -> str:
    """False alarms ('loe' or 'any') per hour of scored fault-free time with the upper bound, or n/a."""
    if not r["scored_fault_free_h"] > 0:
        return NA
    return f"{r[f'far_{name}_per_h']:.3g} per scored hour (< {r[f'far_{name}_per_h_hi']:.3g} at 95 %)"


def compare_lines(outcomes: pd.DataFrame, times: pd.DataFrame, labels) -> list[str]:
    """A paired comparison as two Markdown tables (printed by ``mcfdd compare``): per outcome the runs counted in
    both, each campaign's events, the discordant runs and McNemar's p; per fault kind the detection latency of the
    runs detected by both and the median of its difference b - a with the Wilcoxon signed-rank p."""
    a, b = labels
    rows = [f"| {r['outcome']} ({r['counted_on']}) "
            f"| {interval(r['events_a'], r['runs'], r['rate_a_lo'], r['rate_a_hi'])}"
            f" | {interval(r['events_b'], r['runs'], r['rate_b_lo'], r['rate_b_hi'])} | {r['only_a']} / {r['only_b']} "
            f"| {r['p_value']:.3g} |" for _, r in outcomes[outcomes["runs"] > 0].iterrows()]
    tim = [f"| {r['fault_kind']} | {r['runs']} | {fmt(r['median_a'])} | {fmt(r['median_b'])} | "
           f"{fmt(r['median_difference'])} | {fmt(r['p_value'])} |" for _, r in times.iterrows()]
    head = (f"| fault (detection latency) | detected by both | {a} median (s) | {b} median (s) | median of {b} - {a} "
            "(s) | Wilcoxon p |")
    return ([f"| outcome (runs) | {a} | {b} | discordant: {a} only / {b} only | McNemar p |", "|---|---|---|---|---|",
             *rows, "", head, "|---|---|---|---|---|---|", *tim])


def compare_markdown(outcomes: pd.DataFrame, times: pd.DataFrame, discordant: pd.DataFrame, labels, meta) -> str:
    """``compare.md``: the paired comparison of two campaigns of one space, with the discordant runs' ids."""
    ids = [f"- {name}: {labels[0]} only {list(g.loc[g['event_in'] == 'a', 'scenario_id'])}, {labels[1]} only "
           f"{list(g.loc[g['event_in'] == 'b', 'scenario_id'])}"
           for name, g in discordant.groupby("outcome", sort=False)]
    intro = (f"The same runs (seed {meta.get('seed') or NA}); mcfdd {meta.get('version')}. Counts with "
             "Clopper-Pearson 95 % intervals; McNemar's exact test on the discordant runs; detection latency on the "
             "runs both detect.")
    return "\n".join([f"# Paired comparison: {labels[0]} against {labels[1]}", "", intro, "",
                      *compare_lines(outcomes, times, labels), "", "## Discordant runs", "", *(ids or ["none"]), ""])

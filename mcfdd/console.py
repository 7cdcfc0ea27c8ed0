"""What the ``mcfdd`` command prints after each command (the edge): one or a few lines of its results."""

from __future__ import annotations

import math

import pandas as pd

from mcfdd.report import FAULT_BANDS, NA, per_hour_text


def value_text(value, spec: str = ".3g", unit: str = "") -> str:
    """``value`` formatted, or n/a where it does not exist (nan, None)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return NA
    return f"{value:{spec}}{unit}"


def rate_text(r: dict, key: str) -> str:
    """'rate [lo, hi]' of a summary row, or n/a when no run counts."""
    if math.isnan(r[key]):
        return NA
    return f"{r[key]:.4g} [{r[f'{key}_lo']:.3g}, {r[f'{key}_hi']:.3g}]"


def decisions_text(first: dict) -> str:
    """First decision time of each fault model, e.g. 'pressure-loss-27 at 21.74 s'."""
    return ", ".join(f"{model} at {t:.2f} s" for model, t in first.items()) or "none"


def count_text(r: dict, k: str, n: str, rate: str) -> str:
    """'k/n = rate [lo, hi]' of a summary row (columns ``k``, ``n``, ``rate``, ``rate_lo``, ``rate_hi``), n/a for
    n = 0."""
    return NA if r[n] == 0 else f"{r[k]}/{r[n]} = {rate_text(r, rate)}"


def campaign_lines(overall: dict, workers: pd.DataFrame | None) -> list[str]:
    """The overall rates of a campaign (false alarms per fault-free run, LOE and any alarm apart, false
    identifications beside them; MDR of the faulty runs), and each worker's throughput when chunks ran on
    workers."""
    stalls = f", stall events {overall['stall_events']}" if overall["stall_events"] else ""
    o, free = overall, "fault_free_runs"
    lines = [f"{o['runs']} scenarios ({o[free]} fault-free, {o['faulty_runs']} with a parametric fault): MDR "
             f"{count_text(o, 'missed', 'faulty_runs', 'mdr')}{stalls}",
             f"false alarms per fault-free run: LOE {count_text(o, 'false_alarms_loe', free, 'far_loe')}, "
             f"{per_hour_text(o, 'loe')}; any alarm (LOE or stall identification) "
             f"{count_text(o, 'false_alarms_any', free, 'far_any')}; false identifications "
             f"{count_text(o, 'false_identifications', free, 'false_identification_rate')}"]
    if workers is not None and len(workers):
        lines.append(f"workers: {len(workers)}; " + ", ".join(
            f"{w['worker']} {w['scenarios']} scen in {w['chunks']} chunk(s), {w['scenario_steps_per_s']:.3g} "
            f"scenario-steps/s" for _, w in workers.iterrows()))
    return lines


def simulate_lines(summary: pd.DataFrame) -> list[str]:
    return [f"{r['run']}: max |delta| {r['max_abs_delta_deg']:.2f} deg, stall {r['stall_s']:.2f} s, eta_stall "
            f"{r['eta_stall_s']:.2f} s, first decisions {decisions_text(r['first_decisions_s'])}"
            for _, r in summary.iterrows()]


def fit_lpv_lines(models, k0, error_summary: dict, distances) -> list[str]:
    """Each model's fit error (training and validation) and the smallest distances between neighbours."""
    tr, va = error_summary["training"], error_summary["validation"]
    lines = [f"{'model':<18s} {'k0 1/s':>7s}  {'training RMS / max %':>21s}  {'validation RMS / max %':>23s}  "
             f"near-stall runs"]
    lines += [f"{name:<18s} {float(k0[i]):7.3f}  {100 * tr['rms'][i]:10.3f} / {100 * tr['max'][i]:7.3f}  "
              f"{100 * va['rms'][i]:12.3f} / {100 * va['max'][i]:7.3f}  {tr['near_stall_runs'][i]} / "
              f"{va['near_stall_runs'][i]}" for i, name in enumerate(models)]
    lines += ["smallest H-inf distance |k_j - k_i| / (k_i + k_j) of neighbouring models over the envelope grid",
              "(overall; where the nonlinear models are at least 0.01 apart and keep the pressure margin):"]
    lines += [f"  {models[d.i]:>18s} - {models[d.j]:<18s} {d.overall:.4f}   {d.separated:.4f} "
              f"(nonlinear there {d.nonlinear:.4f})" for d in distances]
    return lines


def worst_case_lines(summ: pd.DataFrame, value: str) -> list[str]:
    return [f"{r['method']}: {r['simulations']} simulations, {r['run_time_s']:.1f} s, worst "
            f"{value_text(r[value], '.5g')}" for _, r in summ.iterrows()]


def tune_lines(validation: pd.DataFrame) -> list[str]:
    return [f"{r['fdd']}: false alarms in {r['fault_free_runs']} fault-free runs: LOE {r['false_alarms_loe']}, any "
            f"{r['false_alarms_any']}; MDR "
            f"{r['missed']}/{r['faulty_runs']}, detection time median "
            f"{value_text(r['detection_time_median_s'], unit=' s')}, stall detector above tau outside stalls in "
            f"{r['stall_detector_fires']} runs" for _, r in validation.iterrows()]


def figures_lines(sweep: pd.DataFrame, grid: dict, stall_events: pd.DataFrame, eta_outside_s: dict) -> list[str]:
    """Fig. 4's decision per grid fault, Fig. 5's eta latencies and the eta time outside stall events."""
    lines = []
    for fam in ("surface", "leakage"):
        rows = sweep[sweep["family"] == fam]
        for v in grid[fam]:
            row = rows.iloc[(rows["fault_size"] - v).abs().argmin()]
            lines.append(f"fig4 {fam} {100 * row['fault_size']:.0f} %: decided {row['detected_model_name']}, first "
                         f"fault model after {value_text(row['detection_time_s'], '.2f', ' s')}, "
                         f"{row['switches']} switch(es)")
    for _, e in stall_events.iterrows():
        parts = [f"{m} none" if math.isnan(e[f"latency_{m}_s"]) else f"{m} {e[f'latency_{m}_s']:.2f} s"
                 for m in ("signal", "model")]
        lines.append(f"stall event {e['onset_s']:.2f}-{e['end_s']:.2f} s: eta latency " + ", ".join(parts))
    lines += [f"eta ({method}) outside stall events: {seconds:.2f} s" for method, seconds in eta_outside_s.items()]
    return lines


def replay_line(row) -> str:
    """One replayed scenario's verdicts (a row of its scenario table), as ``mcfdd replay`` prints them."""
    def at(column):
        t = float(row[column])
        return value_text(t if math.isfinite(t) else float("nan"), ".2f", " s")

    size = f" {row['fault_size']:.3g}" if row["fault_kind"] in FAULT_BANDS else ""
    onset = "" if row["fault_kind"] == "none" else f" at {row['fault_onset_s']:.3g} s"
    return (f"scenario {row['scenario_id']}: {row['fault_kind']}{size}{onset}, {row['manoeuvre_kind']}; false alarm "
            f"{at('false_alarm_time_s')}, detection {at('detection_time_s')}, identified model "
            f"{row['identified_model']} ({at('identification_time_s')}), largest fault-free ratio before the fault "
            f"{value_text(float(row['loe_ratio0_max_pre']))}, status {row['status']}")

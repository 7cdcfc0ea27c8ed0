"""``mcfdd tune`` at the LOE detection level (``tune.level = "detection"``): the decisions that set FAR and MDR.

:mod:`mcfdd.analysis.detection_tuning` tunes the detection thresholds, excitation floor, evaluator
and pole on the smooth tau_f / tau_d of the detection monitor's margins over stored plant
histories, then scans the detection thresholds on the training set (Pareto set of false alarms,
missed detections and detection time) and chooses the smallest alarm-free factor times a safety
factor, or with ``tune.max_missed_fraction`` the candidate with the fewest false alarms among those
within the miss limit (:func:`mcfdd.analysis.detection_tuning.choose_within`). The held-out
campaign (another seed) runs with the configured FDD ('before') and the tuned one ('after') and the
two are compared run by run (:func:`mcfdd.compare`, McNemar's exact test).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from mcfdd import config, io
from mcfdd.analysis import build, detection_tuning as dt, metrics
from mcfdd.progress import note
from mcfdd.workflows.common import dtype_of, load_bank
from mcfdd.workflows.compare import compare
from mcfdd.workflows.tune import TuneResult, ascend, held_out, training_set

COUNTS = ("false_alarms", "missed", "detection_time_s")


def tuned_fdd(fdd: config.FddConfig, values: dict, scale: float, deg: float) -> config.FddConfig:
    """FddConfig with the tuned detection level (6 significant digits; the thresholds times ``scale``)."""
    keys = {"alpha": "evaluator.alpha", "beta": "evaluator.beta", "gamma_1_s": "evaluator.gamma_1_s",
            "pole_1_s": "pole_1_s", "excitation_noise_factor": "excitation_noise_factor",
            "detection_confirm_s": "detection_confirm_s"}
    changes = {f"loe.{keys[k]}": v for k, v in values.items() if k in keys}
    if "excitation_floor" in values:
        changes["loe.excitation_floor_deg"] = values["excitation_floor"] / deg
    for k in dt.THRESHOLDS:
        if k in values:
            changes[f"loe.{k}"] = values[k] * scale
    return config.replace(fdd, {k: float(f"{v:.6g}") for k, v in changes.items()})


def acceptance(table: pd.DataFrame) -> dict:
    """The held-out figures of a campaign table: LOE false alarms in fault-free runs, disconnections from peak
    load fraction ``metrics.LOAD_FRACTION_HIGH`` missed, median detection latency of the detected faulty runs (s)."""
    outcomes = metrics.paired_outcomes(table)
    out = {}
    for key, event_name, runs_name in (("loe_false_alarm", "fault_free_false_alarms", "fault_free_runs"),
                                       ("missed_disconnection_loaded", "loaded_disconnections_missed",
                                        "loaded_disconnections"),
                                       ("missed_separable", "separable_missed", "separable_runs"),
                                       ("missed", "missed", "faulty_runs")):
        _, runs, event = outcomes[key]
        out[event_name], out[runs_name] = int((runs & event).sum()), int(runs.sum())
    detected = np.asarray(table["detected"], bool) & np.asarray(table["must_detect"], bool)
    out["detection_time_median_s"] = float(np.median(table["detection_latency_s"][detected])) if detected.any() \
        else float("nan")
    return out


def tune_detection(cfg: config.TuneConfig, source, progress: bool):
    """The detection-level tuning of a 'tune' config (see the module docstring); a :class:`TuneResult`."""
    ts, tr = cfg.tune, cfg.training
    dtype = dtype_of(tr.precision)
    model = build.plant_model(cfg.plant)
    r_arm = model.actuator.r_arm_m
    deg = math.radians(1.0) * r_arm
    bank, names = load_bank(cfg.fdd, dtype)
    fdd_params = build.fdd_params(cfg.fdd, bank, r_arm)
    settings = build.settings(cfg.evaluation, r_arm)
    start = time.perf_counter()
    train_cfg = cfg.campaign("training")
    data, n = training_set(train_cfg, model, bank, dtype)
    design, _ = build.design(train_cfg)
    hard = jax.device_get(dt.evaluate_columns(fdd_params, settings, data, tr.dt_s))
    must = dt.must_detect_mask(hard, design, metrics.uncertainty_ranges(design), ts.must_detect,
                               ts.must_detect_kinds, ts.min_peak_load_fraction)
    t_plant = time.perf_counter() - start
    tuned_names = dt.names(fdd_params.loe, ts.tune_pole, ts.tune_confirmation)
    theta0 = dt.initial(fdd_params, tuned_names)
    note(f"training set: {n} runs of {tr.duration_s} s simulated once in {t_plant:.1f} s, {int(must.sum())} that "
         f"must be detected; tuning the LOE detection level ({', '.join(tuned_names)}) over {ts.iterations} "
         f"iterations", progress)

    def gap_and_grad(theta):
        return dt.gap_and_grad(theta, fdd_params, settings, data, must, ts.temperature, tr.dt_s)

    result, t_tune = ascend(gap_and_grad, theta0, ts, progress, lambda b: (
        f"tau_f {b['tau_f']:.4g}, tau_d {b['tau_d']:.4g}, false alarms {b['false_alarms']:.0f}, "
        f"missed {b['missed']:.0f}"))
    best = dt.best_iterate(result)
    theta = result.thetas[best]
    b = result.bounds[best]
    positive = bool(b["tau_d"] > b["tau_f"])
    lo, hi = ts.scan_scales
    scales = np.geomspace(lo, hi, ts.threshold_candidates)
    start = time.perf_counter()
    first = jax.device_get(dt.scan(theta, fdd_params, settings, data, must, np.asarray(scales, dtype), tr.dt_s))
    if ts.max_missed_fraction is None:
        scale, qualified = dt.choose(scales, first["false_alarms"], ts.safety), None
    else:
        scale, qualified = dt.choose_within(scales, first["false_alarms"], first["missed"],
                                            first["detection_time_s"], int(must.sum()), ts.max_missed_fraction)
    scales_all = np.unique(np.append(scales, scale))
    got = jax.device_get(dt.scan(theta, fdd_params, settings, data, must, np.asarray(scales_all, dtype), tr.dt_s))
    t_scan = time.perf_counter() - start
    values = dt.natural(theta)
    scan = pd.DataFrame({"scale": scales_all,
                         **{k: np.asarray(values[k]) * scales_all for k in dt.THRESHOLDS if k in values},
                         **{f"training_{k}": np.asarray(got[k]) for k in (*COUNTS, "tau_f", "tau_d")}})
    scan["pareto"] = dt.pareto(scan["training_false_alarms"], scan["training_missed"],
                               scan["training_detection_time_s"])
    scan["chosen"] = np.isclose(scan["scale"], scale, rtol=1e-12)
    tuned = tuned_fdd(cfg.fdd, values, scale, deg)
    history = pd.DataFrame([{"iteration": i, "smooth_gap": g, "tau_f": r["tau_f"], "tau_d": r["tau_d"],
                             "gap": r["tau_d"] - r["tau_f"], **{k: r[k] for k in COUNTS}, **dt.natural(th)}
                            for i, (th, g, r) in enumerate(zip(result.thetas, result.gaps, result.bounds))])
    note(f"  tuned in {t_tune:.1f} s; iteration {best}: tau_f {b['tau_f']:.4g}, tau_d {b['tau_d']:.4g} "
         f"({'positive' if positive else 'no positive'} gap); thresholds x{scale:.4g} chosen from "
         f"{len(scales)} candidates in {t_scan:.1f} s", progress)
    if qualified is False:
        note(f"  no candidate misses at most {ts.max_missed_fraction} of the {int(must.sum())} must-detect runs: "
             f"the one with the fewest missed taken", progress)
    old, new = cfg.fdd.loe, tuned.loe
    rows = [("alpha", old.evaluator.alpha, new.evaluator.alpha), ("beta", old.evaluator.beta, new.evaluator.beta),
            ("gamma_1_s", old.evaluator.gamma_1_s, new.evaluator.gamma_1_s)]
    rows += [(k, getattr(old, k), getattr(new, k)) for k in (
        "pole_1_s", "detection_tau", "detection_contrast", "excitation_floor_deg", "excitation_noise_factor",
        "detection_confirm_s")]
    parameters = pd.DataFrame([{"parameter": k, "before": x, "after": y} for k, x, y in rows])

    campaigns, compiles, t_val, validation = held_out(cfg, tuned, 180.0 / math.pi / r_arm, progress)
    for label in ("before", "after"):
        for k, v in acceptance(campaigns[label].scenarios).items():
            validation.loc[validation["fdd"] == label, f"held_out_{k}"] = v
    paired = compare(campaigns["before"], campaigns["after"], ("before", "after"))
    meta = io.provenance(config.to_json(cfg), tr.seed, models=list(names), validation_seed=str(cfg.validation.seed))
    text = markdown(cfg, source, n, int(must.sum()), history, best, positive, qualified, scan, parameters, validation,
                    paired, {"plant": t_plant, "tune": t_tune, "scan": t_scan, "validation": t_val}, compiles, meta)
    out = TuneResult("loe", tuned, history, parameters, validation, scan, campaigns, compiles, text, "theta/||u||",
                     meta, source)
    out.comparison, out.level = paired, "detection"
    return out


def _cell(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else ""
    if isinstance(v, (float, np.floating)):
        return "nan" if not np.isfinite(v) else f"{v:.4g}"
    return str(v)


def _table(df: pd.DataFrame) -> list[str]:
    return ["| " + " | ".join(df.columns) + " |", "|---" * len(df.columns) + "|",
            *("| " + " | ".join(_cell(v) for v in r) + " |" for r in df.itertuples(index=False))]


def _rule(ts, n_must: int, qualified) -> str:
    """The threshold choice of a detection-level tuning, in words."""
    if ts.max_missed_fraction is None:
        return f"the smallest factor from which no candidate alarms on the training set, times {ts.safety}."
    limit = f"at most {ts.max_missed_fraction} of the {n_must} must-detect runs missed"
    return (f"the candidate with the fewest training false alarms among those with {limit} (ties to the faster "
            f"median detection)." + ("" if qualified else f" NO candidate has {limit}: the one with the fewest "
                                                          f"missed taken."))


def markdown(cfg, source, n, n_must, history, best, positive, qualified, scan, parameters, validation, paired, times,
             compiles, meta) -> str:
    """report.md of a detection-level tuning."""
    ts, tr, va = cfg.tune, cfg.training, cfg.validation
    must = (f"{ts.must_detect} must-detect runs" + (f" of {', '.join(ts.must_detect_kinds)}" if ts.must_detect_kinds
                                                     else "")
            + (f" with peak load fraction >= {ts.min_peak_load_fraction}" if ts.min_peak_load_fraction else ""))
    b = history.iloc[best]
    title = f"Tuning {Path(source).stem}" if source is not None else "Tuning"
    keep = ["fdd", "runs", "fault_free_runs", "false_alarms_loe", "false_alarms_any", "false_identifications",
            "faulty_runs", "missed"] + [
        c for c in validation.columns if c.startswith("held_out_")]
    lines = [f"# {title} (LOE detection level)", "",
             f"Training: {n} stored plant histories of {tr.duration_s} s (seed {tr.seed}; simulated once in "
             f"{times['plant']:.1f} s); tau_d over the {n_must} {must}. Objective: the smooth gap tau_d - tau_f of "
             f"the detection monitor's margins (units theta_0 / ||u||; temperature {ts.temperature}), Adam, "
             f"{ts.iterations} iterations at learning rate {ts.learning_rate} on the parameters' logarithms "
             f"({times['tune']:.1f} s). Iteration {best} (largest hard gap) kept: tau_f {b['tau_f']:.4g}, tau_d "
             f"{b['tau_d']:.4g}: "
             + ("a positive gap." if positive else "NO positive gap on the training set; the trade-off below."),
             "", f"Thresholds: detection_tau and detection_contrast scaled by {ts.threshold_candidates} factors in "
             f"{list(ts.scan_scales)} ({times['scan']:.1f} s); chosen: {_rule(ts, n_must, qualified)}", "",
             "## Parameters", "", *_table(parameters), "",
             "## Training set, per iteration (first, chosen, last)", "",
             *_table(history.iloc[sorted({0, best, len(history) - 1})][
                 ["iteration", "smooth_gap", "tau_f", "tau_d", "gap", *COUNTS]]),
             "", "## Thresholds on the training set (pareto: not dominated in false alarms, missed, time)", "",
             *_table(scan), "",
             f"## Held-out campaign ({va.scenarios} scenarios, seed {va.seed}, {va.duration_s} s; "
             f"{times['validation']:.1f} s, compilations {compiles['before']}, {compiles['after']})", "",
             *_table(validation[keep].T.reset_index().rename(columns={"index": "", 0: "before", 1: "after"})), "",
             "## Paired comparison on the held-out campaign (before vs after, McNemar's exact test)", "",
             *paired.lines(), "",
             f"seed {meta.get('seed')}, mcfdd {meta.get('version')}, revision {meta.get('git_revision')}."]
    return "\n".join(lines) + "\n"

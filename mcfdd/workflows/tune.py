"""Gradient tuning of a detector's evaluator, pole and threshold, checked on a held-out campaign (``mcfdd tune``)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from mcfdd import config, io, search_report
from mcfdd.analysis import batch, build, scenarios, scoring, simulate, tuning
from mcfdd.progress import bar, note
from mcfdd.workflows.campaign import run_campaign, scored_seconds
from mcfdd.workflows.common import CompileCounter, as_config, dtype_of, load_bank, precision, save_figure


def training_set(cfg: config.CampaignConfig, model, bank, dtype):
    """Plant histories of a campaign's design, simulated once, with what their evaluation needs.

    Returns (:class:`mcfdd.analysis.tuning.TrainingSet`, number of runs).
    """
    c = cfg.campaign
    cols, n = build.design(cfg)
    kind = np.asarray(cols.get("fault_kind", np.full(n, "none")))
    nearest, accept = scenarios.true_model(np.asarray(bank.nu), kind, np.asarray(cols.get("fault_size", np.zeros(n))))
    scen = scenarios.to_scenario(cols, dtype)
    plant = simulate.plant_batch(model, scen, simulate.run_keys(c.seed, range(n)), c.n_steps, c.dt_s, c.substeps,
                                 batch.kinds_in(scen.manoeuvre.kind))
    truth = scoring.Truth(jnp.asarray(scenarios.fault_onsets(cols, n), dtype), jnp.asarray(accept),
                          jnp.asarray(nearest))
    return tuning.TrainingSet(plant, truth), n


def tuned_fdd(fdd: config.FddConfig, detector: str, params: dict, tau: float, tune_pole: bool, deg_per_m: float):
    """FddConfig with a detector's tuned evaluator, pole and threshold (6 significant digits), range-checked."""
    p = {k: float(f"{v:.6g}") for k, v in params.items()}
    changes = {f"{detector}.evaluator.{k}": p[k] for k in ("alpha", "beta", "gamma_1_s")}
    if tune_pole:
        changes[f"{detector}.pole_1_s"] = p["pole_1_s"]
    if detector == "stall":
        changes["stall.tau_deg"] = float(f"{tau * deg_per_m:.6g}")
    else:
        changes["loe.tau"] = float(f"{tau:.6g}")
    return config.replace(fdd, changes)


class TuneResult:
    """A tuned detector and its check on a held-out campaign.

    Attributes:
        detector: 'stall' or 'loe'.
        fdd: the tuned FDD settings (an ``FddConfig``; ``mcfdd.load_config(..., overrides=...)``
            or a config's ``fdd`` takes them).
        history: one row per iteration: smooth log gap, tau_f, tau_d (deg or theta/||u||), the
            normalised gap and the parameters.
        parameters: before and after of alpha, beta, gamma_1_s, pole_1_s and the threshold.
        validation: the held-out campaign's rates before and after tuning.
        threshold_scan: false alarms and misses of candidate thresholds on the training set when
            the gap stayed negative, else None.
        campaigns: the held-out :class:`CampaignResult` before and after ('before', 'after').
        compilations: XLA compilations during each held-out campaign (after: 0, the FDD is traced).
        meta: provenance.
    """

    def __init__(self, detector, fdd, history, parameters, validation, threshold_scan, campaigns, compilations,
                 report_text, units, meta, source):
        self.detector, self.fdd, self.history, self.parameters = detector, fdd, history, parameters
        self.validation = validation
        self.threshold_scan, self.campaigns, self.compilations = threshold_scan, campaigns, compilations
        self.report_text, self.units, self.meta, self._source = report_text, units, meta, source
        self.level = "identification" if detector == "loe" else "stall"
        self.comparison = None  # detection level: the held-out campaigns before and after, paired (CompareResult)

    def plot(self, name: str = "history"):
        """'history': tau_f, tau_d and the normalised gap over the iterations, a matplotlib Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if name != "history":
            raise ValueError(f"plot: {name!r} is not one of history")
        if self.level == "detection":
            return plots.detection_tuning_history(self.history)
        return plots.tuning_history(self.history, self.units)

    def fdd_toml(self, fragment_path) -> str:
        """The tuned ``[fdd]`` fragment as TOML text (``mcfdd campaign CONFIG --fdd FILE``)."""
        return config.fdd_fragment(self.fdd, (
            f"FDD settings tuned by `mcfdd tune {self._source or 'CONFIG'}` ("
            + ("LOE detection level: detection thresholds, excitation floor, evaluator and pole"
               if self.level == "detection" else f"{self.detector} detector: evaluator, pole and threshold")
            + f").\nUse with `mcfdd campaign CONFIG --fdd {fragment_path}`."))

    def save(self, out) -> list[Path]:
        """Write the files of ``mcfdd tune`` into ``out``: ``tuned_fdd.toml``, ``history.parquet``,
        ``parameters.parquet``, ``validation.parquet``, ``threshold_scan.parquet`` (if any), ``report.md``,
        ``history.png`` and the held-out campaigns under ``validation/before`` and ``validation/after``."""
        out = Path(out)
        written = [io.write_text(out / "tuned_fdd.toml", self.fdd_toml(out / "tuned_fdd.toml")),
                   io.write_table(self.history, out / "history.parquet", self.meta),
                   io.write_table(self.parameters, out / "parameters.parquet", self.meta),
                   io.write_table(self.validation, out / "validation.parquet", self.meta)]
        if self.threshold_scan is not None:
            written.append(io.write_table(self.threshold_scan, out / "threshold_scan.parquet", self.meta))
        written.append(io.write_text(out / "report.md", self.report_text))
        written.append(save_figure(self.plot(), out / "history.png"))
        for label, result in self.campaigns.items():
            written.extend(result.save(out / "validation" / label, f"Held-out campaign, FDD {label} tuning"))
        if self.comparison is not None:
            written.extend(self.comparison.save(out / "validation" / "compare"))
        return written


def held_out(cfg: config.TuneConfig, tuned: config.FddConfig, deg_per_m: float, progress: bool):
    """The held-out campaign with the configured FDD ('before') and ``tuned`` ('after'), one compilation.

    Returns (campaigns by label, XLA compilations by label, seconds, :func:`mcfdd.search_report.validation_table`).
    """
    campaigns, compiles = {}, {}
    start = time.perf_counter()
    for label, fdd_cfg in (("before", cfg.fdd), ("after", tuned)):
        note(f"held-out campaign, FDD {label} tuning", progress)
        with CompileCounter() as counter:
            campaigns[label] = run_campaign(cfg.campaign("validation", fdd_cfg), progress=progress)
        compiles[label] = counter.count
    seconds = time.perf_counter() - start
    validation = search_report.validation_table({k: v.scenarios for k, v in campaigns.items()}, deg_per_m,
                                         cfg.fdd.stall.identification, scored_seconds(campaigns["before"].config))
    return campaigns, compiles, seconds, validation


def ascend(gap_and_grad, theta0, ts, progress: bool, postfix) -> tuple[tuning.Result, float]:
    """:func:`mcfdd.analysis.tuning.tune` of ``gap_and_grad`` from ``theta0`` with the config's iterations and
    learning rate, under a progress bar whose postfix is ``postfix(bounds)``. Returns (result, seconds)."""
    start = time.perf_counter()
    with bar(ts.iterations + 1, "tuning evaluations", progress) as shown:
        def callback(i, gap, b):
            shown.set_postfix_str(postfix(b), refresh=False)
            shown.update(1)

        result = tuning.tune(gap_and_grad, theta0, ts.iterations, ts.learning_rate, callback)
    return result, time.perf_counter() - start


def tune(cfg, progress: bool = True) -> TuneResult:
    """Tune one detector's evaluator (alpha, beta, gamma), pole and threshold by gradient.

    With ``tune.level = "detection"`` (LOE bank) the detection level is tuned instead
    (:mod:`mcfdd.workflows.tune_detection`: detection thresholds, excitation floor, evaluator, pole on
    the detection monitor's margins; ``threshold_scan`` is then the Pareto scan of the thresholds and
    ``comparison`` the held-out campaigns' paired comparison). Otherwise the plant histories of the
    training campaign are simulated once; the detector's parameters follow Adam on the smooth
    log(tau_d / tau_f) through an FDD-only scan; tau is placed in the gap; the held-out campaign
    runs with the FDD before and after, in one compilation.

    Args:
        cfg: a 'tune' config (:func:`mcfdd.load_config`), or a TOML path or dict of one.
        progress: status lines and bars on stderr; False for silence.

    Returns:
        A :class:`TuneResult`.

    >>> import mcfdd
    >>> space = {"vcas_kt": 380.0, "altitude_m": 0.0, "hinge_scale": 1.3, "manoeuvre_kind": "ol_step",
    ...          "amplitude": [0.9, 1.0], "t_start_s": 0.2, "duration_s": 1.0, "ramp_s": 0.1}
    >>> cfg = {"tune": {"iterations": 1}, "training": {"scenarios": 2, "duration_s": 1.5},
    ...        "validation": {"scenarios": 2, "seed": 1, "duration_s": 1.5}, "evaluation": {"settle_s": 0.1},
    ...        "space": space}
    >>> list(mcfdd.tune(cfg, progress=False).validation["fdd"])
    ['before', 'after']
    """
    source = cfg if isinstance(cfg, (str, Path)) else None
    cfg = as_config(cfg, "tune")
    with precision(cfg.training.precision):
        if cfg.tune.level == "detection":
            from mcfdd.workflows.tune_detection import tune_detection  # it builds on this module's TuneResult

            return tune_detection(cfg, source, progress)
        return _tune(cfg, source, progress)


def _tune(cfg: config.TuneConfig, source, progress: bool) -> TuneResult:
    ts, tr = cfg.tune, cfg.training
    det = ts.detector
    dtype = dtype_of(tr.precision)
    model = build.plant_model(cfg.plant)
    r_arm = model.actuator.r_arm_m
    deg_per_m = 180.0 / math.pi / r_arm
    scale, units = (deg_per_m, "deg") if det == "stall" else (1.0, "theta/||u||")
    bank, names = load_bank(cfg.fdd, dtype)
    fdd_params = build.fdd_params(cfg.fdd, bank, r_arm)
    settings = build.settings(cfg.evaluation, r_arm)
    start = time.perf_counter()
    data, n = training_set(cfg.campaign("training"), model, bank, dtype)
    jax.block_until_ready(data)
    t_plant = time.perf_counter() - start
    note(f"training set: {n} runs of {tr.duration_s} s simulated once in {t_plant:.1f} s; tuning the {det} detector "
         f"({'pole, ' if ts.tune_pole else ''}alpha, beta, gamma) over {ts.iterations} iterations", progress)
    before = {k: float(v) for k, v in tuning.evaluate(fdd_params, settings, data, ts.temperature, tr.dt_s, det).items()}

    def gap_and_grad(theta):
        return tuning.gap_and_grad(theta, fdd_params, settings, data, ts.temperature, tr.dt_s, det, ts.tune_pole)

    result, t_tune = ascend(gap_and_grad, tuning.initial(fdd_params, det), ts, progress, lambda b: (
        f"tau_f {b['tau_f'] * scale:.4g}, tau_d {b['tau_d'] * scale:.4g} {units}, "
        f"normalised gap {tuning.normalised_gap(b['tau_f'], b['tau_d']):.4g}"))
    best = tuning.best_iterate(result)
    chosen = tuning.natural(result.thetas[best])
    tau_f, tau_d = result.bounds[best]["tau_f"], result.bounds[best]["tau_d"]
    scan = None
    if not tau_d > tau_f:
        taus = tuning.candidates(tau_f, tau_d, ts.threshold_candidates)
        trial = build.fdd_params(tuned_fdd(cfg.fdd, det, chosen, tau_f, ts.tune_pole, deg_per_m), bank, r_arm)
        start = time.perf_counter()
        false, missed = tuning.threshold_scan(trial, settings, data, np.asarray(taus, dtype), tr.dt_s, det,
                                              cfg.fdd.stall.identification)
        scan = pd.DataFrame({f"tau_{'deg' if det == 'stall' else 'ratio'}": taus * scale,
                             "training_false_alarms": np.asarray(false), "training_misses": np.asarray(missed)})
        note(f"  negative gap: {len(taus)} thresholds compared on the training set in "
             f"{time.perf_counter() - start:.1f} s", progress)
    tau = tuning.place_threshold(tau_f, tau_d, ts.margin, *(() if scan is None else (
        taus, scan["training_false_alarms"], scan["training_misses"])))
    tuned = tuned_fdd(cfg.fdd, det, chosen, tau, ts.tune_pole, deg_per_m)
    history = pd.DataFrame([{"iteration": i, "smooth_log_gap": g, "tau_f": b["tau_f"] * scale,
                             "tau_d": b["tau_d"] * scale,
                             "normalised_gap": tuning.normalised_gap(b["tau_f"], b["tau_d"]), **tuning.natural(th)}
                            for i, (th, g, b) in enumerate(zip(result.thetas, result.gaps, result.bounds))])
    note(f"  tuned in {t_tune:.1f} s; iteration {best}: tau_f {tau_f * scale:.4g}, tau_d {tau_d * scale:.4g} {units}, "
         f"tau {tau * scale:.4g}", progress)
    old, new = getattr(cfg.fdd, det), getattr(tuned, det)
    tau_key = "tau_deg" if det == "stall" else "tau"
    parameters = pd.DataFrame([{"parameter": k, "before": b, "after": a} for k, b, a in (
        ("alpha", old.evaluator.alpha, new.evaluator.alpha), ("beta", old.evaluator.beta, new.evaluator.beta),
        ("gamma_1_s", old.evaluator.gamma_1_s, new.evaluator.gamma_1_s), ("pole_1_s", old.pole_1_s, new.pole_1_s),
        (tau_key, getattr(old, tau_key), getattr(new, tau_key)))])

    campaigns, compiles, t_val, validation = held_out(cfg, tuned, deg_per_m, progress)
    meta = io.provenance(config.to_json(cfg), tr.seed, models=list(names), validation_seed=str(cfg.validation.seed))
    notes = [f"Tuning of the {det} detector by gradient through the FDD over {n} stored plant histories of "
             f"{tr.duration_s} s (training seed {tr.seed}; plant simulated once in {t_plant:.1f} s). Objective: smooth "
             f"log tau_d - log tau_f (temperature {ts.temperature}), Adam, {ts.iterations} iterations at learning "
             f"rate {ts.learning_rate} on the parameters' logarithms, {t_tune:.1f} s. The iteration with the largest "
             f"hard normalised gap on the training set is kept; tau = tau_f + {ts.margin} (tau_d - tau_f) inside a "
             f"positive gap; otherwise {ts.threshold_candidates} thresholds are compared on the training set by "
             f"false alarms, then missed detections (campaign definitions, {cfg.fdd.stall.identification} "
             f"identification for stall loads), and the middle of the best is kept. Chosen: tau = "
             f"{tau * scale:.5g} {units}.",
             "", f"Held-out campaign: {cfg.validation.scenarios} scenarios, seed "
             f"{cfg.validation.seed}, {cfg.validation.duration_s} s, run with the FDD before and after tuning "
             f"({t_val:.1f} s); the FDD numbers are traced, so both runs share one compilation (XLA compilations "
             f"counted by JAX's monitoring events during each run: {compiles['before']}, {compiles['after']}). "
             f"Bounds as in the campaign report (eqs. 26-27)."]
    title = f"Tuning {Path(source).stem}" if source is not None else "Tuning"
    text = search_report.tuning_markdown(title, det, history, best, {k: before[k] * scale for k in ("tau_f", "tau_d")},
                                  parameters, validation, notes, meta, scan)
    return TuneResult(det, tuned, history, parameters, validation, scan, campaigns, compiles, text, units, meta, source)

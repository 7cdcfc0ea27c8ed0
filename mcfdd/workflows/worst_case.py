"""Worst cases of a detector's bounds (eqs. 26-27) by gradient search against Monte Carlo (``mcfdd worst-case``)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mcfdd import config, io, report
from mcfdd.analysis import build, worst_case as wc
from mcfdd.progress import bar, note
from mcfdd.workflows.common import as_config, dtype_of, load_bank, precision, save_figure


def _points_frame(space, points, scale: float, value: str, **labels):
    """One row per evaluated point: labels, scenario columns, hard and smooth bound (scaled)."""
    table = space.table(points.categories, points.x)
    n = len(points.hard)
    return pd.DataFrame({**{k: np.broadcast_to(np.asarray(v), n) for k, v in labels.items()}, **table,
                         value: points.hard * scale, f"{value}_smooth": points.soft * scale,
                         "stall_events": points.outcomes["stall_events"], "status": points.outcomes["status"]})


class WorstCaseResult:
    """Every simulation of a worst-case search and the worst value per method.

    Attributes:
        points: one row per simulation: ``method`` (screening, gradient, monte_carlo,
            monte_carlo_extra), ``start``, ``iteration``, ``index``, the scenario parameters, the
            bound ``value`` (deg for the stall detector, theta/||u|| for the LOE bank), its smooth
            form, stall events and status.
        summary: per method the number of simulations, run time (s) and worst value.
        value: the name of the bound column, 'bound_deg' or 'bound_ratio'.
        bound: 'free' (tau_f, largest) or 'detect' (tau_d, smallest).
        notes: what was run, for the report.
        meta: provenance.
    """

    def __init__(self, points, summary, value, bound, label, notes, meta):
        self.points, self.summary, self.value, self.bound, self.label, self.notes, self.meta = (
            points, summary, value, bound, label, notes, meta)

    def plot(self, name: str = "history"):
        """'history': the bound per simulation and method, a matplotlib Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if name != "history":
            raise ValueError(f"plot: {name!r} is not one of history")
        return plots.search_history(self.points, self.value, f"{self.value}_smooth", self.label, self.bound)

    def save(self, out, title: str = "Worst case") -> list[Path]:
        """Write ``worst_case.parquet``, ``summary.parquet``, ``report.md`` (headed ``title``), ``history.png``."""
        out = Path(out)
        parameters = [c for c in self.points.columns if c not in (self.value, f"{self.value}_smooth", "method",
                                                                  "start", "iteration", "index", "status")]
        return [io.write_table(self.points, out / "worst_case.parquet", self.meta),
                io.write_table(self.summary, out / "summary.parquet", self.meta),
                io.write_text(out / "report.md", report.worst_case_markdown(title, self.summary, self.points,
                                                                            self.value, self.bound, parameters,
                                                                            self.notes, self.meta)),
                save_figure(self.plot(), out / "history.png")]


def worst_case(cfg, progress: bool = True) -> WorstCaseResult:
    """Search the scenario space for the worst tau_f (eq. 26) or tau_d (eq. 27) of one detector.

    Sobol screening, projected Adam ascent from the worst screened points, and plain Monte Carlo
    with the same number of simulations and with the same run time, for comparison.

    Args:
        cfg: a 'worst-case' config (:func:`mcfdd.load_config`), or a TOML path or dict of one.
        progress: status lines and an iteration bar on stderr; False for silence.

    Returns:
        A :class:`WorstCaseResult`.

    >>> import mcfdd
    >>> cfg = {"simulation": {"duration_s": 0.2}, "evaluation": {"settle_s": 0.1}, "space": {"vcas_kt": [200.0, 300.0]},
    ...        "search": {"screening": 2, "starts": 1, "iterations": 1}}
    >>> result = mcfdd.worst_case(cfg, progress=False)
    >>> result.value, result.points["method"].iloc[0]
    ('bound_deg', 'screening')
    """
    cfg = as_config(cfg, "worst-case")
    with precision(cfg.simulation.precision):
        return _search(cfg, progress)


def _search(cfg: config.WorstCaseConfig, progress: bool) -> WorstCaseResult:
    sim, s = cfg.simulation, cfg.search
    dtype = dtype_of(sim.precision)
    model = build.plant_model(cfg.plant)
    r_arm = model.actuator.r_arm_m
    bank, names = load_bank(cfg.fdd, dtype)
    space = build.search_space(cfg)
    problem = wc.Problem(model, build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm), space,
                         np.asarray(bank.nu), s.detector, s.bound, s.temperature, sim.n_steps, sim.dt_s,
                         sim.substeps, dtype)
    scale, value = (180.0 / math.pi / r_arm, "bound_deg") if s.detector == "stall" else (1.0, "bound_ratio")
    budget = wc.budget(s.screening, s.starts, s.iterations)
    what = f"{'tau_f (26), largest' if s.bound == 'free' else 'tau_d (27), smallest'} {s.detector} bound"
    note(f"worst-case search for {what}: {space.dim} continuous axes, {len(space.categorical)} categorical; "
         f"{sim.duration_s} s runs ({sim.n_steps} steps, {sim.precision}); budget {budget} simulations", progress)
    times, frames = {}, []
    start = time.perf_counter()
    screened = wc.sample(problem, "sobol", s.screening, sim.seed, s.screening)
    times["screening"] = time.perf_counter() - start
    frames.append(_points_frame(space, screened, scale, value, method="screening", start=-1, iteration=-1,
                                index=np.arange(s.screening)))
    note(f"  screening: {s.screening} Sobol points in {times['screening']:.1f} s (compilation included), worst "
         f"{wc.extreme(screened.hard * scale, s.bound)[1]:.5g}", progress)
    idx, u0, cats, keys = wc.starts_from(screened, s.starts, s.bound, sim.seed)
    stamps = [time.perf_counter()]
    with bar(s.iterations + 1, "gradient evaluations", progress) as shown:
        def callback(i, points):
            stamps.append(time.perf_counter())
            shown.set_postfix_str(" ".join(f"{v:.4g}" for v in points.hard * scale), refresh=False)
            shown.update(1)

        iterations = wc.gradient_search(problem, u0, cats, keys, s.iterations, s.learning_rate, callback)
    times["gradient"] = stamps[-1] - stamps[0]
    steps = np.diff(stamps)
    run_time = float(np.mean(steps[1:]) * len(steps)) if len(steps) > 1 else times["gradient"]
    for i, points in enumerate(iterations):
        frames.append(_points_frame(space, points, scale, value, method="gradient", start=idx, iteration=i,
                                    index=np.arange(s.starts)))
    start = time.perf_counter()
    mc = wc.sample(problem, "random", budget, sim.seed + 1, s.screening)
    times["monte_carlo"] = time.perf_counter() - start
    frames.append(_points_frame(space, mc, scale, value, method="monte_carlo", start=-1, iteration=-1,
                                index=np.arange(budget)))
    n_time = int(min(max(budget, round(budget * run_time / max(times["monte_carlo"], 1e-9))), 50 * budget))
    if n_time > budget:
        start = time.perf_counter()
        extra = wc.sample(problem, "random", n_time, sim.seed + 1, s.screening, first=budget)
        times["monte_carlo_extra"] = time.perf_counter() - start
        frames.append(_points_frame(space, extra, scale, value, method="monte_carlo_extra", start=-1, iteration=-1,
                                    index=np.arange(budget, n_time)))
    note(f"  gradient search {times['gradient']:.1f} s ({run_time:.1f} s without compilation), Monte Carlo "
         f"{budget} runs {times['monte_carlo']:.1f} s, {n_time} runs (equal run time) "
         f"{times['monte_carlo'] + times.get('monte_carlo_extra', 0.0):.1f} s", progress)
    df = pd.concat(frames, ignore_index=True)
    meta = io.provenance(config.to_json(cfg), sim.seed, models=list(names))
    summ = report.search_summary(df, value, s.bound, times)
    notes = [f"Worst case of the {what} over the config's scenario space: {s.screening} Sobol points "
             f"screened, the {s.starts} worst started projected Adam ascent ({s.iterations} steps, learning rate "
             f"{s.learning_rate} in the unit cube, smooth maximum over time at temperature {s.temperature} in log "
             f"units), against plain Monte Carlo (random design) with the same number of simulations ({budget}) and "
             f"with as many as run in the gradient search's time without compilation ({n_time}). A gradient "
             f"evaluation costs a forward and a backward pass. Run times include the compilation of the screening "
             f"and of the gradient function; Monte Carlo reuses the screening's compiled batch. "
             f"Values in {'deg (theta of the stall detector)' if s.detector == 'stall' else 'theta / ||u||'}."]
    label = f"{'tau_f' if s.bound == 'free' else 'tau_d'} candidates, {s.detector} detector ({value})"
    return WorstCaseResult(df, summ, value, s.bound, label, notes, meta)

"""Worst cases of a detector's bounds (eqs. 26-27) by gradient search against Monte Carlo (``mcfdd worst-case``)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mcfdd import config, io, search_report
from mcfdd.analysis import build, worst_case as wc
from mcfdd.progress import bar, note
from mcfdd.workflows.common import as_config, dtype_of, load_bank, precision, save_figure

# the bound's column in the points table and its units, per detector
VALUES = {"stall": "bound_deg", "loe": "bound_ratio", "loe_detection": "bound_statistic"}
UNITS = {"stall": "deg (theta of the stall detector, its memory of stall loads left out)", "loe": "theta / ||u||",
         "loe_detection": "theta_0 / ||u|| (the LOE detection level's signed statistic: positive where the FDD "
                          "detects, so tau_f > 0 is a false alarm and tau_d < 0 a missed detection)"}
REPLAY = "replay.toml"


def _points_frame(space, points, scale: float, value: str, seed: int, run_index, **labels):
    """One row per evaluated point: labels, scenario columns, hard and smooth bound (scaled), the run key
    (``seed``, ``run_index``) and the verdict columns the report shows."""
    table = space.table(points.categories, points.x)
    n = len(points.hard)
    out = points.outcomes
    return pd.DataFrame({**{k: np.broadcast_to(np.asarray(v), n) for k, v in labels.items()}, **table,
                         value: points.hard * scale, f"{value}_smooth": points.soft * scale,
                         "stall_events": out["stall_events"], "peak_load_fraction": out["peak_load_fraction"],
                         "status": out["status"], "seed": np.full(n, seed),
                         "run_index": np.broadcast_to(np.asarray(run_index), n)})


class WorstCaseResult:
    """Every simulation of a worst-case search and the worst value per method.

    Attributes:
        points: one row per simulation: ``method`` (screening, gradient, monte_carlo,
            monte_carlo_extra), ``start`` (the screening row a gradient start began from),
            ``iteration``, ``index``, the scenario parameters, the bound ``value`` (:data:`VALUES`;
            units :data:`UNITS`), its smooth form, stall events, peak load fraction, status and the
            run key (``seed``, ``run_index``: row ``run_index`` of a campaign of that seed draws the
            same random numbers).
        summary: per method the number of simulations, run time (s) and worst value.
        value: the name of the bound column (:data:`VALUES`).
        bound: 'free' (tau_f, largest) or 'detect' (tau_d, smallest).
        notes: what was run, for the report.
        meta: provenance.
    """

    def __init__(self, points, summary, value, bound, label, notes, meta, replay_base=None):
        self.points, self.summary, self.value, self.bound, self.label, self.notes, self.meta = (
            points, summary, value, bound, label, notes, meta)
        self.replay_base = replay_base

    def replay(self) -> dict:
        """A 'simulate' config (dict) whose ``[[runs]]`` are the witness of each method of the summary
        (``mcfdd simulate`` gives their time histories): the search's simulation, plant and FDD, and per run
        the witness's scenario and run key."""
        runs, seen = [], set()
        for _, r in self.summary.iterrows():
            if r["row"] < 0 or r["row"] in seen:
                continue
            seen.add(r["row"])
            row = self.points.loc[r["row"]]
            runs.append(build.run_entry(row.to_dict(), f"{row['method']}-{r['row']}", row["seed"], row["run_index"]))
        return {**self.replay_base, "runs": runs}

    def plot(self, name: str = "history"):
        """'history': the bound per simulation and method, a matplotlib Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if name != "history":
            raise ValueError(f"plot: {name!r} is not one of history")
        return plots.search_history(self.points, self.value, f"{self.value}_smooth", self.label, self.bound)

    def save(self, out, title: str = "Worst case") -> list[Path]:
        """Write ``worst_case.parquet``, ``summary.parquet``, ``report.md`` (headed ``title``), ``history.png``
        and ``replay.toml`` (:meth:`replay`)."""
        out = Path(out)
        parameters = [c for c in self.points.columns if c not in (self.value, f"{self.value}_smooth", "method",
                                                                  "start", "iteration", "index", "status")]
        replay = self.replay()
        notes = [*self.notes, f"Replay: `mcfdd simulate {out / REPLAY}` gives the time histories of each method's "
                              f"witness (runs {', '.join(r['name'] for r in replay['runs'])}: the method and the row "
                              f"of worst_case.parquet; each with the witness's scenario and run key)."]
        return [io.write_table(self.points, out / "worst_case.parquet", self.meta),
                io.write_table(self.summary, out / "summary.parquet", self.meta),
                io.write_text(out / "report.md", search_report.worst_case_markdown(title, self.summary, self.points,
                                                                            self.value, self.bound, parameters,
                                                                            notes, self.meta)),
                save_figure(self.plot(), out / "history.png"),
                io.write_text(out / REPLAY, config.to_toml(replay))]


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
                         sim.substeps, dtype, s.min_load_fraction)
    scale, value = 180.0 / math.pi / r_arm if s.detector == "stall" else 1.0, VALUES[s.detector]
    what = f"{'tau_f (26), largest' if s.bound == 'free' else 'tau_d (27), smallest'} {s.detector} bound"
    if s.min_load_fraction > 0:
        what += f" over runs reaching a peak hinge-load fraction of {s.min_load_fraction}"
    refill = f" (screening refilled up to {s.screening_max} points for {s.pool} runs with the event)" if s.pool else ""
    note(f"worst-case search for {what}: {space.dim} continuous axes, {len(space.categorical)} categorical; "
         f"{sim.duration_s} s runs ({sim.n_steps} steps, {sim.precision}); budget "
         f"{wc.budget(s.screening, s.starts, s.iterations)} simulations{refill}", progress)
    times, frames, batch_times = {}, [], []

    def rows(first, n):
        start = time.perf_counter()
        points = wc.sample(problem, "sobol", n, sim.seed, s.screening, first)
        batch_times.append(time.perf_counter() - start)
        return points

    screened, batches = wc.screen(rows, s.screening, s.pool, max(s.screening_max, s.screening))
    n_screened = len(screened.hard)
    budget = wc.budget(n_screened, s.starts, s.iterations)
    times["screening"] = sum(batch_times)
    frames.append(_points_frame(space, screened, scale, value, sim.seed, np.arange(n_screened), method="screening",
                                start=-1, iteration=-1, index=np.arange(n_screened)))
    note(f"  screening: {n_screened} Sobol points in {batches} batch(es), {times['screening']:.1f} s (compilation "
         f"included), worst {wc.extreme(screened.hard * scale, s.bound)[1]:.5g}", progress)
    pool = wc.pool_from(screened, s.starts, s.bound, sim.seed)
    stamps = [time.perf_counter()]
    with bar(s.iterations + 1, "gradient evaluations", progress) as shown:
        def callback(i, points):
            stamps.append(time.perf_counter())
            shown.set_postfix_str(" ".join(f"{v:.4g}" for v in points.hard * scale), refresh=False)
            shown.update(1)

        iterations = wc.gradient_search(problem, *wc.starts_of(pool, s.starts), s.iterations, s.learning_rate,
                                        callback, pool, s.final_temperature, s.patience)
    times["gradient"] = stamps[-1] - stamps[0]
    steps = np.diff(stamps)
    run_time = float(np.mean(steps[1:]) * len(steps)) if len(steps) > 1 else times["gradient"]
    for i, points in enumerate(iterations):
        frames.append(_points_frame(space, points, scale, value, sim.seed, points.start, method="gradient",
                                    start=points.start, iteration=i, index=np.arange(s.starts)))
    used = len(np.unique(np.concatenate([p.start for p in iterations])))
    restarted = used - s.starts
    start = time.perf_counter()
    mc = wc.sample(problem, "random", budget, sim.seed + 1, s.screening)
    times["monte_carlo"] = time.perf_counter() - start
    frames.append(_points_frame(space, mc, scale, value, sim.seed + 1, np.arange(budget), method="monte_carlo",
                                start=-1, iteration=-1, index=np.arange(budget)))
    # the search's time without compilation: the screening's later batches, its first at Monte Carlo's rate
    searched_s = run_time + sum(batch_times[1:])
    n_time = int(min(max(budget, s.screening + round(budget * searched_s / max(times["monte_carlo"], 1e-9))),
                     50 * budget))
    if n_time > budget:
        start = time.perf_counter()
        extra = wc.sample(problem, "random", n_time, sim.seed + 1, s.screening, first=budget)
        times["monte_carlo_extra"] = time.perf_counter() - start
        frames.append(_points_frame(space, extra, scale, value, sim.seed + 1, np.arange(budget, n_time),
                                    method="monte_carlo_extra", start=-1, iteration=-1,
                                    index=np.arange(budget, n_time)))
    note(f"  gradient search {times['gradient']:.1f} s ({run_time:.1f} s without compilation), Monte Carlo "
         f"{budget} runs {times['monte_carlo']:.1f} s, {n_time} runs (equal run time) "
         f"{times['monte_carlo'] + times.get('monte_carlo_extra', 0.0):.1f} s", progress)
    df = pd.concat(frames, ignore_index=True)
    meta = io.provenance(config.to_json(cfg), sim.seed, models=list(names))
    summ = search_report.search_summary(df, value, s.bound, times)
    feasible = int(np.isfinite(screened.hard).sum())
    schedule = f" falling geometrically to {s.final_temperature}" if s.final_temperature > 0 else ""
    notes = [f"Worst case of the {what} over the config's scenario space: {n_screened} Sobol points "
             f"screened ({batches} batch(es) of {s.screening}"
             f"{f', screened on until {s.pool} runs had the event or {s.screening_max} points' if s.pool else ''}), "
             f"the {s.starts} worst started projected Adam ascent ({s.iterations} steps, learning rate "
             f"{s.learning_rate} in the unit cube, smooth maximum over time at temperature {s.temperature}{schedule} "
             f"in {'the statistic' if s.detector == 'loe_detection' else 'log'} units), against plain Monte Carlo "
             f"(random design) with the same number of simulations ({budget}) and with as many as run in the "
             f"search's time without compilation ({n_time}: the gradient steps and the screening's batches, its "
             f"first at Monte Carlo's rate). A start whose "
             f"run loses the event (no bound: {feasible} of {n_screened} screened runs have one) {s.patience} "
             f"evaluation(s) in a row (backtracking with half steps before) is replaced by the next best screened "
             f"run that has it ({restarted} replacements). A gradient "
             f"evaluation costs a forward and a backward pass. Run times include the compilation of the screening "
             f"and of the gradient function; Monte Carlo reuses the screening's compiled batch. "
             f"Values in {UNITS[s.detector]}.",
             search_report.search_verdict(summ, value, s.bound, restarted, len(pool.index) - used)]
    label = f"{'tau_f' if s.bound == 'free' else 'tau_d'} candidates, {s.detector} detector ({value})"
    base = {"simulation": config.to_dict(sim), "plant": config.to_dict(cfg.plant), "fdd": config.to_dict(cfg.fdd)}
    return WorstCaseResult(df, summ, value, s.bound, label, notes, meta, base)

"""How rare is an event of a campaign (``mcfdd probability``): per run, stratum, flight hour and airframe.

The campaign's runs as points of a standard-normal space (:mod:`mcfdd.analysis.probability`),
the event's signed margin as the limit state, and an estimator of :mod:`mcfdd.analysis.rare` per
stratum (each combination of the space's categorical axes): ``probability.repeats`` independent
runs, then more until the pooled coefficient of variation reaches ``probability.target_cov`` or the
stratum's share of ``probability.budget`` is spent. The runs are pooled by
:func:`mcfdd.analysis.rare.repeated`: their mean, with a c.o.v. never below what the spread of their
ln p_hat shows (a within-run c.o.v. can understate: subset simulation's chains mix slowly in
thousands of noise coordinates). Strata are combined with the design's equal shares (the campaign's
per-run probability) and, for the events of fault-free runs, with the exposure weights into a rate
per flight hour, lambda = sum_s w_s p_s 3600 / T_scored (:func:`mcfdd.analysis.rare.per_flight_hour`).
The per-airframe view fixes the parameters an aircraft keeps for life (``[probability.airframe]``)
at corners or drawn airframes (:mod:`mcfdd.analysis.rare.exposure`). Every estimator run is a task
(:mod:`mcfdd.workflows.probability_tasks`) run in process, on an executor or on Dask, with the
same result.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
from jax import device_get
from scipy.stats import norm

from mcfdd import columns, config, io
from mcfdd.analysis import probability as normal_space, rare
from mcfdd.progress import note
from mcfdd.workflows import probability_tasks as tasks
from mcfdd.workflows.common import as_config, dtype_of, precision
from mcfdd.workflows.probability_report import lines, markdown
from mcfdd.workflows.probability_tasks import problem_of, seed_of

__all__ = ["ProbabilityResult", "exposure_weights", "probability", "problem_of"]


@dataclasses.dataclass
class ProbabilityResult:
    """The probability of one event of a campaign.

    Attributes:
        event, method: as ``[probability]``.
        overall: per-run probability over the space (the design's equal shares of the strata);
            for ``missed_detection`` given that the run must be detected.
        groups: {label: Estimate}: per fault kind (missed detection) or all strata.
        rate: events per flight hour (fault-free events), else None.
        strata: one row per stratum: its values, estimate, cov, interval, simulations, hits,
            estimator runs, levels, exposure weight.
        levels: one row per level of every subset-simulation run.
        failures: one row per failure point kept: stratum, scenario columns, margin, ``beta`` = ||u||
            and ``point`` (row of ``failure_points``).
        failure_points: (rows, d) their standard-normal coordinates (parameters, initial and step
            normals): :meth:`replay` gives their time histories.
        notes, meta: what was run and the assumptions; provenance.
        runs: one row per estimator run on a stratum's space: its own estimate, c.o.v. and interval,
            simulations, hits, levels and the lineages of its final level.
        airframes: one row per stratum and airframe point (the per-airframe axes' values) with
            P(event | those values), pooled over ``repeats`` runs; empty when not estimated.
        airframe: the strata combined at each airframe point (:class:`~mcfdd.analysis.rare.Airframes`:
            ``estimates[worst]`` the worst, ``value`` and ``interval`` the quantile), or None.
        airframe_rate: per flight hour at the worst corner (fault-free events, corner view), or None.
    """

    event: str
    method: str
    overall: rare.Estimate
    groups: dict
    rate: rare.Estimate | None
    strata: pd.DataFrame
    levels: pd.DataFrame
    failures: pd.DataFrame
    failure_points: np.ndarray
    notes: list
    meta: dict
    problem: normal_space.Problem | None = None
    args: list | None = None
    precision: str = "float32"
    runs: pd.DataFrame = dataclasses.field(default_factory=pd.DataFrame)
    airframes: pd.DataFrame = dataclasses.field(default_factory=pd.DataFrame)
    airframe: rare.Airframes | None = None
    airframe_rate: rare.Estimate | None = None

    def lines(self) -> list[str]:
        """What the terminal shows."""
        return lines(self)

    def replay(self, i: int):
        """Time histories (PlantOutputs, FddOutputs; leading axis steps) of failure point ``i``."""
        stratum = int(self.failures["stratum"].iloc[i])
        with precision(self.precision):
            return device_get(normal_space.histories(self.problem, self.failure_points[i], self.args[stratum]))

    def save(self, out, title: str = "Probability") -> list[Path]:
        """Write strata.parquet, runs.parquet, levels.parquet, failures.parquet, failure_points.npy, summary.md
        and, with the per-airframe view, airframes.parquet."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        points = out / "failure_points.npy"
        np.save(points, self.failure_points)
        return [io.write_table(self.strata, out / "strata.parquet", self.meta),
                io.write_table(self.runs, out / "runs.parquet", self.meta),
                *([io.write_table(self.airframes, out / "airframes.parquet", self.meta)]
                  if not self.airframes.empty else []),
                io.write_table(self.levels, out / "levels.parquet", self.meta),
                io.write_table(self.failures, out / "failures.parquet", self.meta), points,
                io.write_text(out / "summary.md", markdown(title, self))]


def _shares(axis: config.Axis, table: dict | None) -> dict:
    """Fractions of flight time of an axis's values: the table's, the rest shared equally, normalised."""
    values = list(axis.values)
    table = table or {}
    missing = [v for v in values if v not in table]
    rest = max(1.0 - sum(table.values()), 0.0) / len(missing) if missing else 0.0
    raw = np.array([table.get(v, rest) for v in values], float)
    if raw.sum() <= 0:
        raise config.ConfigError(f"probability.exposure.{axis.name}: no flight time in the space's values "
                                 f"{', '.join(map(str, values))}")
    return dict(zip(values, raw / raw.sum()))


def exposure_weights(cfg: config.CampaignConfig, strata: list[dict]) -> np.ndarray:
    """w_s of each stratum: the product over the categorical axes of its values' shares, normalised."""
    exposure = cfg.probability.exposure
    shares = {a.name: _shares(a, getattr(exposure, a.name, None)) for a in cfg.space.axes
              if a.kind in ("values", "choices")}
    w = np.array([math.prod(shares[name][value] for name, value in s.items()) for s in strata])
    return w / w.sum()


def _scaled(e: rare.Estimate, c: float) -> rare.Estimate:
    return dataclasses.replace(e, estimate=e.estimate * c, interval=(e.interval[0] * c, e.interval[1] * c))


def _combined(estimates, confidence: float) -> rare.Estimate:
    """Equal shares of the strata (the campaign's design); one stratum is its own estimate."""
    if len(estimates) == 1:
        return estimates[0]
    kind = "delta" if all(e.reached and e.hits > 0 and np.isfinite(e.cov) for e in estimates) else "union"
    return rare.combine(estimates, np.full(len(estimates), 1.0 / len(estimates)), confidence, kind)


def per_flight_hour(estimates, weights, scored_s: float, confidence: float) -> rare.Estimate:
    """lambda = sum_s w_s p_s 3600 / T_scored (:func:`mcfdd.analysis.rare.per_flight_hour`); one
    stratum: its estimate and interval scaled."""
    if len(estimates) == 1:
        return dataclasses.replace(_scaled(estimates[0], rare.exposure.SECONDS_PER_HOUR / scored_s),
                                   method="per_flight_hour")
    kind = "delta" if all(e.reached and e.hits > 0 and np.isfinite(e.cov) for e in estimates) else "union"
    return rare.per_flight_hour(estimates, weights, scored_s, confidence, kind)


def acting(stratum: dict, cols: dict) -> dict:
    """The columns of a stratum's failure points that act on its runs: the size of its own fault kind,
    the onset of a fault."""
    kind = stratum.get("fault_kind")
    return {k: v for k, v in cols.items() if not (columns.COLUMN[k].size_of not in ("", kind)
                                                  or (k == "fault_onset_s" and kind == "none"))}


def check_event(cfg: config.CampaignConfig, fault_kinds) -> None:
    """The space must hold runs of the event's fault kinds; else a ConfigError naming probability.event."""
    axis = cfg.space.axis("fault_kind")
    kinds = axis.values if axis else (columns.DEFAULTS["fault_kind"],)
    if not set(kinds) & set(fault_kinds):
        raise config.ConfigError(f"probability.event: {cfg.probability.event!r} is scored on runs of fault_kind "
                                 f"{' or '.join(fault_kinds)}, and space.fault_kind gives {', '.join(kinds)}")


def probability(cfg, progress: bool = True, executor=None, compile_cache=None) -> ProbabilityResult:
    """P(event) per run of a campaign's space, per stratum, per flight hour and per airframe (module docstring).

    Args:
        cfg: a 'campaign' config (:func:`mcfdd.load_config`) with an optional ``[probability]``
            table, or a TOML path or dict of one.
        progress: a line per estimator run on stderr; False for silence.
        executor: None to run the estimator runs in this process, a ``concurrent.futures.Executor``
            or a Dask client (:func:`mcfdd.campaign_executor`): the same result to the last bit.
        compile_cache: the Dask workers' compile-cache folder (None: their user cache, 'off': none).

    Returns:
        A :class:`ProbabilityResult`.
    """
    cfg = as_config(cfg, "campaign")
    with precision(cfg.campaign.precision):
        return _probability(cfg, progress, (executor, compile_cache))


def _probability(cfg: config.CampaignConfig, progress: bool, where) -> ProbabilityResult:
    c, p = cfg.campaign, cfg.probability
    flag, margin, fault_kinds = normal_space.EVENTS[p.event]
    check_event(cfg, fault_kinds)
    prep = tasks.prepared(cfg)
    problem, space, strata = prep.problem, prep.problem.space, prep.strata
    share = max(p.budget // len(strata), 1)
    note(f"P({p.event}) by {p.method}: {len(strata)} strata, d = {space.d} coordinates ({space.k} parameters, "
         f"{space.init_dim} + {space.n_steps} x {space.step_dim} normals); {c.duration_s} s runs; at least "
         f"{p.repeats} runs per stratum, then to c.o.v. {p.target_cov} within {p.budget} simulations ({share} per "
         f"stratum){'' if where[0] is None else ' on ' + type(where[0]).__name__}", progress)
    runs: dict[int, list] = {s: [] for s in range(len(strata))}
    todo = [(s, r, -1) for s in runs for r in range(p.repeats)]
    while todo:
        for (s, r, _), run in zip(todo, tasks.run_tasks(cfg, todo, *where)):
            runs[s].append(run)
            est = rare.repeated(runs[s], p.confidence)
            note(f"  stratum {s + 1}/{len(strata)} ({_label(strata[s])}) run {r + 1}: p = {run.estimate:.3g} "
                 f"(c.o.v. {run.cov:.2f}; pooled {est.estimate:.3g}, c.o.v. {est.cov:.2f}), {len(run.levels)} "
                 f"levels, {run.n_simulations} simulations", progress)
        todo = [(s, len(rs), -1) for s, rs in runs.items()
                if rare.repeated(rs, p.confidence).cov > p.target_cov
                and sum(r.n_simulations for r in rs) + rs[-1].n_simulations <= share]
    estimates = [rare.repeated(runs[s], p.confidence) for s in runs]
    if p.event == "missed_detection":
        estimates = [_scaled(e, 1.0 / _must_share(cfg, problem, stratum)) for e, stratum in zip(estimates, strata)]
    table = pd.DataFrame([{"stratum": s, **stratum, "estimate": e.estimate, "cov": e.cov, "lo": e.interval[0],
                           "hi": e.interval[1], "simulations": sum(r.n_simulations for r in runs[s]), "hits": e.hits,
                           "runs": len(runs[s]), "levels": len(e.levels), "reached": e.reached}
                          for s, (stratum, e) in enumerate(zip(strata, estimates))])
    run_rows = [{"stratum": s, "run": r, "estimate": e.estimate, "cov": e.cov, "lo": e.interval[0],
                 "hi": e.interval[1], "simulations": e.n_simulations, "hits": e.hits, "levels": len(e.levels),
                 "lineages": e.levels[-1].lineages if e.levels else 0, "reached": e.reached}
                for s, rs in runs.items() for r, e in enumerate(rs)]
    level_rows = [{"stratum": s, "run": r, "level": j, **level._asdict()}
                  for s, rs in runs.items() for r, e in enumerate(rs) for j, level in enumerate(e.levels)]
    failure_rows, points = [], []
    for s, (stratum, est) in enumerate(zip(strata, estimates)):
        if len(est.failure_points):
            cols = acting({"fault_kind": cfg.values("fault_kind")[0], **stratum},
                          normal_space.columns_at(space, est.failure_points, prep.args[s]))
            for i, m in enumerate(est.failure_margins):
                failure_rows.append({"stratum": s, **stratum, **{k: v[i] for k, v in cols.items()}, "margin": m,
                                     "beta": float(np.linalg.norm(est.failure_points[i])), "point": len(points)})
                points.append(np.asarray(est.failure_points[i]))
    overall = _combined(estimates, p.confidence)
    kinds = [s.get("fault_kind", cfg.values("fault_kind")[0]) for s in strata]
    groups = ({k: _combined([e for e, kind in zip(estimates, kinds) if kind == k], p.confidence)
               for k in dict.fromkeys(kinds)} if p.event == "missed_detection" else {"all": overall})
    rate, weights, scored_s = None, None, c.duration_s - cfg.evaluation.settle_s
    if fault_kinds == ("none",):
        weights = exposure_weights(cfg, strata)
        table["exposure_weight"] = weights
        rate = per_flight_hour(estimates, weights, scored_s, p.confidence)
    view = per_airframe(cfg, prep, table, weights, scored_s, where, progress)
    notes = _notes(cfg, space, scored_s, p, margin, flag) + airframe_notes(cfg, prep)
    meta = io.provenance(config.to_json(cfg), seed_of(cfg), models=list(prep.names), event=p.event, method=p.method)
    return ProbabilityResult(p.event, p.method, overall, groups, rate, table, pd.DataFrame(level_rows),
                             pd.DataFrame(failure_rows), np.asarray(points).reshape(len(points), space.d), notes, meta,
                             problem, prep.args, c.precision, pd.DataFrame(run_rows), *view)


def per_airframe(cfg: config.CampaignConfig, prep: tasks.Prepared, table: pd.DataFrame, weights, scored_s: float,
                 where, progress: bool):
    """P(event | the per-airframe parameters) at the airframe points (``[probability.airframe]``), ``repeats``
    runs each per stratum: (one row per stratum and point, :class:`~mcfdd.analysis.rare.Airframes` of the strata
    combined, the rate per flight hour at the worst point or None); ``table`` gains each stratum's worst
    (corner view) or quantile. Empty and None without per-airframe axes. ``where``: (executor, compile cache)."""
    p, a = cfg.probability, cfg.probability.airframe
    if not prep.axes:
        return pd.DataFrame(), None, None
    m, strata = len(prep.points), prep.strata
    note(f"per airframe ({', '.join(prep.axes)} fixed): {a.view} view, {m} airframes x {len(strata)} strata x "
         f"{p.repeats} runs", progress)
    todo = [(s, r, i) for s in range(len(strata)) for i in range(m) for r in range(p.repeats)]
    runs: dict = {}
    for (s, _, i), e in zip(todo, tasks.run_tasks(cfg, todo, *where)):
        runs.setdefault((s, i), []).append(e)
    est = {key: rare.repeated(rs, p.confidence) for key, rs in runs.items()}
    if p.event == "missed_detection":
        est = {(s, i): _scaled(e, 1.0 / _must_share(cfg, prep.problem, strata[s])) for (s, i), e in est.items()}
    space = prep.problem.space
    bounds = [(space.lo[space.names.index(n)], space.hi[space.names.index(n)]) for n in prep.axes]
    values = [{n: lo + float(norm.cdf(t)) * (hi - lo) for n, (lo, hi), t in zip(prep.axes, bounds, theta)}
              for theta in prep.points]
    rows = [{"stratum": s, "point": i, **values[i], "estimate": e.estimate, "cov": e.cov, "lo": e.interval[0],
             "hi": e.interval[1], "simulations": sum(r.n_simulations for r in runs[s, i]), "hits": e.hits,
             "runs": len(runs[s, i])} for (s, i), e in est.items()]
    q = a.quantile if a.view == "quantile" else None
    name = "airframe_worst" if q is None else "airframe_quantile"
    for s in range(len(strata)):
        view = rare.exposure.summarise(prep.points, [est[s, i] for i in range(m)], q, p.confidence)
        e = view.estimates[view.worst]
        value, lo, hi = (e.estimate, *e.interval) if q is None else (view.value, *view.interval)
        table.loc[s, [name, f"{name}_lo", f"{name}_hi"]] = value, lo, hi
        if q is None:
            table.loc[s, "airframe_worst_point"] = view.worst
    combined = [_combined([est[s, i] for s in range(len(strata))], p.confidence) for i in range(m)]
    view = rare.exposure.summarise(prep.points, combined, q, p.confidence)
    rate = None
    if weights is not None and q is None:
        rate = per_flight_hour([est[s, view.worst] for s in range(len(strata))], weights, scored_s, p.confidence)
    return pd.DataFrame(rows), view, rate


def airframe_notes(cfg: config.CampaignConfig, prep: tasks.Prepared) -> list[str]:
    a = cfg.probability.airframe
    if not prep.axes:
        return [f"Per airframe: not estimated (view {a.view!r}; none of {', '.join(a.axes) or 'no axes'} varies in "
                f"the space)."]
    how = (f"at the {len(prep.points)} corners that put each axis at its {1 - a.corner:g} and {a.corner:g} quantiles "
           f"(the worst reported)" if a.view == "corner" else
           f"at {len(prep.points)} airframes drawn from the ranges, the {a.quantile:g} quantile over them reported "
           f"with its distribution-free interval")
    return [f"Per airframe: {', '.join(prep.axes)} are fixed for an aircraft's life, so its false alarms are not "
            f"independent across flights; P(event | these parameters) is estimated {how}, the other coordinates "
            f"random as above (airframes.parquet)."]


def _label(stratum: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in stratum.items()) or "the space"


def _must_share(cfg: config.CampaignConfig, problem: normal_space.Problem, stratum: dict) -> float:
    """P(the run must be detected | stratum): the share of its fault sizes whose nearest model is not nominal."""
    kind = stratum.get("fault_kind", cfg.values("fault_kind")[0])
    size_axis = next((n for n, of in columns.SIZE_COLUMNS.items() if of == kind), None)
    lo, hi = cfg.extent(size_axis) if size_axis else (columns.DEFAULTS["fault_size"],) * 2
    return normal_space.must_fraction(problem.nu_bank, kind, lo, hi)


def _notes(cfg, space, scored_s: float, p, margin: str, flag: str) -> list[str]:
    chunk_mb = p.chunk * space.d * np.dtype(dtype_of(cfg.campaign.precision)).itemsize / 2 ** 20
    return [
        f"Event: the campaign's flag `{flag}`, limit state its signed margin `{margin}` (positive exactly where the "
        f"flag is set), from the scoring monitors the campaign scores with; a void run (numbers not finite) is "
        f"outside the event.",
        f"Every run is a point u of N(0, I_d), d = {space.d}: {space.k} continuous axes through the design's uniform "
        f"ranges (x = lo + Phi(u) (hi - lo)), {space.init_dim} normals starting the turbulence filters and "
        f"{space.n_steps} steps x {space.step_dim} normals (turbulence forcing, position-sensor noise). The "
        f"categorical axes are strata, each with the design's equal share.",
        f"Memory: {p.chunk} runs are simulated at once, holding {p.chunk} x {space.d} coordinates "
        f"({chunk_mb:.1f} MiB) and one scan carry per run; subset simulation keeps about 3 x {p.samples} x "
        f"{space.d} coordinates.",
        f"Per flight hour: lambda = sum_s w_s p_s 3600 / T_scored with T_scored = duration_s - settle_s = "
        f"{scored_s:g} s, the exposure weights w_s of [probability.exposure] (turbulence shares from MIL-F-8785C "
        f"3.7.2.1; manoeuvre families in equal shares unless set), renormalised over the space's strata: a rate per "
        f"hour flown in the space's conditions. Flights and scored windows are taken as independent and the model "
        f"as valid over the space; the continuous axes (envelope, servo parameters) are averaged over their ranges.",
    ]

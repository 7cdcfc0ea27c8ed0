"""How rare is an event of a campaign (``mcfdd probability``): per run, per stratum and per flight hour.

The campaign's runs as points of a standard-normal space (:mod:`mcfdd.analysis.probability`),
the event's signed margin as the limit state, and an estimator of :mod:`mcfdd.analysis.rare` per
stratum (each combination of the space's categorical axes), repeated with independent keys until
the pooled coefficient of variation reaches ``probability.target_cov`` or the stratum's share of
``probability.budget`` is spent. Strata are combined with the design's equal shares (the
campaign's per-run probability) and, for the events of fault-free runs, with the exposure
weights into a rate per flight hour, lambda = sum_s w_s p_s 3600 / T_scored
(:func:`mcfdd.analysis.rare.per_flight_hour`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from mcfdd import columns, config, io
from mcfdd.analysis import build, probability as normal_space, rare
from mcfdd.progress import note
from mcfdd.workflows.common import as_config, dtype_of, load_bank, precision
from mcfdd.workflows.probability_report import lines, markdown


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

    def lines(self) -> list[str]:
        """What the terminal shows."""
        return lines(self)

    def replay(self, i: int):
        """Time histories (PlantOutputs, FddOutputs; leading axis steps) of failure point ``i``."""
        stratum = int(self.failures["stratum"].iloc[i])
        with precision(self.precision):
            return jax.device_get(normal_space.histories(self.problem, self.failure_points[i], self.args[stratum]))

    def save(self, out, title: str = "Probability") -> list[Path]:
        """Write strata.parquet, levels.parquet, failures.parquet, failure_points.npy and summary.md."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        points = out / "failure_points.npy"
        np.save(points, self.failure_points)
        return [io.write_table(self.strata, out / "strata.parquet", self.meta),
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


def _divisor(n: int, most: int) -> int:
    """The largest divisor of n not above ``most``."""
    return max(b for b in range(1, min(n, most) + 1) if n % b == 0)


def _run_estimator(g, d: int, key, p, args) -> rare.Estimate:
    common = {"keep": p.keep, "confidence": p.confidence, "args": (args,)}
    if p.method == "subset":
        return rare.subset_simulation(g, d, key, n=p.samples, p0=p.p0, max_levels=p.max_levels, chunk=p.chunk,
                                      **common)
    batch = _divisor(p.samples, p.chunk)
    if p.method == "importance":
        return rare.importance_sampling(g, d, key, n=p.samples, batch=batch, **common)
    return rare.monte_carlo(g, d, key, n=p.samples, batch=batch, **common)


def pooled(runs: list[rare.Estimate], confidence: float) -> rare.Estimate:
    """The mean of independent estimator runs, with its c.o.v. and interval (one run: itself)."""
    if len(runs) == 1:
        return runs[0]
    kind = "delta" if all(r.reached and r.hits > 0 and np.isfinite(r.cov) for r in runs) else "union"
    mean = rare.combine(runs, np.full(len(runs), 1.0 / len(runs)), confidence, kind)
    best = max(runs, key=lambda r: r.hits)
    return dataclasses.replace(mean, method=runs[0].method, levels=best.levels,
                               failure_points=np.concatenate([r.failure_points for r in runs]),
                               failure_margins=np.concatenate([r.failure_margins for r in runs]))


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


def probability(cfg, progress: bool = True) -> ProbabilityResult:
    """P(event) per run of a campaign's space, per stratum and per flight hour (module docstring).

    Args:
        cfg: a 'campaign' config (:func:`mcfdd.load_config`) with an optional ``[probability]``
            table, or a TOML path or dict of one.
        progress: a line per estimator run on stderr; False for silence.

    Returns:
        A :class:`ProbabilityResult`.
    """
    cfg = as_config(cfg, "campaign")
    with precision(cfg.campaign.precision):
        return _probability(cfg, progress)


def problem_of(cfg: config.CampaignConfig) -> tuple[normal_space.Problem, tuple]:
    """The limit state's problem of a campaign config, and the bank's model names."""
    c, p = cfg.campaign, cfg.probability
    dtype = dtype_of(c.precision)
    model = build.plant_model(cfg.plant)
    bank, names = load_bank(cfg.fdd, dtype)
    r_arm = model.actuator.r_arm_m
    space = normal_space.Space.of(cfg.space.axes, cfg.plant.aircraft.max_mach,
                                   normal_space.noise_dims(model), c.n_steps)
    # the limit state closes over plant and FDD: their NumPy leaves become JAX arrays (traced indexing)
    model, fdd_params = jax.tree.map(lambda x: jnp.asarray(x) if isinstance(x, np.ndarray) else x,
                                     (model, build.fdd_params(cfg.fdd, bank, r_arm)))
    problem = normal_space.Problem(model, fdd_params, build.settings(cfg.evaluation, r_arm),
                                    np.asarray(bank.nu), space, normal_space.EVENTS[p.event][1], c.dt_s, c.substeps,
                                    normal_space.manoeuvre_codes(cfg.space.axes))
    return problem, names


def _probability(cfg: config.CampaignConfig, progress: bool) -> ProbabilityResult:
    c, p = cfg.campaign, cfg.probability
    seed = c.seed if p.seed is None else p.seed
    flag, margin, fault_kinds = normal_space.EVENTS[p.event]
    check_event(cfg, fault_kinds)
    dtype = dtype_of(c.precision)
    problem, names = problem_of(cfg)
    space = problem.space
    strata = normal_space.strata(cfg.space.axes, fault_kinds)
    g = normal_space.limit_state(problem)
    share = max(p.budget // len(strata), 1)
    note(f"P({p.event}) by {p.method}: {len(strata)} strata, d = {space.d} coordinates ({space.k} parameters, "
         f"{space.init_dim} + {space.n_steps} x {space.step_dim} normals); {c.duration_s} s runs; budget {p.budget} "
         f"simulations ({share} per stratum), target c.o.v. {p.target_cov}", progress)
    estimates, args_list, level_rows, failure_rows, points, strata_rows = [], [], [], [], [], []
    base_key = jax.random.key(seed)
    for s, stratum in enumerate(strata):
        args = normal_space.stratum_args(cfg.space.axes, stratum, dtype)
        args_list.append(args)
        key, runs, spent = jax.random.fold_in(base_key, s), [], 0
        label = ", ".join(f"{k}={v}" for k, v in stratum.items()) or "the space"
        while True:
            run = _run_estimator(g, space.d, jax.random.fold_in(key, len(runs)), p, args)
            runs.append(run)
            spent += run.n_simulations
            for j, level in enumerate(run.levels):
                level_rows.append({"stratum": s, "run": len(runs) - 1, "level": j, **level._asdict()})
            est = pooled(runs, p.confidence)
            note(f"  stratum {s + 1}/{len(strata)} ({label}) run {len(runs)}: p = {run.estimate:.3g} "
                 f"(pooled {est.estimate:.3g}, c.o.v. {est.cov:.2f}), {len(run.levels)} levels, "
                 f"{run.n_simulations} simulations", progress)
            if est.cov <= p.target_cov or spent + run.n_simulations > share:
                break
        if p.event == "missed_detection":
            est = _scaled(est, 1.0 / _must_share(cfg, problem, stratum))
        estimates.append(est)
        strata_rows.append({"stratum": s, **stratum, "estimate": est.estimate, "cov": est.cov,
                            "lo": est.interval[0], "hi": est.interval[1], "simulations": spent, "hits": est.hits,
                            "runs": len(runs), "levels": len(est.levels), "reached": est.reached})
        if len(est.failure_points):
            cols = acting({"fault_kind": cfg.values("fault_kind")[0], **stratum},
                          normal_space.columns_at(space, est.failure_points, args))
            for i, m in enumerate(est.failure_margins):
                failure_rows.append({"stratum": s, **stratum, **{k: v[i] for k, v in cols.items()}, "margin": m,
                                     "beta": float(np.linalg.norm(est.failure_points[i])), "point": len(points)})
                points.append(np.asarray(est.failure_points[i]))
    table = pd.DataFrame(strata_rows)
    overall = _combined(estimates, p.confidence)
    kinds = [s.get("fault_kind", cfg.values("fault_kind")[0]) for s in strata]
    groups = ({k: _combined([e for e, kind in zip(estimates, kinds) if kind == k], p.confidence)
               for k in dict.fromkeys(kinds)} if p.event == "missed_detection" else {"all": overall})
    rate, scored_s = None, c.duration_s - cfg.evaluation.settle_s
    if fault_kinds == ("none",):
        weights = exposure_weights(cfg, strata)
        table["exposure_weight"] = weights
        rate = per_flight_hour(estimates, weights, scored_s, p.confidence)
    notes = _notes(cfg, space, scored_s, p, margin, flag)
    meta = io.provenance(config.to_json(cfg), seed, models=list(names), event=p.event, method=p.method)
    failures = pd.DataFrame(failure_rows)
    return ProbabilityResult(p.event, p.method, overall, groups, rate, table, pd.DataFrame(level_rows), failures,
                             np.asarray(points).reshape(len(points), space.d), notes, meta, problem, args_list,
                             c.precision)


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

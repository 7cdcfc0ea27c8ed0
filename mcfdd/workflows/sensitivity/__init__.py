"""What drives a campaign's verdicts (``mcfdd sensitivity``): variance-based indices, gradient screen, regional.

On any campaign config, with its optional [sensitivity] table (:class:`mcfdd.config.SensitivityConfig`):

- first-order and total Sobol' indices, with bootstrap intervals, of the continuous outcomes that
  decide a verdict (:data:`~mcfdd.workflows.sensitivity.study.OUTCOMES`) over the space's sampled
  axes and the noise path as one group, from a pick-freeze design run as a campaign
  (:mod:`~mcfdd.workflows.sensitivity.study`);
- the gradient screen (DGSM, with the Sobol'-Kucherenko bound on the total index) of the outcomes
  with a smooth counterpart, by JAX gradients through the simulation at each stratum's A points;
- the regional sensitivity of false alarms and misses in the design's independent runs (A and B).

The estimators are :mod:`mcfdd.analysis.sensitivity`'s; the tables are built in
:mod:`~mcfdd.workflows.sensitivity.tables`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcfdd import config, io, report
from mcfdd.progress import note
from mcfdd.workflows import campaign as campaign_wf
from mcfdd.workflows.common import OutputFolderError, as_config, check_folder, precision, replay_command, save_figure
from mcfdd.workflows.sensitivity import tables
from mcfdd.workflows.sensitivity.study import NOISE, OUTCOMES, Design, design, outcome_names

PLOTS = {
    "indices": "total (dark) and first-order (light) Sobol' indices per factor, ranked, with their intervals; one "
               "panel per outcome and stratum",
    "screen": "DGSM bound nu_i / (pi^2 V) on the total index per continuous factor, ranked, with its interval",
    "regional": "distance D between the factor's values in runs with the event and the others, ranked",
}
TOP = 10  # factors drawn and listed per panel or table


class SensitivityResult:
    """A sensitivity analysis of a campaign space.

    Attributes:
        indices: per (outcome, stratum, factor): ``first``, ``total`` with ``_lo`` / ``_hi``
            bootstrap bounds, kind ('continuous', 'categorical' or 'noise'), base points and runs
            used, the outcome's mean and std; ranked by ``total`` within each (outcome, stratum).
        screen: per (outcome, stratum, continuous factor): DGSM ``nu`` and ``bound`` (on the total
            index) with bounds, points; ranked by ``nu``.
        regional: per (binary outcome, factor): ``rank``, events, runs, ``statistic`` (D),
            ``p_value``, ``test``, Cliff's delta ``effect`` with bounds (continuous factors),
            medians, ``rates`` per level (categorical factors).
        witnesses: the worst false alarms and misses of the design's independent runs.
        runs: the :class:`mcfdd.CampaignResult` of the design's runs.
        design: the :class:`~mcfdd.workflows.sensitivity.study.Design`.
        notes: what was left out or conditional, and the screen's agreement with the runs.
        meta: provenance (resolved config, seed, version, git revision, factors, strata).
    """

    def __init__(self, design_: Design, runs, indices, screen, regional, witnesses, notes, meta):
        self.design, self.runs, self.indices, self.screen, self.regional = design_, runs, indices, screen, regional
        self.witnesses, self.notes, self.meta = witnesses, notes, meta

    def left_out(self) -> dict:
        """Figures of :data:`PLOTS` without rows: name -> why."""
        why = {"indices": "no variance-based indices (method 'screen', or no outcome could be analysed)",
               "screen": "no outcome with a smooth counterpart in a stratum of this space",
               "regional": "no false alarm and no miss among the design's independent runs (or only those)"}
        return {name: why[name] for name in PLOTS if getattr(self, name).empty}

    def plot(self, name: str = "indices"):
        """One of :data:`PLOTS` as a matplotlib Figure: ranked horizontal bars with interval whiskers."""
        from mcfdd import plots

        if name not in PLOTS:
            raise ValueError(f"plot: {name!r} is not one of {', '.join(PLOTS)}")
        if name in self.left_out():
            raise ValueError(f"plot: {name!r} is not drawn: {self.left_out()[name]}")
        if name == "indices":
            return plots.ranked_bars(self.indices, [("total", "total S_T"), ("first", "first order S_1")],
                                     "Sobol' index (share of the outcome's variance)", TOP)
        if name == "screen":
            return plots.ranked_bars(self.screen, [("bound", "DGSM bound on S_T")],
                                     "nu / (pi^2 V), an upper bound on the total index (log scale)", TOP, log=True)
        return plots.ranked_bars(self.regional.assign(stratum=""), [("statistic", "D")],
                                 "distance D, runs with the event against the others (KS or total variation)", TOP)

    def lines(self) -> list[str]:
        """What the command prints: the leading factor of each analysed outcome and event."""
        out = []
        for (outcome, stratum), g in self.indices.groupby(["outcome", "stratum"], sort=False):
            r = g.iloc[0]
            out.append(f"{outcome} [{stratum}]: {r['factor']} S_T {r['total']:.2f} [{r['total_lo']:.2f}, "
                       f"{r['total_hi']:.2f}], S_1 {r['first']:.2f}")
        for (outcome, stratum), g in self.screen.groupby(["outcome", "stratum"], sort=False):
            out.append(f"{outcome} [{stratum}] screen: {g.iloc[0]['factor']} first (nu {g.iloc[0]['nu']:.3g})")
        for outcome, g in self.regional.groupby("outcome", sort=False):
            r, whole = g.iloc[0], g.loc[g["runs"].idxmax()]
            out.append(f"{outcome} ({whole['events']} of {whole['runs']} runs): {r['factor']} D {r['statistic']:.2f} "
                       f"(p {r['p_value']:.2g})")
        return out

    def save(self, out) -> list[Path]:
        """Write ``runs/`` (the design's runs, as ``mcfdd campaign`` writes a campaign) and the sensitivity files."""
        out = Path(out)
        return self.runs.save(out / "runs", "Sensitivity design runs") + self._save_tables(out)

    def _save_tables(self, out: Path) -> list[Path]:
        written = [io.write_table(getattr(self, name), out / f"{name}.parquet", self.meta)
                   for name in ("indices", "screen", "regional", "witnesses")]
        drawn = [name for name in PLOTS if name not in self.left_out()]
        written.append(io.write_text(out / "report.md", markdown(self, drawn, out)))
        written.extend(save_figure(self.plot(name), out / f"{name}.png") for name in drawn)
        return written


def sensitivity(cfg, out=None, resume: bool = False, progress: bool = True, executor=None,
                compile_cache=None) -> SensitivityResult:
    """Sensitivity of a campaign's verdicts to its uncertain parameters and noise.

    Args:
        cfg: a campaign config (:func:`mcfdd.load_config`), or a TOML path or dict of one; its
            [sensitivity] table sets outcomes, method, samples, bootstrap, confidence and seed.
        out: folder for ``runs/`` (the design's runs, one Parquet part per chunk as they finish),
            ``indices.parquet``, ``screen.parquet``, ``regional.parquet``, ``witnesses.parquet``,
            ``report.md`` and the figures; None runs in memory.
        resume: continue the design's runs in ``out`` (only the missing ones are simulated).
        progress, executor, compile_cache: as for :func:`mcfdd.run_campaign` (Dask or any
            ``concurrent.futures.Executor`` runs the design's chunks; the tables are the same).

    Returns:
        A :class:`SensitivityResult`.
    """
    cfg = as_config(cfg, "campaign")
    names = outcome_names(cfg)
    d = design(cfg)
    s = cfg.sensitivity
    if out is not None:
        out = Path(out)
        check_folder(out, "out")
        if not resume and io.folder_entries(out):
            raise OutputFolderError(f"out: {out} exists and is not empty; resume it or choose another folder")
    runs_n = d.plan.n
    note(f"sensitivity ({s.method}): {len(d.factors)} factors ({d.kinds.count('continuous')} continuous, "
         f"{d.kinds.count('categorical')} categorical, the noise path) x {d.samples} base samples = "
         f"{d.per_stratum} runs per stratum, {runs_n // d.per_stratum} strata: {runs_n} runs", progress)
    runs = campaign_wf.run_campaign(d.config, None if out is None else out / "runs", resume, progress, executor,
                                    title="Sensitivity design runs", compile_cache=compile_cache, plan=d.plan)
    notes: list[str] = []
    with precision(d.config.campaign.precision):
        indices = tables.indices_table(d, runs.scenarios, names if s.method == "pick_freeze" else (), s, notes)
        screen = tables.screen_table(d, runs.scenarios, names, s, notes, progress)
    block = d.locate(runs.scenarios["scenario_id"].to_numpy())[1]
    independent = runs.scenarios[block < 2]
    regional = tables.regional_table(cfg, independent, s.bootstrap, s.confidence, d.seed)
    meta = io.provenance(config.to_json(cfg), d.seed, factors=list(d.factors), strata=list(d.strata),
                         outcomes=list(names))
    result = SensitivityResult(d, runs, indices, screen, regional, tables.witnesses(independent), notes, meta)
    if out is not None:
        result._save_tables(out)
    return result


def _ci(value, lo, hi, digits: int = 2) -> str:
    return f"{value:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]" if np.isfinite(lo) else f"{value:.{digits}f}"


def markdown(result: SensitivityResult, drawn, folder=None) -> str:
    """report.md of a sensitivity analysis (in ``folder``: named in the witnesses' replay command)."""
    d, s = result.design, result.design.config.sensitivity
    meta = result.meta
    level = f"{100 * s.confidence:g} %"
    lines = [f"# Sensitivity of {', '.join(outcome_names(d.config))}", "",
             f"{d.plan.n} runs: {d.samples} base samples x {d.blocks} runs per base point "
             f"({'A, B and one A_B per factor' if d.blocks > 1 else 'A only: screen'}) in each of "
             f"{d.plan.n // d.per_stratum} strata ({', '.join(d.strata) or 'one'}); seed {d.seed}, mcfdd "
             f"{meta.get('version')}, revision {meta.get('git_revision')}.", "",
             f"Factors: {', '.join(d.factors)} ({NOISE}: the run's turbulence and sensor-noise sequence, one group). "
             f"Total index S_T: the share of the outcome's variance the factor takes part in (alone or with others); "
             f"first order S_1: alone. {level} intervals: BCa bootstrap over the {s.bootstrap} resamples of the base "
             f"points. The DGSM bound nu / (pi^2 V) is an upper bound on S_T (gradient screen).", ""]
    bounds = {(r.outcome, r.stratum, r.factor): r for r in result.screen.itertuples()}
    for (outcome, stratum), g in result.indices.groupby(["outcome", "stratum"], sort=False):
        first = g.iloc[0]
        lines += [f"## {outcome}, {stratum}", "", f"{OUTCOMES[outcome].what}; mean {first['mean']:.4g}, std "
                  f"{first['std']:.3g} over {first['base_points']} base points ({first['runs']} runs).", "",
                  "| factor | kind | S_T | S_1 | DGSM bound |", "|---|---|---|---|---|"]
        for r in g.head(TOP).itertuples():
            b = bounds.get((outcome, stratum, r.factor))
            lines.append(f"| {r.factor} | {r.kind} | {_ci(r.total, r.total_lo, r.total_hi)} "
                         f"| {_ci(r.first, r.first_lo, r.first_hi)} "
                         f"| {'-' if b is None else _ci(b.bound, b.bound_lo, b.bound_hi)} |")
        if len(g) > TOP:
            lines.append(f"| {len(g) - TOP} others | | S_T at most {g['total'].iloc[TOP:].max():.2f} | | |")
        lines.append("")
    if result.indices.empty and not result.screen.empty:
        lines += ["## Gradient screen", "", "| outcome | stratum | factor | nu | DGSM bound |", "|---|---|---|---|---|"]
        lines += [f"| {r.outcome} | {r.stratum} | {r.factor} | {r.nu:.3g} | {_ci(r.bound, r.bound_lo, r.bound_hi)} |"
                  for _, g in result.screen.groupby(["outcome", "stratum"], sort=False)
                  for r in g.head(TOP).itertuples()]
        lines.append("")
    ids = result.witnesses["scenario_id"].drop_duplicates() if folder is not None else ()
    lines += [report.drivers_markdown(result.regional, result.witnesses, "the design's A and B runs",
                                      replay=replay_command(folder, ids))]
    if result.notes:
        lines += ["## Notes", ""] + [f"- {n}." for n in result.notes] + [""]
    lines += ["## Figures", ""] + [f"- `{name}.png`: {PLOTS[name]}" for name in drawn]
    lines += [f"- `{name}.png` left out: {why}." for name, why in result.left_out().items()]
    return "\n".join(lines) + "\n"


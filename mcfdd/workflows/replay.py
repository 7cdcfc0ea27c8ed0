"""Named scenarios of a campaign replayed as time histories (``mcfdd replay``, :func:`replay`).

A campaign folder holds its resolved configuration (``campaign.json``) and its scenario rows
(``scenarios/part-*.parquet``, finished or interrupted); a sensitivity analysis's folder holds its
design's runs as such a campaign under ``runs/``. A scenario is rebuilt from these alone, as a
campaign chunk is: its design row, truth and random key from its id and the campaign's design
plan (the config's own, or the pick-freeze design of :func:`mcfdd.sensitivity`, whichever made the
stored rows). The named ids then run twice with the same scenarios and keys, at the campaign's
precision, sample time and sub-steps: through the campaign's own chunk program
(:func:`mcfdd.workflows.campaign.run_chunk`, padded to its lane blocks), which gives the outcome
columns, equal to the campaign's rows to the last bit whatever the chunk size, devices or executor
the campaign ran with; and through the simulate path (:func:`mcfdd.workflows.simulate.histories`),
which keeps every sample of the plant and FDD signals.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from mcfdd import config, io
from mcfdd.analysis import build
from mcfdd.progress import note
from mcfdd.workflows import campaign as campaign_wf
from mcfdd.workflows.common import precision, save_figure, slug
from mcfdd.workflows.folder import CAMPAIGN_STATE
from mcfdd.workflows.simulate import Histories, histories


class ReplayError(config.ConfigError):
    """A folder that holds no campaign, or scenario ids it does not hold; the message names which."""


def run_name(scenario_id: int) -> str:
    """The name of a replayed run in its time histories and figure, e.g. 'scenario-481'."""
    return f"scenario-{scenario_id}"


def stored_campaign(folder) -> tuple[config.CampaignConfig, pd.DataFrame, Path]:
    """(resolved config, scenario rows written so far sorted by id, the campaign's folder) of a campaign folder,
    or of a sensitivity analysis's design runs (its ``runs/``); what is wrong is a :class:`ReplayError`."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReplayError(f"replay: {folder} {'is not a folder' if folder.exists() else 'does not exist'}")
    state = folder / CAMPAIGN_STATE
    if not state.is_file() and (folder / "runs" / CAMPAIGN_STATE).is_file():
        folder, state = folder / "runs", folder / "runs" / CAMPAIGN_STATE
    if not state.is_file():
        raise ReplayError(f"replay: {folder} holds no campaign ({CAMPAIGN_STATE} missing)")
    try:
        cfg = config.load_config(json.loads(state.read_text()), "campaign")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, config.ConfigError) as err:
        raise ReplayError(f"replay: {state} is not a readable campaign state ({err})") from None
    parts = sorted((folder / "scenarios").glob("part-*.parquet"))
    if not parts:
        raise ReplayError(f"replay: {folder} holds no scenario rows yet (scenarios/part-*.parquet)")
    frames = []
    for part in parts:
        try:
            frames.append(io.read_checked_table(part))
        except ValueError as err:
            raise ReplayError(f"replay: {part} is damaged ({err}); resume the campaign to run its scenarios "
                              f"again") from None
    table = pd.concat(frames, ignore_index=True)
    return cfg, table.sort_values("scenario_id", kind="stable", ignore_index=True), folder


def _design_plan(cfg: config.CampaignConfig, rows: pd.DataFrame, folder) -> build.DesignPlan:
    """The design plan that made ``rows`` (their design columns): the config's own design or a sensitivity
    analysis's pick-freeze design."""
    from mcfdd.workflows.sensitivity import study  # deferred: the sensitivity tools only for their runs

    ids = rows["scenario_id"].to_numpy()
    for make in (lambda: build.design_plan(cfg), lambda: study.design(cfg).plan):
        try:
            with warnings.catch_warnings():  # a candidate, not the campaign: its design's warnings are not news
                warnings.simplefilter("ignore")
                plan = make()
        except config.ConfigError:
            continue
        if ids.max() < plan.n and all(name in rows and np.array_equal(rows[name].to_numpy(), np.asarray(values))
                                      for name, values in build.design_chunk(cfg, plan, ids).items()):
            return plan
    raise ReplayError(f"replay: the scenario rows of {folder} are not those of its {CAMPAIGN_STATE} "
                      f"(its design gives other parameters; the order of its [space] axes is part of the design)")


def _rows(table: pd.DataFrame, ids, folder) -> pd.DataFrame:
    """The rows of ``ids`` in the order given; an id named twice or not in the table is a :class:`ReplayError`."""
    ids = [int(i) for i in ids]
    if not ids:
        raise ReplayError("--scenarios: no scenario id given")
    have = table["scenario_id"].to_numpy()
    known = set(have.tolist())
    for i in ids:
        if ids.count(i) > 1:
            raise ReplayError(f"--scenarios: scenario {i} is named twice")
        if i not in known:
            where = f"{folder} holds" if folder is not None else "the campaign holds"
            raise ReplayError(f"--scenarios: scenario {i} is not in the campaign; {where} {len(have)} scenario rows "
                              f"with ids {have.min()}..{have.max()}")
    return table.set_index("scenario_id", drop=False).loc[ids].reset_index(drop=True)


def _same(a, b) -> bool:
    """Two columns of one dtype equal to the last bit (numbers compared by their bytes, nan and -0.0 included)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    return a.tobytes() == b.tobytes() if a.dtype.kind in "biufc" else bool(np.array_equal(a, b))


class ReplayResult:
    """Scenarios of a campaign simulated again: their time histories and their outcome columns.

    Attributes:
        ids: the scenario ids, in the order asked.
        rows: the campaign's rows of these scenarios (its scenario table's columns).
        outcomes: the replayed rows (the columns of the campaign's chunk program, same order of rows).
        histories: :class:`mcfdd.Histories` of the runs, each named :func:`run_name` ('scenario-<id>').
        source: the campaign's folder (None for a campaign in memory).
        detection_tau: the LOE detection threshold (theta / ||u||) of the campaign's FDD.
    """

    def __init__(self, ids, rows, outcomes, hist: Histories, source, detection_tau: float):
        self.ids, self.rows, self.outcomes, self.histories = list(ids), rows, outcomes, hist
        self.source, self.detection_tau = source, detection_tau

    def differences(self) -> list[str]:
        """The campaign's columns whose replayed values differ from its rows (not bit for bit); [] when all equal."""
        return [c for c in self.rows.columns if c not in self.outcomes or not _same(self.rows[c], self.outcomes[c])]

    def to_pandas(self) -> pd.DataFrame:
        """Tidy time histories, one row per (run, sample): as :meth:`mcfdd.Histories.to_pandas`."""
        return self.histories.to_pandas()

    def plot(self, scenario_id: int):
        """Deflections, LOE ratios with the detection threshold, decisions and the stall detector of one replayed
        run, with the campaign's onset, alarm and detection times marked; a matplotlib Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if scenario_id not in self.ids:
            raise ValueError(f"plot: scenario {scenario_id} is not one of the replayed {self.ids}")
        frame = self.to_pandas()
        row = self.rows.iloc[self.ids.index(scenario_id)]
        return plots.replay_run(frame[frame["run"] == run_name(scenario_id)], row, self.histories.models,
                                self.detection_tau)

    def save(self, out) -> list[Path]:
        """Write ``timeseries.parquet`` (the histories), ``outcomes.parquet`` (the replayed rows) and a PNG per run
        (``scenario-<id>.png``; for the full aircraft also ``scenario-<id>-flight.png``) into ``out``."""
        out = Path(out)
        meta = self.histories.meta
        written = [io.write_table(self.to_pandas(), out / "timeseries.parquet", meta),
                   io.write_table(self.outcomes, out / "outcomes.parquet", meta)]
        written.extend(save_figure(self.plot(i), out / f"{slug(run_name(i))}.png") for i in self.ids)
        frame = self.to_pandas()
        if "alpha_deg" in frame:
            from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

            written.extend(save_figure(plots.flight_state(frame[frame["run"] == run_name(i)], run_name(i)),
                                       out / f"{slug(run_name(i))}-flight.png") for i in self.ids)
        return written

    def lines(self) -> list[str]:
        """What ``mcfdd replay`` prints: each run's outcomes and whether they equal the campaign's rows."""
        from mcfdd import console

        lines = [console.replay_line(row) for _, row in self.outcomes.iterrows()]
        differ = self.differences()
        lines.append(f"replayed outcome columns: all {len(self.rows.columns)} equal the campaign's rows bit for bit"
                     if not differ else f"replayed outcome columns differing from the campaign's rows: "
                     f"{', '.join(differ)}")
        return lines


def replay_rows(cfg: config.CampaignConfig, table: pd.DataFrame, ids, plan: build.DesignPlan | None = None,
                progress: bool = True, source=None) -> ReplayResult:
    """Replay scenarios ``ids`` of a campaign given by its config and scenario table (see :func:`replay`).

    Args:
        cfg: the campaign's config; table: its scenario rows (any subset holding ``ids``).
        plan: its design plan (None: the config's own design).
        source: the campaign's folder, named in errors and kept on the result.
    """
    rows = _rows(table, ids, source)
    ids = rows["scenario_id"].to_numpy()
    c = cfg.campaign
    with precision(c.precision):
        setup = campaign_wf.campaign_setup(cfg, plan)
        size = campaign_wf.chunk_size(len(ids), setup.n)
        design = build.design_chunk(cfg, setup.plan, ids)
    note(f"replay: {len(ids)} scenario(s) of {c.duration_s} s ({c.n_steps} steps, {c.precision}) through the "
         f"campaign's chunk program (padded to {size}) and with time histories", progress)
    outcomes = pd.DataFrame(campaign_wf.run_chunk(cfg, ids, size, setup.plan))
    frame, names = histories(c, cfg.plant, cfg.fdd, design, [run_name(i) for i in ids], progress, [c.seed] * len(ids),
                             np.asarray(setup.plan.key_index(ids)).tolist())
    meta = io.provenance(config.to_json(cfg), c.seed, models=list(names), scenarios=[int(i) for i in ids],
                         campaign="" if source is None else str(source))
    return ReplayResult(ids.tolist(), rows, outcomes, Histories(frame, names, meta, c.dt_s), source,
                        cfg.fdd.loe.detection_tau)


def replay(campaign_dir, ids, out=None, progress: bool = True) -> ReplayResult:
    """Replay named scenarios of a finished or interrupted campaign as time histories.

    Args:
        campaign_dir: the folder of ``mcfdd campaign`` (or of ``mcfdd sensitivity``: its design's runs).
        ids: scenario ids among the rows the campaign has written, e.g. [481, 3524].
        out: folder for :meth:`ReplayResult.save`'s files; None writes nothing.
        progress: status lines on stderr; False for silence.

    Returns:
        A :class:`ReplayResult`; its ``outcomes`` equal the campaign's ``rows`` bit for bit
        (:meth:`ReplayResult.differences` is empty).
    """
    cfg, table, folder = stored_campaign(campaign_dir)
    rows = _rows(table, ids, folder)
    with precision(cfg.campaign.precision):
        plan = _design_plan(cfg, rows, folder)
    result = replay_rows(cfg, rows, ids, plan, progress, folder)
    if out is not None:
        result.save(out)
    return result

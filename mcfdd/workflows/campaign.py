"""Monte-Carlo campaigns: set-up, chunks as independent tasks, resume, scoring (DESIGN.md sections 2, 5).

A chunk is rebuilt from the config and its scenario ids alone (:func:`run_chunk`), so it can run
in process or on any ``concurrent.futures.Executor``; the driver collects the chunk tables and,
with an output folder, writes one Parquet part per chunk as they arrive.

Over 400 lines because the set-up, the chunk plan, the result object and the driver share the
campaign's state; the output folder's rules are in :mod:`mcfdd.workflows.folder`, resource
estimates in :mod:`mcfdd.workflows.resources`.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import socket
import time
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np
import pandas as pd

from mcfdd import config, io, report
from mcfdd.analysis import build, campaign, metrics, scenarios, scoring, simulate
from mcfdd.progress import bar, note
from mcfdd.workflows import common, folder, resources
from mcfdd.workflows.common import (
    DEG_PER_RAD,
    OutputFolderError,
    as_config,
    check_folder,
    dtype_of,
    is_dask,
    load_bank,
    precision,
    replay_command,
    save_figure,
)

# Each device's share of a chunk is a whole number of LANE_BLOCK scenarios, so a scenario's bits do
# not depend on the chunk size or the device count. Measured on one device (float32 and float64):
# shares of 2 to 250 scenarios give every scenario the bits of a share of 64; a share of 1 does not
# (XLA drops the size-1 batch axis and compiles other code). 16 is one 512-bit vector of float32
# (the campaign program prefers 512-bit vectors): a margin for CPUs whose loop remainders might
# round otherwise, for at most 15 padded scenarios per device and chunk.
LANE_BLOCK = 16
PLOTS = {
    "rates_by_fault": "false alarms per fault-free run (LOE, any) and MDR per fault class with their 95 % intervals",
    "rates_by_envelope": "false alarms per fault-free run (LOE, any) and MDR per speed and altitude cell",
    "rates_by_manoeuvre": "false alarms per fault-free run (LOE, any) and MDR per manoeuvre family",
    "detection_times": "detection latency per fault class (detected runs)",
    "confusion": "identification confusion (true nearest model against decided model, jammed runs included) and, "
                 "with stall loads or jams, stall identification against the truth",
    "detectability": "MDR per dynamic pressure and peak load fraction, separable cells framed",
    "stall_latency": "cumulative distribution of the worst stall-identification latency per run and method, "
                     "with the stall window",
}


class CampaignSetup(NamedTuple):
    """What a process builds once per campaign: plant, FDD, scoring settings and the design's plan.

    The scenarios themselves are built per chunk from their ids (:func:`chunk_inputs`).
    """

    config: object
    model: object
    names: tuple
    fdd_params: object
    settings: object
    nu_bank: np.ndarray  # (N, 2) fault parameters of the bank's models
    plan: build.DesignPlan
    dtype: type

    @property
    def n(self) -> int:
        return self.plan.n

    @property
    def kinds(self) -> tuple:
        return self.plan.kinds


def campaign_setup(cfg: config.CampaignConfig, plan: build.DesignPlan | None = None) -> CampaignSetup:
    """Plant, FDD, evaluation settings and the design plan (built here unless ``plan`` is given)."""
    dtype = dtype_of(cfg.campaign.precision)
    model = build.plant_model(cfg.plant)
    bank, names = load_bank(cfg.fdd, dtype)
    return CampaignSetup(cfg, model, names, build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m),
                         build.settings(cfg.evaluation, model.actuator.r_arm_m), np.asarray(bank.nu),
                         build.design_plan(cfg) if plan is None else plan, dtype)


def design_line(cfg: config.CampaignConfig, n: int) -> str:
    """How the campaign's scenarios are made up, e.g. '16384 scenarios = 4096 samples x 4 cells of fault_kind'."""
    c = cfg.campaign
    names, cells = cfg.grid_cells()
    line = f"{c.scenarios} scenarios = {c.scenarios // cells} samples"
    if names:
        line += f" x {cells} cells of {' x '.join(names)}"
    if n < c.scenarios:
        line += f" ({c.scenarios - n} above the Mach limit dropped: {n} run)"
    return line


def chunk_size(requested: int, n: int, devices: int | None = None) -> int:
    """Scenarios per chunk (every chunk pads to it: one program): the ``n`` scenarios evened out over the fewest
    chunks of at most ``requested``, then rounded up to a whole number of LANE_BLOCK scenarios on each of the
    devices that get any (:func:`chunk_devices`; ``devices`` defaults to this process's JAX devices).

    >>> chunk_size(2048, 2560, devices=4), chunk_size(2048, 10, devices=4), chunk_size(128, 320, devices=2)
    (1280, 16, 128)
    """
    if devices is None:
        devices = jax.device_count()
    n = max(n, 1)
    per_chunk = -(-n // -(-n // min(requested, n)))
    used = min(devices, -(-per_chunk // LANE_BLOCK))
    return -(-per_chunk // (used * LANE_BLOCK)) * used * LANE_BLOCK


def scenario_bytes(setup: CampaignSetup) -> int:
    """Bytes of one scenario's inputs, plant parameters and scan carry in the chunk program (traced, not compiled)."""
    c = setup.config.campaign

    def one():
        scen, truth, key = jax.tree.map(lambda x: x[0], chunk_inputs(setup, c.seed, np.arange(1), 1))
        monitor = scoring.monitors(setup.settings, truth, setup.fdd_params, c.dt_s)
        observer = scoring.observer(setup.settings, truth, monitor)
        return scen, truth, key, simulate.start(setup.model, setup.fdd_params, scen, key, c.dt_s, observer)

    with precision(c.precision):
        return resources.tree_bytes(jax.eval_shape(one))


def _chunk_plan(setup: CampaignSetup, executor, progress: bool) -> int:
    """The chunk size to run: :func:`chunk_size`, smaller where a chunk's memory would not fit; a note when a chunk
    may take long. A campaign whose table, or whose smallest chunk, cannot fit is refused naming the key."""
    c, n = setup.config.campaign, setup.n
    size = chunk_size(c.chunk_size, n)
    per_scenario = scenario_bytes(setup)
    available, table = resources.available_bytes(), resources.table_bytes(n)
    if table + (resources.RUNTIME_BYTES if executor is None else 0) > available:
        raise common.ResourceError(f"campaign.scenarios: the table of {n} scenarios needs about "
                                 f"{resources.gib(table)} in this process, more than the "
                                 f"{resources.gib(available)} available; split the campaign (e.g. by seed)")
    room, where = available - table, "available here"
    if is_dask(executor):
        from mcfdd.workflows import cluster

        limit = cluster.worker_memory(executor)
        room, where = (room, where) if limit is None else (limit, "of the smallest worker's memory limit")
    if resources.chunk_bytes(size, per_scenario) > room:
        fits = resources.largest_chunk(room, per_scenario)
        if fits < LANE_BLOCK:
            raise common.ResourceError(f"campaign.chunk_size: even a chunk of {LANE_BLOCK} scenarios needs about "
                                     f"{resources.gib(resources.chunk_bytes(LANE_BLOCK, per_scenario))}, more than "
                                     f"the {resources.gib(room)} {where}")
        block = LANE_BLOCK * jax.device_count()
        smaller = chunk_size(fits // block * block or fits // LANE_BLOCK * LANE_BLOCK, n)
        note(f"campaign: chunks of {size} scenarios would need about "
             f"{resources.gib(resources.chunk_bytes(size, per_scenario))}; running chunks of {smaller}, which fit in "
             f"the {resources.gib(room)} {where} (the table does not depend on the chunk size)", True)
        size = smaller
    slow = resources.long_chunk_note(size, c.n_steps, resources.cores() if executor is None else 1)
    if slow:
        note(slow, True)
    return size


def chunk_devices(size: int, devices: int) -> int:
    """How many of ``devices`` a chunk of ``size`` (a multiple of LANE_BLOCK) is split over: the most that give each
    a whole number of LANE_BLOCK scenarios (as :func:`mcfdd.analysis.campaign.on_devices` splits it)."""
    return max(d for d in range(1, devices + 1) if size % (d * LANE_BLOCK) == 0)


def _chunk(setup: CampaignSetup, seed: int, ids, size: int):
    """Columns, scenarios, truths, nearest models and keys of ``ids`` padded to ``size`` (by repeating the last id)."""
    padded = np.concatenate([ids, np.repeat(ids[-1:], size - len(ids))])
    cols = build.design_chunk(setup.config, setup.plan, padded)
    kind = np.asarray(cols["fault_kind"])
    nearest, accept = scenarios.true_model(setup.nu_bank, kind, np.asarray(cols.get("fault_size", np.zeros(size))))
    onset = scenarios.fault_onsets(cols, size)
    truth = scoring.Truth(onset.astype(setup.dtype), accept, nearest)
    keys = simulate.run_keys(seed, setup.plan.key_index(padded))
    return cols, scenarios.to_scenario(cols, setup.dtype), truth, onset, nearest, keys


def chunk_inputs(setup: CampaignSetup, seed: int, ids, size: int):
    """Scenarios, truths and keys of ``ids`` padded to ``size`` (by repeating the last id)."""
    _, scen, truth, _, _, keys = _chunk(setup, seed, ids, size)
    return scen, truth, keys


_SETUPS: dict = {}  # config JSON -> (set-up, whether its plan is the config's own design)


def _setup_of(cfg: config.CampaignConfig, plan: build.DesignPlan | None = None) -> CampaignSetup:
    """The set-up of ``cfg``, built once per process for the chunks of one campaign; with ``plan``, that plan."""
    key = config.to_json(cfg)
    setup, own = _SETUPS.get(key, (None, False))
    if setup is None or (plan is None and not own):
        _SETUPS.clear()
        setup = campaign_setup(cfg, plan)
        _SETUPS[key] = (setup, plan is None)
    return setup if plan is None or setup.plan is plan else setup._replace(plan=plan)


def run_chunk(cfg: config.CampaignConfig, ids: np.ndarray, size: int, plan: build.DesignPlan | None = None) -> dict:
    """Simulate and score the scenarios ``ids`` of a campaign, padded to ``size``.

    Args:
        cfg: the campaign config (the chunk is rebuilt from it alone, in whatever process).
        ids: (k,) scenario ids (any k <= size ids, not necessarily consecutive).
        size: the padded batch size (:func:`chunk_size`), the same for every chunk.
        plan: the campaign's :class:`mcfdd.analysis.build.DesignPlan` (computed once by the
            driver and sent to the workers); None builds it here.

    Returns:
        The chunk's rows of the scenario table: column name -> (k,) array.
    """
    c = cfg.campaign
    k = len(ids)
    with precision(c.precision):
        setup = _setup_of(cfg, plan)
        cols, scen, truth, onset, nearest, keys = _chunk(setup, c.seed, ids, size)
        raw = campaign.run_batch(setup.model, setup.fdd_params, setup.settings, scen, truth, keys, c.n_steps, c.dt_s,
                                 c.substeps, setup.kinds, lanes=LANE_BLOCK)
        outc = scoring.table({name: np.asarray(v)[:k] for name, v in raw.items()}, onset[:k], nearest[:k],
                             c.duration_s, cfg.evaluation.t_detec_s)
        cols = {name: np.asarray(v)[:k] for name, v in cols.items()}
        table = {"scenario_id": ids, **cols, **outc}
        table.update(metrics.detectability_columns(cols, outc["peak_load_fraction"], setup.plan.ranges))
    return table


def scored_seconds(cfg: config.CampaignConfig) -> float:
    """Seconds of each run that are scored for false alarms: the run after its settling time."""
    return cfg.campaign.duration_s - cfg.evaluation.settle_s


class CampaignResult:
    """A finished campaign: its tables, provenance, figures and files.

    Attributes:
        scenarios: one row per scenario (sorted by ``scenario_id``): the sampled parameters (units
            in the names), outcomes (false alarm, detection, identification, stall events, status
            as :class:`mcfdd.Status` codes) and per filter i ``ratio_max_pre_i`` /
            ``ratio_min_post_i`` (theta_i / ||u|| before the fault and in the detection window).
        summary: false alarms per fault-free run (LOE detection ``far_loe``, any alarm ``far_any``, false
            identifications; also per hour of scored fault-free time), MDR of the faulty runs,
            identification and stall rates, with Clopper-Pearson 95 % intervals, overall and per stratum
            (columns ``stratum`` and ``label``; :data:`mcfdd.report.FALSE_ALARM_COLUMNS`).
        confusion: true nearest model (rows) against decided model (columns), counts.
        gaps: tau_f (eq. 26), tau_d (eq. 27) and the detection gap per detector, with the scenario of each
            (in ``gaps.parquet`` also the command replaying it: ``tau_f_replay``, ``tau_d_replay``).
        detectability: FAR and MDR per fault class, dynamic-pressure bin and peak-load-fraction
            bin, each cell marked separable under the campaign's uncertainty or not.
        meta: provenance (resolved config JSON, seed, version, git revision, model names).
        models: names of the LPV bank's models, filter i = models[i].
        simulated: how many scenarios this call simulated (fewer than the table's rows on resume).
        workers: per process that ran chunks in this call ('host:pid'): chunks, scenarios, busy
            seconds and scenario-steps per busy second (:func:`worker_table`).
    """

    def __init__(self, cfg: config.CampaignConfig, scenarios, parts: np.ndarray, models, meta: dict,
                 simulated: int, workers=None, plan: build.DesignPlan | None = None):
        self.config, self.scenarios, self.models, self.meta, self.simulated = cfg, scenarios, tuple(models), meta, \
            simulated
        self._parts, self._plan = parts, plan
        self.workers = workers
        deg_per_m = DEG_PER_RAD / cfg.plant.actuator.r_arm_m
        self.summary = report.summary(scenarios, scored_seconds(cfg))
        self.confusion = report.confusion(scenarios, list(models))
        self.gaps = report.gaps(scenarios, deg_per_m)
        self.detectability = report.detectability(scenarios)
        self._drivers = None

    def drivers(self):
        """What drives the false alarms and misses: (regional sensitivity, worst witnesses), tidy tables of the
        campaign's own runs (:func:`mcfdd.workflows.sensitivity.tables.regional_table`), computed once."""
        if self._drivers is None:
            from mcfdd.workflows.sensitivity import tables

            s = self.config.sensitivity
            self._drivers = (tables.regional_table(self.config, self.scenarios, s.bootstrap, s.confidence,
                                                   self.config.campaign.seed if s.seed is None else s.seed),
                             tables.witnesses(self.scenarios))
        return self._drivers

    def replay(self, ids, progress: bool = True):
        """Scenarios ``ids`` of this campaign simulated again, with time histories: a
        :class:`mcfdd.workflows.replay.ReplayResult` (:func:`mcfdd.replay` of its folder)."""
        from mcfdd.workflows import replay  # deferred: the campaign does not need it

        return replay.replay_rows(self.config, self.scenarios, ids, self._plan, progress)

    def overall(self) -> dict:
        """The overall row of :attr:`summary` as a dict (runs, fault_free_runs, far_loe, far_any, mdr, ...)."""
        return self.summary[self.summary["stratum"] == "overall"].iloc[0].to_dict()

    def left_out(self) -> dict:
        """Figures of :data:`PLOTS` this campaign has no data for: name -> why."""
        o, df = self.overall(), self.scenarios
        why = {}
        if o["faulty_runs"] == 0:
            why["detection_times"] = "no run with a parametric fault (leakage, surface damage, disconnection)"
        elif not (df["detected"] & (df["status"] == 0)).any():
            why["detection_times"] = f"none of the {o['faulty_runs']} faulty runs was detected"
        if self.detectability.empty:
            why["detectability"] = "no parametric faults in this campaign"
        if o["stall_events"] == 0:
            why["stall_latency"] = "no relevant stall loads in this campaign"
        if o["faulty_runs"] == 0 and o["jammed_runs"] == 0 and o["stall_events"] == 0 and \
                not (df["identified_model"] >= 0).any():
            why["confusion"] = "no faulty or jammed run, no stall load and no identification in this campaign"
        return why

    def plot(self, name: str):
        """One of the campaign's figures, a matplotlib Figure.

        Args:
            name: one of :data:`PLOTS` ('rates_by_fault', 'rates_by_envelope', 'rates_by_manoeuvre',
                'detection_times', 'confusion', 'detectability', 'stall_latency') that
                :meth:`left_out` does not name.
        """
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if name not in PLOTS:
            raise ValueError(f"plot: {name!r} is not one of {', '.join(PLOTS)}")
        why = self.left_out().get(name)
        if why:
            raise ValueError(f"plot: {name!r} is not drawn for this campaign: {why}")
        if name.startswith("rates_by_"):
            rates = ("far_loe", "far_any") + (("mdr",) if self.overall()["faulty_runs"] > 0 else ())
            return plots.rates_by_stratum(self.summary, name[len("rates_by_"):], rates)
        if name == "detection_times":
            return plots.detection_times(self.scenarios, report.fault_class(self.scenarios))
        if name == "confusion":
            o = self.overall()
            stall = (report.stall_confusion(self.scenarios, self.config.fdd.stall.identification)
                     if o["stall_events"] > 0 or o["jammed_runs"] > 0 else None)
            decidable = [m for m in self.models if m != self.models[0] or m in self.confusion.columns]
            return plots.confusion_matrix(self.confusion.reindex(columns=[*decidable, "no decision"], fill_value=0),
                                          stall)
        if name == "detectability":
            return plots.detectability(self.detectability)
        return plots.stall_latency(self.scenarios, self.config.evaluation.stall_window_s)

    def save(self, out, title: str = "Campaign") -> list[Path]:
        """Write the files of ``mcfdd campaign`` into folder ``out``; returns their paths.

        ``campaign.json`` (resolved config), ``scenarios/part-*.parquet`` (one part per chunk),
        ``summary.parquet``, ``confusion.parquet``, ``gaps.parquet``, ``detectability.parquet``, ``summary.md`` (headed
        ``title``, ending with the figures written and those :meth:`left_out`, with the reason) and a PNG per
        :data:`PLOTS` name not left out.

        The command's rule holds: ``out`` is a new or empty folder, or one holding this same campaign
        (its ``campaign.json`` and no part this result does not write); anything else, a file, or a
        folder another run is writing raises :class:`OutputFolderError` before anything is written.
        """
        out = Path(out)
        self._check_target(out)
        with folder.writing(out, "choose a folder you can write to"):
            lock = io.lock_folder(out)
        if lock is None:
            raise folder.in_use(out)
        try:
            with folder.writing(out, "choose a folder you can write to"):
                return self._write(out, title)
        finally:
            lock.release()

    def _part_names(self) -> set[str]:
        ids = self.scenarios["scenario_id"].to_numpy()
        return {folder.part_name(int(ids[self._parts == part][0])) for part in np.unique(self._parts)}

    def _check_target(self, out: Path):
        """Refuse a folder :meth:`save` must not write into (see there)."""
        check_folder(out, "--out")
        if not io.folder_entries(out):
            return
        state = out / folder.CAMPAIGN_STATE
        if not state.is_file() or folder.stored_differences(state, self.config):
            raise OutputFolderError(f"--out: {out} exists and is not empty and holds no campaign of this "
                                    f"configuration; choose another folder")
        foreign = sorted(p.name for p in (out / "scenarios").glob("part-*.parquet") if p.name not in self._part_names())
        if foreign:
            raise OutputFolderError(f"--out: {out} holds parts of this campaign in other chunks ({foreign[0]}, ...) "
                                    f"that this result would not replace; choose another folder")

    def _write(self, out: Path, title: str) -> list[Path]:
        """:meth:`save` into a folder already checked and locked."""
        left_out = self.left_out()
        no_mdr = " (false alarms only: no faulty runs, so no MDR panel)" if self.overall()["faulty_runs"] == 0 else ""
        drawn = {name: what + (no_mdr if name.startswith("rates_by_") else "") for name, what in PLOTS.items()
                 if name not in left_out}
        written = [io.write_text(out / folder.CAMPAIGN_STATE, folder.state_text(self.config))]
        ids = self.scenarios["scenario_id"].to_numpy()
        for part in np.unique(self._parts):
            rows = self._parts == part
            written.append(io.write_table(self.scenarios[rows].reset_index(drop=True),
                                          out / "scenarios" / folder.part_name(int(ids[rows][0])), self.meta))
        written.append(io.write_table(self.summary, out / "summary.parquet", self.meta))
        written.append(io.write_table(self.confusion.reset_index(), out / "confusion.parquet", self.meta))
        witnesses = {b: self.gaps[f"{b}_scenario_id"].to_numpy() for b in ("tau_f", "tau_d")}  # -1: none
        written.append(io.write_table(self.gaps.assign(**{f"{b}_replay": [replay_command(out, [i] if i >= 0 else [])
                                                                           for i in w] for b, w in witnesses.items()}),
                                      out / "gaps.parquet", self.meta))
        written.append(io.write_table(self.detectability, out / "detectability.parquet", self.meta))
        ids = pd.unique(np.concatenate(list(witnesses.values())))
        written.append(io.write_text(out / "summary.md", report.markdown(title, self.summary, self.confusion,
                                                                         self.gaps, self.meta,
                                                                         replay_command(out, ids[ids >= 0]))
                                     + report.detectability_markdown(self.detectability, self.scenarios)
                                     + report.stall_scoring_markdown(self.scenarios)
                                     + report.drivers_markdown(*self.drivers(), replay=replay_command(
                                         out, self.drivers()[1]["scenario_id"].drop_duplicates()))
                                     + report.figures_markdown(drawn, left_out)))
        written.extend(save_figure(self.plot(name), out / f"{name}.png") for name in drawn)
        return written


@contextlib.contextmanager
def campaign_executor(scheduler: str | None = None, workers: int | None = None, tls_ca_file=None, tls_cert=None,
                      tls_key=None, connect_timeout_s: float = 10.0):
    """Where a campaign's chunks run, for ``run_campaign(..., executor=...)``: None (this process) without
    ``scheduler`` and ``workers``, else a Dask client of that scheduler or of a local cluster of ``workers``
    processes, closed on exit. The TLS files are for a scheduler only; errors name the command's flags."""
    if scheduler is None:
        for key, value in (("tls_ca_file", tls_ca_file), ("tls_cert", tls_cert), ("tls_key", tls_key)):
            if value is not None:
                raise config.ConfigError(f"--{key.replace('_', '-')}: only used with --scheduler (a tls:// "
                                         f"scheduler); give --scheduler ADDR or leave it out")
    if scheduler is None and workers is None:
        yield None
        return
    if connect_timeout_s <= 0:
        raise config.ConfigError(f"--connect-timeout: {connect_timeout_s} is not allowed; expected seconds > 0")
    if workers is not None:
        resources.check_workers(workers)  # before Dask is even imported
    try:
        from mcfdd.workflows import cluster  # deferred: Dask is the optional 'distributed' extra
    except ImportError:
        raise config.ConfigError("--scheduler/--workers need Dask: pip install 'mcfdd[distributed]'") from None
    with cluster.dask_cluster(scheduler, workers, cluster.security(tls_ca_file, tls_cert, tls_key),
                              connect_timeout_s) as client:
        yield client


def chunk_task(cfg: config.CampaignConfig, ids: np.ndarray, size: int, plan: build.DesignPlan):
    """:func:`run_chunk` as a task: (its table, the process that ran it as 'host:pid', seconds taken)."""
    start = time.perf_counter()
    table = run_chunk(cfg, ids, size, plan)
    return table, f"{socket.gethostname()}:{os.getpid()}", time.perf_counter() - start


def _layout(size: int, executor) -> str:
    """How a chunk is spread, for the campaign's status line: devices x share here, or on the workers."""
    if executor is not None:
        return f"each split over its worker's devices, {LANE_BLOCK} lanes at least"
    used = chunk_devices(size, jax.device_count())
    return f"{used} device(s) x {size // used}"


def _submit(executor, cfg, chunks, size: int, plan: build.DesignPlan, cache):
    """The chunks run in process (``executor`` None), on a ``concurrent.futures.Executor`` or on a Dask client.

    Returns (an iterator of (ids, table, worker, seconds) in the order the chunks finish, a
    function cancelling the tasks not yet done).
    """
    if executor is None:
        return ((ids, *chunk_task(cfg, ids, size, plan)) for ids in chunks), lambda: None
    if is_dask(executor):
        from mcfdd.workflows import cluster

        return cluster.submit(executor, chunk_task, cfg, chunks, size, plan, cache)
    futures = {executor.submit(chunk_task, cfg, ids, size, plan): ids for ids in chunks}
    finished = ((futures[f], *f.result()) for f in concurrent.futures.as_completed(futures))
    return finished, lambda: [f.cancel() for f in futures]


def worker_table(records, n_steps: int):
    """Per process that ran chunks: chunks, scenarios, busy seconds and scenario-steps per busy second."""
    frame = pd.DataFrame(records, columns=["worker", "scenarios", "busy_s"])
    table = frame.groupby("worker", sort=True).agg(chunks=("scenarios", "size"), scenarios=("scenarios", "sum"),
                                                   busy_s=("busy_s", "sum")).reset_index()
    table["scenario_steps_per_s"] = table["scenarios"] * n_steps / table["busy_s"]
    return table


def run_campaign(cfg, out=None, resume: bool = False, progress: bool = True, executor=None, on_chunk=None,
                 title: str = "Campaign", compile_cache=None, plan: build.DesignPlan | None = None) -> CampaignResult:
    """Simulate and score every scenario of a campaign.

    Args:
        cfg: a campaign config (:func:`mcfdd.load_config`), or a TOML path or dict of one.
        out: folder for the files of ``mcfdd campaign``, written as chunks finish (one Parquet
            part each) and at the end; None runs in memory and writes nothing.
        resume: continue the campaign in ``out``, simulating only the scenarios not yet written.
        progress: a progress bar on stderr (rate, time left); False for silence.
        executor: None to run chunks in this process, a ``concurrent.futures.Executor`` or a
            ``dask.distributed.Client`` (:func:`mcfdd.dask_cluster`) to which each chunk is
            submitted as a task (:func:`run_chunk`); the table is the same. An exception or
            Ctrl-C in the driver cancels the tasks not yet done; the parts written are kept.
        on_chunk: called with the (k,) ids of each chunk when it is done (e.g. to stop a run).
        title: heading of ``summary.md`` when ``out`` is given.
        compile_cache: folder of JAX's persistent compilation cache, here and on Dask workers
            (:func:`mcfdd.workflows.common.compile_cache`): None for the user's cache folder,
            'off' for none. It does not change results.
        plan: the scenarios to run instead of the config's design (:func:`mcfdd.analysis.build.design_plan`
            with an explicit sample, e.g. the pick-freeze design of :func:`mcfdd.sensitivity`); None: the
            config's own.

    Returns:
        A :class:`CampaignResult`; ``.scenarios`` is bit for bit the table ``mcfdd campaign``
        writes for the same config and seed, whatever the chunk size, devices or executor.

    >>> import mcfdd
    >>> cfg = mcfdd.load_config({"campaign": {"scenarios": 2, "duration_s": 0.1}, "evaluation": {"settle_s": 0.0},
    ...                          "space": {"kci_scale": [0.9, 1.1]}})
    >>> result = mcfdd.run_campaign(cfg, progress=False)
    >>> len(result.scenarios), int(result.overall()["runs"])
    (2, 2)
    """
    cfg = as_config(cfg, "campaign")
    if out is not None:
        out = Path(out)
        folder.check_out(out, resume)
    with precision(cfg.campaign.precision):
        setup = _setup_of(cfg, plan)  # a configuration error (a bad bank) stops the run before any folder is made
    size = _chunk_plan(setup, executor, progress)  # so does a campaign that cannot fit in memory
    common.compile_cache(compile_cache)  # and an unusable cache folder
    if out is None:
        return _run_campaign(setup, None, size, resume, progress, executor, on_chunk, title, compile_cache)
    made = not out.exists()
    with folder.writing(out, "choose a folder you can write to"):
        lock = io.lock_folder(out)
    if lock is None:
        raise folder.in_use(out)
    try:
        return _run_campaign(setup, out, size, resume, progress, executor, on_chunk, title, compile_cache)
    finally:
        lock.release()
        if made:
            folder.remove_if_unused(out)


def _run_campaign(setup, out, size, resume, progress, executor, on_chunk, title, compile_cache) -> CampaignResult:
    """:func:`run_campaign` of a set-up campaign in chunks of ``size``; ``out`` is None or a folder this process has
    locked."""
    cfg = setup.config
    c = cfg.campaign
    n, names = setup.n, setup.names
    if out is not None:
        folder.prepare_dir(out, cfg, resume)
    frames, labels, done = folder.read_parts(out / "scenarios", setup) if out is not None and resume else (
        [], [], np.zeros(n, dtype=bool))
    todo = np.flatnonzero(~done)
    meta = io.provenance(config.to_json(cfg), c.seed, models=list(names))
    chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
    note(design_line(cfg, n), progress)
    note(f"campaign: {n} scenarios of {c.duration_s} s ({c.n_steps} steps, {c.precision}), {len(todo)} to run in "
         f"{len(chunks)} chunk(s) of {size} ({_layout(size, executor)}; {len(chunks) * size - len(todo)} padding "
         f"scenarios)", progress)
    records = []
    with bar(len(todo), "scenarios", progress, unit="scen") as shown:
        finished, cancel = _submit(executor, cfg, chunks, size, setup.plan, compile_cache)
        try:
            for ids, table, worker, seconds in finished:
                frame = pd.DataFrame(table)
                if out is not None:
                    with folder.writing(out, "the parts written so far are kept; make room and continue with --resume"):
                        io.write_table(frame, out / "scenarios" / folder.part_name(int(ids[0])), meta)
                frames.append(frame)
                labels.append(np.full(len(ids), int(ids[0])))
                records.append((worker, len(ids), seconds))
                shown.update(len(ids))
                if on_chunk is not None:
                    on_chunk(ids)
        except BaseException:
            cancel()
            raise
    table = pd.concat(frames, ignore_index=True)
    order = np.argsort(table["scenario_id"].to_numpy(), kind="stable")
    result = CampaignResult(cfg, table.iloc[order].reset_index(drop=True), np.concatenate(labels)[order], names, meta,
                            len(todo), worker_table(records, c.n_steps), setup.plan)
    if out is not None:
        with folder.writing(out, "every scenario part is written; make room and continue with --resume"):
            result._write(out, title)
    return result

"""The ``mcfdd`` command (the edge of the package): configs in, tables and figures out."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mcfdd import config, io
from mcfdd.analysis import build


def _set_precision(precision: str):
    import jax

    jax.config.update("jax_enable_x64", precision == "float64")


def _dtype(precision: str):
    return np.float64 if precision == "float64" else np.float32


def _save_figure(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _say(message: str):
    print(message, file=sys.stderr, flush=True)


def _load_bank(fdd_cfg: config.FddConfig, dtype):
    from mcfdd.fdd import lpv

    try:
        data = io.load_bank_dict(None if fdd_cfg.bank == "default" else fdd_cfg.bank)
        return lpv.from_dict(data, dtype)
    except (OSError, ValueError, KeyError) as err:
        raise config.ConfigError(f"fdd.bank: cannot use {fdd_cfg.bank!r}: {err}") from None


def histories(sim: config.SimulationConfig, plant_cfg: config.PlantConfig, fdd_cfg: config.FddConfig, table: dict,
              run_names):
    """Simulate the runs of a scenario table with plant and FDD in one batch.

    Returns (tidy DataFrame of time histories, LPV model names).
    """
    import jax

    from mcfdd.analysis import batch, simulate
    from mcfdd.analysis.scenarios import to_scenario
    from mcfdd.plant import closed_loop

    dtype = _dtype(sim.precision)
    model = build.plant_model(plant_cfg)
    bank, names = _load_bank(fdd_cfg, dtype)
    fdd_params = build.fdd_params(fdd_cfg, bank, model.actuator.r_arm_m)
    scenarios = to_scenario(table, dtype)
    kinds = batch.kinds_in(scenarios.manoeuvre.kind)
    keys = simulate.run_keys(sim.seed, range(len(run_names)))
    _say(f"simulating {len(run_names)} run(s) of {sim.duration_s} s ({sim.n_steps} steps, {sim.precision})")
    start = time.perf_counter()
    plant, fdd = jax.block_until_ready(
        simulate.fdd_batch(model, fdd_params, scenarios, keys, sim.n_steps, sim.dt_s, sim.substeps, kinds))
    _say(f"  done in {time.perf_counter() - start:.1f} s (compilation included)")
    r_arm = model.actuator.r_arm_m
    to_deg = 180.0 / math.pi

    def deg(x):
        return closed_loop.deflection_deg(np.asarray(x), r_arm)

    columns = {
        "u_c_m": plant.u_c_m, "u_m": plant.u_m, "x_m": plant.x_m, "u_c_deg": deg(plant.u_c_m), "u_deg": deg(plant.u_m),
        "delta_deg": deg(plant.x_m), "dp_avail_norm": plant.dp_avail_norm, "stall": plant.stall,
        "p_deg_s": plant.p_rad_s * to_deg, "phi_deg": plant.phi_rad * to_deg, "stick": plant.stick,
        "nu1": plant.nu1, "nu2": plant.nu2,
    }
    for i in range(len(names)):
        columns[f"r_{i}"] = fdd.r[..., i]
        columns[f"theta_{i}"] = fdd.theta[..., i]
        columns[f"iota_{i}"] = fdd.iota[..., i]
    eta = fdd.eta_signal if fdd_cfg.stall.identification == "signal" else fdd.eta_model
    columns.update({
        "theta_u": fdd.theta_u, "load_fraction": fdd.load_fraction, "excited": fdd.excited,
        "decoded_model": fdd.decoded, "detected_model": fdd.detected, "r_stall": fdd.r_stall,
        "r_stall_deg": deg(fdd.r_stall), "theta_stall": fdd.theta_stall, "iota_stall": fdd.iota_stall,
        "eta_stall": eta, "eta_signal": fdd.eta_signal, "eta_model": fdd.eta_model, "theta_sl": fdd.theta_sl,
    })
    t = np.arange(sim.n_steps) * sim.dt_s
    return io.history_frame(list(run_names), t, {k: np.asarray(v) for k, v in columns.items()}), names


def _runs_table(runs) -> dict:
    rows = [build.run_columns(run) for run in runs]
    return {k: np.array([r[k] for r in rows]) for k in rows[0]}


def cmd_simulate(args) -> int:
    cfg = config.load(config.SimulateConfig, args.config)
    _set_precision(cfg.simulation.precision)
    from mcfdd import plots

    out = Path(args.out) if args.out else io.default_out_dir("simulate", args.config)
    df, names = histories(cfg.simulation, cfg.plant, cfg.fdd, _runs_table(cfg.runs), [r.name for r in cfg.runs])
    meta = io.provenance(config.to_json(cfg), cfg.simulation.seed, models=list(names))
    _say(f"wrote {io.write_table(df, out / 'timeseries.parquet', meta)}")
    dt = cfg.simulation.dt_s
    for name, group in df.groupby("run", sort=False):
        _say(f"wrote {_save_figure(plots.run_timeseries(group, name), out / f'{_slug(name)}.png')}")
        detected = group["detected_model"].to_numpy()
        first = {names[m]: float(group["t_s"].to_numpy()[detected == m][0]) for m in np.unique(detected) if m >= 0}
        print(f"{name}: max |delta| {group['delta_deg'].abs().max():.2f} deg, stall {group['stall'].sum() * dt:.2f} s, "
              f"eta_stall {group['eta_stall'].sum() * dt:.2f} s, first decisions {first or 'none'}")
    return 0


class Progress:
    """One status line on stderr: chunks, scenarios done, scenarios per second, time left."""

    def __init__(self, total: int, chunks: int):
        self.total, self.chunks, self.done, self.chunk = total, chunks, 0, 0
        self.start = time.perf_counter()

    def update(self, scenarios: int):
        self.done += scenarios
        self.chunk += 1
        elapsed = time.perf_counter() - self.start
        speed = self.done / elapsed if elapsed > 0 else float("nan")
        left = (self.total - self.done) / speed if speed > 0 else float("nan")
        end = "\n" if self.done >= self.total else ""
        print(f"\r  chunk {self.chunk}/{self.chunks}  {self.done}/{self.total} scenarios  {speed:.1f} scenarios/s  "
              f"{left:.0f} s left   ", end=end, file=sys.stderr, flush=True)


CAMPAIGN_STATE = "campaign.json"
# Chunks are padded to a multiple of this many scenarios per device: every batch then runs the
# same vectorised code, so results do not depend on the chunk size to the last bit.
LANE_BLOCK = 64


def _campaign_config(args) -> config.CampaignConfig:
    cfg = config.load(config.CampaignConfig, args.config)
    overrides = {}
    for flag, key in (("scenarios", "scenarios"), ("seed", "seed"), ("chunk_size", "chunk_size")):
        value = getattr(args, flag)
        if value is not None:
            if value < (0 if key == "seed" else 1):
                raise config.ConfigError(f"--{flag.replace('_', '-')}: {value} is not allowed; expected "
                                         f"{'a non-negative' if key == 'seed' else 'a positive'} integer")
            overrides[f"campaign.{key}"] = value
    if getattr(args, "fdd", None):
        overrides["fdd"] = config.to_dict(config.load_fdd_fragment(args.fdd))
    return config.replace(cfg, overrides)


def _resolved(cfg: config.CampaignConfig) -> dict:
    """Resolved config without the chunk size, which does not change results."""
    data = config.to_dict(cfg)
    data["campaign"].pop("chunk_size")
    return data


def _prepare_campaign_dir(out: Path, cfg: config.CampaignConfig, resume: bool):
    import json

    state = out / CAMPAIGN_STATE
    resolved = _resolved(cfg)
    if resume:
        if not state.is_file():
            raise config.ConfigError(f"--resume: {out} holds no campaign to resume ({CAMPAIGN_STATE} missing)")
        if json.loads(state.read_text()) != json.loads(json.dumps(resolved)):
            raise config.ConfigError(f"--resume: the configuration differs from the one {out} was started with")
        return
    if out.exists() and any(out.iterdir()):
        raise config.ConfigError(f"--out: {out} exists and is not empty; use --resume to continue it, or another "
                                 f"folder")
    io.write_text(state, json.dumps(resolved, indent=1, sort_keys=True))


class CampaignSetup(NamedTuple):
    """What a campaign builds once before its chunk loop (host arrays over all n scenarios)."""

    model: object
    names: tuple
    fdd_params: object
    settings: object
    cols: dict
    n: int
    onset: np.ndarray  # fault onset times (s), float64
    nearest: np.ndarray
    accept: np.ndarray
    scenarios: object
    kinds: tuple
    dtype: type


def campaign_setup(cfg: config.CampaignConfig) -> CampaignSetup:
    """Plant, FDD, evaluation settings, the sampled design and each scenario's truth."""
    from mcfdd.analysis import batch, scenarios

    dtype = _dtype(cfg.campaign.precision)
    model = build.plant_model(cfg.plant)
    bank, names = _load_bank(cfg.fdd, dtype)
    cols, n = build.design(cfg)
    kind = np.asarray(cols.get("fault_kind", np.full(n, "none")))
    nearest, accept = scenarios.true_model(np.asarray(bank.nu), kind,
                                           np.asarray(cols.get("fault_size", np.zeros(n))))
    all_scenarios = scenarios.to_scenario(cols, dtype)
    return CampaignSetup(model, names, build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m),
                         build.settings(cfg.evaluation, model.actuator.r_arm_m), cols, n,
                         scenarios.fault_onsets(cols, n), nearest, accept, all_scenarios,
                         batch.kinds_in(all_scenarios.manoeuvre.kind), dtype)


def chunk_size(requested: int, n: int) -> int:
    """Scenarios per chunk: ``requested`` (at most n) rounded up to LANE_BLOCK x devices."""
    import jax

    block = LANE_BLOCK * jax.device_count()
    return -(-min(requested, max(n, 1)) // block) * block


def chunk_inputs(setup: CampaignSetup, seed: int, ids, size: int):
    """Scenarios, truths and keys of ``ids`` padded to ``size`` (by repeating the last id)."""
    import jax

    from mcfdd.analysis import campaign, simulate

    padded = np.concatenate([ids, np.repeat(ids[-1:], size - len(ids))])
    scen = jax.tree.map(lambda a: a[padded], setup.scenarios)
    truth = campaign.Truth(setup.onset[padded].astype(setup.dtype), setup.accept[padded])
    return scen, truth, simulate.run_keys(seed, padded)


def run_campaign(cfg: config.CampaignConfig, out: Path, resume: bool = False, on_chunk=None):
    """Simulate every scenario of the campaign not yet written under ``out/scenarios``; returns the table."""
    import pandas as pd

    from mcfdd.analysis import campaign, metrics

    c = cfg.campaign
    setup = campaign_setup(cfg)
    n, names, cols = setup.n, setup.names, setup.cols
    parts = out / "scenarios"
    done = np.zeros(n, dtype=bool)
    if resume and parts.is_dir():
        for part in parts.glob("part-*.parquet"):
            done[pd.read_parquet(part, columns=["scenario_id"])["scenario_id"].to_numpy()] = True
    todo = np.flatnonzero(~done)
    meta = io.provenance(config.to_json(cfg), c.seed, models=list(names))
    size = chunk_size(c.chunk_size, n)
    chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
    _say(f"campaign: {n} scenarios of {c.duration_s} s ({c.n_steps} steps, {c.precision}), "
         f"{len(todo)} to run in {len(chunks)} chunk(s) of {size}")
    progress = Progress(len(todo), len(chunks))
    for ids in chunks:
        scen, truth, keys = chunk_inputs(setup, c.seed, ids, size)
        raw = campaign.run_batch(setup.model, setup.fdd_params, setup.settings, scen, truth, keys, c.n_steps, c.dt_s,
                                 c.substeps, setup.kinds)
        raw = {k: np.asarray(v)[:len(ids)] for k, v in raw.items()}
        outc = metrics.outcomes(raw, setup.onset[ids], setup.accept[ids], setup.nearest[ids], c.duration_s,
                                cfg.evaluation.t_detec_s)
        table = {"scenario_id": ids, **{k: np.asarray(v)[ids] for k, v in cols.items()}, **outc}
        for i in range(len(names)):
            table[f"ratio_max_pre_{i}"] = raw["ratio_max_pre"][:, i]
            table[f"ratio_min_post_{i}"] = raw["ratio_min_post"][:, i]
        io.write_table(pd.DataFrame(table), parts / f"part-{ids[0]:08d}.parquet", meta)
        progress.update(len(ids))
        if on_chunk is not None:
            on_chunk(ids)
    frames = [pd.read_parquet(p) for p in sorted(parts.glob("part-*.parquet"))]
    return pd.concat(frames, ignore_index=True).sort_values("scenario_id", ignore_index=True), names, meta


def cmd_campaign(args) -> int:
    cfg = _campaign_config(args)
    _set_precision(cfg.campaign.precision)
    from mcfdd import plots, report

    if args.out:
        out = Path(args.out)
    elif args.resume:
        out = io.default_out_dir("campaign", args.config)
    else:
        out = io.unused_out_dir("campaign", args.config)
    _prepare_campaign_dir(out, cfg, args.resume)
    try:
        df, names, meta = run_campaign(cfg, out, args.resume)
    except KeyboardInterrupt:
        _say(f"\ninterrupted: finished chunks are kept in {out / 'scenarios'}; continue with --resume")
        return 130
    r_arm = cfg.plant.actuator.r_arm_m
    summ = report.summary(df)
    conf = report.confusion(df, names)
    gap = report.gaps(df, 180.0 / math.pi / r_arm)
    io.write_table(summ, out / "summary.parquet", meta)
    io.write_table(conf.reset_index(), out / "confusion.parquet", meta)
    io.write_table(gap, out / "gaps.parquet", meta)
    io.write_text(out / "summary.md", report.markdown(f"Campaign {Path(args.config).stem}", summ, conf, gap, meta))
    for group in ("fault", "envelope", "manoeuvre"):
        _save_figure(plots.rates_by_stratum(summ, group), out / f"rates_by_{group}.png")
    _save_figure(plots.detection_times(df, report.fault_class(df)), out / "detection_times.png")
    _save_figure(plots.confusion_matrix(conf), out / "confusion.png")
    overall = summ[summ["group"] == "overall"].iloc[0]
    print(f"{overall['runs']} scenarios: FAR {overall['far']:.4g} [{overall['far_lo']:.3g}, {overall['far_hi']:.3g}], "
          f"MDR {overall['mdr']:.4g} [{overall['mdr_lo']:.3g}, {overall['mdr_hi']:.3g}], "
          f"stall events {overall['stall_events']}")
    print(f"summary: {out / 'summary.md'}")
    return 0


def cmd_fit_lpv(args) -> int:
    cfg = config.load(config.LpvFitConfig, args.config)
    _set_precision(cfg.precision)
    import pandas as pd

    from mcfdd import plots
    from mcfdd.analysis import lpv_fit
    from mcfdd.fdd import lpv
    from mcfdd.plant import atmosphere, closed_loop, manoeuvres

    out = Path(args.out) if args.out else io.default_out_dir("fit-lpv", args.config)
    dtype = _dtype(cfg.precision)
    model = build.plant_model(cfg.plant)
    runs, opt, max_mach = cfg.runs, cfg.optimiser, cfg.plant.aircraft.max_mach
    nus, names = build.lpv_nus(cfg), [m.name for m in cfg.models]
    r_arm = model.actuator.r_arm_m
    points = {"training": build.lpv_training_points(cfg.envelope, max_mach),
              "validation": build.lpv_validation_points(cfg.envelope, max_mach, cfg.seed)}
    commands, problems = {}, {}
    start = time.perf_counter()
    for split, (v, h) in points.items():
        commands[split] = build.lpv_manoeuvre_params(cfg, split, dtype)
        problems[split] = lpv_fit.make_problem(model, nus, v, h, commands[split], runs.n_steps, runs.dt_s,
                                               runs.substeps)
        _say(f"{split}: {len(v)} flight points x {len(commands[split].kind)} manoeuvres of {runs.duration_s} s, "
             f"{len(names)} models (nonlinear actuator simulated)")
    bank, free = lpv_fit.initial_bank(model, nus, *points["training"], cfg.exact_disconnection, dtype)
    for i in np.flatnonzero(~free):
        _say(f"{names[i]}: exact gain of eq. (36), {float(bank.k0[i]):.3f} 1/s, not fitted")

    def progress(i, losses):
        last = i + 1 == opt.iterations
        if i % 10 and not last:
            return
        rms = " ".join(f"{100 * math.sqrt(v):.3f}" for v in losses)
        end = "\n" if last else ""
        print(f"\r  iteration {i + 1}/{opt.iterations}  training RMS error (% of amplitude): {rms}   ", end=end,
              file=sys.stderr, flush=True)

    bank, _ = lpv_fit.fit(bank, problems["training"], runs.dt_s, margin=runs.min_pressure, free=free,
                          callback=progress, **config.to_dict(opt))
    _say(f"fitted in {time.perf_counter() - start:.1f} s (simulation and compilation included)")

    frames, summary, x_lpv = [], {}, {}
    for split, problem in problems.items():
        x_lpv[split] = lpv_fit.responses(bank, problem, runs.dt_s)
        rms, max_error = lpv_fit.output_errors(x_lpv[split], problem)
        domain = lpv_fit.in_domain(problem, runs.min_pressure)
        summary[split] = lpv_fit.error_summary(rms, max_error, domain)
        n_commands = len(commands[split].kind)
        v, h = points[split]
        run_columns = {
            "split": np.full(len(v) * n_commands, split), "run": np.arange(len(v) * n_commands),
            "vcas_kt": np.repeat(v / atmosphere.KT_TO_M_S, n_commands), "altitude_m": np.repeat(h, n_commands),
            "manoeuvre": np.tile(np.asarray(manoeuvres.KINDS)[np.asarray(commands[split].kind)], len(v)),
            "amplitude": np.tile(np.asarray(commands[split].amplitude), len(v)),
            "amplitude_deg": closed_loop.deflection_deg(np.asarray(problem.amplitude_m), r_arm),
        }
        frames.append(io.model_run_frame(names, run_columns, {
            "rms_error_pct": 100.0 * np.asarray(rms), "max_error_pct": 100.0 * np.asarray(max_error),
            "min_available_pressure": np.asarray(problem.min_pressure), "in_domain": np.asarray(domain)}))
    errors = pd.concat(frames, ignore_index=True)

    x_max = lpv_fit.stroke_m(model)
    v_grid = np.linspace(*cfg.envelope.vcas_kt, 26) * atmosphere.KT_TO_M_S
    h_grid = np.linspace(*cfg.envelope.altitude_m, 25)
    distances = lpv_fit.neighbour_distances(bank, model, v_grid, h_grid, np.linspace(-x_max, x_max, 51), max_mach,
                                            runs.min_pressure)
    meta = io.provenance(config.to_json(cfg), cfg.seed, models=names)
    fit_info = {
        "method": "output error against the nonlinear actuator (Adam, exponentially decaying step), started from a "
                  "least-squares match of the small-error gains; mcfdd.analysis.lpv_fit",
        "command": f"mcfdd fit-lpv {args.config}",
        "config": config.to_dict(cfg),
        "version": meta["version"],
        "git_revision": meta["git_revision"],
        "exact_gain_models": [names[i] for i in np.flatnonzero(~free)],
        "errors_pct_of_amplitude": {
            name: {split: {"rms": 100.0 * float(s["rms"][i]), "max": 100.0 * float(s["max"][i]),
                           "runs": int(s["runs"][i]), "near_stall_runs": int(s["near_stall_runs"][i])}
                   for split, s in summary.items()}
            for i, name in enumerate(names)},
        "neighbour_distances": [{"models": [names[d.i], names[d.j]], "overall": d.overall, "separated": d.separated,
                                 "nonlinear_at_separated": d.nonlinear} for d in distances],
    }
    _say(f"wrote {io.save_bank(out / 'bank.json', lpv.to_dict(bank, names, {'fit': fit_info}))}")
    _say(f"wrote {io.write_table(errors, out / 'fit_errors.parquet', meta)}")

    problem, m = problems["validation"], commands["validation"]
    idx = np.asarray(lpv_fit.showcase_runs(problem, x_lpv["validation"], runs.min_pressure, len(m.kind)))
    labels = [f"{float(problem.vcas_m_s[b]) / atmosphere.KT_TO_M_S:.0f} kt, {float(problem.altitude_m[b]):.0f} m: "
              f"{manoeuvres.KINDS[int(m.kind[b % len(m.kind)])]} {float(m.amplitude[b % len(m.kind)]):+.2f}"
              for b in idx]

    def deg(x):
        return closed_loop.deflection_deg(np.asarray(x), r_arm)

    columns = {"u_c_deg": deg(problem.u_c_m[idx, :]),
               "amplitude_deg": np.repeat(deg(problem.amplitude_m[idx])[:, None], runs.n_steps, axis=1)}
    for i in range(len(names)):
        columns[f"x_nonlinear_deg_{i}"] = deg(problem.x_m[i, idx, :])
        columns[f"x_lpv_deg_{i}"] = deg(x_lpv["validation"][i, idx, :])
    history = io.history_frame(labels, np.arange(runs.n_steps) * runs.dt_s, columns)
    _say(f"wrote {_save_figure(plots.lpv_responses(history, names), out / 'responses.png')}")

    delta = 0.6 * model.actuator.max_deflection_rad
    h_shown = h_grid[[0, len(h_grid) // 2, -1]]
    k_lpv, k_nl = lpv_fit.gain_comparison(bank, model, v_grid, h_shown, np.array([delta * r_arm]), max_mach)
    gains = io.grid_frame(names, {"vcas_kt": v_grid / atmosphere.KT_TO_M_S, "altitude_m": h_shown,
                                  "delta_deg": [math.degrees(delta)], "direction": [-1.0, 1.0]},
                          {"k_lpv_1_s": k_lpv, "k_nonlinear_1_s": k_nl})
    _say(f"wrote {_save_figure(plots.lpv_gains(gains, names), out / 'gains.png')}")

    print(f"{'model':<18s} {'k0 1/s':>7s}  {'training RMS / max %':>21s}  {'validation RMS / max %':>23s}  "
          f"near-stall runs")
    for i, name in enumerate(names):
        tr, va = summary["training"], summary["validation"]
        print(f"{name:<18s} {float(bank.k0[i]):7.3f}  {100 * tr['rms'][i]:10.3f} / {100 * tr['max'][i]:7.3f}  "
              f"{100 * va['rms'][i]:12.3f} / {100 * va['max'][i]:7.3f}  {tr['near_stall_runs'][i]} / "
              f"{va['near_stall_runs'][i]}")
    print("smallest H-inf distance |k_j - k_i| / (k_i + k_j) of neighbouring models over the envelope grid")
    print("(overall; where the nonlinear models are at least 0.01 apart and keep the pressure margin):")
    for d in distances:
        print(f"  {names[d.i]:>18s} - {names[d.j]:<18s} {d.overall:.4f}   {d.separated:.4f} "
              f"(nonlinear there {d.nonlinear:.4f})")
    return 0


def _points_frame(space, points, scale: float, value: str, **labels):
    """One row per evaluated point: labels, scenario columns, hard and smooth bound (scaled)."""
    import pandas as pd

    table = space.table(points.categories, points.x)
    n = len(points.hard)
    return pd.DataFrame({**{k: np.broadcast_to(np.asarray(v), n) for k, v in labels.items()}, **table,
                         value: points.hard * scale, f"{value}_smooth": points.soft * scale,
                         "stall_events": points.outcomes["stall_events"], "status": points.outcomes["status"]})


def cmd_worst_case(args) -> int:
    cfg = config.load(config.WorstCaseConfig, args.config)
    sim, s = cfg.simulation, cfg.search
    _set_precision(sim.precision)
    import pandas as pd

    from mcfdd import plots, report
    from mcfdd.analysis import worst_case

    out = Path(args.out) if args.out else io.default_out_dir("worst-case", args.config)
    dtype = _dtype(sim.precision)
    model = build.plant_model(cfg.plant)
    r_arm = model.actuator.r_arm_m
    bank, names = _load_bank(cfg.fdd, dtype)
    space = build.search_space(cfg)
    problem = worst_case.Problem(model, build.fdd_params(cfg.fdd, bank, r_arm), build.settings(cfg.evaluation, r_arm),
                                 space, np.asarray(bank.nu), s.detector, s.bound, s.temperature, sim.n_steps, sim.dt_s,
                                 sim.substeps, dtype)
    scale, value = (180.0 / math.pi / r_arm, "bound_deg") if s.detector == "stall" else (1.0, "bound_ratio")
    budget = worst_case.budget(s.screening, s.starts, s.iterations)
    what = f"{'tau_f (26), largest' if s.bound == 'free' else 'tau_d (27), smallest'} {s.detector} bound"
    _say(f"worst-case search for {what}: {space.dim} continuous axes, {len(space.categorical)} categorical; "
         f"{sim.duration_s} s runs ({sim.n_steps} steps, {sim.precision}); budget {budget} simulations")
    times, frames = {}, []
    start = time.perf_counter()
    screened = worst_case.sample(problem, "sobol", s.screening, sim.seed, s.screening)
    times["screening"] = time.perf_counter() - start
    frames.append(_points_frame(space, screened, scale, value, method="screening", start=-1, iteration=-1,
                                index=np.arange(s.screening)))
    _say(f"  screening: {s.screening} Sobol points in {times['screening']:.1f} s (compilation included), worst "
         f"{worst_case.extreme(screened.hard * scale, s.bound)[1]:.5g}")
    idx, u0, cats, keys = worst_case.starts_from(screened, s.starts, s.bound, sim.seed)
    stamps = [time.perf_counter()]

    def progress(i, points):
        stamps.append(time.perf_counter())
        line = " ".join(f"{v:.4g}" for v in points.hard * scale)
        print(f"\r  gradient iteration {i}/{s.iterations}: {line}   ", end="\n" if i == s.iterations else "",
              file=sys.stderr, flush=True)

    iterations = worst_case.gradient_search(problem, u0, cats, keys, s.iterations, s.learning_rate, progress)
    times["gradient"] = stamps[-1] - stamps[0]
    steps = np.diff(stamps)
    run_time = float(np.mean(steps[1:]) * len(steps)) if len(steps) > 1 else times["gradient"]
    for i, points in enumerate(iterations):
        frames.append(_points_frame(space, points, scale, value, method="gradient", start=idx, iteration=i,
                                    index=np.arange(s.starts)))
    start = time.perf_counter()
    mc = worst_case.sample(problem, "random", budget, sim.seed + 1, s.screening)
    times["monte_carlo"] = time.perf_counter() - start
    frames.append(_points_frame(space, mc, scale, value, method="monte_carlo", start=-1, iteration=-1,
                                index=np.arange(budget)))
    n_time = int(min(max(budget, round(budget * run_time / max(times["monte_carlo"], 1e-9))), 50 * budget))
    if n_time > budget:
        start = time.perf_counter()
        extra = worst_case.sample(problem, "random", n_time, sim.seed + 1, s.screening, first=budget)
        times["monte_carlo_extra"] = time.perf_counter() - start
        frames.append(_points_frame(space, extra, scale, value, method="monte_carlo_extra", start=-1, iteration=-1,
                                    index=np.arange(budget, n_time)))
    _say(f"  gradient search {times['gradient']:.1f} s ({run_time:.1f} s without compilation), Monte Carlo "
         f"{budget} runs {times['monte_carlo']:.1f} s, {n_time} runs (equal run time) "
         f"{times['monte_carlo'] + times.get('monte_carlo_extra', 0.0):.1f} s")
    df = pd.concat(frames, ignore_index=True)
    meta = io.provenance(config.to_json(cfg), sim.seed, models=list(names))
    summ = report.search_summary(df, value, s.bound, times)
    parameters = [c for c in df.columns if c not in (value, f"{value}_smooth", "method", "start", "iteration", "index",
                                                     "status")]
    notes = [f"Worst case of the {what} over the scenario space of `{args.config}`: {s.screening} Sobol points "
             f"screened, the {s.starts} worst started projected Adam ascent ({s.iterations} steps, learning rate "
             f"{s.learning_rate} in the unit cube, smooth maximum over time at temperature {s.temperature} in log "
             f"units), against plain Monte Carlo (random design) with the same number of simulations ({budget}) and "
             f"with as many as run in the gradient search's time without compilation ({n_time}). A gradient "
             f"evaluation costs a forward and a backward pass. Run times include the compilation of the screening "
             f"and of the gradient function; Monte Carlo reuses the screening's compiled batch. "
             f"Values in {'deg (theta of the stall detector)' if s.detector == 'stall' else 'theta / ||u||'}."]
    io.write_table(df, out / "worst_case.parquet", meta)
    io.write_table(summ, out / "summary.parquet", meta)
    io.write_text(out / "report.md", report.worst_case_markdown(f"Worst case {Path(args.config).stem}", summ, df, value,
                                                                s.bound, parameters, notes, meta))
    label = f"{'tau_f' if s.bound == 'free' else 'tau_d'} candidates, {s.detector} detector ({value})"
    _save_figure(plots.search_history(df, value, f"{value}_smooth", label, s.bound), out / "history.png")
    for _, r in summ.iterrows():
        print(f"{r['method']}: {r['simulations']} simulations, {r['run_time_s']:.1f} s, worst {r[value]:.5g}")
    print(f"report: {out / 'report.md'}")
    return 0


def _training_set(cfg: config.CampaignConfig, model, bank, dtype):
    """Plant histories of a campaign's design, simulated once, with what their evaluation needs."""
    import jax.numpy as jnp

    from mcfdd.analysis import batch, campaign, scenarios, simulate, tuning

    c = cfg.campaign
    cols, n = build.design(cfg)
    kind = np.asarray(cols.get("fault_kind", np.full(n, "none")))
    nearest, accept = scenarios.true_model(np.asarray(bank.nu), kind, np.asarray(cols.get("fault_size", np.zeros(n))))
    scen = scenarios.to_scenario(cols, dtype)
    plant = simulate.plant_batch(model, scen, simulate.run_keys(c.seed, range(n)), c.n_steps, c.dt_s, c.substeps,
                                 batch.kinds_in(scen.manoeuvre.kind))
    truth = campaign.Truth(jnp.asarray(scenarios.fault_onsets(cols, n), dtype), jnp.asarray(accept))
    counts = jnp.asarray(np.isin(kind, scenarios.PARAMETRIC) & (nearest > 0))
    return tuning.TrainingSet(plant, scen.vcas_m_s, scen.altitude_m, truth, counts), n


def _tuned_fdd(fdd: config.FddConfig, detector: str, params: dict, tau: float, tune_pole: bool, deg_per_m: float):
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


def cmd_tune(args) -> int:
    cfg = config.load(config.TuneConfig, args.config)
    ts, tr = cfg.tune, cfg.training
    _set_precision(tr.precision)
    import jax
    import pandas as pd

    from mcfdd import plots, report
    from mcfdd.analysis import campaign, tuning

    out = Path(args.out) if args.out else io.unused_out_dir("tune", args.config)
    if out.exists() and any(out.iterdir()):
        raise config.ConfigError(f"--out: {out} exists and is not empty; choose another folder")
    det = ts.detector
    dtype = _dtype(tr.precision)
    model = build.plant_model(cfg.plant)
    r_arm = model.actuator.r_arm_m
    deg_per_m = 180.0 / math.pi / r_arm
    scale, units = (deg_per_m, "deg") if det == "stall" else (1.0, "theta/||u||")
    bank, names = _load_bank(cfg.fdd, dtype)
    fdd_params = build.fdd_params(cfg.fdd, bank, r_arm)
    settings = build.settings(cfg.evaluation, r_arm)
    start = time.perf_counter()
    data, n = _training_set(cfg.campaign("training"), model, bank, dtype)
    jax.block_until_ready(data)
    t_plant = time.perf_counter() - start
    _say(f"training set: {n} runs of {tr.duration_s} s simulated once in {t_plant:.1f} s; tuning the {det} detector "
         f"({'pole, ' if ts.tune_pole else ''}alpha, beta, gamma) over {ts.iterations} iterations")
    before = {k: float(v) for k, v in tuning.evaluate(fdd_params, settings, data, ts.temperature, tr.dt_s, det).items()}

    def gap_and_grad(theta):
        return tuning.gap_and_grad(theta, fdd_params, settings, data, ts.temperature, tr.dt_s, det, ts.tune_pole)

    def progress(i, gap, b):
        if i % 5 and i != ts.iterations:
            return
        print(f"\r  iteration {i}/{ts.iterations}: tau_f {b['tau_f'] * scale:.4g}, tau_d {b['tau_d'] * scale:.4g} "
              f"{units}, normalised gap {tuning.normalised_gap(b['tau_f'], b['tau_d']):.4g}   ",
              end="\n" if i == ts.iterations else "", file=sys.stderr, flush=True)

    start = time.perf_counter()
    result = tuning.tune(gap_and_grad, tuning.initial(fdd_params, det), ts.iterations, ts.learning_rate, progress)
    t_tune = time.perf_counter() - start
    best = tuning.best_iterate(result)
    chosen = tuning.natural(result.thetas[best])
    tau_f, tau_d = result.bounds[best]["tau_f"], result.bounds[best]["tau_d"]
    scan = None
    if not tau_d > tau_f:
        taus = tuning.candidates(tau_f, tau_d, ts.threshold_candidates)
        trial = build.fdd_params(_tuned_fdd(cfg.fdd, det, chosen, tau_f, ts.tune_pole, deg_per_m), bank, r_arm)
        start = time.perf_counter()
        false, missed = tuning.threshold_scan(trial, settings, data, np.asarray(taus, dtype), tr.dt_s, det,
                                              cfg.fdd.stall.identification)
        scan = pd.DataFrame({f"tau_{'deg' if det == 'stall' else 'ratio'}": taus * scale,
                             "training_false_alarms": np.asarray(false), "training_misses": np.asarray(missed)})
        _say(f"  negative gap: {len(taus)} thresholds compared on the training set in "
             f"{time.perf_counter() - start:.1f} s")
    tau = tuning.place_threshold(tau_f, tau_d, ts.margin, *(() if scan is None else (
        taus, scan["training_false_alarms"], scan["training_misses"])))
    tuned = _tuned_fdd(cfg.fdd, det, chosen, tau, ts.tune_pole, deg_per_m)
    history = pd.DataFrame([{"iteration": i, "smooth_log_gap": g, "tau_f": b["tau_f"] * scale,
                             "tau_d": b["tau_d"] * scale,
                             "normalised_gap": tuning.normalised_gap(b["tau_f"], b["tau_d"]), **tuning.natural(th)}
                            for i, (th, g, b) in enumerate(zip(result.thetas, result.gaps, result.bounds))])
    _say(f"  tuned in {t_tune:.1f} s; iteration {best}: tau_f {tau_f * scale:.4g}, tau_d {tau_d * scale:.4g} {units}, "
         f"tau {tau * scale:.4g}")
    old, new = getattr(cfg.fdd, det), getattr(tuned, det)
    tau_key = "tau_deg" if det == "stall" else "tau"
    parameters = pd.DataFrame([{"parameter": k, "before": b, "after": a} for k, b, a in (
        ("alpha", old.evaluator.alpha, new.evaluator.alpha), ("beta", old.evaluator.beta, new.evaluator.beta),
        ("gamma_1_s", old.evaluator.gamma_1_s, new.evaluator.gamma_1_s), ("pole_1_s", old.pole_1_s, new.pole_1_s),
        (tau_key, getattr(old, tau_key), getattr(new, tau_key)))])
    io.write_text(out / "tuned_fdd.toml", config.fdd_fragment(tuned, (
        f"FDD settings tuned by `mcfdd tune {args.config}` ({det} detector: evaluator"
        f"{', pole' if ts.tune_pole else ''} and threshold).\n"
        f"Use with `mcfdd campaign CONFIG --fdd {out / 'tuned_fdd.toml'}`.")))

    frames, stall_taus, compiles = {}, {}, []
    start = time.perf_counter()
    for label, fdd_cfg in (("before", cfg.fdd), ("after", tuned)):
        _say(f"held-out campaign, FDD {label} tuning")
        frames[label], _, _ = run_campaign(cfg.campaign("validation", fdd_cfg), out / "validation" / label)
        compiles.append(campaign.run_batch._cache_size())
        stall_taus[label] = fdd_cfg.stall.tau_deg
    t_val = time.perf_counter() - start
    validation = report.validation_table(frames, deg_per_m, stall_taus, cfg.evaluation.stall_window_s,
                                         cfg.fdd.stall.identification)
    meta = io.provenance(config.to_json(cfg), tr.seed, models=list(names), validation_seed=str(cfg.validation.seed))
    io.write_table(history, out / "history.parquet", meta)
    io.write_table(parameters, out / "parameters.parquet", meta)
    io.write_table(validation, out / "validation.parquet", meta)
    if scan is not None:
        io.write_table(scan, out / "threshold_scan.parquet", meta)
    notes = [f"Tuning of the {det} detector by gradient through the FDD over {n} stored plant histories of "
             f"{tr.duration_s} s (training seed {tr.seed}; plant simulated once in {t_plant:.1f} s). Objective: smooth "
             f"log tau_d - log tau_f (temperature {ts.temperature}), Adam, {ts.iterations} iterations at learning "
             f"rate {ts.learning_rate} on the parameters' logarithms, {t_tune:.1f} s. The iteration with the largest "
             f"hard normalised gap on the training set is kept; tau = tau_f + {ts.margin} (tau_d - tau_f) inside a "
             f"positive gap; otherwise {ts.threshold_candidates} thresholds are compared on the training set by "
             f"false alarms, then missed detections (campaign definitions, {cfg.fdd.stall.identification} "
             f"identification for stall loads), and the middle of the best is kept. Chosen: tau = "
             f"{tau * scale:.5g} {units}.",
             "", f"Held-out campaign: {cfg.validation.scenarios} scenarios per design cell, seed "
             f"{cfg.validation.seed}, {cfg.validation.duration_s} s, run with the FDD before and after tuning "
             f"({t_val:.1f} s); the FDD numbers "
             f"are traced, so both runs share one compilation (compiled batch functions after each run: "
             f"{compiles[0]}, {compiles[1]}). Bounds as in the campaign report (eqs. 26-27)."]
    io.write_text(out / "report.md", report.tuning_markdown(f"Tuning {Path(args.config).stem}", det, history, best,
                                                            {k: before[k] * scale for k in ("tau_f", "tau_d")},
                                                            parameters, validation, notes, meta, scan))
    _save_figure(plots.tuning_history(history, units), out / "history.png")
    for _, r in validation.iterrows():
        print(f"{r['fdd']}: FAR {r['false_alarms']}/{r['runs']}, LOE FAR {r['loe_false_alarms']}/{r['runs']}, MDR "
              f"{r['missed']}/{r['faulty_runs']}, detection time median {r['detection_time_median_s']:.3g} s, stall "
              f"detector above tau outside stalls in {r['stall_detector_fires']} runs")
    print(f"tuned FDD: {out / 'tuned_fdd.toml'}\nreport: {out / 'report.md'}")
    return 0


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def cmd_figures(args) -> int:
    from mcfdd import plots
    from mcfdd.analysis import metrics

    folder = Path(args.configs)
    out = Path(args.out) if args.out else Path("results") / "figures"
    fig3_cfg = config.load(config.SimulateConfig, folder / "fig3.toml")
    fig4_cfg = config.load(config.SweepConfig, folder / "fig4.toml")
    fig5_cfg = config.load(config.SimulateConfig, folder / "fig5.toml")
    precisions = {c.simulation.precision for c in (fig3_cfg, fig4_cfg, fig5_cfg)}
    _set_precision("float64" if "float64" in precisions else "float32")

    df3, _ = histories(fig3_cfg.simulation, fig3_cfg.plant, fig3_cfg.fdd, _runs_table(fig3_cfg.runs),
                       [r.name for r in fig3_cfg.runs])
    free = next(r for r in fig3_cfg.runs if r.fault.kind == "none")
    faulty = next(r for r in fig3_cfg.runs if r.fault.kind != "none")
    _say(f"wrote {_save_figure(plots.fig3(df3, free.name, faulty.name, faulty.fault.onset_s), out / 'fig3.png')}")

    table, run_names, family, size = build.sweep_table(fig4_cfg)
    df4, names = histories(fig4_cfg.simulation, fig4_cfg.plant, fig4_cfg.fdd, table, run_names)
    n_steps = fig4_cfg.simulation.n_steps
    detected = df4["detected_model"].to_numpy().reshape(len(run_names), n_steps)
    t = df4["t_s"].to_numpy()[:n_steps]
    onset = fig4_cfg.run.fault.onset_s
    hist = metrics.decision_history(detected, t, np.full(len(run_names), onset))
    import pandas as pd

    sweep = pd.DataFrame({"family": family, "fault_size": size, "detected_model": hist["prevailing_model"],
                          "detected_model_name": [names[m] if m >= 0 else "no decision" for m in
                                                  hist["prevailing_model"]],
                          "first_fault_model": hist["first_model"], "detection_time_s": hist["detection_time_s"] - onset,
                          "switches": hist["switches"]})
    meta = io.provenance(config.to_json(fig4_cfg), fig4_cfg.simulation.seed, models=list(names))
    _say(f"wrote {io.write_table(sweep, out / 'fig4.parquet', meta)}")
    bank, _ = _load_bank(fig4_cfg.fdd, np.float32)
    nu = np.asarray(bank.nu)
    grid = {"surface": sorted(1.0 - nu[np.isclose(nu[:, 0], 1.0), 1]),
            "leakage": sorted(1.0 - nu[np.isclose(nu[:, 1], 1.0), 0])}
    _say(f"wrote {_save_figure(plots.fig4(sweep, names, grid), out / 'fig4.png')}")
    for fam in ("surface", "leakage"):
        for v in grid[fam]:
            row = sweep[(sweep["family"] == fam)].iloc[(sweep.loc[sweep["family"] == fam, "fault_size"] - v).abs().argmin()]
            print(f"fig4 {fam} {100 * row['fault_size']:.0f} %: decided {row['detected_model_name']}, first fault model "
                  f"after {row['detection_time_s']:.2f} s, {row['switches']} switch(es)")

    df5, _ = histories(fig5_cfg.simulation, fig5_cfg.plant, fig5_cfg.fdd, _runs_table(fig5_cfg.runs),
                       [r.name for r in fig5_cfg.runs])
    run5 = df5[df5["run"] == fig5_cfg.runs[0].name]
    _say(f"wrote {_save_figure(plots.fig5(run5), out / 'fig5.png')}")
    max_deg = fig5_cfg.plant.actuator.max_deflection_deg
    _say(f"wrote {_save_figure(plots.fig6(run5, max_deg), out / 'fig6.png')}")
    _report_stall_latencies(run5, fig5_cfg.simulation.dt_s)
    return 0


def _report_stall_latencies(run, dt_s: float):
    """Print each stall event of a run with the latency of both identification methods."""
    stall = run["stall"].to_numpy(dtype=bool)
    t = run["t_s"].to_numpy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stall.astype(int), [0]])))
    outside = ~stall
    for start, end in zip(edges[::2], edges[1::2]):
        parts = []
        for method in ("signal", "model"):
            eta = run[f"eta_{method}"].to_numpy(dtype=bool)[start:end]
            parts.append(f"{method} {t[start + eta.argmax()] - t[start]:.2f} s" if eta.any() else f"{method} none")
        print(f"stall event {t[start]:.2f}-{t[end - 1] + dt_s:.2f} s: eta latency " + ", ".join(parts))
    for method in ("signal", "model"):
        false = run[f"eta_{method}"].to_numpy(dtype=bool) & outside
        print(f"eta ({method}) outside stall events: {false.sum() * dt_s:.2f} s")


def _command(sub, name: str, func, summary: str, example: str | None, out: str):
    """A subcommand taking a TOML config (unless ``example`` is None) and ``--out``."""
    p = sub.add_parser(name, help=summary)
    if example is not None:
        p.add_argument("config", help=f"TOML config, e.g. configs/{example}")
    p.add_argument("--out", help=f"output folder (default {out})")
    p.set_defaults(func=func)
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mcfdd", description="Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis "
        "(Ossmann and Varga, 2015): simulate, fit LPV models, run campaigns, tune, search worst cases.")
    sub = parser.add_subparsers(dest="command", required=True)
    _command(sub, "simulate", cmd_simulate, "simulate the named runs of a config, write time histories and plots",
             "fig5.toml", "results/simulate-<config>")
    p = _command(sub, "campaign", cmd_campaign, "Monte-Carlo campaign over a scenario space: FAR, MDR, detection "
                 "times", "loe_campaign.toml", "a new results/campaign-<config>[-N]")
    p.add_argument("--scenarios", type=int, help="override campaign.scenarios")
    p.add_argument("--seed", type=int, help="override campaign.seed")
    p.add_argument("--chunk-size", type=int, help="override campaign.chunk_size (results do not depend on it)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    p.add_argument("--fdd", help="FDD fragment replacing the config's [fdd] table, e.g. a tune's tuned_fdd.toml")
    _command(sub, "fit-lpv", cmd_fit_lpv, "fit the LPV gain models of the fault models to the nonlinear actuator",
             "lpv_aileron.toml", "results/fit-lpv-<config>")
    p = _command(sub, "figures", cmd_figures, "the paper's Figs. 3-6 from configs fig3/fig4/fig5.toml", None,
                 "results/figures")
    p.add_argument("--configs", default="configs", help="folder holding fig3.toml, fig4.toml, fig5.toml")
    _command(sub, "worst-case", cmd_worst_case, "tau_f or tau_d of a detector by gradient search, against Monte "
             "Carlo", "worst_case_stall.toml", "results/worst-case-<config>")
    _command(sub, "tune", cmd_tune, "tune a detector's evaluator and threshold by gradient; check on a held-out "
             "campaign", "tune_stall.toml", "the first free results/tune-<config>[-N]")
    return parser


def use_all_cores():
    """Expose every CPU core as a JAX device before JAX starts, so batches split over them."""
    flag = "--xla_force_host_platform_device_count"
    flags = os.environ.get("XLA_FLAGS", "")
    if flag not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {flag}={os.cpu_count() or 1}".strip()


def main(argv=None) -> int:
    use_all_cores()
    import jax

    parser = build_parser()
    args = parser.parse_args(argv)
    x64 = jax.config.jax_enable_x64
    try:
        return args.func(args)
    except config.ConfigError as err:
        print(f"mcfdd: configuration error: {err}", file=sys.stderr)
        return 2
    finally:
        jax.config.update("jax_enable_x64", x64)


if __name__ == "__main__":
    sys.exit(main())

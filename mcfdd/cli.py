"""The ``mcfdd`` command (the edge of the package): configs in, tables and figures out."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from mcfdd import config, io


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
    model = plant_cfg.model()
    bank, names = _load_bank(fdd_cfg, dtype)
    fdd_params = fdd_cfg.params(bank, model.actuator.r_arm_m)
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
    rows = [run.columns() for run in runs]
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
    import dataclasses

    cfg = config.load(config.CampaignConfig, args.config)
    overrides = {}
    for flag, key in (("scenarios", "scenarios"), ("seed", "seed"), ("chunk_size", "chunk_size")):
        value = getattr(args, flag)
        if value is not None:
            if value < (0 if key == "seed" else 1):
                raise config.ConfigError(f"--{flag.replace('_', '-')}: {value} is not allowed; expected "
                                         f"{'a non-negative' if key == 'seed' else 'a positive'} integer")
            overrides[key] = value
    return dataclasses.replace(cfg, campaign=dataclasses.replace(cfg.campaign, **overrides))


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


def run_campaign(cfg: config.CampaignConfig, out: Path, resume: bool = False, on_chunk=None):
    """Simulate every scenario of the campaign not yet written under ``out/scenarios``; returns the table."""
    import jax
    import pandas as pd

    from mcfdd.analysis import batch, campaign, metrics, scenarios, simulate

    c = cfg.campaign
    dtype = _dtype(c.precision)
    model = cfg.plant.model()
    bank, names = _load_bank(cfg.fdd, dtype)
    fdd_params = cfg.fdd.params(bank, model.actuator.r_arm_m)
    settings = cfg.evaluation.settings(model.actuator.r_arm_m)
    cols, n = cfg.design()
    onset = scenarios.fault_onsets(cols, n)
    kind = np.asarray(cols.get("fault_kind", np.full(n, "none")))
    nearest, accept = scenarios.true_model(np.asarray(bank.nu), kind,
                                           np.asarray(cols.get("fault_size", np.zeros(n))))
    all_scenarios = scenarios.to_scenario(cols, dtype)
    kinds = batch.kinds_in(all_scenarios.manoeuvre.kind)
    parts = out / "scenarios"
    done = np.zeros(n, dtype=bool)
    if resume and parts.is_dir():
        for part in parts.glob("part-*.parquet"):
            done[pd.read_parquet(part, columns=["scenario_id"])["scenario_id"].to_numpy()] = True
    todo = np.flatnonzero(~done)
    meta = io.provenance(config.to_json(cfg), c.seed, models=list(names))
    block = LANE_BLOCK * jax.device_count()
    size = -(-min(c.chunk_size, max(n, 1)) // block) * block
    chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
    _say(f"campaign: {n} scenarios of {c.duration_s} s ({c.n_steps} steps, {c.precision}), "
         f"{len(todo)} to run in {len(chunks)} chunk(s) of {size}")
    progress = Progress(len(todo), len(chunks))
    for ids in chunks:
        padded = np.concatenate([ids, np.repeat(ids[-1:], size - len(ids))])
        scen = jax.tree.map(lambda a: a[padded], all_scenarios)
        truth = campaign.Truth(onset[padded].astype(dtype), accept[padded])
        raw = campaign.run_batch(model, fdd_params, settings, scen, truth, simulate.run_keys(c.seed, padded),
                                 c.n_steps, c.dt_s, c.substeps, kinds)
        raw = {k: np.asarray(v)[:len(ids)] for k, v in raw.items()}
        outc = metrics.outcomes(raw, onset[ids], accept[ids], nearest[ids], c.duration_s, cfg.evaluation.t_detec_s)
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
    model = cfg.plant.model()
    runs, opt, max_mach = cfg.runs, cfg.optimiser, cfg.plant.aircraft.max_mach
    nus, names = cfg.nus(), [m.name for m in cfg.models]
    r_arm = model.actuator.r_arm_m
    points = {"training": cfg.envelope.training_points(max_mach),
              "validation": cfg.envelope.validation_flight_points(max_mach, cfg.seed)}
    commands, problems = {}, {}
    start = time.perf_counter()
    for split, (v, h) in points.items():
        commands[split] = cfg.manoeuvre_params(split, dtype)
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

    table, run_names, family, size = fig4_cfg.table()
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mcfdd", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="simulate the named runs of a config, write time histories and plots")
    p.add_argument("config", help="TOML config, e.g. configs/fig5.toml")
    p.add_argument("--out", help="output folder (default results/simulate-<config>)")
    p.set_defaults(func=cmd_simulate)
    p = sub.add_parser("campaign", help="Monte-Carlo campaign over a scenario space: FAR, MDR, detection times")
    p.add_argument("config", help="TOML config, e.g. configs/loe_campaign.toml")
    p.add_argument("--out", help="output folder (default: a new results/campaign-<config>[-N])")
    p.add_argument("--scenarios", type=int, help="override campaign.scenarios")
    p.add_argument("--seed", type=int, help="override campaign.seed")
    p.add_argument("--chunk-size", type=int, help="override campaign.chunk_size (results do not depend on it)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    p.set_defaults(func=cmd_campaign)
    p = sub.add_parser("fit-lpv", help="fit the LPV gain models of the fault models to the nonlinear actuator")
    p.add_argument("config", help="TOML config, e.g. configs/lpv_aileron.toml")
    p.add_argument("--out", help="output folder (default results/fit-lpv-<config>)")
    p.set_defaults(func=cmd_fit_lpv)
    p = sub.add_parser("figures", help="the paper's Figs. 3-6 from configs fig3/fig4/fig5.toml")
    p.add_argument("--configs", default="configs", help="folder holding fig3.toml, fig4.toml, fig5.toml")
    p.add_argument("--out", help="output folder (default results/figures)")
    p.set_defaults(func=cmd_figures)
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

"""The ``mcfdd`` command (the edge of the package): configs in, tables and figures out."""

from __future__ import annotations

import argparse
import math
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


def simulate_histories(cfg: config.SimulateConfig):
    """Run the config's runs with plant and FDD in one batch. Returns (tidy DataFrame, model names)."""
    import jax

    from mcfdd.analysis import batch, simulate
    from mcfdd.analysis.scenarios import to_scenario
    from mcfdd.plant import closed_loop

    sim = cfg.simulation
    dtype = _dtype(sim.precision)
    model = cfg.plant.model()
    bank, names = _load_bank(cfg.fdd, dtype)
    fdd_params = cfg.fdd.params(bank, model.actuator.r_arm_m)
    rows = [run.columns() for run in cfg.runs]
    table = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    scenarios = to_scenario(table, dtype)
    kinds = batch.kinds_in(scenarios.manoeuvre.kind)
    keys = simulate.run_keys(sim.seed, range(len(cfg.runs)))
    _say(f"simulating {len(cfg.runs)} run(s) of {sim.duration_s} s ({sim.n_steps} steps, {sim.precision})")
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
    eta = fdd.eta_signal if cfg.fdd.stall.identification == "signal" else fdd.eta_model
    columns.update({
        "theta_u": fdd.theta_u, "detected_model": fdd.detected, "r_stall": fdd.r_stall,
        "theta_stall": fdd.theta_stall, "iota_stall": fdd.iota_stall, "eta_stall": eta,
        "eta_signal": fdd.eta_signal, "eta_model": fdd.eta_model, "theta_sl": fdd.theta_sl,
    })
    t = np.arange(sim.n_steps) * sim.dt_s
    df = io.history_frame([run.name for run in cfg.runs], t, {k: np.asarray(v) for k, v in columns.items()})
    return df, names


def cmd_simulate(args) -> int:
    cfg = config.load(config.SimulateConfig, args.config)
    _set_precision(cfg.simulation.precision)
    from mcfdd import plots

    out = Path(args.out) if args.out else io.default_out_dir("simulate", args.config)
    df, names = simulate_histories(cfg)
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
    size = min(c.chunk_size, max(n, 1))
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

    out = Path(args.out) if args.out else io.default_out_dir("campaign", args.config)
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


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mcfdd", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="simulate the named runs of a config, write time histories and plots")
    p.add_argument("config", help="TOML config, e.g. configs/fig5.toml")
    p.add_argument("--out", help="output folder (default results/simulate-<config>)")
    p.set_defaults(func=cmd_simulate)
    p = sub.add_parser("campaign", help="Monte-Carlo campaign over a scenario space: FAR, MDR, detection times")
    p.add_argument("config", help="TOML config, e.g. configs/loe_campaign.toml")
    p.add_argument("--out", help="output folder (default results/campaign-<config>)")
    p.add_argument("--scenarios", type=int, help="override campaign.scenarios")
    p.add_argument("--seed", type=int, help="override campaign.seed")
    p.add_argument("--chunk-size", type=int, help="override campaign.chunk_size (results do not depend on it)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    p.set_defaults(func=cmd_campaign)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except config.ConfigError as err:
        print(f"mcfdd: configuration error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

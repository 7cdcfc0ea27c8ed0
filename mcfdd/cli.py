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


def cmd_simulate(args) -> int:
    cfg = config.load(config.SimulateConfig, args.config)
    _set_precision(cfg.simulation.precision)
    import jax

    from mcfdd import plots
    from mcfdd.analysis import batch, simulate
    from mcfdd.plant import closed_loop

    out = Path(args.out) if args.out else io.default_out_dir("simulate", args.config)
    sim = cfg.simulation
    model = cfg.plant.model()
    scenarios = batch.stack([run.scenario() for run in cfg.runs], _dtype(sim.precision))
    kinds = batch.kinds_in(scenarios.manoeuvre.kind)
    keys = simulate.run_keys(sim.seed, range(len(cfg.runs)))
    _say(f"simulating {len(cfg.runs)} run(s) of {sim.duration_s} s ({sim.n_steps} steps, {sim.precision})")
    start = time.perf_counter()
    hist = jax.block_until_ready(
        simulate.plant_batch(model, scenarios, keys, sim.n_steps, sim.dt_s, sim.substeps, kinds))
    _say(f"  done in {time.perf_counter() - start:.1f} s (compilation included)")
    r_arm = model.actuator.r_arm_m
    to_deg = 180.0 / math.pi
    columns = {
        "u_c_m": hist.u_c_m, "u_m": hist.u_m, "x_m": hist.x_m,
        "u_c_deg": closed_loop.deflection_deg(hist.u_c_m, r_arm), "u_deg": closed_loop.deflection_deg(hist.u_m, r_arm),
        "delta_deg": closed_loop.deflection_deg(hist.x_m, r_arm), "dp_avail_norm": hist.dp_avail_norm,
        "stall": hist.stall, "p_deg_s": hist.p_rad_s * to_deg, "phi_deg": hist.phi_rad * to_deg,
        "stick": hist.stick, "nu1": hist.nu1, "nu2": hist.nu2,
    }
    names = [run.name for run in cfg.runs]
    t = np.arange(sim.n_steps) * sim.dt_s
    df = io.history_frame(names, t, {k: np.asarray(v) for k, v in columns.items()})
    table = io.write_table(df, out / "timeseries.parquet", io.provenance(config.to_json(cfg), sim.seed))
    _say(f"wrote {table}")
    for name, group in df.groupby("run", sort=False):
        fig = plots.run_timeseries(group, f"{name}")
        _say(f"wrote {_save_figure(fig, out / f'{_slug(name)}.png')}")
        stalled = int(group['stall'].sum())
        print(f"{name}: max |delta| {group['delta_deg'].abs().max():.2f} deg, "
              f"stall {stalled * sim.dt_s:.2f} s, min available pressure {group['dp_avail_norm'].min():.3f} dP")
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

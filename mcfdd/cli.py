"""The ``mcfdd`` command (the edge of the package): arguments -> the public API -> printed results."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import tomllib
import warnings
from pathlib import Path

import mcfdd
from mcfdd import config, io, report


def _say(message: str):
    print(message, file=sys.stderr, flush=True)


def _written(paths):
    for path in paths:
        _say(f"wrote {path}")


def _num(value, spec: str = ".3g", unit: str = "") -> str:
    """``value`` formatted, or n/a where it does not exist (nan, None)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return report.NA
    return f"{value:{spec}}{unit}"


def _rate(r: dict, key: str) -> str:
    """'rate [lo, hi]' of a summary row, or n/a when no run counts."""
    if math.isnan(r[key]):
        return report.NA
    return f"{r[key]:.4g} [{r[f'{key}_lo']:.3g}, {r[f'{key}_hi']:.3g}]"


def _decisions(first: dict) -> str:
    """First decision time of each fault model, e.g. 'pressure-loss-27 at 21.74 s'."""
    return ", ".join(f"{model} at {t:.2f} s" for model, t in first.items()) or "none"


def cmd_simulate(args) -> int:
    result = mcfdd.simulate(mcfdd.load_config(args.config, "simulate"))
    _written(result.save(Path(args.out) if args.out else io.default_out_dir("simulate", args.config)))
    for _, r in result.summary().iterrows():
        print(f"{r['run']}: max |delta| {r['max_abs_delta_deg']:.2f} deg, stall {r['stall_s']:.2f} s, "
              f"eta_stall {r['eta_stall_s']:.2f} s, first decisions {_decisions(r['first_decisions_s'])}")
    return 0


def _settings(pairs) -> dict:
    """``--set KEY=VALUE`` flags as dotted-path overrides; VALUE is read as TOML (a bare word as a string)."""
    overrides = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise config.ConfigError(f"--set: {pair!r} is not KEY=VALUE, e.g. fdd.loe.tau=0.12")
        try:
            overrides[key.strip()] = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            overrides[key.strip()] = text
    return overrides


CAMPAIGN_FLAGS = ("scenarios", "seed", "chunk_size")  # flags that set the campaign.* key of their name


def _campaign_flags(args) -> dict:
    """Overrides of the campaign flags given, each checked against the range of its key."""
    overrides = {}
    for key in CAMPAIGN_FLAGS:
        value = getattr(args, key, None)
        if value is not None:
            try:
                overrides[f"campaign.{key}"] = config.field_value(config.CampaignSettings, key, value)
            except config.Invalid as err:
                raise config.ConfigError(f"--{key.replace('_', '-')}: {err.message} (campaign.{key})") from None
    return overrides


def _campaign_config(args) -> config.CampaignConfig:
    """The campaign config with the flags' overrides and ``--fdd`` fragment; bad flags are named."""
    overrides = _settings(getattr(args, "set", None))
    overrides.update(_campaign_flags(args))
    if getattr(args, "fdd", None):
        overrides["fdd"] = config.to_dict(config.load_fdd_fragment(args.fdd))
    return mcfdd.load_config(args.config, "campaign", overrides)


def _check_cluster_flags(args):
    """The TLS files are for a ``--scheduler``: given without one, they are refused before any work."""
    if args.scheduler is None:
        for key in ("tls_ca_file", "tls_cert", "tls_key"):
            if getattr(args, key) is not None:
                raise config.ConfigError(f"--{key.replace('_', '-')}: only used with --scheduler (a tls:// "
                                         f"scheduler); give --scheduler ADDR or leave it out")


@contextlib.contextmanager
def _campaign_executor(args):
    """None (chunks in this process), or a Dask client for ``--scheduler`` / ``--workers``, closed on exit."""
    if args.scheduler is None and args.workers is None:
        yield None
        return
    if args.connect_timeout <= 0:
        raise config.ConfigError(f"--connect-timeout: {args.connect_timeout} is not allowed; expected seconds > 0")
    try:
        security = mcfdd.dask_security(args.tls_ca_file, args.tls_cert, args.tls_key)
    except ImportError:
        raise config.ConfigError("--scheduler/--workers need Dask: pip install 'mcfdd[distributed]'") from None
    with mcfdd.dask_cluster(args.scheduler, args.workers, security, args.connect_timeout) as client:
        yield client


def _workers_line(workers) -> str:
    """The per-worker throughput of a campaign as one line."""
    return f"workers: {len(workers)}; " + ", ".join(
        f"{w['worker']} {w['scenarios']} scen in {w['chunks']} chunk(s), {w['scenario_steps_per_s']:.3g} "
        f"scenario-steps/s" for _, w in workers.iterrows())


def cmd_campaign(args) -> int:
    _check_cluster_flags(args)
    cfg = _campaign_config(args)
    if args.out:
        out = Path(args.out)
    elif args.resume:
        out = io.default_out_dir("campaign", args.config)
    else:
        out = io.unused_out_dir("campaign", args.config)
    try:
        with _campaign_executor(args) as executor:
            result = mcfdd.run_campaign(cfg, out=out, resume=args.resume, title=f"Campaign {Path(args.config).stem}",
                                        executor=executor, compile_cache=args.compile_cache)
    except KeyboardInterrupt:
        _say(f"\ninterrupted: finished chunks are kept in {out / 'scenarios'}; continue with --resume")
        return 130
    overall = result.overall()
    stalls = f", stall events {overall['stall_events']}" if overall["stall_events"] else ""
    print(f"{overall['runs']} scenarios: FAR {_rate(overall, 'far')}, MDR {_rate(overall, 'mdr')}{stalls}")
    if executor is not None and len(result.workers):  # in process, the one row is this process
        print(_workers_line(result.workers))
    print(f"summary: {out / 'summary.md'}")
    return 0


def cmd_fit_lpv(args) -> int:
    result = mcfdd.fit_lpv(args.config)
    _written(result.save(Path(args.out) if args.out else io.default_out_dir("fit-lpv", args.config)))
    print(f"{'model':<18s} {'k0 1/s':>7s}  {'training RMS / max %':>21s}  {'validation RMS / max %':>23s}  "
          f"near-stall runs")
    tr, va = result.error_summary["training"], result.error_summary["validation"]
    for i, name in enumerate(result.models):
        print(f"{name:<18s} {float(result.bank.k0[i]):7.3f}  {100 * tr['rms'][i]:10.3f} / {100 * tr['max'][i]:7.3f}  "
              f"{100 * va['rms'][i]:12.3f} / {100 * va['max'][i]:7.3f}  {tr['near_stall_runs'][i]} / "
              f"{va['near_stall_runs'][i]}")
    print("smallest H-inf distance |k_j - k_i| / (k_i + k_j) of neighbouring models over the envelope grid")
    print("(overall; where the nonlinear models are at least 0.01 apart and keep the pressure margin):")
    for d in result.distances:
        print(f"  {result.models[d.i]:>18s} - {result.models[d.j]:<18s} {d.overall:.4f}   {d.separated:.4f} "
              f"(nonlinear there {d.nonlinear:.4f})")
    return 0


def cmd_worst_case(args) -> int:
    result = mcfdd.worst_case(args.config)
    out = Path(args.out) if args.out else io.default_out_dir("worst-case", args.config)
    result.save(out, f"Worst case {Path(args.config).stem}")
    for _, r in result.summary.iterrows():
        print(f"{r['method']}: {r['simulations']} simulations, {r['run_time_s']:.1f} s, worst "
              f"{_num(r[result.value], '.5g')}")
    print(f"report: {out / 'report.md'}")
    return 0


def cmd_tune(args) -> int:
    out = Path(args.out) if args.out else io.unused_out_dir("tune", args.config)
    if out.exists() and any(out.iterdir()):
        raise mcfdd.OutputFolderError(f"--out: {out} exists and is not empty; choose another folder")
    result = mcfdd.tune(args.config)
    result.save(out)
    for _, r in result.validation.iterrows():
        print(f"{r['fdd']}: FAR {r['false_alarms']}/{r['runs']}, LOE FAR {r['loe_false_alarms']}/{r['runs']}, MDR "
              f"{r['missed']}/{r['faulty_runs']}, detection time median "
              f"{_num(r['detection_time_median_s'], unit=' s')}, stall "
              f"detector above tau outside stalls in {r['stall_detector_fires']} runs")
    print(f"tuned FDD: {out / 'tuned_fdd.toml'}\nreport: {out / 'report.md'}")
    return 0


def cmd_figures(args) -> int:
    result = mcfdd.paper_figures(args.configs)
    _written(result.save(Path(args.out) if args.out else Path("results") / "figures"))
    sweep = result.sweep
    for fam in ("surface", "leakage"):
        rows = sweep[sweep["family"] == fam]
        for v in result.grid[fam]:
            row = rows.iloc[(rows["fault_size"] - v).abs().argmin()]
            print(f"fig4 {fam} {100 * row['fault_size']:.0f} %: decided {row['detected_model_name']}, "
                  f"first fault model after {_num(row['detection_time_s'], '.2f', ' s')}, {row['switches']} switch(es)")
    for _, e in result.stall_events.iterrows():
        parts = [f"{m} none" if math.isnan(e[f"latency_{m}_s"]) else f"{m} {e[f'latency_{m}_s']:.2f} s"
                 for m in ("signal", "model")]
        print(f"stall event {e['onset_s']:.2f}-{e['end_s']:.2f} s: eta latency " + ", ".join(parts))
    for method, seconds in result.eta_outside_s.items():
        print(f"eta ({method}) outside stall events: {seconds:.2f} s")
    return 0


def cmd_schema(args) -> int:
    print(json.dumps(config.json_schema(args.kind), indent=1))
    return 0


def _command(sub, name: str, func, summary: str, example: str | None, out: str):
    """A subcommand taking a TOML config (unless ``example`` is None) and ``--out``."""
    p = sub.add_parser(name, help=summary)
    if example is not None:
        p.add_argument("config", help=f"TOML config, e.g. configs/{example}")
    p.add_argument("--out", help=f"output folder (default {out})")
    p.set_defaults(func=func)
    return p


def _cluster_flags(p):
    """Where a campaign's chunks run (Dask distributed) and where compiled programs are kept."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDR", help="run the chunks on the Dask cluster of this scheduler, "
                       "e.g. tls://HOST:8786 (tcp:// only inside a trusted network)")
    where.add_argument("--workers", type=int, metavar="N", help="run the chunks on a local Dask cluster of N worker "
                       "processes (127.0.0.1 only), closed at the end")
    p.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                   help="seconds to reach --scheduler and then to wait for a worker (default 10)")
    for flag, what in (("--tls-ca-file", "CA certificate"), ("--tls-cert", "client certificate"),
                       ("--tls-key", "client certificate's key")):
        p.add_argument(flag, metavar="FILE", help=f"TLS {what} for a tls:// scheduler (default: Dask's configuration)")
    p.add_argument("--compile-cache", metavar="DIR|off", help="folder of JAX's persistent compilation cache, here "
                   "and on the workers (default ~/.cache/mcfdd/jax); 'off' to compile every time")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mcfdd", description="Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis "
        "(Ossmann and Varga, 2015): simulate, fit LPV models, run campaigns, tune, search worst cases.")
    sub = parser.add_subparsers(dest="command", required=True)
    _command(sub, "simulate", cmd_simulate, "simulate the named runs of a config, write time histories and plots",
             "fig5.toml", "results/simulate-<config>")
    p = _command(sub, "campaign", cmd_campaign, "Monte-Carlo campaign over a scenario space: FAR, MDR, detection "
                 "times", "loe_campaign.toml", "a new results/campaign-<config>[-N]")
    p.add_argument("--scenarios", type=int, help="total number of scenarios, split evenly over the grid cells "
                   "(overrides campaign.scenarios; a multiple of the number of cells)")
    p.add_argument("--seed", type=int, help="override campaign.seed")
    p.add_argument("--chunk-size", type=int, help="override campaign.chunk_size (results do not depend on it)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    p.add_argument("--fdd", help="FDD fragment replacing the config's [fdd] table, e.g. a tune's tuned_fdd.toml")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config key by its dotted path, e.g. --set fdd.loe.tau=0.12 (repeatable)")
    _cluster_flags(p)
    _command(sub, "fit-lpv", cmd_fit_lpv, "fit the LPV gain models of the fault models to the nonlinear actuator",
             "lpv_aileron.toml", "results/fit-lpv-<config>")
    p = _command(sub, "figures", cmd_figures, "the paper's Figs. 3-6 from configs fig3/fig4/fig5.toml", None,
                 "results/figures")
    p.add_argument("--configs", default="configs", help="folder holding fig3.toml, fig4.toml, fig5.toml")
    _command(sub, "worst-case", cmd_worst_case, "tau_f or tau_d of a detector by gradient search, against Monte "
             "Carlo", "worst_case_stall.toml", "results/worst-case-<config>")
    _command(sub, "tune", cmd_tune, "tune a detector's evaluator and threshold by gradient; check on a held-out "
             "campaign", "tune_stall.toml", "the first free results/tune-<config>[-N]")
    p = sub.add_parser("schema", help="print the JSON Schema of a config kind (for editors and validators)")
    p.add_argument("kind", choices=list(config.KINDS), help="the config kind")
    p.set_defaults(func=cmd_schema)
    return parser


def _check_out_flag(args):
    """``--out`` must name a folder (or nothing yet): refused before any work."""
    out = getattr(args, "out", None)
    if out and Path(out).exists() and not Path(out).is_dir():
        raise config.ConfigError(f"--out: {out} exists and is not a folder; choose a folder")


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"mcfdd: warning: {message}\n"


def main(argv=None) -> int:
    warnings.formatwarning = _one_line_warning
    args = build_parser().parse_args(argv)
    try:
        _check_out_flag(args)
        return args.func(args)
    except config.ConfigError as err:
        print(f"mcfdd: configuration error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"mcfdd: {err.filename or 'file'}: {err.strerror or err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

"""The ``mcfdd`` command (the edge of the package): arguments -> the public API -> printed results.

Arguments are parsed before anything heavy is imported: ``mcfdd --help`` and a bad flag load
neither JAX nor the workflows; each command imports what it runs.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from mcfdd.arguments import cluster, cluster_executor, command


def _say(message: str):
    print(message, file=sys.stderr, flush=True)


def _print(lines):
    for line in lines:
        print(line)


def _written(paths):
    for path in paths:
        _say(f"wrote {path}")


def _start_runtime():
    """Import JAX and start its devices with Ctrl-C held meanwhile (:func:`mcfdd.interrupts.held`); each command
    calls it once its configuration is read, so a mistake there is named without waiting for JAX."""
    from mcfdd import interrupts

    with interrupts.held():
        import jax

        jax.devices()


def cmd_simulate(args) -> int:
    import mcfdd
    from mcfdd import console, io

    cfg = mcfdd.load_config(args.config, "simulate")
    _start_runtime()
    result = mcfdd.simulate(cfg)
    _written(result.save(io.out_dir("simulate", args.config, args.out)))
    _print(console.simulate_lines(result.summary()))
    return 0


CAMPAIGN_FLAGS = ("scenarios", "seed", "chunk_size")  # flags that set the campaign.* key of their name


def _campaign_config(args):
    """The campaign config with ``--set``, the campaign flags and the ``--fdd`` fragment; bad flags are named."""
    import mcfdd
    from mcfdd import flags

    given = {key: getattr(args, key, None) for key in CAMPAIGN_FLAGS}
    overrides = flags.campaign_overrides(getattr(args, "set", None), given, getattr(args, "fdd", None))
    return mcfdd.load_config(args.config, "campaign", overrides)


def cmd_campaign(args) -> int:
    import mcfdd
    from mcfdd import console, interrupts, io

    cfg = _campaign_config(args)
    out = io.out_dir("campaign", args.config, args.out, new=not args.resume)
    try:
        _start_runtime()
        with cluster_executor(args) as executor:
            result = mcfdd.run_campaign(cfg, out=out, resume=args.resume, title=f"Campaign {Path(args.config).stem}",
                                        executor=executor, compile_cache=args.compile_cache)
    except KeyboardInterrupt:
        kept = "finished chunks are kept in {}; continue with --resume".format(out / "scenarios")
        _say(f"\nmcfdd: interrupted: {kept if (out / 'campaign.json').is_file() else 'nothing was written'}")
        return interrupts.INTERRUPTED
    _print(console.campaign_lines(result.overall(), None if executor is None else result.workers))
    print(f"summary: {out / 'summary.md'}")
    return 0


def cmd_sensitivity(args) -> int:
    import mcfdd
    from mcfdd import flags, interrupts, io

    cfg = mcfdd.load_config(args.config, "campaign", flags.set_overrides(args.set))
    out = io.out_dir("sensitivity", args.config, args.out, new=not args.resume)
    try:
        _start_runtime()
        with cluster_executor(args) as executor:
            result = mcfdd.sensitivity(cfg, out=out, resume=args.resume, executor=executor,
                                       compile_cache=args.compile_cache)
    except KeyboardInterrupt:
        _say(f"\nmcfdd: interrupted: finished chunks are kept in {out / 'runs' / 'scenarios'}; continue with --resume")
        return interrupts.INTERRUPTED
    _print(result.lines())
    print(f"report: {out / 'report.md'}")
    return 0


def cmd_probability(args) -> int:
    import mcfdd
    from mcfdd import flags, io

    cfg = mcfdd.load_config(args.config, "campaign", flags.set_overrides(args.set))
    out = io.out_dir("probability", args.config, args.out)
    _start_runtime()
    with cluster_executor(args) as executor:
        result = mcfdd.probability(cfg, executor=executor, compile_cache=args.compile_cache)
    _written(result.save(out, f"Probability {Path(args.config).stem}"))
    _print([*result.lines(), f"summary: {out / 'summary.md'}"])
    return 0


def cmd_replay(args) -> int:
    import mcfdd
    from mcfdd import flags, io

    result = mcfdd.replay(args.campaign_dir, flags.scenario_ids(args.scenarios))
    _written(result.save(io.out_dir("replay", args.campaign_dir, args.out)))
    _print(result.lines())
    return 0


def cmd_compare(args) -> int:
    import mcfdd

    result = mcfdd.compare(args.campaign_a, args.campaign_b)
    out = Path(args.out) if args.out else Path("results") / f"compare-{'-vs-'.join(result.labels)}"
    result.save(out)
    _print(result.lines())
    print(f"report: {out / 'compare.md'}")
    return 0


def cmd_fit_lpv(args) -> int:
    import mcfdd
    from mcfdd import console, io

    cfg = mcfdd.load_config(args.config, "fit-lpv")
    _start_runtime()
    result = mcfdd.fit_lpv(cfg)
    _written(result.save(io.out_dir("fit-lpv", args.config, args.out)))
    _print(console.fit_lpv_lines(result.models, result.bank.k0, result.error_summary, result.distances))
    return 0


def cmd_worst_case(args) -> int:
    import mcfdd
    from mcfdd import console, io

    cfg = mcfdd.load_config(args.config, "worst-case")
    _start_runtime()
    result = mcfdd.worst_case(cfg)
    out = io.out_dir("worst-case", args.config, args.out)
    result.save(out, f"Worst case {Path(args.config).stem}")
    _print(console.worst_case_lines(result.summary, result.value))
    print(f"report: {out / 'report.md'}")
    return 0


def cmd_tune(args) -> int:
    import mcfdd
    from mcfdd import console, io

    out = io.out_dir("tune", args.config, args.out, new=True)
    if out.exists() and any(out.iterdir()):
        raise mcfdd.OutputFolderError(f"--out: {out} exists and is not empty; choose another folder")
    cfg = mcfdd.load_config(args.config, "tune")
    _start_runtime()
    result = mcfdd.tune(cfg)
    result.save(out)
    _print(console.tune_lines(result.validation))
    print(f"tuned FDD: {out / 'tuned_fdd.toml'}\nreport: {out / 'report.md'}")
    return 0


def cmd_figures(args) -> int:
    import mcfdd
    from mcfdd import console

    _start_runtime()
    result = mcfdd.paper_figures(args.configs)
    _written(result.save(Path(args.out) if args.out else Path("results") / "figures"))
    _print(console.figures_lines(result.sweep, result.grid, result.stall_events, result.eta_outside_s))
    return 0


def cmd_schema(args) -> int:
    import json

    from mcfdd import config

    print(json.dumps(config.json_schema(args.kind), indent=1))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mcfdd", description="Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis "
        "(Ossmann and Varga, 2015): simulate, fit LPV models, run campaigns, tune, search worst cases.")
    sub = parser.add_subparsers(dest="command", required=True)
    command(sub, "simulate", cmd_simulate, "simulate the named runs of a config, write time histories and plots",
             "fig5.toml", "results/simulate-<config>")
    p = command(sub, "campaign", cmd_campaign, "Monte-Carlo campaign over a scenario space: FAR, MDR, detection "
                 "times", "loe_campaign.toml", "a new results/campaign-<config>[-N]",
                 "fdd.loe.detection_tau=0.12 (the detection threshold)")
    p.add_argument("--scenarios", type=int, help="total number of scenarios, split evenly over the grid cells "
                   "(overrides campaign.scenarios; a multiple of the number of cells)")
    p.add_argument("--seed", type=int, help="override campaign.seed")
    p.add_argument("--chunk-size", type=int, help="override campaign.chunk_size (results do not depend on it)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    p.add_argument("--fdd", help="FDD fragment replacing the config's [fdd] table, e.g. a tune's tuned_fdd.toml")
    cluster(p)
    p = command(sub, "sensitivity", cmd_sensitivity, "what drives the verdicts: Sobol' indices, gradient screen "
                 "and regional sensitivity over a campaign space ([sensitivity] table)", "fault_free.toml",
                 "a new results/sensitivity-<config>[-N]", "sensitivity.samples=64")
    p.add_argument("--resume", action="store_true", help="continue the interrupted design runs in --out")
    cluster(p)
    p = command(sub, "probability", cmd_probability, "how rare an event of a campaign is: per run, stratum, flight "
                "hour and airframe by subset simulation, importance sampling or Monte Carlo ([probability] table)",
                "validation.toml", "results/probability-<config>", "probability.budget=20000")
    cluster(p)
    p = command(sub, "compare", cmd_compare, "paired comparison of two campaigns of one space (e.g. two FDDs): "
                 "McNemar's exact test per outcome, detection-time differences", None,
                 "results/compare-<a>-vs-<b>")
    p.add_argument("campaign_a", metavar="DIR_A", help="folder of the first campaign (mcfdd campaign --out)")
    p.add_argument("campaign_b", metavar="DIR_B", help="folder of the second campaign, same space and seed")
    p = command(sub, "replay", cmd_replay, "named scenarios of a campaign (or sensitivity) folder again: time "
                "histories and a figure per run", None, "results/replay-<folder>")
    p.add_argument("campaign_dir", metavar="CAMPAIGN_DIR", help="folder of mcfdd campaign or mcfdd sensitivity")
    p.add_argument("--scenarios", required=True, metavar="IDS", help="comma-separated scenario ids, e.g. 481,3524")
    command(sub, "fit-lpv", cmd_fit_lpv, "fit the LPV gain models of the fault models to the nonlinear actuator",
             "lpv_aileron.toml", "results/fit-lpv-<config>")
    p = command(sub, "figures", cmd_figures, "the paper's Figs. 3-6 from configs fig3/fig4/fig5.toml", None,
                 "results/figures")
    p.add_argument("--configs", default="configs", help="folder holding fig3.toml, fig4.toml, fig5.toml")
    command(sub, "worst-case", cmd_worst_case, "tau_f or tau_d of a detector by gradient search, against Monte "
             "Carlo", "worst_case_stall.toml", "results/worst-case-<config>")
    command(sub, "tune", cmd_tune, "tune a detector's evaluator and threshold by gradient; check on a held-out "
             "campaign", "tune_stall.toml", "the first free results/tune-<config>[-N]")
    p = sub.add_parser("schema", help="print the JSON Schema of a config kind (for editors and validators)")
    p.add_argument("kind", help="the config kind: simulate, campaign, fit-lpv, tune, worst-case or sweep")
    p.set_defaults(func=cmd_schema)
    return parser


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"mcfdd: warning: {message}\n"


def main(argv=None) -> int:
    """Run the command of ``argv`` and return its exit status (0, 2 for a user's mistake, 130 interrupted).

    ``argv`` None is this process's command line (the ``mcfdd`` command): an interrupt then ends the
    process with status 130 right after its one line (:func:`mcfdd.interrupts.stop_now`), in whatever
    phase it comes, and an interrupt Python would ignore is delivered again.
    """
    warnings.formatwarning = _one_line_warning
    args = build_parser().parse_args(argv)
    from mcfdd import interrupts

    if argv is None:
        sys.unraisablehook = interrupts.redeliver_ignored
    code = _run(args)
    if code == interrupts.INTERRUPTED and argv is None:
        interrupts.stop_now(code)
    return code


def _run(args) -> int:
    from mcfdd import interrupts

    try:
        with interrupts.held():  # native modules imported (NumPy, pandas, Arrow; JAX if the config needs it)
            from mcfdd import config
            from mcfdd.workflows import common

        try:
            common.check_folder(getattr(args, "out", None), "--out")
            return args.func(args)
        except config.ConfigError as err:
            kind = "" if isinstance(err, common.ResourceError) else "configuration error: "
            print(f"mcfdd: {kind}{err}", file=sys.stderr)
            return 2
        except OSError as err:
            print(f"mcfdd: {err.filename or 'file'}: {err.strerror or err}", file=sys.stderr)
            return 2
    except KeyboardInterrupt:
        _say("\nmcfdd: interrupted")
        return interrupts.INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())

"""The argument groups the ``mcfdd`` subcommands share (argparse; part of the command's edge, :mod:`mcfdd.cli`).

Imported when the arguments are parsed, so it imports nothing heavy.
"""

from __future__ import annotations


def command(sub, name: str, func, summary: str, example: str | None, out: str, sets: str = ""):
    """A subcommand taking a TOML config (unless ``example`` is None), ``--out`` and, with an example
    ``sets``, ``--set``."""
    p = sub.add_parser(name, help=summary)
    if example is not None:
        p.add_argument("config", help=f"TOML config, e.g. configs/{example}")
    p.add_argument("--out", help=f"output folder (default {out})")
    if sets:
        p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config key by its dotted "
                       f"path, e.g. --set {sets} (repeatable)")
    p.set_defaults(func=func)
    return p


def cluster(p):
    """Where a campaign's chunks (or the estimator runs of ``mcfdd probability``) run (Dask distributed) and where
    compiled programs are kept."""
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


def cluster_executor(args):
    """The executor of the :func:`cluster` flags given (``mcfdd.campaign_executor``: a context manager; None
    in process)."""
    import mcfdd

    return mcfdd.campaign_executor(args.scheduler, args.workers, args.tls_ca_file, args.tls_cert, args.tls_key,
                                   args.connect_timeout)

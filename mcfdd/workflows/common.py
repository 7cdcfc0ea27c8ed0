"""Helpers every workflow shares: configs from paths or dicts, precision, the LPV bank, figures."""

from __future__ import annotations

import os
import shlex
from pathlib import Path

import jax
import jax.monitoring
import numpy as np
from jax.experimental.compilation_cache import compilation_cache

from mcfdd import config, io
from mcfdd.fdd import lpv


class ResourceError(config.ConfigError):
    """What a command cannot use, though its configuration is valid: a folder, a disk, a cluster, this machine's
    cores or memory. One line naming the flag or key that asked for it; ``mcfdd`` prints it without calling it a
    configuration error."""


class OutputFolderError(ResourceError):
    """An output folder that cannot be used: not a folder, not empty without resume, or holding another campaign."""


def check_folder(out, name: str):
    """Refuse an output path that exists and is not a folder (``name``: the key or flag that gave it)."""
    if out and Path(out).exists() and not Path(out).is_dir():
        raise OutputFolderError(f"{name}: {out} exists and is not a folder; choose a folder")

DEG_PER_RAD = 180.0 / np.pi


def as_config(cfg, kind: str):
    """``cfg`` itself when parsed already; a TOML path or a dict is loaded as ``kind``."""
    if isinstance(cfg, (str, Path, dict)):
        return config.load_config(cfg, kind)
    return cfg


def is_dask(executor) -> bool:
    """Whether ``executor`` is a Dask client (else None or a ``concurrent.futures.Executor``)."""
    return type(executor).__module__.startswith("distributed")


def dtype_of(precision: str):
    return np.float64 if precision == "float64" else np.float32


def precision(name: str):
    """Context in which JAX computes at ``name`` ('float32' or 'float64'); restores the caller's setting."""
    return jax.enable_x64(name == "float64")


def load_bank(fdd_cfg: config.FddConfig, dtype):
    """The FDD's LPV gain bank and model names; a bad bank is a configuration error naming ``fdd.bank``."""
    try:
        data = io.load_bank_dict(None if fdd_cfg.bank == "default" else fdd_cfg.bank)
        return lpv.from_dict(data, dtype)
    except (OSError, ValueError, KeyError) as err:
        raise config.ConfigError(f"fdd.bank: cannot use {fdd_cfg.bank!r}: {err}") from None


def default_compile_cache() -> Path:
    """The user's cache folder for compiled programs: ``$XDG_CACHE_HOME/mcfdd/jax`` (default ``~/.cache``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mcfdd" / "jax"


def compile_cache(folder=None) -> Path | None:
    """Keep JAX's compiled programs in ``folder`` (JAX's persistent compilation cache), or not.

    A later process compiling the same program (a second run, another Dask worker on the host or
    on a shared file system) loads it from there instead of compiling; results do not change.
    Programs that compile in under a second are not kept (JAX's default). JAX trusts what it
    finds there: the folder must be writable by its user only.

    Args:
        folder: a folder, None for :func:`default_compile_cache`, or 'off' to compile every time.

    Returns:
        The folder in use, or None when off.
    """
    path = None if folder == "off" else Path(folder or default_compile_cache()).expanduser()
    if path is not None:
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise config.ConfigError(f"--compile-cache: cannot use {str(path)!r}: {err.strerror}") from None
    wanted = (str(path) if path is not None else jax.config.jax_compilation_cache_dir, path is not None)
    if (jax.config.jax_compilation_cache_dir, jax.config.jax_enable_compilation_cache) != wanted:
        compilation_cache.reset_cache()
        jax.config.update("jax_compilation_cache_dir", wanted[0])
        jax.config.update("jax_enable_compilation_cache", wanted[1])
    return path


def replay_command(folder, ids) -> str:
    """The command replaying scenarios ``ids`` of the campaign in ``folder`` (:mod:`mcfdd.workflows.replay`), e.g.
    ``mcfdd replay results/x --scenarios 481,3524``; '' without ids."""
    ids = ",".join(str(int(i)) for i in ids)
    return f"mcfdd replay {shlex.quote(str(folder))} --scenarios {ids}" if ids else ''


def save_figure(fig, path: Path) -> Path:
    """Write a figure as PNG (110 dpi) and close it."""
    import matplotlib.pyplot as plt  # deferred: pyplot is heavy and only closes the figure here

    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def slug(name: str) -> str:
    """A file-name-safe form of a run name."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


class CompileCounter:
    """Counts XLA compilations through JAX's own monitoring events while active (a context manager)."""

    EVENT = "/jax/core/compile/backend_compile_duration"

    def __init__(self):
        self.count = 0

    def _listen(self, event: str, duration_s: float, **kwargs):
        if event == self.EVENT:
            self.count += 1

    def __enter__(self):
        jax.monitoring.register_event_duration_secs_listener(self._listen)
        return self

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self._listen)

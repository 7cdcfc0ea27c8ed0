"""Helpers every workflow shares: configs from paths or dicts, precision, the LPV bank, figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcfdd import config, io

DEG_PER_RAD = 180.0 / np.pi


def as_config(cfg, kind: str):
    """``cfg`` itself when parsed already; a TOML path or a dict is loaded as ``kind``."""
    if isinstance(cfg, (str, Path, dict)):
        return config.load_config(cfg, kind)
    return cfg


def dtype_of(precision: str):
    return np.float64 if precision == "float64" else np.float32


def precision(name: str):
    """Context in which JAX computes at ``name`` ('float32' or 'float64'); restores the caller's setting."""
    import jax

    return jax.enable_x64(name == "float64")


def load_bank(fdd_cfg: config.FddConfig, dtype):
    """The FDD's LPV gain bank and model names; a bad bank is a configuration error naming ``fdd.bank``."""
    from mcfdd.fdd import lpv

    try:
        data = io.load_bank_dict(None if fdd_cfg.bank == "default" else fdd_cfg.bank)
        return lpv.from_dict(data, dtype)
    except (OSError, ValueError, KeyError) as err:
        raise config.ConfigError(f"fdd.bank: cannot use {fdd_cfg.bank!r}: {err}") from None


def save_figure(fig, path: Path) -> Path:
    """Write a figure as PNG (110 dpi) and close it."""
    import matplotlib.pyplot as plt

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
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(self._listen)
        return self

    def __exit__(self, *exc):
        import jax.monitoring

        jax.monitoring.unregister_event_duration_listener(self._listen)

"""mcfdd: Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis, in JAX.

The public face of the package (Ossmann and Varga, 2015): load a config, run a command, read its
tables, save its files. Importing ``mcfdd`` exposes two JAX CPU devices per core (``XLA_FLAGS``)
before JAX starts its backends; if JAX was started first, a warning says so and the devices it
has are used (same results, slower).

The names below are re-exported from the modules that hold them, each imported on first use, so
``import mcfdd`` (and ``mcfdd --help``) loads neither JAX nor the workflows until they are needed.
"""

import importlib
import importlib.util

from mcfdd import devices as _devices  # noqa: F401  (first: sets XLA_FLAGS before JAX starts its backends)

__version__ = "0.1.0"

# public name -> the module that holds it
_HOMES = {
    "Status": "mcfdd.analysis.campaign",
    "ConfigError": "mcfdd.config", "load_config": "mcfdd.config",
    "CampaignResult": "mcfdd.workflows.campaign", "OutputFolderError": "mcfdd.workflows.common",
    "campaign_executor": "mcfdd.workflows.campaign", "run_campaign": "mcfdd.workflows.campaign",
    "FiguresResult": "mcfdd.workflows.figures", "paper_figures": "mcfdd.workflows.figures",
    "LpvFitResult": "mcfdd.workflows.fit_lpv", "fit_lpv": "mcfdd.workflows.fit_lpv",
    "Histories": "mcfdd.workflows.simulate", "simulate": "mcfdd.workflows.simulate",
    "TuneResult": "mcfdd.workflows.tune", "tune": "mcfdd.workflows.tune",
    "WorstCaseResult": "mcfdd.workflows.worst_case", "worst_case": "mcfdd.workflows.worst_case",
    "dask_cluster": "mcfdd.workflows.cluster", "dask_security": "mcfdd.workflows.cluster",  # the distributed extra
}
_NAMES_THERE = {"dask_security": "security"}


def __getattr__(name: str):
    """A public name, imported from its module on first use (then cached here); or a submodule."""
    if name in _HOMES:
        value = getattr(importlib.import_module(_HOMES[name]), _NAMES_THERE.get(name, name))
        globals()[name] = value
        return value
    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module 'mcfdd' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_HOMES))


__all__ = sorted(["__version__", *_HOMES])

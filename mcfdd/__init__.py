"""mcfdd: Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis, in JAX.

The public face of the package (Ossmann and Varga, 2015): load a config, run a command, read its
tables, save its files. Importing ``mcfdd`` exposes two JAX CPU devices per core (``XLA_FLAGS``)
before JAX starts its backends; if JAX was started first, a warning says so and the devices it
has are used (same results, slower).

The names below are re-exported from the modules that hold them, each imported on first use
(PEP 562): ``import mcfdd`` and parsing a configuration (``mcfdd.config``) do not import JAX, and
``import mcfdd`` (and ``mcfdd --help``) loads none of the workflows until they are needed.
"""

import importlib
import importlib.util

from mcfdd import devices as _devices  # noqa: F401  (first: sets XLA_FLAGS before JAX starts its backends)

__version__ = "0.1.0"

_EXPORTS = {  # module -> the names it gives the public face
    "mcfdd.analysis.scoring": ("Status",),
    "mcfdd.config": ("ConfigError", "load_config"),
    "mcfdd.workflows.campaign": ("CampaignResult", "campaign_executor", "run_campaign"),
    "mcfdd.workflows.common": ("OutputFolderError",),
    "mcfdd.workflows.compare": ("CampaignMismatchError", "CompareResult", "compare"),
    "mcfdd.workflows.figures": ("FiguresResult", "paper_figures"),
    "mcfdd.workflows.fit_lpv": ("LpvFitResult", "fit_lpv"),
    "mcfdd.workflows.probability": ("ProbabilityResult", "probability"),
    "mcfdd.workflows.replay": ("ReplayError", "ReplayResult", "replay"),
    "mcfdd.workflows.sensitivity": ("SensitivityResult", "sensitivity"),
    "mcfdd.workflows.simulate": ("Histories", "simulate"),
    "mcfdd.workflows.tune": ("TuneResult", "tune"),
    "mcfdd.workflows.worst_case": ("WorstCaseResult", "worst_case"),
    "mcfdd.workflows.cluster": ("dask_cluster", "dask_security"),  # the optional 'distributed' extra
}
_MODULE = {name: module for module, names in _EXPORTS.items() for name in names}
_RENAMED = {"dask_security": "security"}  # public name -> its name in its module


def __getattr__(name: str):
    """A public name, imported from its module on first use (then cached here); or a submodule."""
    if name in _MODULE:
        value = getattr(importlib.import_module(_MODULE[name]), _RENAMED.get(name, name))
        globals()[name] = value
        return value
    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module 'mcfdd' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_MODULE))


__all__ = sorted(["__version__", *_MODULE])

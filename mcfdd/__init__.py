"""mcfdd: Monte-Carlo robustness analysis of flight-actuator fault detection and diagnosis, in JAX.

The public face of the package (Ossmann and Varga, 2015): load a config, run a command, read its
tables, save its files. Importing ``mcfdd`` exposes two JAX CPU devices per core (``XLA_FLAGS``)
before JAX starts its backends; if JAX was started first, a warning says so and the devices it
has are used (same results, slower).
"""

from mcfdd import devices as _devices  # noqa: F401  (first: sets XLA_FLAGS before JAX starts its backends)
from mcfdd.analysis.scoring import Status
from mcfdd.config import ConfigError, load_config
from mcfdd.workflows.campaign import CampaignResult, OutputFolderError, campaign_executor, run_campaign
from mcfdd.workflows.figures import FiguresResult, paper_figures
from mcfdd.workflows.fit_lpv import LpvFitResult, fit_lpv
from mcfdd.workflows.simulate import Histories, simulate
from mcfdd.workflows.tune import TuneResult, tune
from mcfdd.workflows.worst_case import WorstCaseResult, worst_case

__version__ = "0.1.0"


def __getattr__(name: str):
    """``mcfdd.dask_cluster`` and ``mcfdd.dask_security``, imported on first use (the ``distributed`` extra)."""
    if name in ("dask_cluster", "dask_security"):
        from mcfdd.workflows import cluster

        return {"dask_cluster": cluster.dask_cluster, "dask_security": cluster.security}[name]
    raise AttributeError(f"module 'mcfdd' has no attribute {name!r}")


__all__ = [
    "CampaignResult", "ConfigError", "FiguresResult", "Histories", "LpvFitResult", "OutputFolderError", "Status",
    "TuneResult", "WorstCaseResult", "__version__", "campaign_executor", "dask_cluster", "dask_security", "fit_lpv",
    "load_config",
    "paper_figures", "run_campaign",
    "simulate", "tune", "worst_case",
]

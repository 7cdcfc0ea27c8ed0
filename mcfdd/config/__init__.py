"""Configuration: TOML files and dicts validated once into frozen pydantic models (the edge).

Every section is a frozen model that forbids unknown keys; its keys carry their unit in the name
and an allowed range (:func:`spec`) or a set of names (:func:`choice`). Types are strict: a string
is not a number and a bool is not an integer, while an integer is a fine number; nan and inf are
refused. Every error is a :class:`ConfigError` of one line naming the key path
(``runs[1].fault.size``) and what is allowed.

This package parses and nothing else, and imports no JAX: the SI pytrees the simulation uses are
built from the parsed models by :mod:`mcfdd.analysis.build`. The scenario columns (run keys and
space axes) come from the registry :mod:`mcfdd.columns`. Adding a key to a section is one line,
e.g.::

    window_s: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0, doc="what it sets")
    mode: choice(("a", "b")) = spec("a", doc="what it selects")

and cross-key rules go in the section's :meth:`Section.check`, raising :class:`Invalid`.

Modules: :mod:`~mcfdd.config.base` (sections, typed keys, one-line errors),
:mod:`~mcfdd.config.plant`, :mod:`~mcfdd.config.fdd`, :mod:`~mcfdd.config.scenario` (runs and
spaces), :mod:`~mcfdd.config.kinds` and :mod:`~mcfdd.config.lpv` (the kinds of the commands),
:mod:`~mcfdd.config.files` (loading, overrides, writing, JSON Schema).
"""

from mcfdd.config.base import SEED_MAX, ConfigError, Invalid, Section, bounded, choice, spec
from mcfdd.config.fdd import (
                              EvaluatorConfig,
                              FddConfig,
                              LoeDetectionConfig,
                              ModelRuleConfig,
                              SignalRulesConfig,
                              StallDetectionConfig,
)
from mcfdd.config.files import (
                              KINDS,
                              differences,
                              fdd_fragment,
                              infer_kind,
                              json_schema,
                              load,
                              load_config,
                              load_fdd_fragment,
                              load_toml,
                              parse,
                              replace,
                              to_dict,
                              to_json,
                              to_toml,
)
from mcfdd.config.kinds import (
                              DESIGNS,
                              PRECISIONS,
                              CampaignConfig,
                              CampaignSettings,
                              EvaluationConfig,
                              FddFragment,
                              Scored,
                              SearchSettings,
                              SimulateConfig,
                              Simulated,
                              SimulationConfig,
                              SweepConfig,
                              TuneConfig,
                              TuneSettings,
                              WorstCaseConfig,
)
from mcfdd.config.lpv import (
                              PAPER_LPV_MODELS,
                              LpvEnvelopeConfig,
                              LpvFitConfig,
                              LpvModelConfig,
                              LpvOptimiserConfig,
                              LpvRunsConfig,
)
from mcfdd.config.plant import (
                              AIRCRAFT_MODELS,
                              ActuatorConfig,
                              AircraftConfig,
                              ControlLawConfig,
                              HingeConfig,
                              PlantConfig,
)
from mcfdd.config.scenario import Axis, FaultConfig, ManoeuvreConfig, RunConfig, SpaceConfig

__all__ = [
    "AIRCRAFT_MODELS", "DESIGNS", "KINDS", "PAPER_LPV_MODELS", "PRECISIONS", "SEED_MAX",
    "ActuatorConfig", "AircraftConfig", "Axis", "CampaignConfig", "CampaignSettings", "ConfigError",
    "ControlLawConfig", "EvaluationConfig", "EvaluatorConfig", "FaultConfig", "FddConfig", "FddFragment",
    "HingeConfig", "Invalid", "LoeDetectionConfig", "LpvEnvelopeConfig", "LpvFitConfig", "LpvModelConfig",
    "LpvOptimiserConfig", "LpvRunsConfig", "ManoeuvreConfig", "ModelRuleConfig", "PlantConfig", "RunConfig",
    "Scored", "SearchSettings", "Section", "SignalRulesConfig", "SimulateConfig", "Simulated", "SimulationConfig",
    "SpaceConfig", "StallDetectionConfig", "SweepConfig", "TuneConfig", "TuneSettings", "WorstCaseConfig", "bounded",
    "choice", "differences", "fdd_fragment", "infer_kind", "json_schema", "load", "load_config", "load_fdd_fragment",
    "load_toml", "parse", "replace", "spec", "to_dict", "to_json", "to_toml",
]

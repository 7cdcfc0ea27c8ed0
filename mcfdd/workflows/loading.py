"""Configs for the library: a TOML path or a dict, of a named kind, with dotted-path overrides."""

from __future__ import annotations

import copy
from pathlib import Path

from mcfdd import config

KINDS = {"simulate": config.SimulateConfig, "campaign": config.CampaignConfig, "fit-lpv": config.LpvFitConfig,
         "tune": config.TuneConfig, "worst-case": config.WorstCaseConfig, "sweep": config.SweepConfig}
_MARKERS = (("runs", "simulate"), ("search", "worst-case"), ("tune", "tune"), ("optimiser", "fit-lpv"),
            ("models", "fit-lpv"), ("run", "sweep"))


def infer_kind(data: dict) -> str:
    """The config kind its sections say ('campaign' when none of the others' sections is there)."""
    return next((kind for section, kind in _MARKERS if section in data), "campaign")


def _override(data: dict, key: str, value):
    node = data
    parts = key.split(".")
    for i, part in enumerate(parts[:-1]):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise config.ConfigError(f"{'.'.join(parts[:i + 1])}: is a value, not a table; cannot override {key!r}")
        node = child
    node[parts[-1]] = value


def load_config(source, kind: str | None = None, overrides: dict | None = None):
    """A parsed, validated configuration.

    Args:
        source: path of a TOML file, or a dict of its tables.
        kind: 'simulate', 'campaign', 'fit-lpv', 'tune' or 'worst-case' (or 'sweep', Fig. 4);
            None infers it from the sections.
        overrides: dotted key paths to values, e.g. ``{"campaign.scenarios": 256}``, applied to
            the tables before validation, so they are checked exactly like the file.

    Returns:
        The frozen config object of the kind.

    Raises:
        ConfigError: one line naming the file and key path, with the allowed range or choices.

    >>> cfg = load_config({"campaign": {"scenarios": 8}}, overrides={"fdd.loe.tau": 0.12})
    >>> cfg.campaign.scenarios, cfg.fdd.loe.tau
    (8, 0.12)
    """
    if isinstance(source, dict):
        data, where = copy.deepcopy(source), None
    else:
        data, where = config.load_toml(source), Path(source)
    if kind is None:
        kind = infer_kind(data)
    if kind not in KINDS:
        raise config.ConfigError(f"kind: {kind!r} is not one of {', '.join(KINDS)}")
    try:
        for key, value in (overrides or {}).items():
            _override(data, key, value)
        return config.parse(KINDS[kind], data)
    except config.ConfigError as err:
        raise config.ConfigError(f"{where}: {err}" if where else str(err)) from None

"""Loading, overriding, comparing, writing and describing configurations (TOML files and dicts)."""

from __future__ import annotations

import copy
import json
import re
import tomllib
from pathlib import Path

import tomli_w

from mcfdd.config import base
from mcfdd.config.base import ConfigError, Invalid, join, key_path
from mcfdd.config.fdd import FddConfig
from mcfdd.config.kinds import CampaignConfig, FddFragment, SimulateConfig, SweepConfig, TuneConfig, WorstCaseConfig
from mcfdd.config.lpv import LpvFitConfig
from mcfdd.config.scenario import FORMS

KINDS = {"simulate": SimulateConfig, "campaign": CampaignConfig, "fit-lpv": LpvFitConfig, "tune": TuneConfig,
         "worst-case": WorstCaseConfig, "sweep": SweepConfig}


def parse(cls, data: dict, path: str = ""):
    """Section ``cls`` from a TOML table (a dict); errors are one :class:`Invalid` naming the key below ``path``."""
    return base.parse(cls, data, path, FORMS)


def _plain(data):
    if isinstance(data, dict):
        return {k: _plain(v) for k, v in data.items()}
    return [_plain(v) for v in data] if isinstance(data, (list, tuple)) else data


def to_dict(obj) -> dict:
    """The resolved configuration as plain data (tables, lists, scalars); parses back to ``obj``."""
    return _plain(obj.model_dump())


def to_json(obj) -> str:
    """The resolved configuration as JSON, in its own order (the order of [space]'s axes is part of a design)."""
    return json.dumps(to_dict(obj), default=str)


def load_toml(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such configuration file")
    if not path.is_file():
        raise ConfigError(f"{path}: {'a folder' if path.is_dir() else 'not a regular file'}, not a configuration "
                          f"file; give the path of a TOML file")
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (not valid UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply to be a configuration") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read it: {err.strerror or err}") from None


def _in_file(path, fn, *args):
    try:
        return fn(*args)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def load(cls, path):
    """Parse the TOML file at ``path`` into section ``cls``; errors name the file and key."""
    return _in_file(path, parse, cls, load_toml(path))


def _kind(kind: str):
    if kind not in KINDS:
        raise ConfigError(f"kind: {kind!r} is not allowed; expected one of {', '.join(map(repr, KINDS))}")
    return KINDS[kind]


def infer_kind(data: dict) -> str:
    """The config kind whose top-level sections hold every key of ``data`` (and its required ones)."""
    keys = set(data)
    fits = [k for k, cls in KINDS.items() if keys <= set(cls.model_fields)]
    if not fits:
        known = set().union(*(cls.model_fields for cls in KINDS.values()))
        bad = sorted(keys - known) or sorted(keys)
        raise ConfigError(f"{bad[0]}: unknown key; no configuration kind ({', '.join(KINDS)}) has it")
    complete = [k for k in fits if all(n in keys for n, f in KINDS[k].model_fields.items() if f.is_required())]
    fits = complete or fits
    if len(fits) > 1:
        raise ConfigError(f"kind: the sections {', '.join(sorted(keys)) or '(none)'} fit {', '.join(fits)}; "
                          f"pass kind= one of them")
    return fits[0]


_PATH_PART = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def _split_path(path: str) -> list:
    parts = [int(i) if i else name for name, i in _PATH_PART.findall(path)]
    if not parts or key_path(parts) != path:
        raise ConfigError(f"{path!r}: not a key path (expected e.g. campaign.scenarios or runs[1].fault.size)")
    return parts


def with_overrides(data: dict, overrides: dict) -> dict:
    """Copy of raw ``data`` with each dotted key path of ``overrides`` set, tables created as needed.

    Keys are checked by the validation that follows, so an unknown key gives the message it gives in a file.
    """
    data = copy.deepcopy(data)
    for path, value in overrides.items():
        parts = _split_path(path)
        node = data
        for i, part in enumerate(parts):
            where = key_path(parts[:i + 1])
            if isinstance(part, int):
                if not isinstance(node, list) or part >= len(node):
                    raise ConfigError(f"{where}: no such entry ({key_path(parts[:i])} has "
                                      f"{len(node) if isinstance(node, list) else 'no'} entries)")
            elif not isinstance(node, dict):
                raise ConfigError(f"{key_path(parts[:i])}: not a table, cannot set {where}")
            if i == len(parts) - 1:
                node[part] = copy.deepcopy(value)
            else:
                if isinstance(part, str) and part not in node:
                    node[part] = {}
                node = node[part]
    return data


def _from(key: str, overrides) -> bool:
    """Whether an error at ``key`` is about one of the ``overrides``' key paths (or a table on its way)."""
    return any(key == o or key.startswith((f"{o}.", f"{o}[")) or o.startswith((f"{key}.", f"{key}["))
               for o in overrides)


def load_config(source, kind: str | None = None, overrides: dict | None = None):
    """A validated configuration from a TOML file or a dict, with dotted-path overrides.

    Args:
        source: path of a TOML file, or its content as a dict (not modified).
        kind: one of :data:`KINDS` ('simulate', 'campaign', 'fit-lpv', 'tune', 'worst-case',
            'sweep'); inferred from the top-level sections when None.
        overrides: {key path: value}, e.g. ``{"campaign.scenarios": 256, "fdd.loe.tau": 0.12,
            "runs[1].fault.size": 0.3}``, applied to the raw data before validation, so a bad
            value gives the same message as in the file.

    Returns:
        The frozen config model of the kind.

    >>> space = {"kci_scale": [0.9, 1.1]}
    >>> cfg = load_config({"campaign": {"scenarios": 8}, "space": space}, overrides={"fdd.loe.tau": 0.12})
    >>> type(cfg).__name__, cfg.campaign.scenarios, cfg.fdd.loe.tau
    ('CampaignConfig', 8, 0.12)
    """
    from_file = not isinstance(source, dict)
    data = load_toml(source) if from_file else source
    if kind is None:
        kind = _in_file(source, infer_kind, data) if from_file else infer_kind(data)
    cls = _kind(kind)
    overrides = overrides or {}
    try:
        return parse(cls, with_overrides(data, overrides))
    except Invalid as err:
        if not from_file or _from(err.key, overrides):
            raise
        raise ConfigError(f"{source}: {err}") from None


def differences(old, new, path: str = "") -> list[tuple[str, object, object]]:
    """(key path, old value, new value) wherever two resolved configurations (plain data) differ.

    >>> differences({"campaign": {"seed": 1, "grid": ["a"]}}, {"campaign": {"seed": 2, "grid": ["a"]}})
    [('campaign.seed', 1, 2)]
    """
    if isinstance(old, dict) and isinstance(new, dict):
        return [d for key in sorted(set(old) | set(new), key=str)
                for d in differences(old.get(key), new.get(key), join(path, str(key)))]
    return [] if old == new else [(path or "configuration", old, new)]


def replace(cfg, changes: dict):
    """A copy of ``cfg`` with the dotted key paths of ``changes`` set, validated like a file.

    >>> cfg = load_config({"campaign": {"scenarios": 8}, "space": {"kci_scale": [0.9, 1.1]}})
    >>> replace(cfg, {"campaign.seed": 3, "fdd.loe.tau": 0.2}).campaign.seed
    3
    """
    return parse(type(cfg), with_overrides(to_dict(cfg), changes))


def json_schema(kind: str) -> dict:
    """JSON Schema (draft 2020-12) of a configuration kind (one of :data:`KINDS`), for editors and validators.

    >>> schema = json_schema("campaign")
    >>> sorted(schema["properties"]), schema["additionalProperties"]
    (['campaign', 'evaluation', 'fdd', 'plant', 'probability', 'sensitivity', 'space'], False)
    """
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **_kind(kind).model_json_schema()}


def _without_none(data):
    if isinstance(data, dict):
        return {k: _without_none(v) for k, v in data.items() if v is not None}
    if isinstance(data, (list, tuple)):
        return [_without_none(v) for v in data]
    return data


def to_toml(data: dict) -> str:
    """TOML text of nested tables (keys whose value is None are left out: they take their default)."""
    return tomli_w.dumps(_without_none(data))


def fdd_fragment(fdd: FddConfig, comment: str = "") -> str:
    """A config fragment holding only an [fdd] table (``mcfdd campaign --fdd FILE``)."""
    header = "".join(f"# {line}\n" for line in comment.splitlines())
    return header + to_toml({"fdd": to_dict(fdd)})


def load_fdd_fragment(path) -> FddConfig:
    """The [fdd] table of a fragment file, parsed like a config's; errors name the file and key."""
    return load(FddFragment, path).fdd

"""Command-line flags as configuration overrides (the command's side of :mod:`mcfdd.config`).

``--set KEY=VALUE`` pairs, the ``campaign.*`` flags and an ``--fdd`` fragment become the dotted-path
overrides of :func:`mcfdd.config.load_config`; a bad flag is a :class:`~mcfdd.config.ConfigError`
naming the flag.
"""

from __future__ import annotations

import tomllib

from mcfdd import config


def set_overrides(pairs) -> dict:
    """``KEY=VALUE`` texts (the ``--set`` flag) as dotted-path overrides; VALUE is read as TOML (a bare word
    as a string)."""
    overrides = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise config.ConfigError(f"--set: {pair!r} is not KEY=VALUE, e.g. fdd.loe.detection_tau=0.12")
        try:
            overrides[key.strip()] = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            overrides[key.strip()] = text
        except RecursionError:
            raise config.ConfigError(f"--set: the value of {key.strip()} is nested too deeply") from None
    return overrides


def campaign_overrides(set_pairs=(), flags: dict | None = None, fdd_path=None) -> dict:
    """The overrides of a campaign's command line: ``--set`` pairs, then the ``campaign.*`` flags given (each
    checked against its key's type and range, the flag named in the error), then an FDD fragment replacing [fdd].

    >>> campaign_overrides(["fdd.loe.tau=0.12"], {"seed": 3, "chunk_size": None})
    {'fdd.loe.tau': 0.12, 'campaign.seed': 3}
    >>> campaign_overrides(flags={"seed": -1})
    Traceback (most recent call last):
    mcfdd.config.base.ConfigError: --seed: -1 is outside the allowed range [0, 4294967295] (campaign.seed)
    """
    overrides = set_overrides(set_pairs)
    for key, value in (flags or {}).items():
        if value is not None:
            try:
                config.parse(config.CampaignSettings, {key: value})
            except config.Invalid as err:
                raise config.ConfigError(f"--{key.replace('_', '-')}: {err.message} (campaign.{key})") from None
            overrides[f"campaign.{key}"] = value
    if fdd_path:
        overrides["fdd"] = config.to_dict(config.load_fdd_fragment(fdd_path))
    return overrides


def scenario_ids(text: str) -> list[int]:
    """The ``--scenarios`` flag of ``mcfdd replay``: comma-separated scenario ids, e.g. '481,3524'.

    >>> scenario_ids("481, 3524")
    [481, 3524]
    >>> scenario_ids("481,x")
    Traceback (most recent call last):
    mcfdd.config.base.ConfigError: --scenarios: 'x' is not a scenario id (ids are integers >= 0, e.g. 481,3524)
    """
    ids = []
    for item in text.split(","):
        item = item.strip()
        if not item.isdigit():
            raise config.ConfigError(f"--scenarios: {item!r} is not a scenario id (ids are integers >= 0, e.g. "
                                     f"481,3524)")
        ids.append(int(item))
    return ids

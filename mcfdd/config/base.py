"""Sections, typed keys and one-line errors: what every configuration table is made of.

A section is a frozen pydantic model that forbids unknown keys, reads TOML lists as tuples and
takes strict types (a string is not a number, a bool is not an integer, an integer is a fine
number; nan and inf are refused). A key with a range or a set of names carries the message of its
own refusal (:func:`spec`, :func:`bounded`, :func:`choice`), so a failed validation becomes one
line naming the key path (``runs[1].fault.size``) and what is allowed; :func:`parse` turns
pydantic's error into that :class:`ConfigError`.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, WrapValidator, model_validator
from pydantic_core import PydanticUndefined

SEED_MAX = 2**32 - 1  # seeds are 32-bit: JAX keys, numpy and scipy.stats.qmc take them alike


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range."""


class Invalid(ConfigError):
    """A value is refused at ``key``, a path relative to the section or value that refuses it."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}" if key else message)
        self.key, self.message = key, message


def _refusing(kinds: tuple[str, ...], message) -> WrapValidator:
    """A validator that turns pydantic's errors of ``kinds`` on a value into ``message(value)``."""

    def check(value, handler):
        try:
            return handler(value)
        except ValidationError as err:
            if err.errors()[0]["type"] in kinds:
                raise Invalid("", message(value)) from None
            raise

    return WrapValidator(check)


def _bounds(lo, hi, lo_open) -> dict:
    bounds = {} if lo is None else {"gt" if lo_open else "ge": lo}
    return bounds if hi is None else {**bounds, "le": hi}


def _range(lo, hi, lo_open) -> WrapValidator:
    text = f"{'(' if lo_open else '['}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
    return _refusing(("greater_than", "greater_than_equal", "less_than_equal"),
                     lambda value: f"{value!r} is outside the allowed range {text}")


def spec(default=PydanticUndefined, *, lo=None, hi=None, lo_open=False, doc=""):
    """A field with an allowed range [lo, hi] (open at lo if ``lo_open``); no default: required."""
    field = Field(default, description=doc or None, **_bounds(lo, hi, lo_open))
    if lo is not None or hi is not None:
        field.metadata.append(_range(lo, hi, lo_open))
    return field


def bounded(lo=None, hi=None, lo_open=False, tp=float):
    """Type ``tp`` within [lo, hi], e.g. for the elements of a fixed-length list."""
    if lo is None and hi is None:
        return tp
    return Annotated[tp, Field(**_bounds(lo, hi, lo_open)), _range(lo, hi, lo_open)]


def choice(names):
    """One of ``names`` (strings)."""
    expected = ", ".join(repr(n) for n in names)
    return Annotated[Literal[tuple(names)], _refusing(("literal_error",),
                                                      lambda value: f"{value!r} is not allowed; expected one of "
                                                                    f"{expected}")]


class Section(BaseModel):
    """A TOML table: frozen, unknown keys refused, strict types, no nan or inf, lists read as tuples."""

    model_config = ConfigDict(frozen=True, extra="forbid", strict=True, allow_inf_nan=False)
    UNKNOWN: ClassVar[str] = "unknown key; allowed keys are"  # the message of an unknown key, before the keys

    @model_validator(mode="before")
    @classmethod
    def _raw_table(cls, data):
        if not isinstance(data, dict):
            return data
        for key in data:
            if key not in cls.model_fields:
                raise Invalid(key, f"{cls.UNKNOWN} {', '.join(sorted(cls.model_fields))}")
        return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}

    @model_validator(mode="after")
    def _checked(self):
        self.check()
        return self

    def check(self):
        """Rules across keys of the section; raise :class:`Invalid` naming the key."""


# --------------------------------------------------------------------------------------------
# One line from pydantic's error

_EXPECTED = {
    "float_type": "a number", "int_type": "an integer", "int_from_float": "an integer", "bool_type": "true or false",
    "string_type": "a string", "model_type": "a table", "model_attributes_type": "a table", "dict_type": "a table",
    "tuple_type": "a list", "list_type": "a list",
}
_TOML_TYPES = {bool: "boolean", int: "integer", float: "float", str: "string", dict: "table", list: "list",
               tuple: "list"}


def join(path: str, key: str) -> str:
    """``path`` and a key below it: ``a.b``, ``a[1]``."""
    if not (path and key):
        return path or key
    return path + (key if key.startswith("[") else f".{key}")


def key_path(loc) -> str:
    """The key path of a location (keys and list indices), e.g. ``runs[1].fault.size``."""
    path = ""
    for part in loc:
        path = join(path, f"[{part}]" if isinstance(part, int) else str(part))
    return path


def _shown(value) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def describe(error: dict, tags=frozenset()) -> tuple[str, str]:
    """(key path, message) of one of pydantic's errors; ``tags``: location parts that are union tags."""
    path = key_path(p for p in error["loc"] if p not in tags)
    cause = error.get("ctx", {}).get("error")
    if isinstance(cause, Invalid):
        return join(path, cause.key), cause.message
    kind, value = error["type"], error.get("input")
    if kind == "missing":
        return path, "missing required key"
    if kind == "finite_number":
        return path, "nan is not a number" if math.isnan(value) else f"{value!r} is not a finite number"
    if kind in ("too_short", "too_long") and "max_length" in error["ctx"]:
        return path, f"expected a list of {error['ctx']['max_length']} values, got {len(value)}"
    if kind == "too_short":
        return path, "expected a non-empty list"
    if kind in _EXPECTED:
        return path, f"expected {_EXPECTED[kind]}, got {_TOML_TYPES.get(type(value), type(value).__name__)} " \
                     f"{_shown(value)}"
    return path, error["msg"]


def parse(cls, data, path: str = "", tags=frozenset()):
    """Section ``cls`` from a TOML table (a dict); a failure is an :class:`Invalid` naming the key below ``path``."""
    try:
        return cls.model_validate(data)
    except ValidationError as err:
        key, message = describe(err.errors()[0], tags)
        raise Invalid(join(path, key) or "configuration", message) from None

"""Scenario sections, derived from the column registry (:mod:`mcfdd.columns`): runs and spaces.

A single run (``[[runs]]``, a sweep's ``[run]``) sets each scenario column by a key of its
``run``, ``fault`` or ``manoeuvre`` table; a ``[space]`` gives each column it varies one axis, in
the order of the TOML table (the order of the design's dimensions). Types, ranges, defaults and
docs of both come from the registry.

Axis forms in TOML, each a pydantic type (so messages and JSON Schema come from the types):

- a number or a name: the constant ``value``;
- ``[lo, hi]``: a uniform range (a number column; 2 points when gridded);
- ``["a", "b"]``: choices (a named column);
- ``{ values = [...] }``: discrete numbers;
- ``{ range = [lo, hi], n = 5 }``: a range with 5 points when gridded.

Fault sizes are drawn per kind (``leakage_size``, ``surface_damage_size``) and merged into
``fault_size`` by the design.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, ClassVar, Union

from pydantic import (
    AfterValidator,
    BeforeValidator,
    Discriminator,
    Field,
    PlainSerializer,
    PrivateAttr,
    Tag,
    create_model,
    model_serializer,
    model_validator,
)

from mcfdd import columns
from mcfdd.config.base import Invalid, Section, bounded, choice, spec

FORMS = frozenset({"<value>", "<list>", "<values>", "<range>"})  # union tags of the axis forms (no keys)


def column_type(column: columns.Column):
    """The type of a column's values: one of its names, or a number within its range."""
    return choice(column.choices) if column.choices else bounded(column.lo, column.hi, column.lo_open)


def column_field(column: columns.Column):
    return spec(column.default, doc=column.doc)


def run_section(model: str, owner: str, doc: str, base=Section, first=(), last=()):
    """The single-run section ``owner`` of the registry as a model named ``model``.

    Its keys: ``first`` ((key, (type, field)) pairs), a key per column the section owns, then ``last``.
    """
    fields = {c.owner[1]: (column_type(c), column_field(c)) for c in columns.owned_by(owner)}
    return create_model(model, __base__=base, __doc__=doc, __module__=__name__, **dict(first), **fields, **dict(last))


class _FaultRules(Section):
    def check(self):
        if self.kind == "leakage" and self.size >= 1.0:
            raise Invalid("size", f"{self.size} leaves no pressure (nu1 = 0); leakage size must be below 1")


FaultConfig = run_section("FaultConfig", "fault", "The fault of a run, stepping in at ``onset_s``.", _FaultRules)
ManoeuvreConfig = run_section("ManoeuvreConfig", "manoeuvre", "The manoeuvre of a run (family and traced numbers).")
RunConfig = run_section(
    "RunConfig", "run", "One named run: flight point, uncertainties, turbulence and noise, fault, manoeuvre.",
    first=[("name", (str, spec()))],
    last=[("seed", (int | None, spec(None, lo=0, doc="turbulence and sensor noise of this run; unset, every run of "
                                                     "the config draws the same ones (from simulation.seed), so runs "
                                                     "are paired"))),
          ("index", (int, spec(0, lo=0, hi=2**32 - 1, doc="which of the seed's runs: turbulence and sensor noise "
                                                         "of row `index` of a campaign or worst-case search of that "
                                                         "seed (its run key fold_in(key(seed), index))"))),
          ("fault", (FaultConfig, spec(FaultConfig()))), ("manoeuvre", (ManoeuvreConfig, spec(ManoeuvreConfig())))])


# --------------------------------------------------------------------------------------------
# Scenario spaces


@dataclasses.dataclass(frozen=True)
class Axis:
    """One column of a scenario space, as parsed.

    kind: 'const' (``values[0]``), 'range' (uniform on [lo, hi]; ``n`` points when gridded),
    'values' (discrete numbers) or 'choices' (names). Sampling is in :mod:`mcfdd.analysis.scenarios`.
    """

    name: str
    kind: str
    values: tuple = ()
    lo: float = 0.0
    hi: float = 0.0
    n: int = 0

    @property
    def points(self) -> int:
        """Number of grid points when gridded."""
        return max(self.n, 1) if self.kind == "range" else len(self.values)

    @property
    def extent(self) -> tuple:
        """(smallest, largest) value (numbers)."""
        return (self.lo, self.hi) if self.kind == "range" else (min(self.values), max(self.values))

    def toml(self):
        """The axis as written in a [space] table."""
        if self.kind == "const":
            return self.values[0]
        if self.kind == "choices":
            return list(self.values)
        if self.kind == "values":
            return {"values": list(self.values)}
        return [self.lo, self.hi] if self.n == 2 else {"range": [self.lo, self.hi], "n": self.n}


def _pair_length(value):
    if isinstance(value, tuple) and len(value) != 2:
        raise Invalid("", "a range is [lo, hi]; for discrete values write { values = [...] }")
    return value


def _ordered(pair):
    if pair[1] < pair[0]:
        raise Invalid("", f"range [{pair[0]}, {pair[1]}] is empty")
    return pair


def _form(value) -> str | None:
    """The axis form of a TOML value (None: a table that is neither form)."""
    if isinstance(value, dict):
        return "<range>" if "range" in value else "<values>" if "values" in value else None
    return "<list>" if isinstance(value, tuple) else "<value>"


def axis_type(column: columns.Column):
    """The pydantic type of the axis forms of ``column``; it validates to an :class:`Axis`."""
    name, one = column.name, column_type(column)

    def form(tag, tp, make):
        return Annotated[tp, AfterValidator(make), Tag(tag)]

    if column.choices:
        forms = [form("<value>", one, lambda v: Axis(name, "const", (v,))),
                 form("<list>", Annotated[tuple[one, ...], Field(min_length=1)], lambda v: Axis(name, "choices", v))]
    else:
        pair = Annotated[tuple[one, one], BeforeValidator(_pair_length), AfterValidator(_ordered)]
        values = create_model(f"{name}_values", __base__=Section, __doc__="discrete values",
                              values=(tuple[one, ...], Field(min_length=1)))
        grid = create_model(f"{name}_range", __base__=Section, __doc__="a range with n grid points",
                            range=(pair, spec()), n=(int, spec(2, lo=1)))
        forms = [form("<value>", one, lambda v: Axis(name, "const", (v,))),
                 form("<list>", pair, lambda v: Axis(name, "range", lo=v[0], hi=v[1], n=2)),
                 form("<values>", values, lambda v: Axis(name, "values", v.values)),
                 form("<range>", grid, lambda v: Axis(name, "range", lo=v.range[0], hi=v.range[1], n=v.n))]
    tagged = Annotated[Union[tuple(forms)], Discriminator(_form, custom_error_type="axis_form",  # noqa: UP007
                                                          custom_error_message="an axis table needs 'values' or "
                                                                               "'range'")]
    return Annotated[tagged, PlainSerializer(Axis.toml, when_used="unless-none")]


class _Space(Section):
    """Scenario space: one axis per column it varies, in the order of the TOML table.

    In TOML a key takes a number or a name (constant), ``[lo, hi]`` (uniform range), a list of
    names (choices), ``{ values = [...] }`` (discrete numbers) or ``{ range = [lo, hi], n = 5 }``
    (a range with 5 grid points when gridded). Fault sizes are drawn per kind
    (``leakage_size``, ``surface_damage_size``) and merged into ``fault_size``.
    """

    UNKNOWN: ClassVar[str] = "unknown axis; allowed axes are"
    _order: tuple[str, ...] = PrivateAttr(())

    @model_validator(mode="wrap")
    @classmethod
    def _keep_order(cls, data, handler):
        space = handler(data)
        if isinstance(data, dict):
            space._order = tuple(data)
        return space

    @model_serializer(mode="wrap")
    def _to_toml(self, handler) -> dict:
        data = handler(self)
        return {name: data[name] for name in self._order}

    @property
    def axes(self) -> tuple[Axis, ...]:
        """The axes in the order of the TOML table."""
        return tuple(getattr(self, name) for name in self._order)

    def axis(self, name) -> Axis | None:
        return getattr(self, name) if name in self._order else None


SpaceConfig = create_model("SpaceConfig", __base__=_Space, __doc__=_Space.__doc__, __module__=__name__,
                           **{c.name: (axis_type(c), Field(None, description=c.doc or None,
                                                           json_schema_extra={"default": c.default}))
                              for c in columns.AXES})  # an axis left out is the column's default

"""The uncertain parameters of a run: each uncertainty scale multiplies nominal plant constants.

Which constant a scale multiplies is declared with its column (:attr:`mcfdd.columns.Column.scales`);
both aircraft models apply the scales through :func:`scaled`, once per run in their ``prepare``.
The hinge-load scale is applied by each model where it computes the load.
"""

from __future__ import annotations

from typing import NamedTuple

from mcfdd import columns


def scaled(nominal: NamedTuple, scenario) -> NamedTuple:
    """``nominal`` (plant constants, e.g. ``ActuatorParams``) with each field an uncertainty scale of
    ``scenario`` (a :class:`~mcfdd.plant.closed_loop.Scenario`) multiplies, multiplied by it."""
    owner = type(nominal).__name__
    scale = {field: column.leaf for column in columns.UNCERTAIN for kind, field in column.scales if kind == owner}
    # in the order of the constants' fields: the traced program, and so the compiled one, keeps one order
    return nominal._replace(**{field: getattr(nominal, field) * getattr(scenario, scale[field])
                               for field in nominal._fields if field in scale})

"""Plant-truth monitors: the run's status, detectability peaks and flight point (DESIGN.md 5, 5a).

- :func:`status`: a :class:`Status` code, 1 where any monitored signal (measured position, the
  detectors' theta) went non-finite: the run's outcomes are void (its verdicts false, its margins nan).
- :func:`peaks`: the plant's own peak hinge-load fraction ``|F_aero| / (nu1 dP S)`` while the rod
  moves (rate at least ``MOVING_RATE_M_S``) and peak |deflection|, both after the fault onset
  (fault-free runs: over the settled run); the detectability of a fault (DESIGN.md section 5) is
  judged at that load (:func:`mcfdd.analysis.metrics.detectability_columns`).
- :func:`flight_point`: the smallest and largest measured Vcas and altitude of the run (constant
  on the roll axis; the full aircraft's move with its manoeuvre).
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.analysis.scoring.core import Monitor, Sample, Settings, Truth, Windows, extend, finite_or_nan

MOVING_RATE_M_S = 1e-3  # rod rate (about 1.1 deg/s of surface) above which the rod counts as moving


class Status(enum.IntEnum):
    """Scenario status code, the ``status`` column of a campaign table; ``.meaning`` says what it means."""

    OK = 0, "the run's numbers stayed finite; its outcomes count"
    NON_FINITE = 1, "a monitored signal went non-finite; the run's outcomes are void and not counted"

    def __new__(cls, code: int, meaning: str):
        member = int.__new__(cls, code)
        member._value_ = code
        member.meaning = meaning
        return member


def status() -> Monitor:
    """The run's :class:`Status` (finiteness is tracked by the windows)."""
    return Monitor(lambda dtype: (), lambda state, w, sample: state,
                   lambda state, end: {"status": jnp.where(end.ok, int(Status.OK), int(Status.NON_FINITE))
                                       .astype(jnp.int32)})


class Peaks(NamedTuple):
    load_fraction: jnp.ndarray
    deflection_rad: jnp.ndarray


def peaks(s: Settings, truth: Truth) -> Monitor:
    """Peak load fraction (rod moving) and peak |deflection| after the onset."""
    def init(dtype):
        return Peaks(jnp.asarray(-jnp.inf, dtype), jnp.asarray(-jnp.inf, dtype))

    def update(state: Peaks, w: Windows, sample: Sample) -> Peaks:
        plant = sample.plant
        after = jnp.where(jnp.isfinite(truth.onset_s), w.t >= truth.onset_s, w.settled)
        moving = after & (jnp.abs(plant.rate_m_s) >= MOVING_RATE_M_S)
        return Peaks(jnp.where(moving, jnp.maximum(state.load_fraction, plant.load_fraction), state.load_fraction),
                     jnp.where(after, jnp.maximum(state.deflection_rad, jnp.abs(plant.delta_rad)),
                               state.deflection_rad))

    def finalize(state: Peaks, end: Windows) -> dict:
        return {"peak_load_fraction": finite_or_nan(state.load_fraction),
                "peak_deflection_deg": finite_or_nan(jnp.degrees(state.deflection_rad))}

    return Monitor(init, update, finalize)


def flight_point() -> Monitor:
    """(min, max) of the measured Vcas (m/s) and altitude (m)."""
    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        return jnp.stack([inf, -inf]), jnp.stack([inf, -inf])

    def update(state, w: Windows, sample: Sample):
        return extend(state[0], sample.plant.vcas_m_s), extend(state[1], sample.plant.altitude_m)

    def finalize(state, end: Windows) -> dict:
        return {"vcas_min_m_s": state[0][0], "vcas_max_m_s": state[0][1], "altitude_min_m": state[1][0],
                "altitude_max_m": state[1][1]}

    return Monitor(init, update, finalize)

"""Pilot manoeuvres and open-loop actuator command profiles (DESIGN.md section 3).

A manoeuvre is a family (an integer code) and traced numbers: amplitude, timing and frequencies,
so that they can be sampled and searched. Closed-loop families move the sidestick (fraction of
full stick, sign = direction) or set a steady sideslip; open-loop families drive the actuator
command directly (fraction of full deflection) and bypass the control law, for component-level
runs and LPV fitting. Inputs ramp over ``ramp_s`` to stay at realistic rates.

Families (``t`` counts from ``t_start_s``; ``A`` amplitude, ``D`` duration, ``H`` hold):
- quiet: nothing (turbulence only)
- doublet: stick +A for D, then -A for D
- bank_to_bank: stick +A for D, hold H, -A for 2 D, hold H, +A for D
- roll_protection: stick A held for D (full stick: the bank protection takes over)
- sideslip: steady sideslip ``sideslip_rad`` held for D, none for H, the opposite one for D
  (ramps over ramp_s); stick neutral
- ol_step: command A for D
- ol_doublet: command +A for D, then -A for D
- ol_sweep: chirp from freq_lo_hz to freq_hi_hz over D, amplitude A
- ol_multisine: five Schroeder-phased sines spread log-uniformly over the band, scaled by 1/2.5 and
  clipped so that the peak stays within A

Families of the full aircraft (``plant.aircraft.model = "rcam"``; the paper's Section 6.2.2):
- level_flight: nothing (as quiet)
- pitch_doublet: longitudinal stick +A for D, then -A for D (positive: pull, nose up)
- pedal_doublet: pedal +A for D, then -A for D (full pedal demands the law's largest sideslip)
- nose_up, nose_down: longitudinal stick |A| pulled or pushed for D, then released
- fpa_change: flight-path-angle target ``fpa_rad`` for D, then level again
- heading_change: heading target moved by ``heading_change_rad`` from ``t_start_s`` on
- speed_change: autothrust target moved by ``delta_vcas_m_s`` from ``t_start_s`` on (ramped)
- coordinated_turn: bank target ``bank_rad`` for D, then wings level; the rudder coordinates

A closed-loop input is held within its box; ramps of ``ramp_s`` lead in and out.

Which families a batch contains is static (``kinds``): only their profiles are computed.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.compute import once
from mcfdd.plant.choices import MANOEUVRE_KINDS as KINDS, OPEN_LOOP_KINDS

KIND_CODE = {name: code for code, name in enumerate(KINDS)}
OPEN_LOOP = frozenset(KIND_CODE[k] for k in OPEN_LOOP_KINDS)
_MULTISINE_TONES = 5
_MULTISINE_PEAK = 2.5  # the unit-amplitude Schroeder sum peaks at 2.0-2.4 over the usual bands


class ManoeuvreParams(NamedTuple):
    kind: int = 0
    amplitude: float = 0.0
    t_start_s: float = 5.0
    duration_s: float = 2.0
    hold_s: float = 2.0
    ramp_s: float = 0.3
    freq_lo_hz: float = 0.1
    freq_hi_hz: float = 2.0
    sideslip_rad: float = 0.0
    fpa_rad: float = 0.0
    heading_change_rad: float = 0.0
    bank_rad: float = 0.0
    delta_vcas_m_s: float = 0.0


class ManoeuvreInputs(NamedTuple):
    """Pilot inputs at one time: stick in [-1, 1], sideslip (rad), open-loop command (fraction).

    The full aircraft also reads the longitudinal stick and pedal in [-1, 1], the flight-path
    angle target (rad), the heading-target change (rad, with its mode flag), the bank target (rad,
    with its mode flag) and the change of the speed target (m/s).
    """

    stick: jnp.ndarray
    sideslip_rad: jnp.ndarray
    command: jnp.ndarray
    open_loop: jnp.ndarray
    pitch_stick: jnp.ndarray = 0.0
    pedal: jnp.ndarray = 0.0
    fpa_rad: jnp.ndarray = 0.0
    heading_change_rad: jnp.ndarray = 0.0
    heading_mode: jnp.ndarray = False
    bank_rad: jnp.ndarray = 0.0
    bank_mode: jnp.ndarray = False
    delta_vcas_m_s: jnp.ndarray = 0.0


def _box(t, start, end, ramp):
    """1 on [start + ramp, end - ramp], linear ramps, 0 outside."""
    return jnp.clip(jnp.minimum(t - start, end - t) / ramp, 0.0, 1.0)


def _profile(code: int, m: ManoeuvreParams, t):
    d, h, r = m.duration_s, m.hold_s, jnp.maximum(m.ramp_s, 1e-3)
    name = KINDS[code]
    if name in ("quiet", "sideslip", "level_flight", "heading_change", "speed_change"):
        return jnp.zeros_like(t)
    if name in ("doublet", "ol_doublet", "pitch_doublet", "pedal_doublet"):
        return m.amplitude * (_box(t, 0.0, d, r) - _box(t, d, 2.0 * d, r))
    if name == "bank_to_bank":
        return m.amplitude * (_box(t, 0.0, d, r) - _box(t, d + h, 3.0 * d + h, r)
                              + _box(t, 3.0 * d + 2.0 * h, 4.0 * d + 2.0 * h, r))
    if name in ("roll_protection", "ol_step"):
        return m.amplitude * _box(t, 0.0, d, r)
    if name in ("nose_up", "nose_down"):
        return (1.0 if name == "nose_up" else -1.0) * jnp.abs(m.amplitude) * _box(t, 0.0, d, r)
    if name == "fpa_change":
        return m.fpa_rad * _box(t, 0.0, d, r)
    if name == "coordinated_turn":
        return m.bank_rad * _box(t, 0.0, d, r)
    tc = jnp.clip(t, 0.0, d)
    window = _box(t, 0.0, d, r)
    if name == "ol_sweep":
        phase = m.freq_lo_hz * tc + (m.freq_hi_hz - m.freq_lo_hz) * tc**2 / (2.0 * d)
        return m.amplitude * window * jnp.sin(2.0 * math.pi * phase)
    total = jnp.zeros_like(t)
    ratio = m.freq_hi_hz / m.freq_lo_hz
    for k in range(_MULTISINE_TONES):
        f = m.freq_lo_hz * ratio ** (k / (_MULTISINE_TONES - 1))
        total = total + jnp.sin(2.0 * math.pi * f * tc - math.pi * k * (k + 1) / _MULTISINE_TONES)
    return m.amplitude * window * jnp.clip(total / _MULTISINE_PEAK, -1.0, 1.0)


def inputs(m: ManoeuvreParams, t_s, kinds: tuple[int, ...], one=None) -> ManoeuvreInputs:
    """Pilot inputs at time ``t_s`` for a manoeuvre whose family is one of the static ``kinds``.

    With ``one`` (:func:`mcfdd.compute.once`) the profile, which every channel reads, is computed once.
    """
    t = t_s - m.t_start_s
    value = jnp.zeros_like(jnp.asarray(t, dtype=jnp.result_type(float)))
    for code in kinds:
        value = jnp.where(m.kind == code, _profile(code, m, t), value)
    if one is not None:
        value = once(value, one)
    open_loop = jnp.zeros_like(value, dtype=bool)
    for code in OPEN_LOOP & set(kinds):
        open_loop = open_loop | (m.kind == code)
    sideslip = jnp.zeros_like(value)
    if KIND_CODE["sideslip"] in kinds:
        ramp = jnp.maximum(m.ramp_s, 1e-3)
        d = m.duration_s
        profile = _box(t, 0.0, d, ramp) - _box(t, d + m.hold_s, 2.0 * d + m.hold_s, ramp)
        sideslip = jnp.where(m.kind == KIND_CODE["sideslip"], m.sideslip_rad * profile, 0.0)
    channels = {}
    for channel, families in (("stick", ("doublet", "bank_to_bank", "roll_protection")),
                              ("pitch_stick", ("pitch_doublet", "nose_up", "nose_down")),
                              ("pedal", ("pedal_doublet",)), ("fpa_rad", ("fpa_change",)),
                              ("bank_rad", ("coordinated_turn",))):
        mine = jnp.zeros_like(value, dtype=bool)
        for code in {KIND_CODE[f] for f in families} & set(kinds):
            mine = mine | (m.kind == code)
        channels[channel] = jnp.where(mine, value, 0.0)

    def mode(name):
        if KIND_CODE[name] not in kinds:
            return jnp.zeros_like(value, dtype=bool)
        return (t >= 0.0) & (m.kind == KIND_CODE[name])

    heading_mode, bank_mode = mode("heading_change"), mode("coordinated_turn")
    speed = jnp.zeros_like(value)
    if KIND_CODE["speed_change"] in kinds:
        ramp = jnp.maximum(m.ramp_s, 1e-3)
        speed = jnp.where(m.kind == KIND_CODE["speed_change"], m.delta_vcas_m_s * jnp.clip(t / ramp, 0.0, 1.0), 0.0)
    return ManoeuvreInputs(channels["stick"], sideslip, jnp.where(open_loop, value, 0.0), open_loop,
                           pitch_stick=channels["pitch_stick"], pedal=channels["pedal"], fpa_rad=channels["fpa_rad"],
                           heading_change_rad=jnp.where(heading_mode, m.heading_change_rad, 0.0),
                           heading_mode=heading_mode, bank_rad=channels["bank_rad"], bank_mode=bank_mode,
                           delta_vcas_m_s=speed)

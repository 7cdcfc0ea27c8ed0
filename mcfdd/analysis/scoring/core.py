"""Scoring monitors: the windows every definition shares, the monitor contract and its chain (DESIGN.md 5, 5a).

Every outcome of a run (DESIGN.md section 5) is produced by a :class:`Monitor`, a triple of pure
functions in the style of optax's ``GradientTransformation``:

- ``init(dtype) -> state``: the running reduction before the first sample;
- ``update(state, windows, sample) -> state``: one sample folded in, given the :class:`Windows` of
  that sample and the :class:`Sample` (plant and FDD outputs);
- ``finalize(state, end) -> columns``: the run's table columns (name -> array), given the
  :class:`Windows` of the end of the run (``end``: every open stall event closes there, and
  ``end.ok`` says whether the run's numbers stayed finite).

Settings and truth of the scenario (and, where a margin needs it, the FDD's threshold) are closed
over when a monitor is built, as optax closes over its hyperparameters: monitors are built inside
the traced per-scenario function, so they may be traced numbers. :func:`named_chain` composes
monitors into one (optax's ``named_chain``): its state is a dict of the members' states and its
columns the union of theirs (a name given twice is an error).

The windows the definitions share are computed once per sample (:func:`windows`) from the plant's
stall truth, the scenario's fault onset and the FDD's excitation, and passed to every monitor:

- settled: t >= ``settle_s``; before_fault: t < onset;
- stall events: the intervals where the plant's stall flag is set; ``opening`` at the first sample
  of one, ``closing`` at the first sample after it (or at the end of the run), ``relevant`` where the
  closing event lasted ``stall_min_duration_s`` and its tracking error reached ``stall_min_error_m``,
  ``in_stall_window`` within ``stall_window_s`` of the onset of the event under way;
- clear: no stall load and more than ``stall_grace_s`` since the last one ended;
- quiet: settled, before the fault and clear (where a decision is a false alarm);
- in_window: the detection window ``[t_f, t_f + t_detec]``;
- excited and the ratios theta_i / ||u|| of the FDD.

The windows' own small state (:class:`Events`: the stall event under way, the last sample's
monitored signals for the run's status) is carried beside the monitors'.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.compute import ONE, once
from mcfdd.fdd.system import FddOutputs
from mcfdd.plant.signals import PlantOutputs


class Settings(NamedTuple):
    """Evaluation settings (traced; times in s, error in m)."""

    settle_s: float
    t_detec_s: float
    stall_grace_s: float
    stall_min_duration_s: float
    stall_min_error_m: float
    stall_window_s: float
    one: float = ONE  # a runtime 1.0 for :func:`mcfdd.compute.once`


class Truth(NamedTuple):
    """What a scenario's scoring knows of it: fault onset (s, inf without a fault), the acceptable
    identifications (N,) and the nearest model (0 fault-free, -1 a non-parametric fault)."""

    onset_s: jnp.ndarray
    accept: jnp.ndarray
    nearest: jnp.ndarray


class Sample(NamedTuple):
    """One sample of a run: plant outputs (the truth) and FDD outputs."""

    plant: PlantOutputs
    fdd: FddOutputs


class Windows(NamedTuple):
    """The windows of one sample (booleans unless noted), shared by every monitor."""

    t: jnp.ndarray  # time of the sample (s)
    settled: jnp.ndarray
    before_fault: jnp.ndarray
    stall: jnp.ndarray  # a stall load under way (the plant's flag)
    opening: jnp.ndarray
    closing: jnp.ndarray
    relevant: jnp.ndarray  # the event closing here is relevant
    event_start: jnp.ndarray  # onset of the event under way or last closed (s; inf before the first)
    in_stall_window: jnp.ndarray
    clear: jnp.ndarray
    quiet: jnp.ndarray
    in_window: jnp.ndarray
    excited: jnp.ndarray
    ratio: jnp.ndarray  # (N,) theta_i / ||u||
    ok: jnp.ndarray | None  # at the end of the run (None at a sample): every sample's numbers finite


class Events(NamedTuple):
    """State of the windows: the stall event under way and the monitored signals of the last sample."""

    in_event: jnp.ndarray
    start: jnp.ndarray
    max_error: jnp.ndarray
    last_end: jnp.ndarray
    monitored: tuple  # (u, theta_stall, theta (N,)) of the last sample


def events_init(dtype, n_models: int) -> Events:
    inf = jnp.asarray(jnp.inf, dtype)
    zero = jnp.zeros((), dtype)
    return Events(jnp.asarray(False), inf, zero, -inf, (zero, zero, jnp.zeros(n_models, dtype)))


def _relevant(s: Settings, events: Events, t, closing):
    """The event under way closes at t and lasted long enough with a large enough tracking error."""
    long_enough = t - events.start >= s.stall_min_duration_s
    return once(closing & long_enough & (events.max_error >= s.stall_min_error_m), s.one)


def windows(s: Settings, truth: Truth, events: Events, t, plant: PlantOutputs, fdd: FddOutputs):
    """The windows of the sample at time t. Returns (new events state, :class:`Windows`)."""
    stall_now = plant.stall
    closing = events.in_event & ~stall_now
    relevant = _relevant(s, events, t, closing)
    last_end = jnp.where(closing, t, events.last_end)
    opening = stall_now & ~events.in_event
    error = jnp.abs(plant.u_c_m - plant.x_m)
    start = jnp.where(opening, t, events.start)
    max_error = jnp.where(opening, error, jnp.maximum(events.max_error, jnp.where(stall_now, error, 0.0)))
    settled = t >= s.settle_s
    clear = once(~stall_now & (t - last_end > s.stall_grace_s), s.one)
    before_fault = t < truth.onset_s
    w = Windows(
        t=t, settled=settled, before_fault=before_fault, stall=stall_now, opening=opening, closing=closing,
        relevant=relevant, event_start=start, in_stall_window=stall_now & (t - start <= s.stall_window_s),
        clear=clear, quiet=once(settled & before_fault & clear, s.one),
        in_window=once((t >= truth.onset_s) & (t <= truth.onset_s + s.t_detec_s), s.one),
        excited=fdd.excited, ratio=fdd.ratio, ok=None)
    return Events(stall_now, start, max_error, last_end, (plant.u_m, fdd.theta_stall, fdd.theta)), w


def end_windows(s: Settings, events: Events, t_end) -> Windows:
    """The windows of the end of a run at t_end: the event under way closes; no sample is scored.

    ``ok``: the measured position and the detectors' theta stayed finite at every sample. It is
    decided on the last sample: a non-finite measurement makes the residuals non-finite (a gated
    filter restarts from the measurement, which does not help), and a non-finite residual stays in
    the Narendra evaluators' integrators for good (eq. 14 forgets by a factor and never restarts;
    0 times inf is nan), so every theta after it is non-finite too (tested).
    """
    false = jnp.asarray(False)
    u, theta_stall, theta = events.monitored
    return Windows(t=t_end, settled=false, before_fault=false, stall=false, opening=false, closing=events.in_event,
                   relevant=_relevant(s, events, t_end, events.in_event), event_start=events.start,
                   in_stall_window=false, clear=false, quiet=false, in_window=false, excited=false,
                   ratio=jnp.zeros(()),
                   ok=jnp.isfinite(u) & jnp.isfinite(theta_stall) & jnp.all(jnp.isfinite(theta)))


class Monitor(NamedTuple):
    """A scoring monitor: ``init(dtype)``, ``update(state, windows, sample)``, ``finalize(state, end)``."""

    init: Callable
    update: Callable
    finalize: Callable


def named_chain(*named: tuple[str, Monitor]) -> Monitor:
    """The monitors run side by side: state {name: state}, columns the union of theirs."""
    def init(dtype):
        return {name: m.init(dtype) for name, m in named}

    def update(state, w: Windows, sample: Sample):
        return {name: m.update(state[name], w, sample) for name, m in named}

    def finalize(state, end: Windows) -> dict:
        columns = {}
        for name, m in named:
            part = m.finalize(state[name], end)
            twice = set(part) & set(columns)
            if twice:
                raise ValueError(f"monitor {name!r} gives columns already given: {', '.join(sorted(twice))}")
            columns.update(part)
        return columns

    return Monitor(init, update, finalize)


def first(time, now, t):
    """The first time ``now`` held: ``time`` if already set, else t where ``now`` (t only increases)."""
    return jnp.minimum(time, jnp.where(now, t, jnp.inf))


def extend(bounds, value):
    """(min, max) widened to include ``value``."""
    return jnp.stack([jnp.minimum(bounds[0], value), jnp.maximum(bounds[1], value)])


def finite_or_nan(x):
    """``x`` where finite, nan elsewhere (a statistic of no sample)."""
    return jnp.where(jnp.isfinite(x), x, jnp.nan)


def void(ok, x):
    """A margin of a run whose numbers stayed finite; nan for a void run."""
    return jnp.where(ok, x, jnp.nan)


def tiny(x):
    """The smallest positive normal number of x's dtype: where a margin's sign is forced, its magnitude."""
    return jnp.finfo(jnp.result_type(x)).tiny


def signed(flag, margin):
    """``margin`` with the sign of ``flag`` (positive where set, negative elsewhere): where the two
    disagree, which happens only within rounding of zero, the smallest normal number of that sign."""
    return jnp.where(flag, jnp.maximum(margin, tiny(margin)), jnp.minimum(margin, -tiny(margin)))

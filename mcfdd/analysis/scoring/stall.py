"""Stall monitors: the detector outside stall loads, stall events and latencies, false identifications, jams.

Stall events are the plant's own truth (the windows' ``opening``/``closing``, DESIGN.md section
5); an event is relevant if it lasts ``stall_min_duration_s`` and its tracking error reaches
``stall_min_error_m``.

- :func:`detector`: the stall detector's largest theta at the quiet samples, less the evaluator's
  memory of stall loads (its false-alarm bound, eq. 26), and ``stall_false_detection``: that
  reached tau there; the margin is theta over tau, relative, ``(max theta - tau) / tau`` (at a tie
  the smallest positive number). The memory of stall loads: the Narendra evaluator (14) is linear
  in |r|, so theta splits exactly into the part driven by the residual of the samples outside
  stall loads and their grace time and the part driven by the residual within them, which decays
  at gamma (the paper's 0.1 1/s: a 10-s memory) after the stall ends. That second part is the
  detection of a stall that happened (eq. 27's side), not a false alarm: a fault-free run in the
  sense of eq. (26) has no stall load, and after a transient one the detector is back in
  fault-free operation only for what the stall no longer drives. So the exclusion after a stall
  lasts exactly until the evaluator has forgotten it, for that part alone; a new residual after
  the grace time counts in full. (With the grace time alone, the stall detector's tau_f on
  ``configs/worst_case_stall.toml`` was the memory of a 9-s stall half a second after it: 34 deg
  against tau = 1 deg.) The detector's own iota = 1 carried by that memory is the stall's
  indication held on; identification (eta, :func:`false_identification`) is scored on the FDD's
  own eta, with the grace time.
- :func:`events`: relevant events counted, those identified by each method (eta = 1 while the
  event lasts) and the worst latency (first eta = 1 minus onset) of each; per relevant event the
  peak theta within ``stall_window_s`` of the onset, its smallest value over the run (the
  detection bound, eq. 27, read as "detected within the window"); ``stall_missed_detection``: a
  relevant event whose peak stayed below tau (the detector missed it), margin ``(tau - least
  peak) / tau``; ``stall_missed_<method>``: a relevant event the method did not identify within
  the window.
- :func:`false_identification` (per method): eta = 1 outside stall loads, after the settling time,
  before any fault (``eta_false_<method>``, first time). Not counted within ``stall_grace_s`` after
  an event, nor just before one begins: a sample with eta = 1 is held pending for the grace time
  and dropped if an event opens meanwhile (the plant flags a stall once the pressure has all but
  vanished, shortly after the rod slowed down). The margin (``eta_false_<method>_margin``) is the
  largest over the quiet samples of the FDD's signed eta margin (:class:`mcfdd.fdd.system.FddOutputs`:
  the least of the detector's theta over tau, the gate (34)-(35) and rule (33) or Q_sl's theta_sl
  under its tau, each relative to its threshold; its sign is eta's), signed by the verdict:
  positive exactly for a false identification. Below zero it says how near the rules
  came; a run whose only eta = 1 outside stall loads was explained by a stall onset within the
  grace time scores just below zero (a later onset would have made it count).
- :func:`jams`: the first eta = 1 (either method) on a jammed rod, a jam taken for a stall.

Margins are signed by their verdict (:func:`mcfdd.analysis.scoring.core.signed`: where a margin and
its verdict disagree, only within rounding of zero, the smallest normal number of the verdict's
sign) and nan for a void run. With a temperature the monitors also give smooth versions
(``smooth_log_*`` of the theta statistics, ``*_margin_smooth`` of the margins, signed the same
way), which tend to the hard ones as T -> 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.analysis.scoring import smooth
from mcfdd.analysis.scoring.core import Monitor, Sample, Settings, Truth, Windows, finite_or_nan, first, signed, void
from mcfdd.fdd import decision, evaluator

METHODS = ("signal", "model")


class Detector(NamedTuple):
    theta_max_free: jnp.ndarray
    memory: jnp.ndarray  # the evaluator's xi driven by the residual within stall loads and their grace
    soft: smooth.SoftMax | None


def detector(s: Settings, truth: Truth, tau, evaluation: evaluator.NarendraParams, dt_s: float,
             temperature=None) -> Monitor:
    """The stall detector at the quiet samples, less its memory of stall loads; ``tau`` its threshold (rod
    units), ``evaluation`` its evaluator (14), stepped at the FDD's sample time ``dt_s`` (its decay the FDD's own,
    computed once per step)."""
    def init(dtype):
        return Detector(jnp.asarray(-jnp.inf, dtype), jnp.zeros((), dtype),
                        None if temperature is None else smooth.softmax_init(dtype))

    def update(state: Detector, w: Windows, sample: Sample) -> Detector:
        # the same step as the FDD's evaluator, on the residual of the excluded samples only; at a clear
        # sample its theta is the memory before the sample (its input is 0 there)
        memory, remembered = evaluator.step(evaluation, state.memory, jnp.where(w.clear, 0.0, sample.fdd.r_stall),
                                            dt_s)
        theta = sample.fdd.theta_stall - remembered
        soft = state.soft
        if soft is not None:
            soft = smooth.softmax_step(temperature, soft, smooth.log_stat(theta), w.quiet)
        return Detector(jnp.where(w.quiet, jnp.maximum(state.theta_max_free, theta), state.theta_max_free), memory,
                        soft)

    def finalize(state: Detector, end: Windows) -> dict:
        fired = end.ok & (state.theta_max_free >= tau)
        columns = {"stall_theta_max_free": finite_or_nan(state.theta_max_free), "stall_false_detection": fired,
                   "stall_false_detection_margin": void(end.ok, signed(fired, decision.relative(state.theta_max_free,
                                                                                                tau)))}
        if state.soft is not None:
            log_max = smooth.softmax_value(temperature, state.soft)
            columns["smooth_log_stall_theta_max_free"] = log_max
            columns["stall_false_detection_margin_smooth"] = void(end.ok, signed(fired, jnp.where(
                log_max > -jnp.inf, decision.relative(jnp.exp(log_max), tau), -jnp.inf)))
        return columns

    return Monitor(init, update, finalize)


class Events(NamedTuple):
    theta_peak: jnp.ndarray  # of the event under way
    eta: jnp.ndarray  # (2,) first eta = 1 of each method in the event under way
    n_events: jnp.ndarray
    identified: jnp.ndarray  # (2,) relevant events identified by each method
    worst_latency: jnp.ndarray  # (2,)
    peak_min: jnp.ndarray
    soft: tuple | None  # (event under way, minimum over events) smooth maxima of log theta and of minus the peaks


def events(s: Settings, truth: Truth, tau, temperature=None) -> Monitor:
    """Relevant stall events, their identification by both methods and the detector's peaks."""
    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        zero = jnp.zeros(len(METHODS), jnp.int32)
        soft = None if temperature is None else (smooth.softmax_init(dtype), smooth.softmax_init(dtype))
        return Events(-inf, jnp.full(len(METHODS), inf), jnp.asarray(0, jnp.int32), zero, jnp.full(len(METHODS), -inf),
                      inf, soft)

    def close(state: Events, w: Windows) -> Events:
        """Book the event closing at w (if it is relevant)."""
        relevant = w.relevant
        found = relevant & jnp.isfinite(state.eta)
        soft = state.soft
        if soft is not None:
            soft = (soft[0], smooth.softmax_step(temperature, soft[1], -smooth.softmax_value(temperature, soft[0]),
                                                 relevant))
        return state._replace(
            n_events=state.n_events + relevant.astype(jnp.int32), identified=state.identified + found.astype(jnp.int32),
            worst_latency=jnp.where(found, jnp.maximum(state.worst_latency, state.eta - w.event_start),
                                    state.worst_latency),
            peak_min=jnp.where(relevant, jnp.minimum(state.peak_min, state.theta_peak), state.peak_min), soft=soft)

    def update(state: Events, w: Windows, sample: Sample) -> Events:
        fdd = sample.fdd
        state = close(state, w)
        theta = fdd.theta_stall
        soft = state.soft
        if soft is not None:
            soft = (smooth.softmax_step(temperature, smooth.reset(soft[0], w.opening), smooth.log_stat(theta),
                                        w.in_stall_window), soft[1])
        eta = jnp.where(w.opening, jnp.inf, state.eta)
        return state._replace(
            theta_peak=jnp.where(w.opening, theta, jnp.where(w.in_stall_window, jnp.maximum(state.theta_peak, theta),
                                                             state.theta_peak)),
            eta=first(eta, w.stall & jnp.stack([fdd.eta_signal, fdd.eta_model]), w.t), soft=soft)

    def finalize(state: Events, end: Windows) -> dict:
        state = close(state, end)
        missed = end.ok & (state.peak_min < tau)
        late = (state.worst_latency > s.stall_window_s) | (state.identified < state.n_events)
        columns = {"stall_events": state.n_events, "stall_seen": jnp.isfinite(end.event_start),
                   "stall_theta_peak_min": finite_or_nan(state.peak_min), "stall_missed_detection": missed,
                   "stall_missed_detection_margin": void(end.ok, signed(missed, decision.below(state.peak_min, tau)))}
        for i, method in enumerate(METHODS):
            columns[f"stall_identified_{method}"] = state.identified[i]
            columns[f"stall_worst_latency_{method}_s"] = finite_or_nan(state.worst_latency[i])
            columns[f"stall_missed_{method}"] = end.ok & late[i]
        if state.soft is not None:
            log_min = -smooth.softmax_value(temperature, state.soft[1])
            columns["smooth_log_stall_theta_peak_min"] = log_min
            columns["stall_missed_detection_margin_smooth"] = void(end.ok, signed(missed, decision.below(
                jnp.exp(log_min), tau)))
        return columns

    return Monitor(init, update, finalize)


class FalseIdentification(NamedTuple):
    found: jnp.ndarray  # first counted eta = 1 outside stall loads
    pending: jnp.ndarray  # first eta = 1 of the pending interval (inf: none)
    quiet_max: jnp.ndarray  # largest margin at the quiet samples
    soft: smooth.SoftMax | None  # its smooth version


def false_identification(s: Settings, truth: Truth, method: str, temperature=None) -> Monitor:
    """eta = 1 of ``method`` ('signal' or 'model') outside stall loads: a false stall identification."""
    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        return FalseIdentification(inf, inf, -inf, None if temperature is None else smooth.softmax_init(dtype))

    def update(state: FalseIdentification, w: Windows, sample: Sample) -> FalseIdentification:
        eta = getattr(sample.fdd, f"eta_{method}")
        margin = getattr(sample.fdd, f"eta_{method}_margin")
        outside = w.settled & w.clear & eta
        # pending is a time or inf, so "explained" (a stall opens within the grace time) and "expired"
        # (the grace time is over) are disjoint, and an opening drops a pending time either way
        expired = w.t - state.pending > s.stall_grace_s
        pending = jnp.where(expired | w.opening, jnp.inf, state.pending)
        soft = state.soft
        if soft is not None:
            soft = smooth.softmax_step(temperature, soft, margin, w.quiet)
        return FalseIdentification(
            jnp.minimum(state.found, jnp.where(expired, state.pending, jnp.inf)),
            jnp.where(outside & (pending == jnp.inf), w.t, pending),
            jnp.where(w.quiet, jnp.maximum(state.quiet_max, margin), state.quiet_max), soft)

    def finalize(state: FalseIdentification, end: Windows) -> dict:
        found = jnp.minimum(state.found, state.pending)
        flag = end.ok & (found < truth.onset_s)
        columns = {f"eta_false_{method}": flag, f"eta_false_{method}_time_s": finite_or_nan(found),
                   f"eta_false_{method}_margin": void(end.ok, signed(flag, state.quiet_max))}
        if state.soft is not None:
            columns[f"eta_false_{method}_margin_smooth"] = void(end.ok, signed(flag, smooth.softmax_value(temperature,
                                                                                                          state.soft)))
        return columns

    return Monitor(init, update, finalize)


def jams(s: Settings, truth: Truth) -> Monitor:
    """The first eta = 1 of either method on a jammed rod."""
    def init(dtype):
        return jnp.asarray(jnp.inf, dtype)

    def update(jam_time, w: Windows, sample: Sample):
        return first(jam_time, sample.plant.jammed & (sample.fdd.eta_signal | sample.fdd.eta_model), w.t)

    def finalize(jam_time, end: Windows) -> dict:
        return {"jam_taken_for_stall": end.ok & jnp.isfinite(jam_time),
                "jam_taken_for_stall_time_s": finite_or_nan(jam_time)}

    return Monitor(init, update, finalize)

"""LOE monitors: detection, identification and the ratio statistics of eqs. (26)-(27) (DESIGN.md 5, 5a).

Two levels, as an FDD engineer reads them (DESIGN.md section 5).

:func:`detection`, the detection level ("an LOE fault is present": the fault-free model rejected,
confirmed; the FDD's ``fault_detected``):

- ``false_alarm`` (and ``false_alarm_time_s``, its first time): a detection at a quiet sample
  (settled, before any fault, clear of stall loads and their grace);
- ``detected``, ``detection_time_s``: the first detection within the detection window
  ``[t_f, t_f + t_detec]``; ``must_detect``: a faulty run whose nearest model is a fault model;
  ``missed``: such a run not detected;
- ``false_alarm_margin``: the largest over the quiet samples of the FDD's signed statistic of the
  confirmed rejection (:func:`mcfdd.fdd.decision.confirmed_margin`, in units of theta_0 / ||u||),
  signed by the verdict (where the statistic and the verdict disagree, only within rounding of
  zero, the smallest normal number of the verdict's sign): positive exactly for a false alarm. At a
  sample that rejects, the statistic is the smaller of the least rejection margin over the current
  run of rejecting samples and the run's shortfall against the confirmation time as a fraction of
  it, times ``detection_tau``; at a sample that does not, its own rejection margin less a whole
  confirmation's shortfall. The rejection margin is the least of ``theta_0 / ||u|| - tau_d``,
  ``contrast - c_d`` and the excitation over its floor and the time since a stall identification
  over the hold, each relative and times tau_d (:func:`mcfdd.fdd.system.rejection_margin`). So
  below zero the margin says how far the run came: a rejection held for 60 % of the confirmation
  time scores -0.4 tau_d, a run whose best sample fell 0.01 short of tau_d about -(0.01 + tau_d).
- ``missed_margin``: minus the largest statistic over the detection window, signed by the verdict,
  for runs that must be detected (nan elsewhere): positive exactly for a missed detection.

:func:`identification`, the identification level (the decoded signature (15), confirmed): the
first fault model identified before any fault (a ``false_identification`` in fault-free runs) or
within the window, its time, and ``identified_correctly`` (the nearest grid model or one of the
two that bracket the fault); ``identification_false_alarm``, the level's false alarm as
``false_alarm`` is detection's: a fault model identified at a quiet sample of any run.

:func:`ratios`: per filter i the largest theta_i / ||u|| at the excited quiet samples and the
smallest within the window, the fault-free filter's largest ratio within the window (detection
level, eq. 27) and, over the window, the peak of the smallest ratio among the filters that must
fire (those not accepted for the true fault; identification level, eq. 27).

Margins are nan for a void run (its numbers went non-finite). With a temperature T the monitors
also give the smooth versions (``*_smooth``: the maximum over samples replaced by the log-sum-exp
at T, :mod:`mcfdd.analysis.scoring.smooth`, signed by the verdict as the hard margin is; the
statistics of :func:`ratios` on their logarithm, ``smooth_log_*``), which tend to the hard ones as
T -> 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.analysis.scoring import smooth
from mcfdd.analysis.scoring.core import Monitor, Sample, Settings, Truth, Windows, finite_or_nan, first, signed, void
from mcfdd.compute import once
from mcfdd.fdd import decision


class Detection(NamedTuple):
    fa_time: jnp.ndarray
    det_time: jnp.ndarray
    fa_margin: jnp.ndarray  # largest confirmed-rejection statistic at the quiet samples
    det_margin: jnp.ndarray  # ... within the detection window
    soft: tuple | None  # (quiet, window) smooth maxima of the statistic, with a temperature


def detection(s: Settings, truth: Truth, temperature=None) -> Monitor:
    """The detection level: false alarm, detection, missed detection and their margins."""
    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        soft = None if temperature is None else (smooth.softmax_init(dtype), smooth.softmax_init(dtype))
        return Detection(inf, inf, -inf, -inf, soft)

    def update(state: Detection, w: Windows, sample: Sample) -> Detection:
        fdd = sample.fdd
        stat = fdd.detection_margin
        soft = state.soft
        if soft is not None:
            soft = (smooth.softmax_step(temperature, soft[0], stat, w.quiet),
                    smooth.softmax_step(temperature, soft[1], stat, w.in_window))
        return Detection(first(state.fa_time, w.quiet & fdd.fault_detected, w.t),
                         first(state.det_time, w.in_window & fdd.fault_detected, w.t),
                         jnp.where(w.quiet, jnp.maximum(state.fa_margin, stat), state.fa_margin),
                         jnp.where(w.in_window, jnp.maximum(state.det_margin, stat), state.det_margin), soft)

    def finalize(state: Detection, end: Windows) -> dict:
        ok = end.ok
        faulty = jnp.isfinite(truth.onset_s)
        must = ok & faulty & (truth.nearest >= 1)
        detected = ok & faulty & jnp.isfinite(state.det_time)
        false_alarm = ok & jnp.isfinite(state.fa_time)
        columns = {
            "false_alarm": false_alarm, "false_alarm_time_s": state.fa_time,
            "detected": detected, "detection_time_s": jnp.where(detected, state.det_time, jnp.nan),
            "must_detect": must, "missed": must & ~detected,
            "false_alarm_margin": void(ok, signed(false_alarm, state.fa_margin)),
            "missed_margin": jnp.where(must, -signed(detected, state.det_margin), jnp.nan),
        }
        if state.soft is not None:
            columns["false_alarm_margin_smooth"] = void(ok, signed(false_alarm, smooth.softmax_value(temperature,
                                                                                                      state.soft[0])))
            columns["missed_margin_smooth"] = jnp.where(must, -signed(detected, smooth.softmax_value(temperature,
                                                                                                       state.soft[1])),
                                                        jnp.nan)
        return columns

    return Monitor(init, update, finalize)


class Identification(NamedTuple):
    fid_time: jnp.ndarray
    fid_model: jnp.ndarray
    id_time: jnp.ndarray
    id_model: jnp.ndarray


def identification(s: Settings, truth: Truth) -> Monitor:
    """The identification level: the first fault model identified, before any fault or in the window."""
    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        none = jnp.asarray(decision.NO_DECISION, jnp.int32)
        return Identification(inf, none, inf, none)

    def update(state: Identification, w: Windows, sample: Sample) -> Identification:
        detected = sample.fdd.detected
        fault_model = detected >= 1
        new_fid = once(w.quiet & fault_model & ~jnp.isfinite(state.fid_time), s.one)
        new_id = once(w.in_window & fault_model & ~jnp.isfinite(state.id_time), s.one)
        return Identification(jnp.where(new_fid, w.t, state.fid_time), jnp.where(new_fid, detected, state.fid_model),
                              jnp.where(new_id, w.t, state.id_time), jnp.where(new_id, detected, state.id_model))

    def finalize(state: Identification, end: Windows) -> dict:
        faulty = jnp.isfinite(truth.onset_s)
        time = jnp.where(faulty, state.id_time, state.fid_time)
        identified = end.ok & jnp.isfinite(time)
        model = jnp.where(identified, jnp.where(faulty, state.id_model, state.fid_model), decision.NO_DECISION)
        accepted = truth.accept[jnp.clip(model, 0, truth.accept.shape[-1] - 1)]
        return {"identified_model": model, "identification_time_s": jnp.where(identified, time, jnp.nan),
                "identified_correctly": identified & faulty & accepted & (model >= 0),
                "false_identification": identified & ~faulty,
                "identification_false_alarm": end.ok & jnp.isfinite(state.fid_time)}

    return Monitor(init, update, finalize)


class Ratios(NamedTuple):
    max_pre: jnp.ndarray  # (N,)
    min_post: jnp.ndarray  # (N,)
    ratio0_max_post: jnp.ndarray
    others_min_peak: jnp.ndarray
    soft: tuple | None  # (free, detect) smooth maxima of the log ratios, with a temperature


def ratios(s: Settings, truth: Truth, temperature=None) -> Monitor:
    """Ratio statistics theta_i / ||u|| of the excited samples, before the fault and in the window."""
    n_models = truth.accept.shape[-1]

    def init(dtype):
        inf = jnp.asarray(jnp.inf, dtype)
        soft = None if temperature is None else (smooth.softmax_init(dtype), smooth.softmax_init(dtype))
        return Ratios(jnp.full(n_models, -inf), jnp.full(n_models, inf), -inf, -inf, soft)

    def update(state: Ratios, w: Windows, sample: Sample) -> Ratios:
        pre = w.quiet & w.excited
        post = w.in_window & w.excited
        ratio = w.ratio
        soft = state.soft
        if soft is not None:
            log_ratio = smooth.log_stat(ratio)
            must_fire = smooth.soft_min(log_ratio, ~truth.accept, temperature)
            soft = (smooth.softmax_step(temperature, soft[0], log_ratio[0], pre),
                    smooth.softmax_step(temperature, soft[1], must_fire, post))
        others_min = jnp.min(jnp.where(truth.accept, jnp.inf, ratio))
        return Ratios(jnp.where(pre, jnp.maximum(state.max_pre, ratio), state.max_pre),
                      jnp.where(post, jnp.minimum(state.min_post, ratio), state.min_post),
                      jnp.where(post, jnp.maximum(state.ratio0_max_post, ratio[0]), state.ratio0_max_post),
                      jnp.where(post, jnp.maximum(state.others_min_peak, others_min), state.others_min_peak), soft)

    def finalize(state: Ratios, end: Windows) -> dict:
        columns = {"loe_ratio0_max_pre": finite_or_nan(state.max_pre[0]),
                   "loe_others_min_peak": finite_or_nan(state.others_min_peak),
                   "loe_ratio0_max_post": finite_or_nan(state.ratio0_max_post),
                   **{f"ratio_max_pre_{i}": state.max_pre[i] for i in range(n_models)},
                   **{f"ratio_min_post_{i}": state.min_post[i] for i in range(n_models)}}
        if state.soft is not None:
            columns["smooth_log_loe_ratio0_max_pre"] = smooth.softmax_value(temperature, state.soft[0])
            columns["smooth_log_loe_others_min_peak"] = smooth.softmax_value(temperature, state.soft[1])
        return columns

    return Monitor(init, update, finalize)

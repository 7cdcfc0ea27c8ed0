"""Batched Monte-Carlo simulation with online reductions (DESIGN.md sections 2 and 5).

Plant and both FDD systems run together in one scan per scenario; the carry holds, besides the
dynamic states, running reductions of what a campaign reports, so memory is O(batch), not
O(batch x steps). Per scenario (definitions of DESIGN.md section 5):

- LOE, two levels. Detection (the fault-free model rejected, confirmed): false alarm (a
  detection after the settling time, before any fault and away from stall loads) with its first
  time; detection time (first detection within [t_f, t_f + t_detec]). Identification (a fault
  model decoded from the signature, confirmed): the first identified fault model and its time,
  before any fault (away from stall loads, after settling) and within the detection window; the
  fault-free filter's largest ratio within the window (its inf over faulty runs is the
  detection bound of eq. 27 for the detection level); per filter i the largest
  ratio theta_i / ||u|| before the fault and the smallest within the detection window (excited
  samples only, where a decision can be made); the fault-free filter's largest ratio (no false
  alarm is possible while it stays below tau) and, over the detection window, the peak of the
  smallest ratio among the filters that must all fire (those not accepted for the true fault).
- Stall loads: events are the intervals where the plant's stall flag is set; an event is
  relevant if it lasts at least ``stall_min_duration_s`` and the tracking error reaches
  ``stall_min_error_m``. Counted: relevant events, identified ones per identification method and
  the worst latency (first eta = 1 minus onset) of each method; eta = 1 outside events (not
  counted within a grace period after an event, nor just before one begins); the stall
  detector's largest theta outside events before any fault (its false-alarm bound, eq. 26) and,
  per relevant event, the peak theta within ``stall_window_s`` of the onset (its smallest value
  over the run feeds the detection bound, eq. 27, read as "detected within the window").
- Plant truth for detectability: the largest hinge-load fraction ``|F_aero| / (nu1 dP S)`` while
  the rod moves (rate at least ``MOVING_RATE_M_S``) and the largest |deflection|, both after the
  fault onset (for fault-free runs over the settled run).
- Jams taken for stalls: the first eta = 1 (either identification method) on a jammed rod.
- flight point: the smallest and largest measured Vcas and altitude of the run (constant on the
  roll axis; the full aircraft's move with its manoeuvre).
- status: a :class:`Status` code (0 ok, 1 if any monitored signal went non-finite: outcomes void).
"""

from __future__ import annotations

import enum
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcfdd.analysis.simulate import scan_steps
from mcfdd.compute import ONE, once
from mcfdd.fdd import decision, system
from mcfdd.plant import closed_loop

class Status(enum.IntEnum):
    """Scenario status code, the ``status`` column of a campaign table; ``.meaning`` says what it means."""

    OK = 0, "the run's numbers stayed finite; its outcomes count"
    NON_FINITE = 1, "a monitored signal went non-finite; the run's outcomes are void and not counted"

    def __new__(cls, code: int, meaning: str):
        member = int.__new__(cls, code)
        member._value_ = code
        member.meaning = meaning
        return member


MOVING_RATE_M_S = 1e-3  # rod rate (about 1.1 deg/s of surface) above which the rod counts as moving


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
    """What a scenario's evaluation needs to know: fault onset and acceptable models (N,)."""

    onset_s: jnp.ndarray
    accept: jnp.ndarray


class Reduction(NamedTuple):
    finite: jnp.ndarray
    fa_time: jnp.ndarray
    det_time: jnp.ndarray
    fid_time: jnp.ndarray
    fid_model: jnp.ndarray
    id_time: jnp.ndarray
    id_model: jnp.ndarray
    ratio0_max_post: jnp.ndarray
    ratio_max_pre: jnp.ndarray
    ratio_min_post: jnp.ndarray
    others_min_peak: jnp.ndarray
    in_event: jnp.ndarray
    event_start: jnp.ndarray
    event_max_error: jnp.ndarray
    event_theta_peak: jnp.ndarray
    event_eta_signal: jnp.ndarray
    event_eta_model: jnp.ndarray
    last_stall_end: jnp.ndarray
    n_events: jnp.ndarray
    n_identified_signal: jnp.ndarray
    n_identified_model: jnp.ndarray
    worst_latency_signal: jnp.ndarray
    worst_latency_model: jnp.ndarray
    theta_peak_min: jnp.ndarray
    eta_outside_signal: jnp.ndarray
    eta_outside_model: jnp.ndarray
    eta_pending_signal: jnp.ndarray
    eta_pending_model: jnp.ndarray
    theta_stall_max_free: jnp.ndarray
    peak_load_fraction: jnp.ndarray
    peak_deflection_rad: jnp.ndarray
    jam_stall_time: jnp.ndarray
    vcas_range: jnp.ndarray  # (min, max), m/s
    altitude_range: jnp.ndarray  # (min, max), m


def reduction_init(n_models: int, dtype) -> Reduction:
    inf = jnp.asarray(jnp.inf, dtype)
    zero_i = jnp.asarray(0, jnp.int32)
    return Reduction(
        finite=jnp.asarray(True), fa_time=inf, det_time=inf, fid_time=inf,
        fid_model=jnp.asarray(decision.NO_DECISION, jnp.int32), id_time=inf,
        id_model=jnp.asarray(decision.NO_DECISION, jnp.int32), ratio0_max_post=-inf,
        ratio_max_pre=jnp.full(n_models, -inf),
        ratio_min_post=jnp.full(n_models, inf), others_min_peak=-inf, in_event=jnp.asarray(False),
        event_start=inf, event_max_error=jnp.zeros((), dtype), event_theta_peak=-inf, event_eta_signal=inf,
        event_eta_model=inf, last_stall_end=-inf, n_events=zero_i, n_identified_signal=zero_i,
        n_identified_model=zero_i, worst_latency_signal=-inf, worst_latency_model=-inf, theta_peak_min=inf,
        eta_outside_signal=inf, eta_outside_model=inf, eta_pending_signal=inf, eta_pending_model=inf,
        theta_stall_max_free=-inf, peak_load_fraction=-inf, peak_deflection_rad=-inf, jam_stall_time=inf,
        vcas_range=jnp.stack([inf, -inf]), altitude_range=jnp.stack([inf, -inf]))


def _close_event(s: Settings, red: Reduction, t_end, closing):
    """Book the current stall event if ``closing`` (its last sample was before ``t_end``)."""
    long_enough = t_end - red.event_start >= s.stall_min_duration_s
    relevant = once(closing & long_enough & (red.event_max_error >= s.stall_min_error_m), s.one)
    found_sig, found_mod = once((relevant & jnp.isfinite(red.event_eta_signal),
                                 relevant & jnp.isfinite(red.event_eta_model)), s.one)
    return red._replace(
        n_events=red.n_events + relevant.astype(jnp.int32),
        n_identified_signal=red.n_identified_signal + found_sig.astype(jnp.int32),
        n_identified_model=red.n_identified_model + found_mod.astype(jnp.int32),
        worst_latency_signal=jnp.where(found_sig, jnp.maximum(red.worst_latency_signal,
                                                              red.event_eta_signal - red.event_start),
                                       red.worst_latency_signal),
        worst_latency_model=jnp.where(found_mod, jnp.maximum(red.worst_latency_model,
                                                             red.event_eta_model - red.event_start),
                                      red.worst_latency_model),
        theta_peak_min=jnp.where(relevant, jnp.minimum(red.theta_peak_min, red.event_theta_peak), red.theta_peak_min),
        last_stall_end=jnp.where(closing, t_end, red.last_stall_end),
        in_event=red.in_event & ~closing,
    )


def _eta_outside(s: Settings, red: Reduction, method: str, outside, opening, t) -> dict:
    """eta = 1 away from stall loads: held as pending for the grace time, dropped if a stall begins.

    The plant flags a stall once the available pressure has all but vanished, shortly after the
    rod has slowed down, so eta = 1 just before an onset is not a false identification.
    """
    pending = getattr(red, f"eta_pending_{method}")
    found = getattr(red, f"eta_outside_{method}")
    # pending is a time or inf, so "explained" (a stall opens within the grace time) and "expired"
    # (the grace time is over) are disjoint, and an opening drops a pending time either way
    expired = t - pending > s.stall_grace_s
    found = jnp.minimum(found, jnp.where(expired, pending, jnp.inf))
    pending = jnp.where(expired | opening, jnp.inf, pending)
    pending = jnp.where(outside & (pending == jnp.inf), t, pending)
    return {f"eta_outside_{method}": found, f"eta_pending_{method}": pending}


def reduction_step(s: Settings, truth: Truth, red: Reduction, t, plant: closed_loop.PlantOutputs,
                   fdd: system.FddOutputs) -> Reduction:
    """Fold one sample into the running reductions."""
    stall_now = plant.stall
    red = _close_event(s, red, t, once(red.in_event & ~stall_now, s.one))
    opening = once(stall_now & ~red.in_event, s.one)
    error = jnp.abs(plant.u_c_m - plant.x_m)
    red = red._replace(
        in_event=stall_now,  # = in_event & ~closing | opening
        event_start=jnp.where(opening, t, red.event_start),
        event_max_error=jnp.where(opening, error, jnp.maximum(red.event_max_error, jnp.where(stall_now, error, 0.0))),
        event_theta_peak=jnp.where(opening, fdd.theta_stall, jnp.where(
            stall_now & (t - red.event_start <= s.stall_window_s), jnp.maximum(red.event_theta_peak, fdd.theta_stall),
            red.event_theta_peak)),
        event_eta_signal=jnp.where(opening, jnp.inf, red.event_eta_signal),
        event_eta_model=jnp.where(opening, jnp.inf, red.event_eta_model),
    )
    red = red._replace(
        event_eta_signal=_first(red.event_eta_signal, stall_now & fdd.eta_signal, t),
        event_eta_model=_first(red.event_eta_model, stall_now & fdd.eta_model, t),
    )
    settled = t >= s.settle_s
    clear_of_stall = once(~stall_now & (t - red.last_stall_end > s.stall_grace_s), s.one)
    before_fault = t < truth.onset_s
    quiet = once(settled & before_fault & clear_of_stall, s.one)
    in_window = once((t >= truth.onset_s) & (t <= truth.onset_s + s.t_detec_s), s.one)
    fault_model = fdd.detected >= 1
    new_fid = once(quiet & fault_model & ~jnp.isfinite(red.fid_time), s.one)
    new_id = once(in_window & fault_model & ~jnp.isfinite(red.id_time), s.one)
    ratio = once(fdd.theta / jnp.where(fdd.excited, fdd.theta_u, 1.0), s.one)
    pre = quiet & fdd.excited
    post = in_window & fdd.excited
    others_min = jnp.min(jnp.where(truth.accept, jnp.inf, ratio))
    finite = jnp.isfinite(plant.u_m) & jnp.isfinite(fdd.theta_stall) & jnp.all(jnp.isfinite(fdd.theta))
    return red._replace(
        finite=red.finite & finite,
        fa_time=_first(red.fa_time, quiet & fdd.fault_detected, t),
        det_time=_first(red.det_time, in_window & fdd.fault_detected, t),
        fid_time=jnp.where(new_fid, t, red.fid_time),
        fid_model=jnp.where(new_fid, fdd.detected, red.fid_model),
        id_time=jnp.where(new_id, t, red.id_time),
        id_model=jnp.where(new_id, fdd.detected, red.id_model),
        ratio0_max_post=jnp.where(post, jnp.maximum(red.ratio0_max_post, ratio[0]), red.ratio0_max_post),
        ratio_max_pre=jnp.where(pre, jnp.maximum(red.ratio_max_pre, ratio), red.ratio_max_pre),
        ratio_min_post=jnp.where(post, jnp.minimum(red.ratio_min_post, ratio), red.ratio_min_post),
        others_min_peak=jnp.where(post, jnp.maximum(red.others_min_peak, others_min), red.others_min_peak),
        **_eta_outside(s, red, "signal", settled & clear_of_stall & fdd.eta_signal, opening, t),
        **_eta_outside(s, red, "model", settled & clear_of_stall & fdd.eta_model, opening, t),
        theta_stall_max_free=jnp.where(quiet, jnp.maximum(red.theta_stall_max_free, fdd.theta_stall),
                                       red.theta_stall_max_free),
        **_truth_peaks(s, truth, red, t, plant, fdd),
        vcas_range=_extend(red.vcas_range, plant.vcas_m_s),
        altitude_range=_extend(red.altitude_range, plant.altitude_m),
    )


def _first(time, now, t):
    """The first time ``now`` held: ``time`` if already set, else t where ``now`` (t only increases)."""
    return jnp.minimum(time, jnp.where(now, t, jnp.inf))


def _extend(bounds, value):
    """(min, max) widened to include ``value``."""
    return jnp.stack([jnp.minimum(bounds[0], value), jnp.maximum(bounds[1], value)])


def _truth_peaks(s: Settings, truth: Truth, red: Reduction, t, plant: closed_loop.PlantOutputs,
                 fdd: system.FddOutputs) -> dict:
    """Peak load fraction (rod moving) and peak |deflection| after the onset; first eta = 1 on a jammed rod."""
    after = jnp.where(jnp.isfinite(truth.onset_s), t >= truth.onset_s, t >= s.settle_s)
    moving = after & (jnp.abs(plant.rate_m_s) >= MOVING_RATE_M_S)
    jam_stall = plant.jammed & (fdd.eta_signal | fdd.eta_model)
    return {
        "peak_load_fraction": jnp.where(moving, jnp.maximum(red.peak_load_fraction, plant.load_fraction),
                                        red.peak_load_fraction),
        "peak_deflection_rad": jnp.where(after, jnp.maximum(red.peak_deflection_rad, jnp.abs(plant.delta_rad)),
                                         red.peak_deflection_rad),
        "jam_stall_time": _first(red.jam_stall_time, jam_stall, t),
    }


def finalize(s: Settings, red: Reduction, t_end) -> dict:
    """Close an event still open at the end of the run; outcomes as a dict of arrays."""
    red = _close_event(s, red, t_end, red.in_event)
    red = red._replace(eta_outside_signal=jnp.minimum(red.eta_outside_signal, red.eta_pending_signal),
                       eta_outside_model=jnp.minimum(red.eta_outside_model, red.eta_pending_model))
    return {
        "status": jnp.where(red.finite, int(Status.OK), int(Status.NON_FINITE)).astype(jnp.int32),
        "false_alarm_time_s": red.fa_time, "detection_time_s": red.det_time,
        "false_identification_time_s": red.fid_time, "false_identification_model": red.fid_model,
        "identification_time_s": red.id_time, "identified_model": red.id_model,
        "ratio0_max_post": red.ratio0_max_post,
        "ratio_max_pre": red.ratio_max_pre, "ratio_min_post": red.ratio_min_post,
        "others_min_peak": red.others_min_peak,
        "stall_events": red.n_events, "stall_identified_signal": red.n_identified_signal,
        "stall_identified_model": red.n_identified_model, "stall_worst_latency_signal_s": red.worst_latency_signal,
        "stall_worst_latency_model_s": red.worst_latency_model, "stall_theta_peak_min": red.theta_peak_min,
        "eta_outside_signal_time_s": red.eta_outside_signal, "eta_outside_model_time_s": red.eta_outside_model,
        "stall_theta_max_free": red.theta_stall_max_free,
        "stall_seen": jnp.isfinite(red.last_stall_end),
        "peak_load_fraction": red.peak_load_fraction, "peak_deflection_deg": jnp.degrees(red.peak_deflection_rad),
        "jam_stall_time_s": red.jam_stall_time,
        "vcas_min_m_s": red.vcas_range[0], "vcas_max_m_s": red.vcas_range[1],
        "altitude_min_m": red.altitude_range[0], "altitude_max_m": red.altitude_range[1],
    }


def init_one(model: closed_loop.PlantModel, fdd_params: system.FddParams, scenario: closed_loop.Scenario, key,
             dt_s: float):
    """Plant parameters and the scan carry (plant, FDD and reduction states) of one scenario at t = 0."""
    params = closed_loop.prepare(model, scenario, dt_s)
    plant_state = closed_loop.init(params, jax.random.normal(key, (3,)))
    zero = jnp.zeros_like(params.qbar_pa)
    fdd_state = system.init(fdd_params, zero)
    return params, (plant_state, fdd_state, reduction_init(fdd_params.loe.bank.k0.shape[0], zero.dtype))


def step_one(params: closed_loop.RunParams, fdd_params: system.FddParams, settings: Settings,
             scenario: closed_loop.Scenario, truth: Truth, carry, k, noise, dt_s: float, substeps: int,
             kinds: tuple[int, ...]):
    """Sample k of one scenario: plant, FDD and reductions. Returns (new carry, plant outputs, FDD outputs)."""
    plant_state, fdd_state, red = carry
    t = k * dt_s
    plant_state, out = closed_loop.step(params, plant_state, t, noise, dt_s, substeps, kinds)
    fdd_state, fo = system.step(fdd_params, fdd_state, out.u_c_m, out.u_m, out.vcas_m_s, out.altitude_m,
                                t, dt_s)
    return (plant_state, fdd_state, reduction_step(settings, truth, red, t, out, fo)), out, fo


def run_one(model: closed_loop.PlantModel, fdd_params: system.FddParams, settings: Settings,
            scenario: closed_loop.Scenario, truth: Truth, key, n_steps: int, dt_s: float, substeps: int,
            kinds: tuple[int, ...]) -> dict:
    """Outcomes of one scenario (no time histories kept)."""
    params, carry = init_one(model, fdd_params, scenario, key, dt_s)

    def body(carry, k, noise):
        return step_one(params, fdd_params, settings, scenario, truth, carry, k, noise, dt_s, substeps, kinds)[0], None

    (_, _, red), _ = scan_steps(body, carry, key, n_steps, closed_loop.NOISE_DIM)
    return finalize(settings, red, n_steps * dt_s)


# XLA CPU options of the campaign program (per function, not global flags): AVX-512-wide vectors
# where the CPU has them, and no YNNPACK library fusions (the step has no dot or reduction large
# enough to gain from them). Measured faster with bit-identical outcomes (benchmarks/RESULTS.md).
XLA_CPU_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": ""}


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"), compiler_options=XLA_CPU_OPTIONS)
def device_batch(model, fdd_params, settings, scenarios, truths, keys, n_steps: int, dt_s: float, substeps: int,
                 kinds: tuple[int, ...]) -> dict:
    """:func:`run_one` over a batch (leading axis of scenarios, truths and keys), one jit, on one device."""
    def one(scenario, truth, key):
        return run_one(model, fdd_params, settings, scenario, truth, key, n_steps, dt_s, substeps, kinds)

    return jax.vmap(one)(scenarios, truths, keys)


def on_devices(fn, *args, batched: tuple[bool, ...], lanes: int | None = None) -> dict:
    """``fn(*args)`` with the arguments marked in ``batched`` split evenly over the devices.

    Each device gets an equal share of the leading axis and runs ``fn`` (a single-device jitted
    function) on it; the other arguments are copied to every device. Dispatch is asynchronous, so
    the devices run at the same time; ``fn`` compiles once for each device it runs on. With
    ``lanes``, the batch goes to as many devices as give each a whole number of ``lanes``
    scenarios (one device if none does); without, a batch that does not divide among all the devices
    runs on the first one. Returns ``fn``'s outputs as NumPy arrays, the shares concatenated in order.

    Every device thus runs the same program as a single device would, whatever the number of
    devices. Splitting inside one jit with ``shard_map`` does not: XLA compiles a program with
    several partitions through its SPMD partitioner, and the optimised per-device program then
    differs from the single-device one in how floating-point constants are folded and
    reassociated (the Dryden pole ``exp(-pi V dt / (4 b))`` is evaluated in another order, for
    one), so results depended on the device count in their last bits.
    """
    devices = jax.devices()
    n = next(jax.tree.leaves(a)[0].shape[0] for a, b in zip(args, batched) if b)
    if lanes is not None:
        devices = devices[:max((d for d in range(1, len(devices) + 1) if n % (d * lanes) == 0), default=1)]
    elif n % len(devices):
        devices = devices[:1]
    size = n // len(devices)

    outs = []
    for i, device in enumerate(devices):
        share = [jax.tree.map(lambda x: x[i * size:(i + 1) * size], a) if b else a for a, b in zip(args, batched)]
        outs.append(fn(*jax.device_put(share, device)))
    return jax.tree.map(lambda *parts: np.concatenate([np.asarray(p) for p in parts]), *outs)


def run_batch(model, fdd_params, settings, scenarios, truths, keys, n_steps: int, dt_s: float, substeps: int,
              kinds: tuple[int, ...], lanes: int | None = None) -> dict:
    """:func:`device_batch` with the batch split over the devices by :func:`on_devices`.

    With several devices (on a CPU: ``--xla_force_host_platform_device_count``) each runs the
    single-device program on its share, so a scenario's numbers are the same to the last bit
    whatever the number of devices, provided no share is a single scenario (XLA then drops the
    batch axis and compiles other code): ``mcfdd campaign`` gives each device a whole number of
    ``lanes`` (``mcfdd.workflows.campaign.LANE_BLOCK``). Returns NumPy arrays, batch axis first.
    """
    return on_devices(partial(device_batch, n_steps=n_steps, dt_s=dt_s, substeps=substeps, kinds=kinds), model,
                      fdd_params, settings, scenarios, truths, keys, batched=(False, False, False, True, True, True),
                      lanes=lanes)

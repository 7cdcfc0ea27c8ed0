"""Decision making: eq. (15) with its normalisation, signature decoding, and eq. (25).

The paper compares theta_i with tau_i ||u|| and leaves ||u|| undefined. Here ||u|| is the same
Narendra evaluator run on the low-passed magnitude of the measured tracking error
``a/(s+a) |u_c - u|``; the residuals are driven by that error: on a first-order plant of gain k_j,
filter i gives ``(k_j - k_i)/k0_i * a/(s+a) (u_c - u)``, so theta_i / ||u|| is the relative gain
mismatch |k_j - k_i| / k0_i at every sample while the error keeps its sign (in transients too: a
model rod's tracking error in its place decays faster than a slower plant's after a manoeuvre,
and the ratio grew on the tail) and at most that otherwise; one tau_m serves all filters. Below
an excitation floor no decision is made: the signature is only meaningful while the rod is
driven; the floor may apply to a load-weighted ||u|| (see
:func:`mcfdd.fdd.system.excitation_weight`).

The floor may also follow the run's own sensor noise (see :func:`noise_step`): ||u|| of a rod at
rest is about 0.8 times the noise RMS, which varies from one position sensor to another.

A decoded model becomes a decision once it has been decoded without interruption for a
confirmation time (the usual confirmation of industrial monitors; 0 s confirms at once), which
keeps short noise-driven signatures from raising alarms.

A confirmed decision also has a signed statistic (:func:`confirmed_margin`), on board like the
decision itself, positive where the decision is confirmed: the scoring's false alarm and missed
detection margins (DESIGN.md section 5a) are its extremes over their windows.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

NO_DECISION = -1
# E|n_k - 2 n_(k-1) + n_(k-2)| / sigma for white Gaussian noise n of RMS sigma: the second
# difference has variance 6 sigma^2 and a half-normal magnitude of mean sqrt(2 / pi) sqrt(6) sigma.
SECOND_DIFFERENCE_MEAN = math.sqrt(12.0 / math.pi)


class NoiseState(NamedTuple):
    """Online estimate of the position sensor's noise (:func:`noise_step`)."""

    previous: jnp.ndarray  # (2,) measured positions of the two samples before (m)
    mean: jnp.ndarray  # exponentially weighted sum of |second difference| (m)
    weight: jnp.ndarray  # the sum of those weights (0 until the first second difference)
    seen: jnp.ndarray  # samples seen, counted up to 2 (a second difference needs two before)


def noise_init(u0) -> NoiseState:
    u0 = jnp.asarray(u0)
    zero = jnp.zeros_like(u0)
    return NoiseState(jnp.stack([u0, u0]), zero, zero, zero)


def noise_step(gamma, state: NoiseState, u, dt_s: float):
    """RMS of the position sensor's noise estimated online from the measured position u (m).

    The second difference ``u_k - 2 u_(k-1) + u_(k-2)`` is a high-pass that removes a held
    position and a constant rate: what is left of the rod is its acceleration times dt^2 (at most
    about 0.2 mm during the few samples in which a slew starts or stops, nothing on a hold or a
    steady slew), while white sensor noise of RMS sigma keeps a mean magnitude of
    ``SECOND_DIFFERENCE_MEAN sigma``. The estimate is that mean over the samples so far, each
    forgotten at ``gamma`` (1/s), normalised by the sum of the weights (so it is unbiased from the
    third sample on, with no start-up transient), divided by ``SECOND_DIFFERENCE_MEAN``. With
    gamma = 0.1 1/s (10 s of memory) a manoeuvre's few rod accelerations move it by about 1 %.
    Returns (new state, estimated RMS in m; 0 before the third sample).
    """
    d2 = u - 2.0 * state.previous[0] + state.previous[1]
    decay = jnp.exp(-gamma * dt_s)
    gain = jnp.where(state.seen >= 2.0, 1.0 - decay, 0.0)
    mean = decay * state.mean + gain * jnp.abs(d2)
    weight = decay * state.weight + gain
    rms = jnp.where(weight > 0.0, mean / jnp.where(weight > 0.0, weight, 1.0), 0.0) / SECOND_DIFFERENCE_MEAN
    return NoiseState(jnp.stack([u, state.previous[0]]), mean, weight, jnp.minimum(state.seen + 1.0, 2.0)), rms


def excitation_init(u0):
    """State of the low-pass in equilibrium (output 0) at measured position u0.

    Also the restart of the low-pass while residual evaluation is suspended (see
    :func:`mcfdd.fdd.system.step`), so that it leaves no transient of a gated interval behind.
    """
    return jnp.zeros_like(jnp.asarray(u0))


def excitation_step(a, state, u_c, u, dt_s: float):
    """Low-passed magnitude of the measured tracking error, ``a/(s+a) |u_c - u|``, exact for the error
    held over the sample. Returns (new state, output).

    Filter i of the bank is driven by the signed error: on a sampled first-order plant of gain
    k_j, ``r_i+ = exp(-aT) r_i + c_i (exp(-k_i T) - exp(-k_j T)) (u_c - u)`` (see
    :mod:`mcfdd.fdd.residual`), and ``c_0 (1 - exp(-k0 T)) = 1 - exp(-aT)``. While the error keeps
    its sign, r_i is therefore this output times ``(exp(-k_i T) - exp(-k_j T)) / (1 - exp(-k0_i T))``,
    about ``(k_j - k_i) / k0_i``, at every sample; when it changes sign, |r_i| is at most that. The
    magnitude matters: the low-pass of the signed error cancels between the slews out and back of a
    manoeuvre, while a residual whose gain mismatch differs between them (the load opposes one and
    aids the other) does not, so a signed ||u|| made theta_i / ||u|| grow on every manoeuvre's tail.
    """
    phi_a = jnp.exp(-a * dt_s)
    return phi_a * state + (1.0 - phi_a) * jnp.abs(u_c - u), state


def relative(x, threshold, scale=1.0):
    """Signed margin of ``x >= threshold`` relative to the threshold, ``(x - threshold) (scale / threshold)``
    (absolute where the threshold is not positive): positive where x exceeds it, up to rounding."""
    return (x - threshold) * (scale / jnp.where(threshold > 0, threshold, 1.0))


def below(x, threshold, scale=1.0):
    """Signed margin of ``x <= threshold``, ``(threshold - x) (scale / threshold)``, as :func:`relative`."""
    return (threshold - x) * (scale / jnp.where(threshold > 0, threshold, 1.0))


def signature(theta, theta_u, tau):
    """iota_i = [theta_i >= tau_i ||u||], eq. (15). Shapes broadcast over models."""
    return theta >= tau * theta_u


def decode(iota, excited):
    """Model id from a signature: the index of its only zero, else NO_DECISION (-1)."""
    zeros = ~iota
    single = jnp.sum(zeros) == 1
    return jnp.where(single & excited, jnp.argmax(zeros), NO_DECISION).astype(jnp.int32)


def confirm_init():
    """Confirmation state: (model decoded so far, how long it has been decoded in a row in s)."""
    return jnp.asarray(NO_DECISION, jnp.int32), jnp.asarray(0.0)


def confirm_step(confirm_s, state, decoded, dt_s: float):
    """Returns (new state, confirmed model id or NO_DECISION)."""
    model, held = state
    held = jnp.where((decoded == model) & (decoded != NO_DECISION), held + dt_s, 0.0)
    confirmed = jnp.where((decoded != NO_DECISION) & (held >= confirm_s - 0.5 * dt_s), decoded, NO_DECISION)
    return (decoded, held), confirmed.astype(jnp.int32)


def threshold(theta, tau):
    """iota = [theta >= tau], eq. (25)."""
    return theta >= tau


def confirmed_margin(confirm_s, scale, run_min, margin, decided, held, dt_s: float):
    """Signed statistic of a confirmed decision, positive where it is confirmed (up to rounding). Returns
    (new run minimum, statistic), in the units of ``margin``.

    ``margin`` is the sample's signed margin of the decision (positive where it is decided, up to
    rounding), ``decided`` the decision of the sample and ``held`` the time it has been held (the
    state of :func:`confirm_step` after this sample, s). While decided, the
    statistic is the smaller of the run minimum (the least margin over the current run of decided
    samples) and the shortfall of the run against the confirmation time as a fraction of it, times
    ``scale``: ``scale (held - (confirm_s - dt/2)) / max(confirm_s, dt)``; it turns positive when the
    run is confirmed and stays positive while every sample of the run is decided. Undecided samples
    score their own margin minus a whole confirmation's shortfall, so the statistic is continuous
    where a run starts. Its sign differs from the confirmation only within rounding of zero (the
    margins of the samples against the comparisons that decide them); the scoring makes it exact
    (:mod:`mcfdd.analysis.scoring.loe`).
    """
    run_min = jnp.where(held > 0.0, jnp.minimum(run_min, margin), margin)
    need = confirm_s - 0.5 * dt_s
    per_s = scale / jnp.maximum(confirm_s, dt_s)
    return run_min, jnp.where(decided, jnp.minimum(run_min, (held - need) * per_s),
                              margin - jnp.maximum(need, 0.0) * per_s)

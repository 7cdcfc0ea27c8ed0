"""Fitting the LPV gain models of eqs. (3)-(4) to the nonlinear actuator of eqs. (1)-(2) (Section 3).

For each fault model nu^(i) the 12 coefficients of ``k^(i)(rho)`` (see :mod:`mcfdd.fdd.lpv`) are
found in two steps.

1. Gain match, the initial guess: the small-error gain of the nonlinear actuator,
   ``K = Kci Kp sqrt((nu1 dP - nu2 s F_aero(p, x) / S) / dP_ref)``, sampled over the flight points,
   the deflection range and both directions, is fitted by linear least squares.
2. Output error: the LPV model (3) is simulated as the FDD assumes it (:mod:`mcfdd.fdd.residual`),
   with u_c held over a sample and the gain frozen at the model's own state,

       x+ = u_c - (u_c - x) exp(-k T),   k = k^(i)(x, sgn(u_c - x), p),

   against the nonlinear actuator (:func:`mcfdd.plant.actuator.step`, fault nu^(i) from t = 0, no
   sensor noise) on open-loop commands at flight points over the envelope. Adam with an
   exponentially decaying step minimises the mean squared output error, normalised by each run's
   amplitude (peak |u_c|), with gradients through the scan; all models at once (the loss is a sum
   of one term per model, so each model's fit is independent).

Runs in which the nonlinear actuator has less than a margin of its supply pressure left to move
(near a stall load, eq. (2) with A -> 0) are outside the domain of a first-order LPV model: they are
not fitted and are reported apart. For nu2 = 0 (disconnected or lost surface) eq. (36) gives the
exact gain ``Kci Kp sqrt(nu1 dP / dP_ref)``, which may replace the fit.

The fitted models must stay apart: :func:`neighbour_distances` gives the smallest H-inf distances
of eq. (16) between neighbouring models over the envelope, beside those of the nonlinear models.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mcfdd.analysis import batch, optimise
from mcfdd.analysis.simulate import sample_time
from mcfdd.fdd import lpv, thresholds
from mcfdd.plant import actuator, atmosphere, closed_loop, hinge, manoeuvres


def envelope_grid(vcas_m_s, altitude_m, max_mach: float):
    """Flight points (Vcas, h) of a grid below the Mach limit, as two flat arrays."""
    v, h = np.meshgrid(np.asarray(vcas_m_s, float), np.asarray(altitude_m, float), indexing="ij")
    keep = atmosphere.below_mach(vcas_m_s, altitude_m, max_mach)
    return v[keep], h[keep]


def stroke_m(model: closed_loop.PlantModel) -> float:
    """Largest rod position x_max = r_arm * max deflection (m)."""
    return model.actuator.r_arm_m * model.actuator.max_deflection_rad


def _load(model: closed_loop.PlantModel, vcas_m_s, altitude_m, x_m):
    """Hinge load F_aero (N) from the table at rod position x (broadcasts)."""
    at = jnp.vectorize(lambda v, h, d: hinge.interpolate(model.table, v, h, d))
    return at(vcas_m_s, altitude_m, x_m / model.actuator.r_arm_m)


def _small_error_gain(act: actuator.ActuatorParams, pressure_pa):
    return act.kci_m_s_a * act.kp_a_m * jnp.sqrt(jnp.maximum(pressure_pa, 0.0) / act.ref_pressure_pa)


def small_error_gain(model: closed_loop.PlantModel, nu, vcas_m_s, altitude_m, x_m, direction):
    """Gain of the nonlinear actuator for a vanishing error moving in ``direction`` (broadcasts)."""
    act = model.actuator
    pressure = actuator.available_pressure(act, nu[0], nu[1], _load(model, vcas_m_s, altitude_m, x_m), direction)
    return _small_error_gain(act, pressure)


@jax.jit
def nonlinear_grid(model: closed_loop.PlantModel, nus, vcas_m_s, altitude_m, x_m):
    """Small-error gain (1/s) and available pressure A / dP of each fault model on a grid.

    Each has shape (N, n_vcas, n_alt, n_x, 2), last axis s = -1, +1 (as
    :func:`mcfdd.fdd.thresholds.gain_grid`).
    """
    act = model.actuator
    v, h, x, s = jnp.meshgrid(vcas_m_s, altitude_m, x_m, jnp.array([-1.0, 1.0]), indexing="ij")
    load = _load(model, v, h, x)
    pressure = jax.vmap(lambda nu: actuator.available_pressure(act, nu[0], nu[1], load, s))(nus)
    return _small_error_gain(act, pressure), pressure / act.supply_pressure_pa


def design_matrix(norm: lpv.Normalisation, vcas_m_s, altitude_m, x_m, direction):
    """Rows of the linear map from the 12 coefficients to k(rho), shape (n, 12)."""
    basis = np.asarray(lpv.scheduling(norm, vcas_m_s, altitude_m))
    xn = (np.asarray(x_m) / norm.x_scale_m)[:, None]
    s = np.asarray(direction)[:, None]
    return np.concatenate([basis, s * basis, xn * basis, xn * s * basis], axis=1)


def gain_match(model: closed_loop.PlantModel, nus, vcas_m_s, altitude_m, n_x: int = 21,
               norm: lpv.Normalisation | None = None) -> np.ndarray:
    """Least-squares coefficients (N, 4, 3) of the small-error gains on the given flight points."""
    x_max = stroke_m(model)
    norm = norm or lpv.Normalisation(x_scale_m=x_max)
    x = np.linspace(-x_max, x_max, n_x)
    pts_v = np.repeat(np.asarray(vcas_m_s, float), n_x * 2)
    pts_h = np.repeat(np.asarray(altitude_m, float), n_x * 2)
    pts_x = np.tile(np.repeat(x, 2), len(vcas_m_s))
    pts_s = np.tile([-1.0, 1.0], len(vcas_m_s) * n_x)
    design = design_matrix(norm, pts_v, pts_h, pts_x, pts_s)
    out = []
    for nu in nus:
        k = np.asarray(jax.jit(small_error_gain)(model, jnp.asarray(nu), pts_v, pts_h, pts_x, pts_s))
        coef, *_ = np.linalg.lstsq(design, k, rcond=None)
        out.append(coef.reshape(4, 3))
    return np.stack(out)


def exact_disconnection_gain(act: actuator.ActuatorParams, nu1: float = 1.0) -> float:
    """Eq. (36): gain with no hinge load, ``Kci Kp sqrt(nu1 dP / dP_ref)`` (1/s)."""
    return act.kci_m_s_a * act.kp_a_m * float(np.sqrt(nu1 * act.supply_pressure_pa / act.ref_pressure_pa))


def initial_bank(model: closed_loop.PlantModel, nus, vcas_m_s, altitude_m, exact_disconnection: bool = False,
                 dtype=np.float64) -> tuple[lpv.GainBank, np.ndarray]:
    """Gain-match bank on the given flight points, the start of :func:`fit`.

    With ``exact_disconnection`` the models with nu2 = 0 take the constant gain of eq. (36).
    Returns (bank, free) where ``free`` (N,) marks the models :func:`fit` may change.
    """
    nus = np.asarray(nus, float)
    norm = lpv.Normalisation(x_scale_m=stroke_m(model))
    coef = gain_match(model, nus, vcas_m_s, altitude_m, norm=norm)
    exact = exact_disconnection & (nus[:, 1] == 0.0)
    for i in np.flatnonzero(exact):
        coef[i] = lpv.constant_coefficients(exact_disconnection_gain(model.actuator, nus[i, 0]))
    return lpv.make_bank(coef, nus, coef[:, 0, 0], norm, dtype), ~exact


class FitProblem(NamedTuple):
    """Responses of the nonlinear actuator for N fault models on B runs of T samples.

    Runs are the product of P flight points and M commands, flight-point major: run b flies
    point b // M with command b % M.

    vcas_m_s, altitude_m: (B,) flight point of each run (m/s, m)
    u_c_m: (B, T) rod command (m), held over each sample
    amplitude_m: (B,) peak |u_c| of each run (m), the scale of its output error
    x_m: (N, B, T) rod position (m) of the nonlinear actuator with fault nu^(i) from t = 0
    min_pressure: (N, B) smallest available pressure A / dP over the run (<= 0: stall load)
    """

    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray
    u_c_m: jnp.ndarray
    amplitude_m: jnp.ndarray
    x_m: jnp.ndarray
    min_pressure: jnp.ndarray


def commands(manoeuvre: manoeuvres.ManoeuvreParams, x_max_m, n_steps: int, dt_s: float, kinds: tuple[int, ...]):
    """Rod commands (M, T) of open-loop profiles (leaves of ``manoeuvre`` with a leading axis M)."""
    t = sample_time(jnp.arange(n_steps), dt_s)
    profile = jax.vmap(lambda m: manoeuvres.inputs(m, t, kinds).command)(manoeuvre)
    return jnp.clip(profile, -1.0, 1.0) * x_max_m


def nonlinear_response(model: closed_loop.PlantModel, nu, vcas_m_s, altitude_m, u_c_m, dt_s: float, substeps: int):
    """Rod position (T,) and available pressure A / dP (T,) of the nonlinear actuator driven by u_c (T,)."""
    act = model.actuator
    load = hinge.flight_point_slice(model.table, vcas_m_s, altitude_m)
    fault = actuator.ActuatorFault(nu[0], nu[1], onset_s=0.0)

    def body(state, inputs):
        k, u_c = inputs
        state, out = actuator.step(act, fault, model.table.delta_rad, load, state, u_c, sample_time(k, dt_s), dt_s,
                                   substeps)
        return state, (out.x_m, out.dp_avail_norm)

    n = u_c_m.shape[0]
    return jax.lax.scan(body, actuator.init(act, jnp.zeros_like(u_c_m[0])), (jnp.arange(n), u_c_m))[1]


def make_problem(model: closed_loop.PlantModel, nus, vcas_m_s, altitude_m, manoeuvre: manoeuvres.ManoeuvreParams,
                 n_steps: int, dt_s: float, substeps: int) -> FitProblem:
    """Nonlinear responses of the models ``nus`` (N, 2) to M open-loop manoeuvres (leaves (M,)) at P
    flight points (P,), n_steps samples of dt_s each."""
    return _problem(model, jnp.asarray(nus), jnp.asarray(vcas_m_s), jnp.asarray(altitude_m), manoeuvre, n_steps,
                    dt_s, substeps, batch.kinds_in(manoeuvre.kind))


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"))
def _problem(model, nus, vcas_m_s, altitude_m, manoeuvre, n_steps, dt_s, substeps, kinds) -> FitProblem:
    u_c = commands(manoeuvre, stroke_m(model), n_steps, dt_s, kinds)
    n_points, n_commands = vcas_m_s.shape[0], u_c.shape[0]
    v = jnp.repeat(vcas_m_s, n_commands)
    h = jnp.repeat(altitude_m, n_commands)
    u = jnp.tile(u_c, (n_points, 1))

    def one(nu, v, h, u):
        return nonlinear_response(model, nu, v, h, u, dt_s, substeps)

    x, pressure = jax.vmap(jax.vmap(one, (None, 0, 0, 0)), (0, None, None, None))(nus, v, h, u)
    return FitProblem(v, h, u, jnp.max(jnp.abs(u), axis=1), x, jnp.min(pressure, axis=2))


def in_domain(problem: FitProblem, margin: float):
    """Runs (N, B) in which the nonlinear actuator keeps at least ``margin`` of dP to move the rod."""
    return problem.min_pressure >= margin


def lpv_response(bank: lpv.GainBank, vcas_m_s, altitude_m, u_c_m, dt_s: float):
    """Rod positions (N, T) of every model of the bank driven by u_c (T,) from x = 0 (output error)."""
    def body(x, u_c):
        k = lpv.gains(bank, x, jnp.sign(u_c - x), vcas_m_s, altitude_m)
        return u_c - (u_c - x) * jnp.exp(-k * dt_s), x

    x0 = jnp.zeros(bank.coef.shape[0], u_c_m.dtype)
    return jax.lax.scan(body, x0, u_c_m)[1].T


def responses(bank: lpv.GainBank, problem: FitProblem, dt_s: float):
    """LPV rod positions (N, B, T) on the runs of ``problem``."""
    x = jax.vmap(lambda v, h, u: lpv_response(bank, v, h, u, dt_s))(problem.vcas_m_s, problem.altitude_m,
                                                                     problem.u_c_m)
    return jnp.moveaxis(x, 0, 1)


def normalised_error(x_lpv, problem: FitProblem):
    """Output error (N, B, T) of LPV responses, as a fraction of each run's amplitude."""
    return (x_lpv - problem.x_m) / problem.amplitude_m[:, None]


def output_errors(x_lpv, problem: FitProblem):
    """RMS and maximum output error of each model on each run, (N, B) each, fractions of the amplitude."""
    e = normalised_error(x_lpv, problem)
    return jnp.sqrt(jnp.mean(e**2, axis=-1)), jnp.max(jnp.abs(e), axis=-1)


def _losses(coef, bank: lpv.GainBank, problem: FitProblem, weight, dt_s: float):
    """Mean squared normalised output error of each model over its weighted runs, (N,)."""
    e = normalised_error(responses(bank._replace(coef=coef), problem, dt_s), problem)
    return jnp.sum(weight * jnp.mean(e**2, axis=-1), axis=1) / jnp.maximum(jnp.sum(weight, axis=1), 1.0)


@partial(jax.jit, static_argnames="dt_s")
def _loss_and_grad(coef, bank: lpv.GainBank, problem: FitProblem, weight, free, dt_s: float):
    """Total loss, the losses of the models (N,) and the gradient in the free models' coefficients."""
    def total(c):
        losses = _losses(c, bank, problem, weight, dt_s)
        return jnp.sum(losses), losses

    (value, losses), grads = jax.value_and_grad(total, has_aux=True)(coef)
    return value, losses, grads * free[:, None, None]


def fit(bank: lpv.GainBank, problem: FitProblem, dt_s: float, *, iterations: int, learning_rate: float,
        final_learning_rate: float, margin: float, free=None, callback=None):
    """Output-error fit of the bank's coefficients, starting from ``bank`` (e.g. :func:`initial_bank`).

    Adam, step decaying exponentially from ``learning_rate`` to ``final_learning_rate`` (1/s) over
    ``iterations`` (:func:`mcfdd.analysis.optimise.run`); only runs :func:`in_domain` for ``margin``
    count; models with ``free`` False (N,) keep their coefficients. ``callback(iteration, losses)``
    is called after every iteration with the losses (N,) before its update. Returns (fitted bank
    with k0 = C0 const, i.e. the gain at the reference flight point and x = 0 averaged over both
    directions; loss history (iterations, N)).
    """
    n = bank.coef.shape[0]
    free = jnp.ones(n, bank.coef.dtype) if free is None else jnp.asarray(free, bank.coef.dtype)
    weight = in_domain(problem, margin).astype(bank.coef.dtype)
    schedule = optax.exponential_decay(learning_rate, iterations, final_learning_rate / learning_rate)
    adam = optax.chain(optax.scale_by_adam(), optax.scale_by_schedule(lambda i: -schedule(i)))

    def fn(coef):
        value, losses, grads = _loss_and_grad(coef, bank, problem, weight, free, dt_s)
        return value, np.asarray(losses), grads

    trace = optimise.run(fn, bank.coef, adam, iterations, evaluate_last=False,
                         callback=None if callback is None else (lambda i, value, losses: callback(i, losses)))
    return bank._replace(coef=trace.final, k0=trace.final[:, 0, 0]), np.stack(trace.aux)


def error_summary(rms, max_error, domain):
    """Per-model summary over the runs in the domain (fractions of the amplitude).

    Returns a dict of (N,) arrays: ``rms`` (root of the mean squared error over the runs), ``max``,
    ``runs`` (in the domain) and ``near_stall_runs`` (left out).
    """
    rms, max_error, domain = np.asarray(rms), np.asarray(max_error), np.asarray(domain)
    count = domain.sum(axis=1)
    return {
        "rms": np.sqrt(np.where(domain, rms**2, 0.0).sum(axis=1) / np.maximum(count, 1)),
        "max": np.where(domain, max_error, 0.0).max(axis=1),
        "runs": count,
        "near_stall_runs": (~domain).sum(axis=1),
    }


def neighbour_pairs(nus) -> list[tuple[int, int]]:
    """Pairs of models that differ in one fault parameter and are adjacent along it.

    E.g. for Section 6.1: fault-free - 34 % - 67 % - 100 % surface loss, fault-free - 15 % - 27 %
    pressure loss.
    """
    nus = np.asarray(nus, float)
    pairs = []
    for axis in (0, 1):
        other = 1 - axis
        for value in np.unique(nus[:, other]):
            line = np.flatnonzero(nus[:, other] == value)
            line = line[np.argsort(-nus[line, axis])]
            pairs += [(int(a), int(b)) for a, b in zip(line[:-1], line[1:])]
    return pairs


def gain_comparison(bank: lpv.GainBank, model: closed_loop.PlantModel, vcas_m_s, altitude_m, x_m, max_mach: float):
    """LPV gains and the nonlinear small-error gains (1/s) on a grid, NaN above the Mach limit.

    Each has shape (N, n_vcas, n_alt, n_x, 2), last axis s = -1, +1.
    """
    k_lpv = np.asarray(thresholds.gain_grid(bank, vcas_m_s, altitude_m, x_m))
    k_nonlinear = np.asarray(nonlinear_grid(model, bank.nu, vcas_m_s, altitude_m, x_m)[0])
    above = ~atmosphere.below_mach(vcas_m_s, altitude_m, max_mach)[None, :, :, None, None]
    return np.where(above, np.nan, k_lpv), np.where(above, np.nan, k_nonlinear)


def showcase_runs(problem: FitProblem, x_lpv, margin: float, n_commands: int) -> list[int]:
    """Runs worth plotting: at the flight points of lowest, median and highest dynamic pressure,
    the run (of the ``n_commands`` flown there) with the largest RMS error of any model in the domain."""
    rms, _ = output_errors(x_lpv, problem)
    worst = np.where(np.asarray(in_domain(problem, margin)), np.asarray(rms), 0.0).max(axis=0)
    worst = worst.reshape(-1, n_commands)
    qbar = np.asarray(atmosphere.dynamic_pressure(problem.vcas_m_s[::n_commands], problem.altitude_m[::n_commands]))
    points = dict.fromkeys(int(p) for p in np.argsort(qbar)[[0, len(qbar) // 2, -1]])
    return [p * n_commands + int(np.argmax(worst[p])) for p in points]


class PairDistance(NamedTuple):
    """Smallest H-inf distance ``|k_j - k_i| / (k_i + k_j)`` of models i and j over a grid.

    overall: over the whole grid (zero where surface-damage models meet at zero hinge load)
    separated: over the grid points where both nonlinear models keep the pressure margin and their
        own small-error gains are at least ``separation`` apart: where the physics tells them apart
    nonlinear: the nonlinear models' own distance at the grid point of ``separated``
    """

    i: int
    j: int
    overall: float
    separated: float
    nonlinear: float


def neighbour_distances(bank: lpv.GainBank, model: closed_loop.PlantModel, vcas_m_s, altitude_m, x_m,
                        max_mach: float, margin: float, separation: float = 0.01) -> list[PairDistance]:
    """Distinguishability of neighbouring models (:func:`neighbour_pairs`) over an envelope grid.

    The grid is Vcas (n_v,) x altitude (n_h,) below the Mach limit, rod positions x (n_x,) and both
    directions; distances as in eq. (16) (:mod:`mcfdd.fdd.thresholds`).
    """
    lpv_d = np.asarray(jax.jit(thresholds.pairwise_distances)(bank, vcas_m_s, altitude_m, x_m))
    gain, pressure = (np.asarray(a) for a in nonlinear_grid(model, bank.nu, vcas_m_s, altitude_m, x_m))
    envelope = np.broadcast_to(atmosphere.below_mach(vcas_m_s, altitude_m, max_mach)[:, :, None, None], gain.shape[1:])
    overall = np.asarray(thresholds.minimum_distances(lpv_d, envelope))
    out = []
    for i, j in neighbour_pairs(bank.nu):
        keep = envelope & (pressure[i] >= margin) & (pressure[j] >= margin)
        nl_d = np.where(keep, np.asarray(thresholds.hinf_distance(gain[i], gain[j])), 0.0)
        apart = np.where(keep & (nl_d >= separation), lpv_d[i, j], np.inf)
        at = np.unravel_index(np.argmin(apart), apart.shape)
        out.append(PairDistance(i, j, float(overall[i, j]), float(apart[at]), float(nl_d[at])))
    return out

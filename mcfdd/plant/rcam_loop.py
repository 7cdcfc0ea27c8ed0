"""The full aircraft in closed loop: RCAM rigid body, flight law, monitored aileron, lags, wind.

``plant.aircraft.model = "rcam"``: the pure pair :func:`init` / :func:`step` that
:mod:`mcfdd.plant.closed_loop` dispatches to. A run starts trimmed in level flight at its
(Vcas, h, mass) (:func:`mcfdd.plant.rcam.trim`, once per scenario). One step at time t:

1. pilot and navigation inputs of the manoeuvre, gusts of the turbulence filters;
2. air data from the state: true and calibrated airspeed, altitude, alpha, beta, flight path;
3. the flight law (:mod:`mcfdd.plant.flight_law`) with gains scheduled on the measured qbar
   turns them into aileron, stabiliser, rudder and throttle commands; u_c = delta_a r_arm
   (open-loop families drive the actuator directly, as on the roll axis);
4. the monitored aileron is the nonlinear actuator of eqs. (1)-(2) under the hinge load of the
   actual flight point: the table slice at the measured (Vcas, h), corrected for the actual
   angle of attack (the load is affine in alpha; the table holds it at the level-flight alpha);
5. the other aileron, the stabiliser and the rudder follow their commands through first-order
   lags, each engine its throttle through the engine lag; the roll power of the monitored
   aileron is scaled by nu2;
6. the rigid body advances one Runge-Kutta step with those surfaces and the gusts.

The outputs carry the measured Vcas and altitude on which the FDD schedules.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from mcfdd.plant import actuator, aircraft, atmosphere, control_law, flight_law, hinge, manoeuvres, rcam, turbulence
from mcfdd.plant.signals import RcamOutputs
from mcfdd.plant.uncertainty import scaled


class Lags(NamedTuple):
    """Time constants (s) of the surfaces that are not monitored and of the engines (assumed values)."""

    aileron_s: float = 0.04
    stabiliser_s: float = 0.15
    rudder_s: float = 0.1
    engine_s: float = 1.5


class RcamModel(NamedTuple):
    """Constants shared by all runs of the full aircraft, including the hinge-load table."""

    actuator: actuator.ActuatorParams
    aircraft: aircraft.AircraftParams
    rcam: rcam.RcamParams
    roll: control_law.RollLawParams
    law: flight_law.FlightLawParams
    lags: Lags
    table: hinge.HingeTable
    surface: hinge.HingeSurface


class RcamRunParams(NamedTuple):
    actuator: actuator.ActuatorParams
    fault: actuator.ActuatorFault
    table: hinge.HingeTable
    surface: hinge.HingeSurface
    hinge_scale: jnp.ndarray
    aircraft: aircraft.AircraftParams
    rcam: rcam.RcamParams
    roll: control_law.RollLawParams
    law: flight_law.FlightLawParams
    lags: Lags
    trim: rcam.Trim
    law_trim: flight_law.Trim
    turbulence: turbulence.TurbulenceParams
    manoeuvre: manoeuvres.ManoeuvreParams
    qbar_pa: jnp.ndarray
    noise_std_m: jnp.ndarray


class RcamPlantState(NamedTuple):
    actuator: actuator.ActuatorState
    body: rcam.RcamState
    aileron: jnp.ndarray  # the other aileron (rad)
    stabiliser: jnp.ndarray
    rudder: jnp.ndarray
    throttle1: jnp.ndarray
    throttle2: jnp.ndarray
    law: flight_law.LawState
    gust: jnp.ndarray


def build_model(actuator_params: actuator.ActuatorParams, aircraft_params: aircraft.AircraftParams,
                roll_params: control_law.RollLawParams, surface: hinge.HingeSurface, table: hinge.HingeTable,
                rcam_params: rcam.RcamParams = rcam.RcamParams(), law_params=flight_law.FlightLawParams(),
                lags=Lags()) -> RcamModel:
    """Full-aircraft constants around a hinge table built as for the roll axis."""
    return RcamModel(actuator_params, aircraft_params, rcam_params, roll_params, law_params, lags, table, surface)


def prepare(model: RcamModel, scenario, dt_s: float) -> RcamRunParams:
    """Per-run parameters: uncertainties applied, the level trim at (Vcas, h, mass), turbulence discretised."""
    act = scaled(model.actuator, scenario)
    body = scaled(model.rcam, scenario)
    trim = rcam.trim(body, scenario.vcas_m_s, scenario.altitude_m)
    qbar, _, tas = atmosphere.flight_condition(scenario.vcas_m_s, scenario.altitude_m)
    return RcamRunParams(
        actuator=act, fault=scenario.fault, table=model.table, surface=model.surface,
        hinge_scale=jnp.asarray(scenario.hinge_scale), aircraft=model.aircraft, rcam=body, roll=model.roll,
        law=model.law, lags=model.lags, trim=trim,
        law_trim=flight_law.Trim(trim.stabiliser, trim.throttle, jnp.asarray(scenario.vcas_m_s)),
        turbulence=turbulence.discretise(scenario.turbulence_level, scenario.altitude_m, tas, model.aircraft.span_m,
                                         dt_s),
        manoeuvre=scenario.manoeuvre, qbar_pa=qbar, noise_std_m=jnp.asarray(scenario.noise_std_m))


def init(params: RcamRunParams, noise3) -> RcamPlantState:
    """Trimmed level flight; turbulence from its stationary distribution (3 normals)."""
    zero = jnp.zeros_like(params.qbar_pa)
    return RcamPlantState(actuator.init(params.actuator, zero), params.trim.state, zero, params.trim.stabiliser + zero,
                          zero, params.trim.throttle + zero, params.trim.throttle + zero, flight_law.init(zero),
                          turbulence.init(params.turbulence, noise3))


def _powers(params: RcamRunParams, qbar, tas) -> flight_law.ControlPowers:
    """Nominal control powers of the healthy aircraft at the measured flight point."""
    b = params.rcam
    roll_damping, aileron_power = aircraft.roll_derivatives(params.aircraft, qbar, tas, b.mass_kg * b.ixx_m2)
    pitch = -qbar * 3.1 * b.tail_area_m2 * b.tail_arm_m / (b.mass_kg * b.iyy_m2)
    yaw = -0.63 * qbar * b.wing_area_m2 * b.mean_chord_m / (b.mass_kg * b.izz_m2)
    throttle = 2.0 * b.thrust_mass_kg * b.gravity_m_s2 / b.mass_kg
    return flight_law.ControlPowers(roll_damping, aileron_power, pitch, yaw, throttle)


def step(params: RcamRunParams, state: RcamPlantState, t_s, noise, dt_s: float, substeps: int,
         kinds: tuple[int, ...]):
    """One sample of the full aircraft in closed loop. ``noise`` holds 4 standard normals.

    Returns (new state, :class:`~mcfdd.plant.signals.RcamOutputs` at time ``t_s``).
    """
    act = params.actuator
    pilot = manoeuvres.inputs(params.manoeuvre, t_s, kinds)
    gust_next, (v_gust, p_gust) = turbulence.step(params.turbulence, state.gust, noise[:3])
    b = state.body
    air = rcam.air_data(b, v_gust)
    _, pressure, density, sound = atmosphere.isa(b.altitude)
    vcas = atmosphere.calibrated_airspeed_at_pressure(air.airspeed / sound, pressure)
    qbar = 0.5 * density * air.airspeed**2
    sphi, cphi, sth, cth = jnp.sin(b.phi), jnp.cos(b.phi), jnp.sin(b.theta), jnp.cos(b.theta)
    climb = b.u * sth - (b.v * sphi + b.w * cphi) * cth
    gamma = jnp.arcsin(jnp.clip(climb / jnp.sqrt(b.u**2 + b.v**2 + b.w**2), -1.0, 1.0))
    meas = flight_law.Measurements(b, air.beta, gamma, air.airspeed, vcas)

    max_delta = act.max_deflection_rad
    law_state, cmd = flight_law.step(params.law, params.roll, params.law_trim, _powers(params, qbar, air.airspeed),
                                     state.law, pilot, meas, max_delta, dt_s)
    delta_c = jnp.where(pilot.open_loop, jnp.clip(pilot.command, -1.0, 1.0) * max_delta, cmd.aileron)
    u_c = delta_c * act.r_arm_m

    s = params.surface
    table_alpha = aircraft.trim_alpha(params.aircraft, qbar)
    alpha_load = -qbar * s.area_m2 * s.chord_m * s.ch_alpha * (air.alpha - params.rcam.alpha_l0_rad - table_alpha)
    load = (hinge.flight_point_slice(params.table, vcas, b.altitude) + alpha_load / act.r_arm_m) * params.hinge_scale
    act_state, out = actuator.step(act, params.fault, params.table.delta_rad, load, state.actuator, u_c, t_s, dt_s,
                                   substeps)
    delta = out.x_m / act.r_arm_m
    aileron = aircraft.effective_aileron(params.aircraft, delta, state.aileron, out.nu2)
    controls = rcam.RcamControls(aileron, state.stabiliser, state.rudder, state.throttle1, state.throttle2)
    body, rates = rcam.step(params.rcam, b, controls, density, dt_s, v_gust, p_gust)

    lags = params.lags
    g = params.rcam.gravity_m_s2
    nz = -(rates.w - g * cth * cphi + b.p * b.v - b.q * b.u) / g
    outputs = RcamOutputs(
        u_c_m=u_c, u_m=out.x_m + params.noise_std_m * noise[3], x_m=out.x_m, delta_rad=delta,
        rate_m_s=out.rate_m_s, load_fraction=out.load_fraction, jammed=out.jammed, dp_avail_norm=out.dp_avail_norm,
        stall=out.stall, p_rad_s=b.p, phi_rad=b.phi, stick=pilot.stick, nu1=out.nu1, nu2=out.nu2, vcas_m_s=vcas,
        altitude_m=b.altitude, alpha_rad=air.alpha, beta_rad=air.beta, theta_rad=b.theta, q_rad_s=b.q, r_rad_s=b.r,
        psi_rad=b.psi, nz_g=nz)
    new_state = RcamPlantState(
        act_state, body,
        rcam.first_order_lag(state.aileron, delta_c, lags.aileron_s, dt_s),
        rcam.first_order_lag(state.stabiliser, cmd.stabiliser, lags.stabiliser_s, dt_s),
        rcam.first_order_lag(state.rudder, cmd.rudder, lags.rudder_s, dt_s),
        rcam.first_order_lag(state.throttle1, cmd.throttle, lags.engine_s, dt_s),
        rcam.first_order_lag(state.throttle2, cmd.throttle, lags.engine_s, dt_s),
        law_state, gust_next)
    return new_state, outputs

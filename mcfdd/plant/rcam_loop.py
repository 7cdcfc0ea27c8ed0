"""The full aircraft in closed loop: RCAM rigid body, flight law, monitored aileron, limited surfaces, wind.

``plant.aircraft.model = "rcam"``: the pure pair :func:`init` / :func:`step` that
:mod:`mcfdd.plant.closed_loop` dispatches to. A run starts trimmed in level flight at its
(Vcas, h, mass) (:func:`mcfdd.plant.rcam.trim`, once per scenario). One step at time t:

1. pilot and navigation inputs of the manoeuvre; the six Dryden gusts at the current altitude
   and speed (:func:`mcfdd.plant.turbulence.gust_step`);
2. air data in the gusts: true and calibrated airspeed, altitude, alpha, beta, flight path; the
   rigid body's derivatives with the surfaces where the sample starts, hence the load factor;
3. the flight law (:mod:`mcfdd.plant.flight_law`) with gains scheduled on the measured qbar
   turns them into aileron, stabiliser, rudder and throttle commands; u_c = delta_a r_arm
   (open-loop families drive the actuator directly, as on the roll axis);
4. the monitored aileron is the nonlinear actuator of eqs. (1)-(2) under the hinge load of the
   actual flight point: the table's line at the measured (Vcas, h) and the rod's deflection
   (:func:`mcfdd.plant.hinge.point_line`), corrected for the actual angle of attack (the load is
   affine in alpha; the table holds it at the level-flight alpha);
5. the other surfaces follow their commands as first-order actuators with the position and
   rate limits of :class:`Surfaces` (the other aileron as a healthy twin of the monitored
   actuator); the roll power of the monitored aileron is scaled by nu2;
6. the rigid body advances one Runge-Kutta step with the surfaces and the gusts held (its first
   stage the derivatives of 2).

Quantities that several later parts of the step read (pilot inputs, gusts, air data, law
commands, the actuator's outputs, each Runge-Kutta stage) are computed once
(:func:`mcfdd.compute.once`). The outputs carry the measured Vcas and altitude on which the FDD
schedules.

Surfaces (TP-088-3, the RCAM report's actuator limits; S public, D derived, A assumed):

| surface | position (deg) | rate (deg/s) | time constant (s) |
|---|---|---|---|
| stabiliser (tailplane) | -25 .. +10 S | 15 S | 0.15 S |
| rudder | -30 .. +30 S | 25 S | 0.15 S |
| throttles, engine thrust | 0.5 .. 10 S | 1.6 S | 1.5 A (engine lag) |
| other aileron (twin of the monitored one) | +-25 S | 100 D (Kci i_max / r_arm) | 0.04 D (1 / (Kci Kp)) |

The position limits are also those of the public RCAM transcriptions; the rate limits and the
0.15 s time constant are the report's actuator data as quoted from it (not re-read from the PDF
in this change). The two engines receive the same command and start at the same trim, so one
state serves both.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
from jax import lax

from mcfdd.compute import ONE, once
from mcfdd.plant import actuator, aircraft, atmosphere, control_law, flight_law, hinge, manoeuvres, rcam, turbulence
from mcfdd.plant.signals import RcamOutputs
from mcfdd.plant.uncertainty import scaled

INIT_NOISE_DIM = turbulence.GUST_NORMALS  # normals at the start: the forming filters' states
NOISE_DIM = turbulence.GUST_NORMALS + 1  # normals per step: six for the gusts, one for the position sensor
NORMALS = "box_muller"  # how a campaign run draws them (:func:`mcfdd.analysis.noise.normals`)


class Surface(NamedTuple):
    """A first-order actuator with position limits (rad) and a rate limit (rad/s)."""

    time_constant_s: float
    min_rad: float
    max_rad: float
    max_rate_rad_s: float


class Surfaces(NamedTuple):
    """The surfaces that are not monitored and the engines (see the module docstring for the sources)."""

    stabiliser: Surface = Surface(0.15, math.radians(-25.0), math.radians(10.0), math.radians(15.0))
    rudder: Surface = Surface(0.15, math.radians(-30.0), math.radians(30.0), math.radians(25.0))
    throttle: Surface = Surface(1.5, math.radians(0.5), math.radians(10.0), math.radians(1.6))


class SurfaceStep(NamedTuple):
    """One sample of a :class:`Surface`: exact lag gain 1 - exp(-dt / tau), limits (rad), largest change (rad)."""

    gain: jnp.ndarray
    lo: jnp.ndarray
    hi: jnp.ndarray
    max_change: jnp.ndarray


class SurfaceSteps(NamedTuple):
    aileron: SurfaceStep
    stabiliser: SurfaceStep
    rudder: SurfaceStep
    throttle: SurfaceStep


class RcamModel(NamedTuple):
    """Constants shared by all runs of the full aircraft, including the hinge-load table."""

    actuator: actuator.ActuatorParams
    aircraft: aircraft.AircraftParams
    rcam: rcam.RcamParams
    roll: control_law.RollLawParams
    law: flight_law.FlightLawParams
    surfaces: Surfaces
    table: hinge.HingeTable
    surface: hinge.HingeSurface
    one: float = ONE  # a runtime 1.0 for :func:`mcfdd.compute.once`


class RcamRunParams(NamedTuple):
    actuator: actuator.ActuatorParams
    fault: actuator.ActuatorFault
    table: hinge.HingeTable
    surface: hinge.HingeSurface
    hinge_scale: jnp.ndarray
    aircraft: aircraft.AircraftParams
    rcam: rcam.RcamParams
    body: rcam.Body
    roll: control_law.RollLawParams
    law: flight_law.FlightLawParams
    authority: flight_law.Authority
    surfaces: SurfaceSteps
    trim: rcam.Trim
    law_trim: flight_law.Trim
    unit_powers: flight_law.ControlPowers  # at qbar = 1 Pa, V = 1 m/s, alpha = 0 (:func:`unit_powers`)
    gust: turbulence.GustParams
    manoeuvre: manoeuvres.ManoeuvreParams
    qbar_pa: jnp.ndarray
    noise_std_m: jnp.ndarray
    one: jnp.ndarray


class RcamPlantState(NamedTuple):
    actuator: actuator.ActuatorState
    body: rcam.RcamState
    aileron: jnp.ndarray  # the other aileron (rad)
    stabiliser: jnp.ndarray
    rudder: jnp.ndarray
    throttle: jnp.ndarray  # each engine's throttle (rad; thrust delta_th m g)
    law: flight_law.LawState
    gust: turbulence.GustState


def build_model(actuator_params: actuator.ActuatorParams, aircraft_params: aircraft.AircraftParams,
                roll_params: control_law.RollLawParams, surface: hinge.HingeSurface, table: hinge.HingeTable,
                rcam_params: rcam.RcamParams = rcam.RcamParams(), law_params=flight_law.FlightLawParams(),
                surfaces=Surfaces()) -> RcamModel:
    """Full-aircraft constants around a hinge table built as for the roll axis."""
    return RcamModel(actuator_params, aircraft_params, rcam_params, roll_params, law_params, surfaces, table, surface)


def twin_aileron(params: actuator.ActuatorParams) -> Surface:
    """The other aileron as a healthy twin of the monitored actuator without load: its no-load bandwidth
    Kci Kp, its full-current rate Kci i_max and its stops."""
    return Surface(1.0 / (params.kci_m_s_a * params.kp_a_m), -params.max_deflection_rad, params.max_deflection_rad,
                   params.kci_m_s_a * params.max_current_a / params.r_arm_m)


def surface_step(surface: Surface, dt_s: float) -> SurfaceStep:
    """The per-sample numbers of a surface."""
    return SurfaceStep(-jnp.expm1(-dt_s / jnp.asarray(surface.time_constant_s)), jnp.asarray(surface.min_rad),
                       jnp.asarray(surface.max_rad), jnp.asarray(surface.max_rate_rad_s) * dt_s)


def follow(s: SurfaceStep, position, command):
    """One sample of a surface: the exact lag step towards the command held within the position limits,
    cut to the rate limit (rad)."""
    change = (lax.clamp(s.lo, command, s.hi) - position) * s.gain  # clamp: one operation, as jnp.clip's two
    return position + lax.clamp(-s.max_change, change, s.max_change)


def prepare(model: RcamModel, scenario, dt_s: float) -> RcamRunParams:
    """Per-run parameters: uncertainties applied, the level trim at (Vcas, h, mass), the gusts' constants."""
    nominal = model.actuator
    act = scaled(nominal, scenario)
    body = scaled(model.rcam, scenario)
    trim = rcam.trim(body, scenario.vcas_m_s, scenario.altitude_m)
    qbar = atmosphere.flight_condition(scenario.vcas_m_s, scenario.altitude_m)[0]
    s = model.surfaces
    return RcamRunParams(
        actuator=act, fault=scenario.fault, table=model.table, surface=model.surface,
        hinge_scale=jnp.asarray(scenario.hinge_scale), aircraft=model.aircraft, rcam=body,
        body=rcam.body_constants(body), roll=model.roll, law=model.law,
        authority=flight_law.Authority(s.stabiliser.min_rad, s.stabiliser.max_rad, s.rudder.max_rad,
                                       s.throttle.min_rad, s.throttle.max_rad),
        surfaces=SurfaceSteps(*(surface_step(x, dt_s) for x in (twin_aileron(nominal), s.stabiliser, s.rudder,
                                                                 s.throttle))),
        trim=trim, law_trim=flight_law.Trim(trim.stabiliser, trim.throttle, jnp.asarray(scenario.vcas_m_s)),
        unit_powers=unit_powers(model.aircraft, body),
        gust=turbulence.gust_params(scenario.turbulence_level, model.aircraft.span_m),
        manoeuvre=scenario.manoeuvre, qbar_pa=qbar, noise_std_m=jnp.asarray(scenario.noise_std_m),
        one=jnp.asarray(model.one))


def init(params: RcamRunParams, noise) -> RcamPlantState:
    """Trimmed level flight; the gust filters from their stationary distribution (INIT_NOISE_DIM normals)."""
    zero = jnp.zeros_like(params.qbar_pa)
    return RcamPlantState(actuator.init(params.actuator, zero), params.trim.state, zero, params.trim.stabiliser + zero,
                          zero, params.trim.throttle + zero, flight_law.init(zero), turbulence.gust_init(noise))


def unit_powers(aircraft_params: aircraft.AircraftParams, b: rcam.RcamParams) -> flight_law.ControlPowers:
    """Per-run control powers of the healthy aircraft at qbar = 1 Pa, V = 1 m/s and alpha = 0 (:func:`_powers`)."""
    roll_damping, aileron_power = aircraft.roll_derivatives(aircraft_params, 1.0, 1.0, b.mass_kg * b.ixx_m2)
    pitch = -3.1 * b.tail_area_m2 * b.tail_arm_m / (b.mass_kg * b.iyy_m2)
    yaw_scale = b.wing_area_m2 * b.mean_chord_m / (b.mass_kg * b.izz_m2)
    throttle = 2.0 * b.thrust_mass_kg * b.gravity_m_s2 / b.mass_kg
    return flight_law.ControlPowers(roll_damping, aileron_power, pitch, -0.63 * yaw_scale, throttle, yaw_scale)


def _powers(unit: flight_law.ControlPowers, qbar, qbar_per_tas, alpha) -> flight_law.ControlPowers:
    """Nominal control powers of the healthy aircraft at the measured flight point from the run's
    :func:`unit_powers`: L_p in qbar / V (``qbar_per_tas`` = rho V / 2, Pa s/m), the control powers and N_beta in
    qbar (TP-088-3's C_n_beta(alpha))."""
    return flight_law.ControlPowers(unit.roll_damping * qbar_per_tas, unit.aileron * qbar, unit.stabiliser * qbar,
                                    unit.rudder * qbar, unit.throttle,
                                    unit.sideslip * qbar * (1.0 - alpha * (180.0 / (15.0 * math.pi))))


def step(params: RcamRunParams, state: RcamPlantState, t_s, noise, dt_s: float, substeps: int,
         kinds: tuple[int, ...]):
    """One sample of the full aircraft in closed loop. ``noise`` holds NOISE_DIM standard normals.

    Returns (new state, :class:`~mcfdd.plant.signals.RcamOutputs` at time ``t_s``).
    """
    act, one = params.actuator, params.one
    noise = once(noise, one)
    pilot = once(manoeuvres.inputs(params.manoeuvre, t_s, kinds, one), one)
    b = state.body
    speed = jnp.sqrt(b.u**2 + b.v**2 + b.w**2)  # through the frozen gust field
    gust_next, gust = turbulence.gust_step(params.gust, state.gust, b.altitude, speed, noise[:turbulence.GUST_NORMALS],
                                           dt_s, one)
    gust = once(gust, one)
    air = rcam.air_data(b, gust)
    temperature = once(atmosphere.isa_temperature(b.altitude), one)
    _, pressure, density, sound = atmosphere.isa(b.altitude, temperature)
    pressure, density = once((pressure, density), one)  # the speed of sound is read once, as a divisor
    vcas = atmosphere.calibrated_airspeed_at_pressure(air.airspeed / sound, pressure)
    qbar = 0.5 * density * air.airspeed**2
    sphi, cphi, sth, cth = once((jnp.sin(b.phi), jnp.cos(b.phi), jnp.sin(b.theta), jnp.cos(b.theta)), one)
    climb = b.u * sth - (b.v * sphi + b.w * cphi) * cth
    gamma = jnp.arcsin(jnp.clip(climb / speed, -1.0, 1.0))
    air, vcas, qbar, gamma = once((air, vcas, qbar, gamma), one)

    # the surfaces where the sample starts (the monitored aileron at its rod, its power scaled by nu2)
    delta = state.actuator.x_m / act.r_arm_m
    nu = actuator.active_nu(params.fault, t_s)[1]
    aileron = aircraft.effective_aileron(params.aircraft, delta, state.aileron, nu)
    controls = rcam.RcamControls(once(aileron, one), state.stabiliser, state.rudder, state.throttle, state.throttle)
    rates, nz = rcam.derivatives_and_load(params.rcam, b, controls, density, gust, one, params.body)
    rates, nz = rcam.store_rates(rates, one), once(nz, one)
    meas = flight_law.Measurements(b, air.beta, gamma, air.airspeed, vcas, nz)

    max_delta = act.max_deflection_rad
    powers = once(_powers(params.unit_powers, qbar, 0.5 * density * air.airspeed, air.alpha), one)
    law_state, cmd = flight_law.step(params.law, params.roll, params.law_trim, powers, state.law, pilot, meas,
                                     max_delta, params.authority, dt_s, one)
    cmd = once(cmd, one)
    delta_c = once(jnp.where(pilot.open_loop, jnp.clip(pilot.command, -1.0, 1.0) * max_delta, cmd.aileron), one)
    u_c = once(delta_c * act.r_arm_m, one)

    s = params.surface
    table_alpha = aircraft.trim_alpha(params.aircraft, qbar)
    alpha_load = -qbar * s.area_m2 * s.chord_m * s.ch_alpha * (air.alpha - params.rcam.alpha_l0_rad - table_alpha)
    load, slope = hinge.point_line(params.table, vcas, b.altitude, delta, one)
    line = once(((load + alpha_load / act.r_arm_m) * params.hinge_scale, slope * params.hinge_scale), one)
    act_state, out = actuator.advance(act, params.fault, line, state.actuator, u_c, t_s, dt_s, substeps, one)
    out = once(out, one)
    body, _ = rcam.step(params.rcam, b, controls, density, dt_s, gust, one, params.body, rates)

    outputs = RcamOutputs(
        u_c_m=u_c, u_m=out.x_m + params.noise_std_m * noise[turbulence.GUST_NORMALS], x_m=out.x_m, delta_rad=delta,
        rate_m_s=out.rate_m_s, load_fraction=out.load_fraction, jammed=out.jammed, dp_avail_norm=out.dp_avail_norm,
        stall=out.stall, p_rad_s=b.p, phi_rad=b.phi, stick=pilot.stick, nu1=out.nu1, nu2=out.nu2, vcas_m_s=vcas,
        altitude_m=b.altitude, alpha_rad=air.alpha, beta_rad=air.beta, theta_rad=b.theta, q_rad_s=b.q, r_rad_s=b.r,
        psi_rad=b.psi, nz_g=nz, stabiliser_rad=state.stabiliser, rudder_rad=state.rudder, throttle_rad=state.throttle)
    surfaces = params.surfaces
    new_state = RcamPlantState(
        act_state, body, follow(surfaces.aileron, state.aileron, delta_c),
        follow(surfaces.stabiliser, state.stabiliser, cmd.stabiliser),
        follow(surfaces.rudder, state.rudder, cmd.rudder),
        follow(surfaces.throttle, state.throttle, cmd.throttle), law_state, gust_next)
    return new_state, outputs

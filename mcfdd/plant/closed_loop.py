"""The simulated world of one run: flight point, actuator, roll axis, control law, pilot, wind.

A run is described by a :class:`Scenario` of traced numbers (flight point, uncertainty scales,
fault, manoeuvre, turbulence level, sensor noise). :func:`prepare` turns it, with the constants of
a :class:`PlantModel`, into the per-run :class:`RunParams` (scheduled gains, hinge-table slice,
discretised turbulence); :func:`init` and :func:`step` are the pure pair that a scan runs. One
step at time t:

1. pilot inputs of the manoeuvre, gusts of the turbulence filters;
2. the roll-rate law turns stick and measured roll rate into the surface command, unless an
   open-loop profile drives the actuator directly; u_c = delta_c r_arm;
3. the actuator advances with u_c held over the sample; its rod position x(t) plus sensor noise is
   the measurement u(t);
4. the roll axis advances with the effective aileron deflection.

Everything is written for one scenario; batches come from ``jax.vmap``.

The full aircraft (``plant.aircraft.model = "rcam"``) lives in :mod:`mcfdd.plant.rcam_loop` with
the same three functions; :func:`loop` picks the pair of a model (the one dispatch on the type of
the model, static), so callers use one interface. Both return outputs with the Vcas and altitude
the FDD schedules on (constant on the roll axis).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from mcfdd.compute import ONE, once
from mcfdd.plant import actuator, aircraft, atmosphere, control_law, hinge, manoeuvres, rcam_loop, turbulence
from mcfdd.plant.signals import PlantOutputs
from mcfdd.plant.uncertainty import scaled

DT_S = 0.01
INIT_NOISE_DIM = 3  # normals at the start: the turbulence filters' states
NOISE_DIM = 4  # normals per step: three for turbulence, one for the position sensor


class Scenario(NamedTuple):
    """Traced description of one run. SI units; scales are multiplicative (1 = nominal)."""

    vcas_m_s: float = 250.0 * atmosphere.KT_TO_M_S
    altitude_m: float = 3000.0
    supply_pressure_scale: float = 1.0
    kci_scale: float = 1.0
    kd_scale: float = 1.0
    hinge_scale: float = 1.0
    roll_inertia_scale: float = 1.0
    mass_scale: float = 1.0  # full aircraft only: mass of the run over the nominal one
    noise_std_m: float = 5e-5
    turbulence_level: float = 1.0
    fault: actuator.ActuatorFault = actuator.ActuatorFault()
    manoeuvre: manoeuvres.ManoeuvreParams = manoeuvres.ManoeuvreParams()


class PlantModel(NamedTuple):
    """Constants shared by all runs, including the hinge-load table."""

    actuator: actuator.ActuatorParams
    aircraft: aircraft.AircraftParams
    law: control_law.RollLawParams
    table: hinge.HingeTable
    one: float = ONE  # a runtime 1.0 for :func:`mcfdd.compute.once`


class RunParams(NamedTuple):
    actuator: actuator.ActuatorParams
    fault: actuator.ActuatorFault
    delta_grid_rad: jnp.ndarray
    load_slice_n: jnp.ndarray
    aircraft: aircraft.AircraftParams
    law: control_law.RollLawParams
    gains: control_law.RollLawGains
    turbulence: turbulence.TurbulenceParams
    manoeuvre: manoeuvres.ManoeuvreParams
    qbar_pa: jnp.ndarray
    tas_m_s: jnp.ndarray
    roll_inertia_kg_m2: jnp.ndarray
    noise_std_m: jnp.ndarray
    vcas_m_s: jnp.ndarray
    altitude_m: jnp.ndarray
    one: jnp.ndarray


class PlantState(NamedTuple):
    actuator: actuator.ActuatorState
    roll: aircraft.RollState
    integrator: jnp.ndarray
    gust: jnp.ndarray


def build_model(actuator_params=actuator.ActuatorParams(), aircraft_params=aircraft.AircraftParams(),
                law_params=control_law.RollLawParams(), surface=hinge.HingeSurface(),
                vcas_range_m_s=(40.0, 220.0), altitude_range_m=(0.0, 13000.0), grid=(37, 27, 51),
                aircraft_model: str = "roll_axis"):
    """Plant constants with the hinge table tabulated over the given ranges (uniform grids).

    ``aircraft_model`` is ``"roll_axis"`` (a :class:`PlantModel`) or ``"rcam"`` (a
    :class:`~mcfdd.plant.rcam_loop.RcamModel` with the same table).
    """
    max_delta = actuator_params.max_deflection_rad
    table = hinge.build_table(
        surface, actuator_params.r_arm_m, lambda qbar: aircraft.trim_alpha(aircraft_params, qbar),
        np.linspace(*vcas_range_m_s, grid[0]), np.linspace(*altitude_range_m, grid[1]),
        np.linspace(-max_delta, max_delta, grid[2]))
    if aircraft_model == "rcam":
        return rcam_loop.build_model(actuator_params, aircraft_params, law_params, surface, table)
    return PlantModel(actuator_params, aircraft_params, law_params, table)


def prepare(model: PlantModel, scenario: Scenario, dt_s: float = DT_S) -> RunParams:
    """Per-run parameters: uncertainties applied, gains scheduled, turbulence discretised."""
    act = scaled(model.actuator, scenario)
    qbar, _, tas = atmosphere.flight_condition(scenario.vcas_m_s, scenario.altitude_m)
    load = hinge.flight_point_slice(model.table, scenario.vcas_m_s, scenario.altitude_m) * scenario.hinge_scale
    roll_damping, aileron_power = aircraft.roll_derivatives(model.aircraft, qbar, tas,
                                                            model.aircraft.roll_inertia_kg_m2)
    return RunParams(
        actuator=act,
        fault=scenario.fault,
        delta_grid_rad=model.table.delta_rad,
        load_slice_n=load,
        aircraft=model.aircraft,
        law=model.law,
        gains=control_law.schedule(model.law, roll_damping, aileron_power),
        turbulence=turbulence.discretise(scenario.turbulence_level, scenario.altitude_m, tas,
                                         model.aircraft.span_m, dt_s),
        manoeuvre=scenario.manoeuvre,
        qbar_pa=qbar,
        tas_m_s=tas,
        roll_inertia_kg_m2=scaled(model.aircraft, scenario).roll_inertia_kg_m2,
        noise_std_m=jnp.asarray(scenario.noise_std_m),
        vcas_m_s=jnp.asarray(scenario.vcas_m_s),
        altitude_m=jnp.asarray(scenario.altitude_m),
        one=jnp.asarray(model.one),
    )


def init(params: RunParams, noise) -> PlantState:
    """Trimmed wings-level start; turbulence from its stationary distribution (INIT_NOISE_DIM normals)."""
    zero = jnp.zeros_like(params.qbar_pa)
    return PlantState(actuator.init(params.actuator, zero), aircraft.init(zero, zero), control_law.init() + zero,
                      turbulence.init(params.turbulence, noise))


def step(params: RunParams, state: PlantState, t_s, noise, dt_s: float = DT_S, substeps: int = 2,
         kinds: tuple[int, ...] = tuple(range(len(manoeuvres.KINDS)))):
    """One sample of the closed loop. ``noise`` holds the step's NOISE_DIM normals.

    Returns (new state, :class:`PlantOutputs` at time ``t_s``).
    """
    act = params.actuator
    noise = once(noise, params.one)  # the normals feed several fusions; drawn once
    pilot = once(manoeuvres.inputs(params.manoeuvre, t_s, kinds), params.one)
    gust_next, (v_gust, p_gust) = turbulence.step(params.turbulence, state.gust, noise[:3])
    max_delta = act.max_deflection_rad
    p_cmd = once(control_law.roll_rate_demand(params.law, pilot.stick, state.roll.phi_rad), params.one)
    integrator, delta_c = control_law.step(params.law, params.gains, state.integrator, p_cmd,
                                           state.roll.p_rad_s, max_delta, dt_s)
    delta_c = once(jnp.where(pilot.open_loop, jnp.clip(pilot.command, -1.0, 1.0) * max_delta, delta_c), params.one)
    u_c = once(delta_c * act.r_arm_m, params.one)
    act_state, out = actuator.step(act, params.fault, params.delta_grid_rad, params.load_slice_n,
                                   state.actuator, u_c, t_s, dt_s, substeps, params.one)
    out = once(out, params.one)
    delta = out.x_m / act.r_arm_m
    delta_eff = aircraft.effective_aileron(params.aircraft, delta, delta_c, out.nu2)
    roll = aircraft.step(params.aircraft, state.roll, delta_eff, pilot.sideslip_rad, p_gust, v_gust,
                         params.qbar_pa, params.tas_m_s, params.roll_inertia_kg_m2, dt_s)
    outputs = PlantOutputs(
        u_c_m=u_c,
        u_m=out.x_m + params.noise_std_m * noise[3],
        x_m=out.x_m,
        delta_rad=delta,
        rate_m_s=out.rate_m_s,
        load_fraction=out.load_fraction,
        jammed=out.jammed,
        dp_avail_norm=out.dp_avail_norm,
        stall=out.stall,
        p_rad_s=state.roll.p_rad_s,
        phi_rad=state.roll.phi_rad,
        stick=pilot.stick,
        nu1=out.nu1,
        nu2=out.nu2,
        vcas_m_s=params.vcas_m_s,
        altitude_m=params.altitude_m,
    )
    return PlantState(act_state, roll, integrator, gust_next), outputs


class Loop(NamedTuple):
    """The pure functions of one plant: ``prepare(model, scenario, dt_s) -> params``,
    ``init(params, normals) -> state`` (``init_noise_dim`` normals) and ``step(params, state, t_s,
    normals, dt_s, substeps, kinds) -> (state, outputs)`` (``noise_dim`` normals per step: (3, 4) on
    the roll axis, (6, 7) on the full aircraft with its six gust components). ``normals`` names the
    transform that draws a campaign run's per-step normals (:func:`mcfdd.analysis.noise.normals`): the
    inverse-CDF on the roll axis, Box-Muller pairs on the full aircraft."""

    prepare: Callable
    init: Callable
    step: Callable
    init_noise_dim: int
    noise_dim: int
    normals: str = "inverse_cdf"


LOOPS = {PlantModel: Loop(prepare, init, step, INIT_NOISE_DIM, NOISE_DIM),
         rcam_loop.RcamModel: Loop(rcam_loop.prepare, rcam_loop.init, rcam_loop.step, rcam_loop.INIT_NOISE_DIM,
                                   rcam_loop.NOISE_DIM, rcam_loop.NORMALS)}


def loop(model) -> Loop:
    """The plant functions of ``model`` (a :class:`PlantModel` or a
    :class:`~mcfdd.plant.rcam_loop.RcamModel`): the one place the aircraft is chosen."""
    return LOOPS[type(model)]


def deflection_deg(x_m, r_arm_m):
    """Surface deflection (deg) of a rod position (m)."""
    return x_m / r_arm_m * (180.0 / math.pi)

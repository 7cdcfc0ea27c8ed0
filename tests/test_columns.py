"""The scenario-column registry (mcfdd.columns) and what derives from it: the configuration's run keys and
space axes, the table-to-scenario conversion against hand-written SI conversions, and the uncertainty
application of both aircraft models against the nominal constants times the scales."""

import math

import jax
import numpy as np
import pytest

from mcfdd import columns, config
from mcfdd.analysis import build, scenarios
from mcfdd.plant import actuator, aircraft, closed_loop, rcam, uncertainty
from mcfdd.plant.choices import MANOEUVRE_KINDS

KT = 1852.0 / 3600.0


def test_every_scenario_leaf_is_set_by_one_column():
    leaves = [c.leaf for c in columns.TABLE if c.leaf != "fault"]
    assert len(leaves) == len(set(leaves))
    expected = {f for f in closed_loop.Scenario._fields if f not in ("fault", "manoeuvre")}
    expected |= {f"manoeuvre.{f}" for f in closed_loop.Scenario().manoeuvre._fields}
    assert set(leaves) == expected
    assert [c.name for c in columns.TABLE if c.leaf == "fault"] == ["fault_kind", "fault_size", "fault_onset_s"]


def test_defaults_give_the_plants_default_scenario():
    """A row that sets no column is the plant's own default Scenario, leaf for leaf."""
    got = scenarios.to_scenario({}, np.float64)
    want = closed_loop.Scenario()
    for name, a, b in zip(closed_loop.Scenario._fields, got, want, strict=True):
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            assert float(x) == pytest.approx(float(y), rel=1e-15), name


def test_run_sections_own_exactly_the_table_columns():
    owners = {"run": config.RunConfig, "fault": config.FaultConfig, "manoeuvre": config.ManoeuvreConfig}
    owned = {(c.owner[0], c.owner[1]) for c in columns.TABLE}
    declared = {(section, key) for section, cls in owners.items() for key in cls.model_fields
                if key not in ("name", "seed", "index", "fault", "manoeuvre")}  # seed, index: the run's key
    assert owned == declared
    assert set(config.SpaceConfig.model_fields) == {c.name for c in columns.AXES}
    assert "fault_size" not in config.SpaceConfig.model_fields and "leakage_size" in config.SpaceConfig.model_fields


def test_a_run_row_converts_to_si_as_written_by_hand():
    run = config.RunConfig(name="r", vcas_kt=300.0, altitude_m=2000.0, noise_std_mm=0.07, turbulence="moderate",
                           kci_scale=0.9, fault=config.FaultConfig(kind="leakage", size=0.2, onset_s=12.0),
                           manoeuvre=config.ManoeuvreConfig(kind="sideslip", sideslip_deg=8.0, bank_deg=-30.0,
                                                            delta_vcas_kt=15.0, amplitude=0.5))
    row = build.run_columns(run)
    assert list(row) == [c.name for c in columns.TABLE]
    s = scenarios.to_scenario({k: np.asarray([v]) for k, v in row.items()}, np.float64)
    assert s.vcas_m_s[0] == pytest.approx(300.0 * KT, rel=1e-15)
    assert s.altitude_m[0] == 2000.0 and s.kci_scale[0] == 0.9 and s.turbulence_level[0] == 2.0
    assert s.noise_std_m[0] == pytest.approx(7e-5, rel=1e-15)
    assert (s.fault.nu1[0], s.fault.nu2[0], s.fault.onset_s[0], s.fault.jam_onset_s[0]) == (0.8, 1.0, 12.0, math.inf)
    m = s.manoeuvre
    assert m.kind[0] == MANOEUVRE_KINDS.index("sideslip") and m.kind.dtype == np.int32
    assert m.sideslip_rad[0] == pytest.approx(math.radians(8.0), rel=1e-15)
    assert m.bank_rad[0] == pytest.approx(math.radians(-30.0), rel=1e-15)
    assert m.delta_vcas_m_s[0] == pytest.approx(15.0 * KT, rel=1e-15) and m.amplitude[0] == 0.5


def test_per_kind_sizes_merge_into_fault_size():
    cols = {"fault_kind": np.array(["leakage", "surface_damage", "disconnection", "none"]),
            "leakage_size": np.array([0.1, 0.2, 0.3, 0.4]), "surface_damage_size": np.array([0.5, 0.6, 0.7, 0.8])}
    merged = scenarios.merge_fault_sizes(dict(cols))
    assert "leakage_size" not in merged and "surface_damage_size" not in merged
    np.testing.assert_array_equal(merged["fault_size"], [0.1, 0.6, 0.0, 0.0])
    untouched = {"fault_kind": np.array(["none"])}
    assert scenarios.merge_fault_sizes(untouched) is untouched and "fault_size" not in untouched


def test_uncertainty_scales_multiply_the_declared_constants_of_both_aircraft_models():
    scen = closed_loop.Scenario(supply_pressure_scale=0.9, kci_scale=1.1, kd_scale=1.3, roll_inertia_scale=0.8,
                                mass_scale=0.95, hinge_scale=1.2)
    nominal = actuator.ActuatorParams()
    act = uncertainty.scaled(nominal, scen)
    assert act.supply_pressure_pa == nominal.supply_pressure_pa * 0.9 and act.kci_m_s_a == nominal.kci_m_s_a * 1.1
    assert act.kd_n_s2_m2 == nominal.kd_n_s2_m2 * 1.3
    assert act._replace(supply_pressure_pa=0, kci_m_s_a=0, kd_n_s2_m2=0) == nominal._replace(
        supply_pressure_pa=0, kci_m_s_a=0, kd_n_s2_m2=0), "nothing else changes"
    plane = aircraft.AircraftParams()
    assert uncertainty.scaled(plane, scen) == plane._replace(roll_inertia_kg_m2=plane.roll_inertia_kg_m2 * 0.8)
    body = uncertainty.scaled(rcam.RcamParams(), scen)
    assert body == rcam.RcamParams()._replace(mass_kg=rcam.RcamParams().mass_kg * 0.95,
                                              ixx_m2=rcam.RcamParams().ixx_m2 * 0.8)
    types = {"ActuatorParams": actuator.ActuatorParams, "AircraftParams": aircraft.AircraftParams,
             "RcamParams": rcam.RcamParams}
    for column in columns.UNCERTAIN:
        for owner, field in column.scales:
            assert field in types[owner]._fields, (column.name, owner, field)


def test_both_aircraft_models_prepare_runs_with_the_scaled_constants():
    scen = scenarios.to_scenario({"kci_scale": 1.1, "kd_scale": 0.7, "roll_inertia_scale": 1.2, "mass_scale": 0.9},
                                 np.float64)
    for name in ("roll_axis", "rcam"):
        model = build.plant_model(config.PlantConfig(aircraft=config.AircraftConfig(model=name)))
        params = closed_loop.loop(model).prepare(model, scen, closed_loop.DT_S)
        assert float(params.actuator.kci_m_s_a) == pytest.approx(model.actuator.kci_m_s_a * 1.1, rel=1e-15)
        assert float(params.actuator.kd_n_s2_m2) == pytest.approx(model.actuator.kd_n_s2_m2 * 0.7, rel=1e-15)
        if name == "rcam":
            assert float(params.rcam.mass_kg) == pytest.approx(model.rcam.mass_kg * 0.9, rel=1e-15)
            assert float(params.rcam.ixx_m2) == pytest.approx(model.rcam.ixx_m2 * 1.2, rel=1e-15)
        else:
            assert float(params.roll_inertia_kg_m2) == pytest.approx(model.aircraft.roll_inertia_kg_m2 * 1.2,
                                                                     rel=1e-15)
            assert params.aircraft == model.aircraft, "the roll law is scheduled on the nominal inertia"

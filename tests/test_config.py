"""The config layer: every kind of bad configuration fails with a ConfigError naming its key, the
shipped configs parse, and ``mcfdd simulate`` writes the table, figure and provenance it promises."""

import copy
import json
import math
import re
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest

from mcfdd import cli, config, io

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _valid():
    """A small valid ``mcfdd simulate`` configuration as parsed TOML."""
    return {
        "simulation": {"duration_s": 1.0, "seed": 1},
        "plant": {"actuator": {"supply_pressure_pa": 2.0e7}},
        "runs": [
            {"name": "a", "vcas_kt": 250.0, "altitude_m": 3000.0, "turbulence": "light",
             "fault": {"kind": "leakage", "size": 0.2, "onset_s": 0.5},
             "manoeuvre": {"kind": "doublet", "amplitude": 0.5}},
            {"name": "b", "manoeuvre": {"kind": "ol_sweep", "amplitude": 0.3}},
        ],
    }


def _edit(data, path, value):
    """Set the entry at ``path`` (keys and list indices) of a copy of ``data``; ``...`` deletes it."""
    data = copy.deepcopy(data)
    node = data
    for key in path[:-1]:
        node = node.setdefault(key, {}) if isinstance(node, dict) else node[key]
    if value is ...:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


BAD = [
    # (id, edit path, bad value, key path the message must name)
    ("unknown top-level key", ("simulaton",), {}, "simulaton"),
    ("unknown nested key", ("runs", 0, "manoeuvre", "amplitud"), 0.5, "runs[0].manoeuvre.amplitud"),
    ("unknown plant key", ("plant", "actuator", "supply_pressure"), 2e7, "plant.actuator.supply_pressure"),
    ("string for a number", ("runs", 0, "vcas_kt"), "250", "runs[0].vcas_kt"),
    ("bool for a number", ("runs", 1, "altitude_m"), True, "runs[1].altitude_m"),
    ("float for an int", ("simulation", "seed"), 1.5, "simulation.seed"),
    ("float for an int substeps", ("simulation", "substeps"), 4.0, "simulation.substeps"),
    ("string for a table", ("runs", 0, "fault"), "leakage", "runs[0].fault"),
    ("table for the runs list", ("runs",), {"name": "a"}, "runs"),
    ("nan", ("runs", 0, "vcas_kt"), math.nan, "runs[0].vcas_kt"),
    ("negative supply pressure", ("plant", "actuator", "supply_pressure_pa"), -2.07e7,
     "plant.actuator.supply_pressure_pa"),
    ("nu below 0: fault size 1.5", ("runs", 0, "fault"), {"kind": "surface_damage", "size": 1.5}, "runs[0].fault.size"),
    ("leakage size 1: nu1 = 0", ("runs", 0, "fault", "size"), 1.0, "runs[0].fault.size"),
    ("amplitude 2", ("runs", 0, "manoeuvre", "amplitude"), 2.0, "runs[0].manoeuvre.amplitude"),
    ("speed above the envelope", ("runs", 1, "vcas_kt"), 500.0, "runs[1].vcas_kt"),
    ("unknown fault kind", ("runs", 0, "fault", "kind"), "leak", "runs[0].fault.kind"),
    ("unknown manoeuvre kind", ("runs", 1, "manoeuvre", "kind"), "barrel_roll", "runs[1].manoeuvre.kind"),
    ("unknown turbulence", ("runs", 0, "turbulence"), "severe", "runs[0].turbulence"),
    ("unknown precision", ("simulation", "precision"), "float16", "simulation.precision"),
    ("duplicate run names", ("runs", 1, "name"), "a", "runs[1].name"),
    ("no runs", ("runs",), [], "runs"),
    ("runs missing", ("runs",), ..., "runs"),
    ("run without a name", ("runs", 0, "name"), ..., "runs[0].name"),
]


@pytest.mark.parametrize("path, value, key", [case[1:] for case in BAD], ids=[case[0] for case in BAD])
def test_bad_config_names_its_key(path, value, key):
    with pytest.raises(config.ConfigError, match=re.escape(key)):
        config.parse(config.SimulateConfig, _edit(_valid(), path, value))


def test_mach_above_limit_is_refused():
    data = _edit(_edit(_valid(), ("runs", 1, "vcas_kt"), 420.0), ("runs", 1, "altitude_m"), 12000.0)
    with pytest.raises(config.ConfigError, match=r"runs\[1\].*Mach"):
        config.parse(config.SimulateConfig, data)


def test_valid_config_converts_to_si():
    cfg = config.parse(config.SimulateConfig, _valid())
    assert [run.name for run in cfg.runs] == ["a", "b"]
    assert cfg.runs[0].fault.size == 0.2 and cfg.runs[1].fault.kind == "none"
    actuator = cfg.plant.model().actuator
    assert actuator.supply_pressure_pa == 2.0e7 and actuator.ref_pressure_pa == 2.0e7
    assert actuator.max_current_a == pytest.approx(8e-3)
    assert actuator.max_deflection_rad == pytest.approx(math.radians(25.0))


def test_missing_file(tmp_path):
    path = tmp_path / "absent.toml"
    with pytest.raises(config.ConfigError, match=re.escape(str(path))):
        config.load(config.SimulateConfig, path)


def test_invalid_toml(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[[runs]]\nname = 'a'\nvcas_kt = \n")
    with pytest.raises(config.ConfigError, match=re.escape(str(path)) + ".*TOML"):
        config.load(config.SimulateConfig, path)


def test_file_error_names_file_and_key(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text("[[runs]]\nname = 'a'\nmanoeuvre = { kind = 'doublet', amplitud = 0.5 }\n")
    with pytest.raises(config.ConfigError, match=re.escape(f"{path}: runs[0].manoeuvre.amplitud")):
        config.load(config.SimulateConfig, path)


@pytest.mark.parametrize("name", ["fig3.toml", "fig5.toml"])
def test_shipped_configs_parse(name):
    cfg = config.load(config.SimulateConfig, CONFIGS / name)
    assert len(cfg.runs) >= 1 and cfg.simulation.n_steps > 0


# ---------------------------------------------------------------------------------------------
# mcfdd simulate


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """``mcfdd simulate`` of fig3 and fig5, in-process: {name: (output folder, parsed config)}.

    The command computes at the config's precision (float32 here) and leaves the caller's
    jax_enable_x64 as it was.
    """
    x64 = jax.config.jax_enable_x64
    runs = {}
    for name in ("fig3", "fig5"):
        out = tmp_path_factory.mktemp(name)
        assert cli.main(["simulate", str(CONFIGS / f"{name}.toml"), "--out", str(out)]) == 0
        runs[name] = out, config.load(config.SimulateConfig, CONFIGS / f"{name}.toml")
    assert jax.config.jax_enable_x64 == x64
    return runs


def _tracking_error_deg(df, r_arm_m):
    return np.degrees(np.abs(df["u_c_m"] - df["x_m"]).to_numpy() / r_arm_m)


@pytest.mark.parametrize("name", ["fig3", "fig5"])
def test_simulate_writes_table_figure_and_provenance(simulated, name):
    out, cfg = simulated[name]
    table = out / "timeseries.parquet"
    df = pd.read_parquet(table)
    required = {"run", "t_s", "u_c_m", "u_m", "x_m", "delta_deg", "dp_avail_norm", "stall", "p_deg_s", "phi_deg"}
    assert required <= set(df.columns)
    assert len(df) == len(cfg.runs) * cfg.simulation.n_steps
    assert list(df["run"].unique()) == [run.name for run in cfg.runs]
    assert np.isfinite(df.drop(columns="run").to_numpy(dtype=float)).all()
    for run in cfg.runs:
        assert (out / f"{run.name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    meta = io.read_metadata(table)
    assert json.loads(meta["config"]) == json.loads(config.to_json(cfg))
    assert meta["seed"] == str(cfg.simulation.seed)


def test_fig5_has_two_stall_intervals(simulated):
    """At least two separate stall intervals in which u_c - x grows above 2 deg of deflection."""
    out, cfg = simulated["fig5"]
    df = pd.read_parquet(out / "timeseries.parquet")
    stall = df["stall"].to_numpy().astype(int)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stall, [0]])))
    error = _tracking_error_deg(df, cfg.plant.actuator.r_arm_m)
    large = [start for start, end in zip(edges[::2], edges[1::2], strict=True) if error[start:end].max() > 2.0]
    assert len(large) >= 2


def test_fig3_leakage_lags_fault_free(simulated):
    """After the 15 s onset, during the manoeuvre, the leaking actuator tracks its command worse."""
    out, cfg = simulated["fig3"]
    df = pd.read_parquet(out / "timeseries.parquet")
    leak = next(run for run in cfg.runs if run.fault.kind == "leakage")
    m = leak.manoeuvre
    end = m.t_start_s + 4.0 * m.duration_s + 2.0 * m.hold_s  # bank_to_bank: D, H, 2 D, H, D
    window = (df["t_s"] >= leak.fault.onset_s) & (df["t_s"] <= end)
    error = pd.Series(_tracking_error_deg(df, cfg.plant.actuator.r_arm_m))[window.to_numpy()]
    mean = error.groupby(df["run"][window].to_numpy()).mean()
    free = next(run.name for run in cfg.runs if run.fault.kind == "none")
    assert mean[leak.name] > mean[free]

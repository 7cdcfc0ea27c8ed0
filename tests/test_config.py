"""The config layer: every kind of bad configuration fails with a ConfigError naming its key, the
shipped configs parse, and ``mcfdd simulate`` writes the table, figure and provenance it promises."""

import copy
import json
import math
import re
import subprocess
import sys

import jax
import jsonschema
import numpy as np
import pandas as pd
import pytest

import mcfdd
from helpers import CONFIGS
from mcfdd import cli, config, io
from mcfdd.analysis import build


def _valid():
    """A small valid ``mcfdd simulate`` configuration as parsed TOML."""
    return {
        "simulation": {"duration_s": 1.0, "seed": 1},
        "plant": {"actuator": {"supply_pressure_pa": 2.0e7}},
        "runs": [
            {"name": "a", "vcas_kt": 250.0, "altitude_m": 3000.0, "turbulence": "light",
             "fault": {"kind": "leakage", "size": 0.2, "onset_s": 0.5},
             "manoeuvre": {"kind": "doublet", "amplitude": 0.5, "t_start_s": 0.2}},
            {"name": "b", "manoeuvre": {"kind": "ol_sweep", "amplitude": 0.3, "t_start_s": 0.2}},
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
    ("unknown turbulence", ("runs", 0, "turbulence"), "extreme", "runs[0].turbulence"),
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
    actuator = build.plant_model(cfg.plant).actuator
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


@pytest.mark.parametrize("path, value, key", [case[1:] for case in BAD], ids=[case[0] for case in BAD])
def test_bad_config_error_is_one_line_without_pydantic_text(path, value, key):
    with pytest.raises(config.ConfigError) as err:
        config.parse(config.SimulateConfig, _edit(_valid(), path, value))
    text = str(err.value)
    assert text.startswith(f"{key}:") and "\n" not in text
    assert not re.search(r"pydantic|errors\.pydantic\.dev|type=|For further information|validation error", text)


def test_range_and_choices_are_named():
    bad = _edit(_valid(), ("runs", 1, "vcas_kt"), 500.0)
    with pytest.raises(config.ConfigError, match=re.escape("runs[1].vcas_kt: 500.0 is outside the allowed range "
                                                           "[80.0, 420.0]")):
        config.parse(config.SimulateConfig, bad)
    bad = _edit(_valid(), ("runs", 0, "turbulence"), "extreme")
    with pytest.raises(config.ConfigError, match="expected one of 'none', 'light', 'moderate', 'severe'"):
        config.parse(config.SimulateConfig, bad)


def test_an_integer_is_a_number_and_the_models_are_frozen():
    cfg = config.parse(config.SimulateConfig, _edit(_valid(), ("runs", 0, "vcas_kt"), 250))
    assert cfg.runs[0].vcas_kt == 250.0 and isinstance(cfg.runs[0].vcas_kt, float)
    with pytest.raises(ValueError):
        cfg.runs[0].vcas_kt = 300.0


def test_not_utf8_file_names_the_file(tmp_path):
    path = tmp_path / "binary.toml"
    path.write_bytes(b"[simulation]\nseed = 1\n# \xff\xfe\x00\x81\n")
    with pytest.raises(config.ConfigError, match=re.escape(str(path)) + ".*UTF-8") as err:
        config.load_config(path)
    assert "\n" not in str(err.value)


EXPECTED_KIND = {"fault_free": "campaign", "loe_campaign": "campaign", "stall_campaign": "campaign",
                 "fig3": "simulate", "fig5": "simulate", "fig4": "sweep", "lpv_aileron": "fit-lpv",
                 "tune_loe": "tune", "tune_stall": "tune", "tune_validation": "tune", "tune_default": "tune",
                 "tune_validation_rcam": "tune", "tune_validation_kci10": "tune", "worst_case_stall": "worst-case",
                 "worst_case_stall_detect": "worst-case", "worst_case_loe_detection": "worst-case",
                 "worst_case_loe_detection_free": "worst-case", "rcam_campaign": "campaign",
                 "rcam_campaign_roll_axis": "campaign", "rcam_simulate": "simulate", "validation": "campaign",
                 "validation_rcam": "campaign",
                 "validation_kci10": "campaign"}


def test_expected_kinds_cover_every_shipped_config():
    assert {p.stem for p in CONFIGS.glob("*.toml")} == set(EXPECTED_KIND)


@pytest.mark.parametrize("name", sorted(EXPECTED_KIND))
def test_every_shipped_config_loads_with_its_inferred_kind(name):
    path = CONFIGS / f"{name}.toml"
    data = config.load_toml(path)
    assert config.infer_kind(data) == EXPECTED_KIND[name]
    cfg = config.load_config(path)
    assert type(cfg) is config.KINDS[EXPECTED_KIND[name]]
    assert cfg == config.load_config(path, kind=EXPECTED_KIND[name]) == config.load(type(cfg), path)


@pytest.mark.parametrize("name", sorted(EXPECTED_KIND))
def test_written_toml_loads_back_to_an_equal_config(tmp_path, name):
    cfg = config.load_config(CONFIGS / f"{name}.toml")
    path = tmp_path / "written.toml"
    path.write_text(config.to_toml(config.to_dict(cfg)))
    assert config.load_config(path, kind=EXPECTED_KIND[name]) == cfg


def test_kind_errors():
    with pytest.raises(config.ConfigError, match="kind: the sections fdd, space fit campaign, tune, worst-case"):
        config.load_config({"space": {"vcas_kt": 250.0}, "fdd": {}})
    with pytest.raises(config.ConfigError, match="kind: 'campain' is not allowed; expected one of 'simulate'"):
        config.load_config({}, kind="campain")
    with pytest.raises(config.ConfigError, match="campain: unknown key; no configuration kind"):
        config.load_config({"campain": {"scenarios": 4}})
    with pytest.raises(config.ConfigError, match="kind"):
        config.json_schema("campain")


def test_overrides_set_dotted_paths_and_list_entries():
    cfg = config.load_config(CONFIGS / "fault_free.toml",
                             overrides={"campaign.scenarios": 320, "fdd.loe.tau": 0.12, "space.vcas_kt": [150, 300]})
    base = config.load_config(CONFIGS / "fault_free.toml")
    assert (cfg.campaign.scenarios, cfg.fdd.loe.tau) == (320, 0.12)
    assert cfg.space.axis("vcas_kt") == config.Axis("vcas_kt", "range", lo=150.0, hi=300.0, n=2)
    assert [a.name for a in cfg.space.axes] == [a.name for a in base.space.axes]
    assert cfg.campaign.seed == base.campaign.seed and cfg.plant == base.plant
    sim = config.load_config(_valid(), overrides={"runs[1].fault.size": 0.3, "runs[1].fault.kind": "leakage",
                                                  "runs[1].fault.onset_s": 0.5})
    assert (sim.runs[1].fault.kind, sim.runs[1].fault.size) == ("leakage", 0.3)
    assert _valid()["runs"][1].get("fault") is None, "the source dict is not modified"


@pytest.mark.parametrize("overrides, message", [
    ({"campaign.scenario": 4}, "campaign.scenario: unknown key; allowed keys are chunk_size, design"),
    ({"fdd.lo.tau": 0.1}, "fdd.lo: unknown key; allowed keys are bank, loe, stall"),
    ({"campaing.seed": 1}, "campaing: unknown key; allowed keys are campaign, evaluation, fdd, plant, probability, "
                          "sensitivity, space"),
    ({"space.vcas": 250.0}, "space.vcas: unknown axis"),
    ({"campaign.seed.x": 1}, "campaign.seed: not a table"),
    ({"campaign..seed": 1}, "not a key path"),
])
def test_override_into_a_missing_key_is_named(overrides, message):
    with pytest.raises(config.ConfigError, match=re.escape(message)):
        config.load_config(CONFIGS / "fault_free.toml", overrides=overrides)


def test_override_of_a_missing_list_entry_is_named():
    with pytest.raises(config.ConfigError, match=re.escape("runs[5]: no such entry (runs has 2 entries)")):
        config.load_config(_valid(), overrides={"runs[5].name": "c"})
    with pytest.raises(config.ConfigError, match=re.escape("runs[1].fault.size: 1.5 is outside the allowed range")):
        config.load_config(_valid(), overrides={"runs[1].fault": {"kind": "surface_damage", "size": 1.5}})


@pytest.mark.parametrize("key, value", [("campaign.scenarios", 0), ("campaign.scenarios", "256"),
                                        ("fdd.loe.tau", -0.1), ("campaign.design", "halton"),
                                        ("space.fault_kind", ["nothing"])])
def test_bad_override_gives_the_message_of_the_same_value_in_a_file(tmp_path, key, value):
    data = _edit(config.load_toml(CONFIGS / "fault_free.toml"), tuple(key.split(".")), value)
    path = tmp_path / "edited.toml"
    path.write_text(config.to_toml(data))
    with pytest.raises(config.ConfigError) as in_file:
        config.load_config(path)
    with pytest.raises(config.ConfigError) as overridden:
        config.load_config(CONFIGS / "fault_free.toml", overrides={key: value})
    assert str(in_file.value) == f"{path}: {overridden.value}"
    assert str(overridden.value).startswith(key)


def test_replace_is_validated():
    cfg = config.load_config(CONFIGS / "fault_free.toml")
    changed = config.replace(cfg, {"campaign.seed": 3, "fdd.stall.evaluator.beta": 2})
    assert changed.campaign.seed == 3 and changed.fdd.stall.evaluator.beta == 2.0
    assert config.replace(changed, {"campaign.seed": cfg.campaign.seed, "fdd.stall.evaluator.beta": 1.0}) == cfg
    with pytest.raises(config.ConfigError,
                       match=re.escape("campaign.seed: -1 is outside the allowed range [0, 4294967295]")):
        config.replace(cfg, {"campaign.seed": -1})
    with pytest.raises(config.ConfigError, match="space.vcas_kt: range"):
        config.replace(cfg, {"space.vcas_kt": [300.0, 200.0]})
    base = config.parse(config.SimulateConfig, _valid())
    sim = config.replace(base, {"runs[1].manoeuvre.amplitude": -0.3})
    assert sim.runs[1].manoeuvre.amplitude == -0.3 and sim.runs[0] == base.runs[0]


PARSE_ONLY = """
import sys
from pathlib import Path

import mcfdd.config

for path in sorted(Path(sys.argv[1]).glob("*.toml")):
    mcfdd.config.load_config(path)
print(" ".join(sorted(m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib")
                      or m.startswith(("mcfdd.analysis", "mcfdd.workflows", "mcfdd.fdd")))))
"""


def test_parsing_configs_imports_no_jax_and_no_analysis():
    """In a fresh process, ``import mcfdd.config`` and loading every shipped config import neither JAX nor
    the analysis, workflow or FDD modules: the configuration parses and builds nothing."""
    out = subprocess.run([sys.executable, "-c", PARSE_ONLY, str(CONFIGS)], capture_output=True, text=True, check=True)
    assert out.stdout.split() == []


@pytest.mark.parametrize("name", sorted(EXPECTED_KIND))
def test_shipped_configs_validate_against_their_json_schema(name):
    data = config.load_toml(CONFIGS / f"{name}.toml")
    jsonschema.Draft202012Validator(config.json_schema(EXPECTED_KIND[name])).validate(data)


@pytest.mark.parametrize("edit", [
    lambda d: d["campaign"].update(scenarioz=8),
    lambda d: d.update(campain={}),
    lambda d: d["space"].update(vcas_k=[200.0, 300.0]),
    lambda d: d["space"].update(vcas_kt={"range": [200.0, 300.0], "m": 3}),
    lambda d: d["space"].update(turbulence=["light", "extreme"]),
    lambda d: d["campaign"].update(scenarios="8"),
    lambda d: d["space"].update(kd_scale=[0.5, 1.0, 2.0]),
])
def test_campaign_schema_rejects_what_the_parser_rejects(edit):
    schema = jsonschema.Draft202012Validator(config.json_schema("campaign"))
    for path in CONFIGS.glob("*.toml"):
        if EXPECTED_KIND[path.stem] != "campaign":
            continue
        data = config.load_toml(path)
        edit(data)
        assert not schema.is_valid(data)
        with pytest.raises(config.ConfigError):
            config.load_config(data, kind="campaign")


def test_campaign_schema_accepts_every_axis_form():
    data = {"space": {"vcas_kt": 250.0, "altitude_m": [0.0, 3000.0], "kd_scale": {"values": [0.8, 1.2]},
                      "hinge_scale": {"range": [0.9, 1.1], "n": 5}, "turbulence": ["light", "moderate"],
                      "fault_kind": "none"}}
    jsonschema.Draft202012Validator(config.json_schema("campaign")).validate(data)
    axes = config.load_config(data, kind="campaign").space.axes
    assert [a.kind for a in axes] == ["const", "range", "values", "range", "choices", "const"]
    assert axes[3].n == 5


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


def test_fig3_runs_are_paired_before_the_onset(simulated):
    """Runs of one config share turbulence and sensor noise: before the 15 s onset the faulty and the
    fault-free run of fig3 are identical to the last bit in every plant and FDD signal; after it the
    deflections differ."""
    out, cfg = simulated["fig3"]
    df = pd.read_parquet(out / "timeseries.parquet")
    leak = next(run for run in cfg.runs if run.fault.kind == "leakage")
    free = next(run for run in cfg.runs if run.fault.kind == "none")
    a, b = (df[df["run"] == run.name].drop(columns="run").reset_index(drop=True) for run in (free, leak))
    before = (a["t_s"] < leak.fault.onset_s).to_numpy()
    assert before.sum() == round(leak.fault.onset_s / cfg.simulation.dt_s)
    for name in a.columns:
        np.testing.assert_array_equal(a[name].to_numpy()[before], b[name].to_numpy()[before], err_msg=name)
    after = np.abs(a["delta_deg"].to_numpy() - b["delta_deg"].to_numpy())[~before]
    assert after.max() > 0.1


def test_a_run_with_its_own_seed_draws_its_own_noise():
    """Unset, a run draws simulation.seed's numbers; ``seed`` on a run gives it its own, the same for
    every run of that seed."""
    run = {"turbulence": "moderate", "vcas_kt": 300.0}
    df = mcfdd.simulate({"simulation": {"duration_s": 0.5, "seed": 4},
                         "runs": [{"name": "shared", **run}, {"name": "own", "seed": 9, **run},
                                  {"name": "own-again", "seed": 9, **run}, {"name": "explicit", "seed": 4, **run}]},
                        progress=False).to_pandas()
    u = {name: g["u_m"].to_numpy() for name, g in df.groupby("run")}
    np.testing.assert_array_equal(u["own"], u["own-again"])
    np.testing.assert_array_equal(u["shared"], u["explicit"])
    assert np.abs(u["own"] - u["shared"]).max() > 0.0


@pytest.mark.parametrize("key, value, message", [
    ("saturation_rate_fraction", 1.5, "1.5 is outside the allowed range [0.0, 1.0]"),
    ("saturation_rate_fraction", -0.1, "-0.1 is outside the allowed range [0.0, 1.0]"),
    ("saturation_rate_fraction", "half", "expected a number, got string 'half'"),
    ("saturation_error_deg", 0.0, "0.0 is outside the allowed range (0.0, 25.0]"),
    ("rate_pole_1_s", 0.0, "0.0 is outside the allowed range (0.0, 10000.0]"),
])
def test_bad_stall_gate_values_are_named(key, value, message):
    """The stall detector's rate-saturation gate: a bad value ends with one line naming its key and range."""
    with pytest.raises(config.ConfigError, match=re.escape(f"fdd.stall.{key}: {message}")):
        config.load_config(CONFIGS / "stall_campaign.toml", overrides={f"fdd.stall.{key}": value})


@pytest.mark.parametrize("key, value, message", [
    ("identification_tau_deg", -0.5, "-0.5 is outside the allowed range [0.0, inf]"),
    ("identification_residual_deg", -0.1, "-0.1 is outside the allowed range [0.0, inf]"),
    ("identification_residual_deg", "small", "expected a number, got string 'small'"),
    ("identification_threshold_deg", 0.7, "unknown key"),
])
def test_bad_identification_gate_values_are_named(key, value, message):
    """The stall identification gate: a bad value or a misspelt key ends with one line naming the key."""
    with pytest.raises(config.ConfigError, match=re.escape(f"fdd.stall.{key}: {message}")):
        config.load_config(CONFIGS / "stall_campaign.toml", overrides={f"fdd.stall.{key}": value})


def test_identification_gate_off_by_default_and_built_only_when_on():
    """Both keys 0 (the default) build no identification gate (stall_campaign.toml ships 0.8 and 0.3 deg); either one
    builds it in rod units, its theta threshold the detector's tau where identification_tau_deg is 0 and no residual
    condition where identification_residual_deg is 0."""
    from mcfdd.fdd import lpv

    bank = lpv.from_dict(io.load_bank_dict(), dtype=np.float64)[0]
    r_arm = 0.0525
    deg = math.radians(1.0) * r_arm

    def gate(**keys):
        cfg = config.load_config(CONFIGS / "fault_free.toml",
                                 overrides={f"fdd.stall.{k}": v for k, v in keys.items()})
        return build.fdd_params(cfg.fdd, bank, r_arm).stall.identification

    assert gate() is None
    shipped = config.load_config(CONFIGS / "stall_campaign.toml").fdd.stall
    assert (shipped.identification_tau_deg, shipped.identification_residual_deg) == (0.8, 0.3)
    only_tau = gate(identification_tau_deg=0.7)
    assert only_tau.tau == pytest.approx(0.7 * deg, rel=1e-12) and only_tau.residual_min_m is None
    only_residual = gate(identification_residual_deg=0.3, tau_deg=1.2)
    assert only_residual.tau == pytest.approx(1.2 * deg, rel=1e-12)
    assert only_residual.residual_min_m == pytest.approx(0.3 * deg, rel=1e-12)


def test_stall_gate_off_by_default_and_built_only_when_on():
    """A config without the gate builds none (so its campaigns are those of before); stall_campaign.toml ships it at
    0.5; a fraction builds it in rod units."""
    from mcfdd.fdd import lpv

    bank = lpv.from_dict(io.load_bank_dict(), dtype=np.float64)[0]
    off = config.load_config(CONFIGS / "fault_free.toml")
    assert config.load_config(CONFIGS / "stall_campaign.toml").fdd.stall.saturation_rate_fraction == 0.5
    on = config.load_config(CONFIGS / "stall_campaign.toml", overrides={"fdd.stall.saturation_rate_fraction": 0.4,
                                                                         "fdd.stall.saturation_error_deg": 3.0})
    assert off.fdd.stall.saturation_rate_fraction == 0.0
    r_arm = 0.0525
    assert build.fdd_params(off.fdd, bank, r_arm).stall.saturation is None
    gate = build.fdd_params(on.fdd, bank, r_arm).stall.saturation
    assert gate.rate_fraction == 0.4 and gate.rate_pole == 100.0
    assert gate.error_m == pytest.approx(math.radians(3.0) * r_arm, rel=1e-12)

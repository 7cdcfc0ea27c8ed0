"""Sensitivity analysis: estimators against closed forms and scipy, a campaign built to have one driver, errors."""

import concurrent.futures
import math
import shlex
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy import stats

import mcfdd
from mcfdd import cli, config, io
from mcfdd.analysis import build, sensitivity as sens
from mcfdd.workflows import sensitivity as sens_wf
from mcfdd.workflows.sensitivity import tables

A_ISH, B_ISH = 7.0, 0.1
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def ishigami(u, xp=np):
    """Ishigami on [-pi, pi]^3 from the unit cube (u (..., 3)), in NumPy or (xp=jax.numpy) JAX."""
    x = -np.pi + 2 * np.pi * u
    return xp.sin(x[..., 0]) + A_ISH * xp.sin(x[..., 1]) ** 2 + B_ISH * x[..., 2] ** 4 * xp.sin(x[..., 0])


def ishigami_indices():
    """Analytic first-order and total indices (Ishigami and Homma 1990)."""
    v1 = 0.5 * (1 + B_ISH * np.pi ** 4 / 5) ** 2
    v2 = A_ISH ** 2 / 8
    v13 = B_ISH ** 2 * np.pi ** 8 * (1 / 18 - 1 / 50)
    v = v1 + v2 + v13
    return np.array([v1, v2, 0.0]) / v, np.array([v1 + v13, v2, v13]) / v, v


def g_function(u, a):
    """Sobol's g-function, prod (|4 u_i - 2| + a_i) / (1 + a_i)."""
    return jnp.prod((jnp.abs(4 * u - 2) + a) / (1 + a), axis=-1)


def pick_freeze_run(fn, n, dim, seed):
    a, b = sens.saltelli_matrices(n, dim, seed)
    rows, _ = sens.pick_freeze(a, b)
    return sens.split_blocks(fn(rows), n)


def test_pick_freeze_blocks_take_one_column_from_b():
    a, b = sens.saltelli_matrices(16, 3, 5)
    rows, from_b = sens.pick_freeze(a, b)
    blocks = rows.reshape(5, 16, 3)
    np.testing.assert_array_equal(blocks[0], a)
    np.testing.assert_array_equal(blocks[1], b)
    for i in range(3):
        expected = a.copy()
        expected[:, i] = b[:, i]
        np.testing.assert_array_equal(blocks[2 + i], expected)
        assert from_b.reshape(5, 16, 3)[2 + i].sum(axis=1).tolist() == [1] * 16
    f_a, f_b, f_ab = sens.split_blocks(np.arange(80.0), 16)
    assert f_a.tolist() == list(range(16)) and f_b[0] == 16 and f_ab.shape == (3, 16) and f_ab[2, 0] == 64


def test_estimators_equal_scipy_sobol_indices():
    f_a, f_b, f_ab = pick_freeze_run(ishigami, 256, 3, 1)
    ours = sens.sobol_indices(f_a, f_b, f_ab, resamples=100)
    ref = stats.sobol_indices(func={"f_A": f_a[None], "f_B": f_b[None], "f_AB": f_ab[:, None]}, n=256)
    np.testing.assert_allclose(ours["first"], ref.first_order, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(ours["total"], ref.total_order, rtol=1e-12, atol=1e-14)


def test_ishigami_indices_lie_within_their_intervals():
    first, total, variance = ishigami_indices()
    r = sens.sobol_indices(*pick_freeze_run(ishigami, 1024, 3, 0), resamples=1000, seed=0)
    assert np.all((r["first_lo"] <= first) & (first <= r["first_hi"])), (r["first_lo"], first, r["first_hi"])
    assert np.all((r["total_lo"] <= total) & (total <= r["total_hi"])), (r["total_lo"], total, r["total_hi"])
    assert r["variance"] == pytest.approx(variance, rel=0.05)
    assert r["total_lo"][2] > 0.15 and abs(r["first"][2]) < 0.05  # x3 acts only with x1


def test_ishigami_interval_coverage_over_seeds_is_plausible():
    first, total, _ = ishigami_indices()
    inside, widths = [], []
    for seed in range(20):
        r = sens.sobol_indices(*pick_freeze_run(ishigami, 256, 3, 100 + seed), resamples=300, seed=seed)
        inside += list((r["first_lo"] <= first) & (first <= r["first_hi"]))
        inside += list((r["total_lo"] <= total) & (total <= r["total_hi"]))
        widths += list(r["first_hi"] - r["first_lo"]) + list(r["total_hi"] - r["total_lo"])
    coverage = np.mean(inside)
    assert 0.85 <= coverage <= 1.0, coverage  # nominal 0.95; scrambled Sobol' points are better than iid
    assert np.mean(widths) < 0.3


def dgsm_of(fn, n, dim, seed):
    u = stats.qmc.Sobol(dim, scramble=True, seed=seed).random(n)
    grads = np.asarray(jax.vmap(jax.grad(fn))(jnp.asarray(u)))
    return sens.dgsm(grads, np.asarray(jax.vmap(fn)(jnp.asarray(u))), resamples=500, seed=seed)


def test_dgsm_of_ishigami_matches_its_closed_form_and_bounds_the_total_indices():
    r = dgsm_of(lambda u: ishigami(u, jnp), 4096, 3, 2)
    scale = (2 * np.pi) ** 2  # d/du = 2 pi d/dx
    nu = scale * np.array([0.5 * (1 + 2 * B_ISH * np.pi ** 4 / 5 + B_ISH ** 2 * np.pi ** 8 / 9), A_ISH ** 2 / 2,
                           16 * B_ISH ** 2 * np.pi ** 6 / 7 / 2])
    assert np.all((r["nu_lo"] <= nu) & (nu <= r["nu_hi"])), (r["nu_lo"], nu, r["nu_hi"])
    _, total, variance = ishigami_indices()
    assert np.all(nu / (np.pi ** 2 * variance) >= total)  # Sobol'-Kucherenko
    assert np.all(r["bound_hi"] >= total)
    # the screen ranks otherwise here: x2 > x3 > x1 by nu, x1 > x2 > x3 by the total index
    assert np.argsort(-r["nu"]).tolist() == [1, 2, 0] and np.argsort(-total).tolist() == [0, 1, 2]


def test_dgsm_ranks_like_the_total_indices_on_the_g_function():
    a = jnp.asarray([0.0, 0.5, 3.0, 9.0])

    def fn(u):
        return g_function(u, a)

    vi = 1 / (3 * (1 + np.asarray(a)) ** 2)
    total = vi * np.prod(1 + vi) / (1 + vi) / (np.prod(1 + vi) - 1)
    screen = dgsm_of(fn, 1024, 4, 3)
    r = sens.sobol_indices(*pick_freeze_run(lambda x: np.asarray(fn(jnp.asarray(x))), 1024, 4, 3), resamples=300)
    assert np.argsort(-screen["nu"]).tolist() == np.argsort(-r["total"]).tolist() == np.argsort(-total).tolist()
    assert np.all(screen["bound"] >= r["total_lo"])


def test_cliffs_delta_is_the_mann_whitney_effect():
    rng = np.random.default_rng(4)
    x_e, x_o = np.round(rng.normal(0.7, 1, 150), 1), np.round(rng.normal(0, 1, 700), 1)  # with ties
    delta, lo, hi = sens.cliffs_delta(x_e, x_o, resamples=2000, seed=1)
    u = stats.mannwhitneyu(x_e, x_o).statistic
    assert delta == pytest.approx(2 * u / (len(x_e) * len(x_o)) - 1, abs=1e-12)
    assert lo < delta < hi and lo > 0.0  # the events sit higher


def synthetic_table(n=4000, seed=0):
    """A campaign-like table whose false alarms depend on Kci alone, misses on the leakage size alone."""
    rng = np.random.default_rng(seed)
    kind = np.array(["none", "leakage", "disconnection", "none"])[rng.integers(0, 4, n)]
    t = pd.DataFrame({"scenario_id": np.arange(n), "status": np.where(np.arange(n) == 7, 1, 0), "fault_kind": kind,
                      "kci_scale": rng.uniform(0.9, 1.1, n), "noise_std_mm": rng.uniform(0.03, 0.07, n),
                      "turbulence": np.array(["light", "moderate"])[rng.integers(0, 2, n)],
                      "fault_size": np.where(kind == "leakage", rng.uniform(0.1, 0.3, n), 0.0)})
    t["true_model"] = np.where(kind == "none", 0, 1)
    t["false_alarm"] = t["kci_scale"] < 0.93
    t["loe_ratio0_max_pre"] = 1.0 - t["kci_scale"] + 0.01 * rng.random(n)
    t["missed"] = (kind == "leakage") & (t["fault_size"] < 0.15)
    t["separable"] = t["fault_size"] > 0.12
    t["fault_distance"] = t["fault_size"] / 4
    return t


SYNTHETIC_SPACE = {"kci_scale": [0.9, 1.1], "noise_std_mm": [0.03, 0.07], "turbulence": ["light", "moderate"],
                   "fault_kind": ["none", "leakage", "disconnection"], "leakage_size": [0.1, 0.3]}


def test_regional_table_ranks_the_one_driver_first_with_the_others_near_zero():
    t = synthetic_table()
    cfg = mcfdd.load_config({"space": SYNTHETIC_SPACE}, "campaign")
    df = tables.regional_table(cfg, t, resamples=300, confidence=0.95, seed=0)
    fa = df[df["outcome"] == "false_alarm"].set_index("factor")
    assert fa.index[0] == "kci_scale" and fa.loc["kci_scale", "statistic"] > 0.9
    assert fa.loc["kci_scale", "effect_hi"] < -0.9 and fa.loc["kci_scale", "p_value"] < 1e-100
    assert fa["statistic"].iloc[1:].max() < 0.1 and "fault_kind" not in fa.index  # fault-free runs only
    assert fa.loc["kci_scale", "runs"] == int(((t["fault_kind"] == "none") & (t["status"] == 0)).sum())
    missed = df[df["outcome"] == "missed"].set_index("factor")
    assert missed.index[0] == "leakage_size" and missed.loc["leakage_size", "statistic"] > 0.9
    assert missed.loc["leakage_size", "runs"] == int(((t["fault_kind"] == "leakage") & (t["status"] == 0)).sum())
    assert missed.loc["fault_kind", "kind"] == "categorical" and missed.loc["fault_kind", "statistic"] > 0.4
    assert missed.drop(index=["leakage_size", "fault_kind"])["statistic"].max() < 0.1
    turb = missed.loc["turbulence"]
    counts = [[int(((t["turbulence"] == v) & t["missed"] & (t["status"] == 0)).sum()),
               int(((t["turbulence"] == v) & ~t["missed"] & (t["status"] == 0) & (t["fault_kind"] != "none")).sum())]
              for v in ("light", "moderate")]
    assert turb["test"] == "fisher" and turb["p_value"] == pytest.approx(stats.fisher_exact(counts).pvalue)
    assert turb["rates"] == f"light {counts[0][0]}/{sum(counts[0])}; moderate {counts[1][0]}/{sum(counts[1])}"


def test_witnesses_are_the_largest_alarms_and_the_most_separable_misses():
    t = synthetic_table()
    w = tables.witnesses(t, 3)
    fa = t[t["false_alarm"] & (t["status"] == 0)].nlargest(3, "loe_ratio0_max_pre")
    assert w[w["outcome"] == "false_alarm"]["scenario_id"].tolist() == fa["scenario_id"].tolist()
    missed = w[w["outcome"] == "missed"]
    assert t.set_index("scenario_id").loc[missed["scenario_id"], "separable"].all()
    assert missed["value"].is_monotonic_decreasing


# A fault-free campaign whose false alarms depend on Kci alone: one doublet at one flight point, no
# turbulence, small sensor noise, Kci +-15 % against +-2 % supply pressure and +-1 % roll inertia, and
# detection_tau low enough for the slow servos to alarm (6 s runs, 32 base samples: 192 runs).
ONE_DRIVER = """
[campaign]
scenarios = 256
design = "sobol"
seed = 3
chunk_size = 512
duration_s = 6.0

[evaluation]
settle_s = 0.5

[fdd.loe]
load_gate = "fault_free"
excitation_floor_deg = 0.15
excitation_noise_factor = 0.0
detection_tau = 0.06

[space]
vcas_kt = 280.0
altitude_m = 2000.0
kci_scale = [0.85, 1.15]
supply_pressure_scale = [0.98, 1.02]
roll_inertia_scale = [0.99, 1.01]
noise_std_mm = 0.03
turbulence = "none"
fault_kind = "none"
manoeuvre_kind = "doublet"
amplitude = 0.8
t_start_s = 1.0
duration_s = 2.0

[sensitivity]
samples = 32
bootstrap = 500
outcomes = ["loe_ratio0_max_pre"]
"""


@pytest.fixture(scope="module")
def one_driver(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sensitivity")
    path = folder / "one_driver.toml"
    path.write_text(ONE_DRIVER)
    return path, mcfdd.sensitivity(path, out=folder / "out", progress=False), folder / "out"


def test_one_driver_campaign_ranks_kci_first_with_the_others_near_zero(one_driver):
    _, result, _ = one_driver
    idx = result.indices.set_index("factor")
    assert idx.index[0] == "kci_scale" and idx.loc["kci_scale", "total_lo"] > 0.5
    assert idx.loc["kci_scale", "first_lo"] > 0.5
    assert idx["total"].drop("kci_scale").max() < 0.1
    assert set(idx.index) == {"kci_scale", "supply_pressure_scale", "roll_inertia_scale", "noise_path"}
    assert (idx["base_points"] == 32).all() and (idx["runs"] == 32 * 6).all()
    fa = result.regional[result.regional["outcome"] == "false_alarm"].set_index("factor")
    assert fa.index[0] == "kci_scale" and fa.loc["kci_scale", "p_value"] < 0.01
    assert fa.loc["kci_scale", "effect_hi"] < 0 and fa.loc["kci_scale", "median_event"] < 0.9  # alarms at low Kci
    assert fa["p_value"].drop("kci_scale").min() > 0.05


def test_gradient_screen_ranks_like_the_total_indices_on_a_campaign_space(one_driver):
    _, result, _ = one_driver
    screen = result.screen
    continuous = result.indices[result.indices["kind"] == "continuous"]
    assert screen["factor"].tolist() == continuous["factor"].tolist() == ["kci_scale", "supply_pressure_scale",
                                                                         "roll_inertia_scale"]
    merged = continuous.merge(screen, on=["outcome", "stratum", "factor"]).set_index("factor")
    # S_T <= nu / (pi^2 V) where the effect is not negligible; gradients of the smooth statistic do not see
    # the hard one's jumps (a sample entering or leaving the excitation gate), the only way roll inertia
    # acts here (S_T about 5e-5)
    assert (merged["total_lo"] <= merged["bound_hi"]).loc[["kci_scale", "supply_pressure_scale"]].all()
    assert merged.loc["roll_inertia_scale", "total_hi"] < 1e-3
    assert any("within" in n for n in result.notes)


def test_design_runs_swap_one_factor_per_block(one_driver):
    _, result, _ = one_driver
    d, table = result.design, result.runs.scenarios
    assert d.factors == ("kci_scale", "supply_pressure_scale", "roll_inertia_scale", "noise_path")
    _, block, base = d.locate(table["scenario_id"].to_numpy())
    params = ["kci_scale", "supply_pressure_scale", "roll_inertia_scale"]
    a = table[block == 0].set_index(base[block == 0])
    b = table[block == 1].set_index(base[block == 1])
    for i, factor in enumerate(d.factors):
        ab = table[block == 2 + i].set_index(base[block == 2 + i])
        for p in params:
            np.testing.assert_array_equal(ab[p], (b if p == factor else a)[p])
        keys = d.plan.keys[ab["scenario_id"]]
        np.testing.assert_array_equal(keys, d.plan.keys[(b if factor == "noise_path" else a)["scenario_id"]])
    roll = table[block == 4].set_index(base[block == 4])
    np.testing.assert_allclose(roll["loe_ratio0_max_pre"], a["loe_ratio0_max_pre"], rtol=0.05)


def test_design_runs_do_not_depend_on_chunks_or_executor(one_driver):
    _, result, _ = one_driver
    d = result.design
    cfg = config.replace(d.config, {"campaign.chunk_size": 128})
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        again = mcfdd.run_campaign(cfg, progress=False, executor=pool, plan=d.plan)
    pd.testing.assert_frame_equal(again.scenarios, result.runs.scenarios, check_exact=True)


def test_command_writes_the_api_tables_and_resumes_a_finished_folder(one_driver, tmp_path, capsys):
    path, result, folder = one_driver
    assert cli.main(["sensitivity", str(path), "--out", str(tmp_path / "cli")]) == 0
    printed = capsys.readouterr().out
    assert "loe_ratio0_max_pre [all]: kci_scale S_T" in printed and "false_alarm (" in printed
    for name in ("indices", "screen", "regional", "witnesses"):
        pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "cli" / f"{name}.parquet"), getattr(result, name),
                                      check_exact=True)
    meta = io.read_metadata(folder / "indices.parquet")
    assert meta["seed"] == "3" and "sensitivity" in meta["config"] and "kci_scale" in meta["factors"]
    report = (folder / "report.md").read_text()
    assert "| kci_scale | continuous |" in report and "## What drives the false alarms and misses" in report
    assert all((folder / f"{name}.png").is_file() for name in sens_wf.PLOTS)
    again = mcfdd.sensitivity(path, out=folder, resume=True, progress=False)
    assert again.runs.simulated == 0
    pd.testing.assert_frame_equal(again.indices, result.indices, check_exact=True)


def test_figure_ranks_the_bars_and_refuses_unknown_names(one_driver):
    _, result, _ = one_driver
    fig = result.plot("indices")
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 1 and visible[0].get_title() == "loe_ratio0_max_pre"
    assert [t.get_text() for t in visible[0].get_yticklabels()][-1] == "kci_scale"  # largest on top
    with pytest.raises(ValueError, match="plot: 'pie' is not one of indices, screen, regional"):
        result.plot("pie")


def test_campaign_summary_says_what_drives_its_false_alarms(one_driver, tmp_path):
    path, _, _ = one_driver
    result = mcfdd.run_campaign(path, out=tmp_path / "campaign", progress=False)
    regional, witnesses = result.drivers()
    assert regional.iloc[0]["factor"] == "kci_scale" and regional.iloc[0]["outcome"] == "false_alarm"
    alarms = result.scenarios[result.scenarios["false_alarm"]]
    assert witnesses["scenario_id"].iloc[0] == alarms.loc[alarms["loe_ratio0_max_pre"].idxmax(), "scenario_id"]
    summary = (tmp_path / "campaign" / "summary.md").read_text()
    section = summary.split("## What drives the false alarms and misses")[1]
    assert f"- false alarm ({len(alarms)} of 256 runs): kci_scale D" in section
    assert f"scenario {witnesses['scenario_id'].iloc[0]} (loe_ratio0_max_pre" in section


def test_the_report_replays_the_witnesses_of_the_design_runs(one_driver):
    """The witnesses are runs of the pick-freeze design (not of the config's own design): the replay command of
    report.md rebuilds them from the design runs' folder with the outcome columns bit for bit."""
    _, result, out = one_driver
    line = next(s for s in (out / "report.md").read_text().splitlines() if s.startswith("- Replay the witnesses"))
    command = shlex.split(line.split("`")[1])
    ids = [int(i) for i in command[4].split(",")]
    assert command[2] == str(out) and ids == list(dict.fromkeys(result.witnesses["scenario_id"]))
    replayed = mcfdd.replay(command[2], ids, progress=False)
    assert replayed.differences() == []
    frame = replayed.to_pandas()  # the histories are the same runs: detection begins at the campaign's alarm time
    alarms = replayed.rows[replayed.rows["false_alarm"]]
    assert len(alarms)
    for _, row in alarms.iterrows():
        g = frame[(frame["run"] == f"scenario-{row['scenario_id']}") & (frame["t_s"] >= 0.5)]
        assert abs(g.loc[g["fault_detected"], "t_s"].iloc[0] - row["false_alarm_time_s"]) < 1e-4
    assert replayed.rows["kci_scale"].tolist() == result.runs.scenarios.set_index("scenario_id").loc[ids,
                                                                                                  "kci_scale"].tolist()


@pytest.mark.parametrize("changes, message", [
    ({"sensitivity.outcomes": ["far"]}, "sensitivity.outcomes[0]: 'far' is not an outcome; expected one of"),
    ({"sensitivity.outcomes": ["detection_latency_s"]}, "sensitivity.outcomes[0]: detection_latency_s needs faulty "
                                                         "runs; space.fault_kind has none"),
    ({"sensitivity.samples": 12}, "sensitivity.samples: 12 is not a power of 2"),
    ({"sensitivity.samples": 4}, "sensitivity.samples: 4 is outside the allowed range [8, 65536]"),
    ({"sensitivity.bootstrap": 10}, "sensitivity.bootstrap: 10 is outside the allowed range [100, 100000]"),
    ({"space.kci_scale": 1.0, "space.supply_pressure_scale": 1.0, "space.roll_inertia_scale": 1.0,
      "space.turbulence": ["none", "light"]}, "space: no continuous axis ([lo, hi]) to analyse"),
])
def test_bad_inputs_are_one_line_errors(tmp_path, capsys, changes, message):
    path = tmp_path / "bad.toml"
    path.write_text(ONE_DRIVER)
    with pytest.raises(config.ConfigError) as err:
        mcfdd.sensitivity(mcfdd.load_config(path, overrides=changes), progress=False)
    assert message in str(err.value) and "\n" not in str(err.value)
    argv = ["sensitivity", str(path), "--out", str(tmp_path / "out")]
    argv += [a for k, v in changes.items() for a in ("--set", f"{k}={v!r}".replace("'", '"'))]
    assert cli.main(argv) == 2
    stderr = capsys.readouterr().err
    assert message in stderr and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_estimators_refuse_what_they_cannot_estimate():
    with pytest.raises(ValueError, match="12 base samples: expected a power of 2"):
        sens.saltelli_matrices(12, 2, 0)
    with pytest.raises(ValueError, match="does not vary"):
        sens.sobol_indices(np.ones(8), np.ones(8), np.ones((2, 8)))
    assert math.isclose(sens.regional_categorical(np.array(["a"] * 5), np.arange(5) < 2)["p_value"], 1.0)


def test_design_of_a_shipped_space_maps_its_unit_rows_to_columns_and_strata():
    cfg = mcfdd.load_config(CONFIGS / "validation_kci10.toml", overrides={"sensitivity.samples": 8})
    d = sens_wf.design(cfg)
    assert d.strata == ("fault_kind",) and d.config.campaign.grid == ("fault_kind",)
    assert d.factors[-1] == "noise_path" and d.kinds.count("categorical") == 2  # turbulence, manoeuvre family
    assert d.blocks == len(d.factors) + 2 and d.plan.n == d.config.campaign.scenarios == 4 * 8 * d.blocks
    ids = np.arange(d.plan.n)
    cols = build.design_chunk(d.config, d.plan, ids)
    cell, block, base = d.locate(ids)
    axis = cfg.space.axis("kci_scale")
    i = d.factors.index("kci_scale")
    np.testing.assert_allclose(cols["kci_scale"], axis.lo + d.unit[block * 8 + base, i] * (axis.hi - axis.lo))
    kinds = np.array(["none", "leakage", "surface_damage", "disconnection"])
    assert (np.asarray(cols["fault_kind"]) == kinds[cell]).all()
    noise = block == 2 + d.factors.index("noise_path")
    np.testing.assert_array_equal(d.plan.keys[noise], cell[noise] * 16 + 8 + base[noise])  # B's noise path
    np.testing.assert_array_equal(d.plan.keys[block == 0], cell[block == 0] * 16 + base[block == 0])
    screen = sens_wf.design(config.replace(cfg, {"sensitivity.method": "screen"}))
    assert screen.blocks == 1 and screen.plan.n == 4 * 8
    np.testing.assert_array_equal(screen.unit[:, :-1], d.unit[:8, :-1])  # the A points

"""Worst-case search: restarts that keep the event, witnesses that are what a campaign scores, replays.

The optimiser's restarts on a synthetic score (an infeasible start continues as a fresh start from
the next pool point, step for step as a run started there); the hard statistic of each method's
witness of a small search against the campaign's own monitored batch over the scenario and run key
written in ``replay.toml`` (the config ``mcfdd simulate`` replays), for the stall detector's tau_f
and the LOE detection level's tau_d; that config parsed as a 'simulate' config and run.
"""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import mcfdd
from mcfdd import config
from mcfdd.analysis import campaign, optimise, scenarios, scoring, simulate, worst_case as wc
from mcfdd.workflows import campaign as runner
from mcfdd.workflows.common import precision

TARGET = jnp.array([0.2, 0.3])


@jax.jit
def synthetic(u):
    """Concave score with its maximum at TARGET, infeasible (-inf) where u[0] > 0.5."""
    value, grad = jax.vmap(jax.value_and_grad(lambda v: -jnp.sum((v - TARGET) ** 2)))(u)
    return jnp.where(u[:, 0] > 0.5, -jnp.inf, value), None, grad


def box(u):
    return optax.projections.projection_box(u, 0.0, 1.0)


def test_an_infeasible_start_is_replaced_by_the_next_pool_point():
    pool = np.array([[0.1, 0.9], [0.8, 0.8], [0.9, 0.1], [0.4, 0.6], [0.3, 0.1]])
    restarts = optimise.Restarts(pool, 2)
    trace = optimise.run(synthetic, jnp.asarray(pool[:2]), optimise.backtracking(0.05), 12, maximize=True,
                         project=box, restarts=restarts)
    params = [np.asarray(p) for p in trace.params]
    # start 1 was infeasible at its first point: it moved to pool point 2, infeasible too, then to point 3
    np.testing.assert_array_equal(params[1][1], pool[2])
    np.testing.assert_array_equal(params[2][1], pool[3])
    np.testing.assert_array_equal(restarts.slots, [0, 3])
    assert restarts.next == 4
    # from there it is a fresh start: step for step the run of a single start from pool point 3
    alone = optimise.run(synthetic, jnp.asarray(pool[3:4]), optimise.backtracking(0.05), 10, maximize=True,
                         project=box)
    np.testing.assert_allclose(np.stack([p[1] for p in params[2:]]), np.stack([np.asarray(p)[0] for p in alone.params]),
                               rtol=1e-12, atol=1e-15)
    # start 0 never left its first point's descent and improved
    assert np.all(np.isfinite([np.asarray(v)[0] for v in trace.values]))
    assert float(np.asarray(trace.values[-1])[0]) > float(np.asarray(trace.values[0])[0])


def test_without_pool_points_left_an_infeasible_start_backtracks():
    pool = np.array([[0.1, 0.9], [0.8, 0.8]])
    restarts = optimise.Restarts(pool, 2)
    trace = optimise.run(synthetic, jnp.asarray(pool), optimise.backtracking(0.05), 3, maximize=True, project=box,
                         restarts=restarts)
    np.testing.assert_array_equal(restarts.slots, [0, 1])
    # it has no feasible point: each step returns to where it stands and takes half the step before
    moves = [np.abs(np.asarray(b)[1] - np.asarray(a)[1]).max() for a, b in zip(trace.params, trace.params[1:])]
    assert 0.0 < moves[0] <= 0.05 and moves[1] == pytest.approx(moves[0] / 2, rel=0.2)
    assert all(np.isneginf(np.asarray(v)[1]) for v in trace.values)
    with pytest.raises(ValueError, match="3 starts need 1 to 2 pool points"):
        optimise.Restarts(pool, 3)


EDGE = jnp.array([0.7, 0.3])


@jax.jit
def beyond(u):
    """Concave score whose maximum (EDGE) lies outside the feasible set u[0] <= 0.5: the supremum is on its edge."""
    value, grad = jax.vmap(jax.value_and_grad(lambda v: -jnp.sum((v - EDGE) ** 2)))(u)
    return jnp.where(u[:, 0] > 0.5, -jnp.inf, value), None, grad


@pytest.mark.parametrize("patience", [1, 2, 3])
def test_a_start_is_replaced_after_patience_infeasible_evaluations_in_a_row(patience):
    pool = np.array([[0.3, 0.3], [0.1, 0.1]])
    restarts = optimise.Restarts(pool, 1, patience)
    trace = optimise.run(beyond, jnp.asarray(pool[:1]), optimise.backtracking(0.05), 30, maximize=True,
                         project=box, restarts=restarts)
    infeasible = np.array([not np.isfinite(np.asarray(v)[0]) for v in trace.values])
    params = np.stack([np.asarray(p)[0] for p in trace.params])
    # brute-force reference: the first evaluation that closes a run of `patience` infeasible ones
    runs = np.array([infeasible[max(0, i - patience + 1):i + 1].all() and i + 1 >= patience
                     for i in range(len(infeasible))])
    first = int(np.argmax(runs))
    assert runs.any() and restarts.slots[0] == 1
    np.testing.assert_array_equal(params[first + 1], pool[1])
    assert not np.any(np.all(params[:first + 1] == pool[1], axis=1))
    # before that the start backtracked towards the edge: its best feasible point lies within a step of it
    best = max(float(np.asarray(v)[0]) for v in trace.values[:first + 1] if np.isfinite(np.asarray(v)[0]))
    assert -0.2 ** 2 - 2 * 0.2 * 0.05 <= best < -0.2 ** 2
    with pytest.raises(ValueError, match="patience 0"):
        optimise.Restarts(pool, 1, 0)


def test_the_pool_holds_the_starts_then_the_runs_with_the_event_worst_first():
    hard = np.array([0.3, np.nan, 0.9, 0.1, np.nan, 0.5])
    points = wc.Points(np.arange(6.0)[:, None], {"turbulence": np.array(list("abcdef"))}, np.zeros((6, 1)), hard,
                       hard, {})
    pool = wc.pool_from(points, 2, "free", 0)
    np.testing.assert_array_equal(pool.index, [2, 5, 0, 3])
    np.testing.assert_array_equal(pool.categories["turbulence"], list("cfad"))
    low = wc.pool_from(points, 2, "detect", 0)
    np.testing.assert_array_equal(low.index, [3, 0, 5, 2])


def test_the_temperature_falls_geometrically_to_the_final_one():
    t = wc.temperatures(0.01, 0.001, 4)
    np.testing.assert_allclose(t, 0.01 * 0.1 ** (np.arange(5) / 4), rtol=1e-15)
    assert t[0] == 0.01 and t[-1] == pytest.approx(0.001, rel=1e-14) and np.all(np.diff(t) < 0)
    np.testing.assert_array_equal(wc.temperatures(0.05, 0.0, 3), [0.05] * 4)


def toy_rows(first, n):
    """Rows first .. n - 1 of a toy design: u = row / 100, the bound finite at every fifth row."""
    rows = np.arange(first, n)
    hard = np.where(rows % 5 == 0, rows / 100.0, np.nan)
    return wc.Points(rows[:, None] / 100.0, {"turbulence": np.array(["light", "moderate"])[rows % 2]},
                     rows[:, None] * 1.0, hard, hard, {"peak_load_fraction": rows / 10.0})


def test_the_screening_goes_on_in_batches_until_enough_runs_have_the_event():
    # 8 rows per batch: rows 0, 5 in the first, 10, 15 in the second, 20 in the third; want 4
    screened, batches = wc.screen(toy_rows, 8, 4, 64)
    assert batches == 2 and len(screened.hard) == 16
    whole = toy_rows(0, 16)  # brute force: the same rows at once
    for field in ("u", "x", "soft"):
        np.testing.assert_array_equal(getattr(screened, field), getattr(whole, field))
    np.testing.assert_array_equal(screened.categories["turbulence"], whole.categories["turbulence"])
    np.testing.assert_array_equal(screened.outcomes["peak_load_fraction"], whole.outcomes["peak_load_fraction"])
    assert np.isfinite(screened.hard).sum() == 4
    # capped by the most rows (a whole batch), and one batch when nothing is wanted
    capped, n = wc.screen(toy_rows, 8, 100, 20)
    assert n == 2 and len(capped.hard) == 16
    assert wc.screen(toy_rows, 8, 0, 64)[1] == 1
    # the pool of the refilled screening: the starts, then every run with the event, worst first
    pool = wc.pool_from(screened, 2, "detect", 0)
    np.testing.assert_array_equal(pool.index, [0, 5, 10, 15])


SPACE = """
[simulation]
duration_s = 2.0
precision = "float64"
seed = 3

[evaluation]
settle_s = 0.2

[search]
screening = 4
starts = 2
iterations = 2
learning_rate = 0.1

[space]
vcas_kt = [280.0, 360.0]
altitude_m = 0.0
turbulence = ["light", "moderate"]
kci_scale = [0.9, 1.1]
noise_std_mm = [0.03, 0.07]
manoeuvre_kind = ["doublet", "sideslip"]
amplitude = [0.5, 1.0]
t_start_s = [0.3, 1.0]
duration_s = [0.5, 1.0]
"""
STALL_FREE = SPACE + 'fault_kind = "none"\n'
DETECTION = (SPACE.replace("[search]", '[search]\ndetector = "loe_detection"\nbound = "detect"\ntemperature = 0.01\n'
                                       'final_temperature = 0.001\npool = 6\nscreening_max = 12')
             + 'fault_kind = ["disconnection", "surface_damage"]\nsurface_damage_size = [0.5, 1.0]\n'
               'fault_onset_s = [0.3, 0.8]\n\n[fdd.loe]\ndetection_confirm_s = 0.1\n')


def campaign_columns(replay: config.SimulateConfig, cfg: config.WorstCaseConfig) -> dict:
    """The campaign's monitored batch (:func:`mcfdd.analysis.campaign.device_batch`) over the replay's runs."""
    from mcfdd.workflows.simulate import runs_table

    table = runs_table(replay.runs)
    setup = runner.campaign_setup(config.CampaignConfig.model_validate(
        {"plant": config.to_dict(replay.plant), "fdd": config.to_dict(replay.fdd),
         "evaluation": config.to_dict(cfg.evaluation), "space": {"vcas_kt": [280.0, 360.0]},
         "campaign": {"scenarios": 4, "precision": "float64"}}))
    n = len(replay.runs)
    nearest, accept = scenarios.true_model(setup.nu_bank, table["fault_kind"], table["fault_size"])
    truth = scoring.Truth(scenarios.fault_onsets(table, n), accept, nearest)
    keys = jnp.concatenate([simulate.run_keys(r.seed, [r.index]) for r in replay.runs])
    sim = replay.simulation
    scen = scenarios.to_scenario(table, np.float64)
    kinds = tuple(sorted(set(np.asarray(scen.manoeuvre.kind).tolist())))
    return {k: np.asarray(v) for k, v in campaign.device_batch(setup.model, setup.fdd_params, setup.settings, scen,
                                                               truth, keys, sim.n_steps, sim.dt_s, sim.substeps,
                                                               kinds).items()}


@pytest.mark.parametrize("text", [STALL_FREE, DETECTION], ids=["stall_free", "loe_detection_detect"])
def test_each_witness_is_what_a_campaign_of_its_replay_scores(text, tmp_path):
    path = tmp_path / "search.toml"
    path.write_text(text)
    cfg = mcfdd.load_config(path)
    result = mcfdd.worst_case(cfg, progress=False)
    result.save(tmp_path / "out")
    replay = mcfdd.load_config(tmp_path / "out" / "replay.toml")
    assert isinstance(replay, config.SimulateConfig) and len(replay.runs) >= 2
    assert f"mcfdd simulate {tmp_path / 'out' / 'replay.toml'}" in (tmp_path / "out" / "report.md").read_text()
    with precision("float64"):
        columns = campaign_columns(replay, cfg)
    stat = wc.statistic(cfg.search.detector, cfg.search.bound)
    scale = 1.0 if cfg.search.detector != "stall" else 180.0 / np.pi / replay.plant.actuator.r_arm_m
    for i, run in enumerate(replay.runs):
        method, row = run.name.rsplit("-", 1)
        witness = result.points.loc[int(row)]
        assert witness["method"] == method
        assert stat.sign * columns[stat.hard][i] * scale == pytest.approx(witness[result.value], rel=1e-9, abs=1e-12)
    if cfg.search.detector == "loe_detection":  # the detection level's statistic: the sign is the verdict
        assert np.array_equal(columns["missed"], columns[stat.hard] > 0)
        # the screening went on until 6 runs had the event (or 12 points); the budget counts every row
        screened = result.points[result.points["method"] == "screening"]
        assert len(screened) in (4, 8, 12)
        assert len(screened) == 12 or np.isfinite(screened[result.value]).sum() >= 6
        assert (result.points["method"] == "monte_carlo").sum() == len(screened) + 2 * 3
        # each gradient step's smooth statistic is the log-sum-exp over the window at the schedule's temperature:
        # hard <= smooth <= hard + T_i log K (K samples at most)
        grad = result.points[result.points["method"] == "gradient"]
        t = wc.temperatures(0.01, 0.001, cfg.search.iterations)[grad["iteration"].to_numpy()]
        gap = (grad[f"{result.value}_smooth"] - grad[result.value]).to_numpy()
        ok = np.isfinite(gap)
        assert ok.any() and np.all(gap[ok] >= -1e-12)
        assert np.all(gap[ok] <= t[ok] * np.log(cfg.simulation.n_steps) + 1e-12)
    histories = mcfdd.simulate(replay, progress=False)
    assert histories.runs == [r.name for r in replay.runs]

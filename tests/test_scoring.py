"""Scoring monitors (DESIGN.md sections 5, 5a) against independent NumPy references.

Per family, a NumPy scoring loop written here over the recorded per-sample plant and FDD signals
of a few short runs is compared, exactly, with the monitors' columns over the same signals; the
campaign's columns with those of the recorded signals (as before the monitors existed); the FDD's
signed decision statistic with a NumPy reimplementation; every signed margin's sign with its hard
flag on 2,048 runs of a real campaign space in float32 and in float64; the smooth versions
against their hard limits; the smooth extremes against scipy's logsumexp. One module (about 500
lines): the families' references share the recorded runs and the windows' reference.
"""

from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp

import mcfdd
from helpers import SMALL
from mcfdd import config
from mcfdd.analysis import build, campaign, scenarios, scoring, simulate, tuning
from mcfdd.analysis.scoring import smooth
from mcfdd.workflows import campaign as runner
from mcfdd.workflows.common import load_bank, precision

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
# Short runs of the campaign tests' space that reach stall loads (high speed, large hinge scale, large
# commands), with LOE settings that detect and identify within seconds and signal rules that identify
# stalls readily (also outside stall loads, and on jammed rods): every family has something to count.
HARSH = (SMALL.format(n=24).replace("vcas_kt = [200.0, 360.0]", "vcas_kt = [300.0, 360.0]")
         .replace("altitude_m = [0.0, 6000.0]", "altitude_m = [0.0, 1500.0]")
         .replace("hinge_scale = [0.9, 1.4]", "hinge_scale = [1.3, 1.6]")
         .replace('manoeuvre_kind = ["doublet", "ol_doublet", "sideslip"]',
                  'manoeuvre_kind = ["ol_doublet", "doublet"]')
         .replace("amplitude = [0.5, 1.0]", "amplitude = [0.8, 1.0]")
         .replace("t_detec_s = 120.0", "t_detec_s = 120.0\nstall_grace_s = 0.2")
         + "\n[fdd.loe]\nconfirm_s = 0.0\ntau = 0.05\nexcitation_floor_deg = 0.01\ndetection_confirm_s = 0.3\n"
         "excitation_noise_factor = 0.0\nload_gate = \"fault_free\"\n"
         "detection_contrast = 0.0\ndetection_tau = 0.04\n\n[fdd.stall.signal]\nrate_min_deg_s = 60.0\n"
         "command_min_deg = 2.0\n"
         "position_min_deg = 2.0\nerror_min_deg = 0.2\n\n[fdd.stall.model]\ntau_deg = 40.0\n")


class Recorded:
    """A config's runs: their setup, truth and recorded plant and FDD histories (float64)."""

    def __init__(self, cfg):
        c = cfg.campaign
        self.cfg = cfg
        cols, self.n = build.design(cfg)
        self.model = build.plant_model(cfg.plant)
        bank, _ = load_bank(cfg.fdd, np.float64)
        self.fdd_params = build.fdd_params(cfg.fdd, bank, self.model.actuator.r_arm_m)
        self.settings = build.settings(cfg.evaluation, self.model.actuator.r_arm_m)
        self.onset = scenarios.fault_onsets(cols, self.n)
        self.nearest, self.accept = scenarios.true_model(np.asarray(bank.nu), cols["fault_kind"], cols["fault_size"])
        self.truth = scoring.Truth(self.onset, self.accept, self.nearest)
        self.scen = scenarios.to_scenario(cols, np.float64)
        self.kinds = tuple(sorted(set(np.asarray(self.scen.manoeuvre.kind).tolist())))
        self.keys = simulate.run_keys(c.seed, range(self.n))
        self.n_steps, self.dt = c.n_steps, c.dt_s
        self.plant, self.fdd = simulate.fdd_batch(self.model, self.fdd_params, self.scen, self.keys, c.n_steps, c.dt_s,
                                                  c.substeps, self.kinds)
        self.t = np.arange(c.n_steps) * c.dt_s

    def signal(self, name, i):
        source = self.plant if name in self.plant._fields else self.fdd
        return np.asarray(getattr(source, name)[i])


@partial(jax.jit, static_argnames="dt_s")
def score_recorded(settings, truth, fdd_params, plant, fdd, dt_s: float, temperature=None):
    """The monitors' columns over recorded signals (leading axes: runs, samples), one run per lane."""
    def one(truth, plant, fdd):
        monitor = scoring.monitors(settings, truth, fdd_params, dt_s, temperature)
        observer = scoring.observer(settings, truth, monitor)

        def body(state, xs):
            k, p, f = xs
            return observer.update(state, simulate.sample_time(k, dt_s), p, f)[0], None

        state, _ = jax.lax.scan(body, observer.init(plant.u_m.dtype), (jnp.arange(plant.u_m.shape[0]), plant, fdd))
        return scoring.finalize(settings, monitor, state, plant.u_m.shape[0] * dt_s)

    return jax.vmap(one)(truth, plant, fdd)


@pytest.fixture(scope="module")
def harsh(tmp_path_factory):
    path = tmp_path_factory.mktemp("scoring") / "harsh.toml"
    path.write_text(HARSH)
    rec = Recorded(config.load(config.CampaignConfig, path))
    rec.columns = {k: np.asarray(v) for k, v in score_recorded(rec.settings, rec.truth, rec.fdd_params, rec.plant,
                                                                 rec.fdd, rec.dt).items()}
    return rec


# ---------------------------------------------------------------------------------------------
# The NumPy reference: windows (DESIGN.md section 5) of one recorded run


def numpy_windows(rec: Recorded, i: int) -> dict:
    s, t, n = rec.settings, rec.t, rec.n_steps
    stall = rec.signal("stall", i)
    error = np.abs(rec.signal("u_c_m", i) - rec.signal("x_m", i))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stall.astype(int), [0]])))
    events = []
    for start, end in zip(edges[::2], edges[1::2]):
        t_end = t[end] if end < n else n * rec.dt
        relevant = (t_end - t[start] >= s.stall_min_duration_s) and (error[start:end].max() >= s.stall_min_error_m)
        events.append((start, end, relevant))
    last_end = np.full(n, -np.inf)
    for start, end, _ in events:
        if end < n:
            last_end[end:] = t[end]
    settled = t >= s.settle_s
    clear = ~stall & (t - last_end > s.stall_grace_s)
    onset = rec.onset[i]
    before = t < onset
    finite = (np.isfinite(rec.signal("u_m", i)) & np.isfinite(rec.signal("theta_stall", i))
              & np.isfinite(rec.signal("theta", i)).all(axis=1))
    return {"events": events, "settled": settled, "clear": clear, "before": before,
            "quiet": settled & before & clear, "in_window": (t >= onset) & (t <= onset + s.t_detec_s),
            "ok": bool(finite.all()), "openings": [start for start, _, _ in events]}


def first_time(t, mask):
    return t[mask][0] if mask.any() else np.inf


def largest(values, mask):
    return values[mask].max() if mask.any() else -np.inf


def nan_if_not_finite(x):
    return x if np.isfinite(x) else np.nan


def assert_columns(rec: Recorded, expected: dict):
    """Each expected column (name -> (n,) values) equals the monitors' column exactly (nan where nan)."""
    for name, values in expected.items():
        np.testing.assert_array_equal(rec.columns[name], np.asarray(values), err_msg=name)


# ---------------------------------------------------------------------------------------------
# LOE family


def test_loe_monitors_equal_a_numpy_scoring_of_the_recorded_signals(harsh):
    rec = harsh
    tiny = np.finfo(np.float64).tiny
    expected = {k: [] for k in ("false_alarm", "false_alarm_time_s", "detected", "detection_time_s", "must_detect",
                                "missed", "false_alarm_margin", "missed_margin", "identified_model",
                                "identification_time_s", "identified_correctly", "false_identification",
                                "identification_false_alarm", "loe_ratio0_max_pre", "loe_others_min_peak",
                                "loe_ratio0_max_post")}
    n_models = rec.accept.shape[1]
    for name in [f"ratio_{k}_{j}" for k in ("max_pre", "min_post") for j in range(n_models)]:
        expected[name] = []
    for i in range(rec.n):
        w = numpy_windows(rec, i)
        ok, t, quiet, window = w["ok"], rec.t, w["quiet"], w["in_window"]
        faulty = np.isfinite(rec.onset[i])
        fault = rec.signal("fault_detected", i)
        stat = rec.signal("detection_margin", i)
        fa_time, det_time = first_time(t, quiet & fault), first_time(t, window & fault)
        detected = ok and faulty and np.isfinite(det_time)
        must = ok and faulty and rec.nearest[i] >= 1
        expected["false_alarm"].append(ok and np.isfinite(fa_time))
        expected["false_alarm_time_s"].append(fa_time)
        expected["detected"].append(detected)
        expected["detection_time_s"].append(det_time if detected else np.nan)
        expected["must_detect"].append(must)
        expected["missed"].append(must and not detected)
        fa_best, det_best = largest(stat, quiet), largest(stat, window)
        expected["false_alarm_margin"].append((max(fa_best, tiny) if np.isfinite(fa_time) else min(fa_best, -tiny))
                                              if ok else np.nan)
        expected["missed_margin"].append(-(max(det_best, tiny) if detected else min(det_best, -tiny)) if must
                                         else np.nan)
        decided = rec.signal("detected", i)
        fid, idw = quiet & (decided >= 1), window & (decided >= 1)
        time = first_time(t, idw) if faulty else first_time(t, fid)
        identified = ok and np.isfinite(time)
        model = (decided[idw][0] if faulty else decided[fid][0]) if identified else -1
        expected["identified_model"].append(model)
        expected["identification_time_s"].append(time if identified else np.nan)
        expected["identified_correctly"].append(identified and faulty and model >= 0 and rec.accept[i, model])
        expected["false_identification"].append(identified and not faulty)
        expected["identification_false_alarm"].append(ok and fid.any())
        ratio, excited = rec.signal("ratio", i), rec.signal("excited", i)
        pre, post = quiet & excited, window & excited
        max_pre = ratio[pre].max(axis=0) if pre.any() else np.full(n_models, -np.inf)
        min_post = ratio[post].min(axis=0) if post.any() else np.full(n_models, np.inf)
        must_fire = np.where(rec.accept[i], np.inf, ratio).min(axis=1)
        expected["loe_ratio0_max_pre"].append(nan_if_not_finite(max_pre[0]))
        expected["loe_others_min_peak"].append(nan_if_not_finite(largest(must_fire, post)))
        expected["loe_ratio0_max_post"].append(nan_if_not_finite(largest(ratio[:, 0], post)))
        for j in range(n_models):
            expected[f"ratio_max_pre_{j}"].append(max_pre[j])
            expected[f"ratio_min_post_{j}"].append(min_post[j])
    assert_columns(rec, expected)
    assert np.any(expected["detected"]) and np.any(expected["missed"]) and np.any(expected["false_alarm"])
    assert np.any(np.asarray(expected["identified_model"]) >= 1)


def numpy_confirmed_statistic(rec: Recorded, i: int):
    """The FDD's signed statistic of the confirmed rejection, from the recorded theta, ||u|| and eta."""
    loe, dt = rec.fdd_params.loe, rec.dt
    theta, theta_u, theta_w = rec.signal("theta", i), rec.signal("theta_u", i), rec.signal("theta_w", i)
    eta = rec.signal("eta_signal", i) | rec.signal("eta_model", i)
    since, held, run_min, prev = np.inf, 0.0, 0.0, False
    out, confirmed = [], []
    tau = loe.detection_tau
    need = loe.detection_confirm_s - 0.5 * dt
    per_s = tau / max(loe.detection_confirm_s, dt)
    floor = loe.excitation_floor if loe.excitation_floor > 0 else 1.0
    hold = loe.stall_hold_s if loe.stall_hold_s > 0 else 1.0
    for k in range(rec.n_steps):
        since = 0.0 if eta[k] else since + dt
        aware = since <= loe.stall_hold_s
        contrast = theta[k, 0] - theta[k, 1:].min()
        rejected = (theta_w[k] >= loe.excitation_floor and not aware and theta[k, 0] >= loe.detection_tau * theta_u[k]
                    and contrast >= loe.detection_contrast * theta_u[k])
        held = held + dt if (rejected and prev) else 0.0
        prev = rejected
        den = theta_u[k] if theta_u[k] > 0 else 1.0
        margin = min(theta[k, 0] / den - tau, contrast / den - loe.detection_contrast,
                     (theta_w[k] - loe.excitation_floor) * tau / floor, (since - loe.stall_hold_s) * tau / hold)
        run_min = min(run_min, margin) if held > 0 else margin
        raw = min(run_min, (held - need) * per_s) if rejected else margin - max(need, 0.0) * per_s
        out.append(raw)
        confirmed.append(rejected and held >= need)
    return np.asarray(out), np.asarray(confirmed)


def test_the_fdd_detection_statistic_is_signed_by_its_decision_and_matches_numpy(harsh):
    rec = harsh
    for i in range(rec.n):
        raw, confirmed = numpy_confirmed_statistic(rec, i)
        stat = rec.signal("detection_margin", i)
        np.testing.assert_array_equal(confirmed, rec.signal("fault_detected", i))
        np.testing.assert_allclose(stat, raw, rtol=1e-9, atol=1e-15)
        near = np.abs(stat) < 1e-12  # the sign is the detection's but within rounding of zero
        np.testing.assert_array_equal((stat > 0)[~near], confirmed[~near])
    confirmed_runs = [numpy_confirmed_statistic(rec, i)[1].any() for i in range(rec.n)]
    assert any(confirmed_runs) and not all(confirmed_runs)


# ---------------------------------------------------------------------------------------------
# Stall family


def numpy_pending_chain(rec: Recorded, i: int, w: dict, method: str):
    """eta = 1 outside stall loads with the grace rule, run sample by sample: the first counted time."""
    s, t = rec.settings, rec.t
    outside = w["settled"] & w["clear"] & rec.signal(f"eta_{method}", i)
    openings = set(w["openings"])
    found, pending = np.inf, np.inf
    for k in range(rec.n_steps):
        if t[k] - pending > s.stall_grace_s:  # expired: the interval counts
            found, pending = min(found, pending), np.inf
        elif k in openings:  # a stall opens within the grace time: dropped
            pending = np.inf
        if outside[k] and pending == np.inf:
            pending = t[k]
    return min(found, pending)


def numpy_stall_memory(rec: Recorded, i: int, w: dict):
    """Per sample, the part of the stall detector's theta driven by the residual of the samples that are
    not clear (within stall loads and their grace time): eq. (14) run on that residual alone."""
    ev = rec.fdd_params.stall.evaluator
    r = np.abs(rec.signal("r_stall", i))
    decay = np.exp(-ev.gamma * rec.dt)  # the FDD's evaluator steps at the sample time
    memory, out = 0.0, np.zeros(rec.n_steps)
    for k in range(rec.n_steps):
        masked = 0.0 if w["clear"][k] else r[k]
        out[k] = memory + ev.alpha * masked
        memory = decay * memory + ev.beta * (1.0 - decay) / ev.gamma * masked
    return out


def test_stall_monitors_equal_a_numpy_scoring_of_the_recorded_signals(harsh):
    rec = harsh
    s, t = rec.settings, rec.t
    tau = rec.fdd_params.stall.tau
    tiny = np.finfo(np.float64).tiny
    names = ["stall_events", "stall_seen", "stall_theta_peak_min", "stall_missed_detection",
             "stall_missed_detection_margin", "stall_theta_max_free", "stall_false_detection",
             "stall_false_detection_margin", "jam_taken_for_stall", "jam_taken_for_stall_time_s"]
    names += [f"{k}_{m}" for m in ("signal", "model") for k in ("stall_identified", "stall_missed")]
    names += [f"stall_worst_latency_{m}_s" for m in ("signal", "model")]
    names += [f"eta_false_{m}{k}" for m in ("signal", "model") for k in ("", "_time_s", "_margin")]
    expected = {k: [] for k in names}
    explained = remembered = 0
    for i in range(rec.n):
        w = numpy_windows(rec, i)
        ok = w["ok"]
        theta = rec.signal("theta_stall", i)
        relevant = [(a, b) for a, b, r in w["events"] if r]
        peaks = [theta[a:b][t[a:b] - t[a] <= s.stall_window_s].max() for a, b in relevant]
        peak_min = min(peaks, default=np.inf)
        expected["stall_events"].append(len(relevant))
        expected["stall_seen"].append(bool(w["events"]))
        expected["stall_theta_peak_min"].append(nan_if_not_finite(peak_min))
        expected["stall_missed_detection"].append(ok and peak_min < tau)
        below = (tau - peak_min) * (1.0 / tau)
        expected["stall_missed_detection_margin"].append((max(below, tiny) if peak_min < tau else min(below, -tiny))
                                                         if ok else np.nan)
        free = largest(theta - numpy_stall_memory(rec, i, w), w["quiet"])
        remembered += largest(theta, w["quiet"]) > free
        fired = ok and free >= tau
        expected["stall_theta_max_free"].append(nan_if_not_finite(free))
        expected["stall_false_detection"].append(fired)
        margin = (free - tau) * (1.0 / tau)
        expected["stall_false_detection_margin"].append((max(margin, tiny) if fired else min(margin, -tiny)) if ok
                                                        else np.nan)
        for method in ("signal", "model"):
            eta = rec.signal(f"eta_{method}", i)
            latencies = [t[a:b][eta[a:b]][0] - t[a] for a, b in relevant if eta[a:b].any()]
            worst = max(latencies, default=-np.inf)
            expected[f"stall_identified_{method}"].append(len(latencies))
            expected[f"stall_worst_latency_{method}_s"].append(nan_if_not_finite(worst))
            late = worst > s.stall_window_s or len(latencies) < len(relevant)
            expected[f"stall_missed_{method}"].append(ok and late)
            # a false identification: eta = 1 outside stall loads not followed by an opening within the grace time
            outside = np.flatnonzero(w["settled"] & w["clear"] & eta)
            unexplained = [k for k in outside if not any(t[k] < t[o] and t[o] - t[k] <= s.stall_grace_s
                                                         for o in w["openings"])]
            explained += len(outside) - len(unexplained)
            found = t[unexplained[0]] if unexplained else np.inf
            assert numpy_pending_chain(rec, i, w, method) == found
            flag = ok and found < rec.onset[i]
            best = largest(rec.signal(f"eta_{method}_margin", i), w["quiet"])
            signed = max(best, tiny) if flag else min(best, -tiny)
            expected[f"eta_false_{method}"].append(flag)
            expected[f"eta_false_{method}_time_s"].append(nan_if_not_finite(found))
            expected[f"eta_false_{method}_margin"].append(signed if ok else np.nan)
        jam = rec.signal("jammed", i) & (rec.signal("eta_signal", i) | rec.signal("eta_model", i))
        jam_time = first_time(t, jam)
        expected["jam_taken_for_stall"].append(ok and np.isfinite(jam_time))
        expected["jam_taken_for_stall_time_s"].append(nan_if_not_finite(jam_time))
    free = ("stall_theta_max_free", "stall_false_detection_margin")  # exp of XLA and NumPy may differ in the last bit
    assert_columns(rec, {k: v for k, v in expected.items() if k not in free})
    for name in free:
        np.testing.assert_allclose(rec.columns[name], expected[name], rtol=1e-12, atol=1e-15, err_msg=name)
    assert sum(expected["stall_events"]) > 0 and sum(expected["stall_identified_signal"]) > 0
    assert remembered > 0  # some run's largest theta at a quiet sample was the memory of a stall load
    assert any(expected["jam_taken_for_stall"]) and any(expected["eta_false_signal"]), explained
    assert not all(expected["eta_false_signal"]) and any(expected["stall_false_detection"])


# ---------------------------------------------------------------------------------------------
# Plant truth family


def test_truth_monitors_equal_a_numpy_scoring_of_the_recorded_signals(harsh):
    rec = harsh
    t = rec.t
    expected = {k: [] for k in ("status", "peak_load_fraction", "peak_deflection_deg", "vcas_min_m_s", "vcas_max_m_s",
                                "altitude_min_m", "altitude_max_m")}
    for i in range(rec.n):
        w = numpy_windows(rec, i)
        after = t >= rec.onset[i] if np.isfinite(rec.onset[i]) else w["settled"]
        moving = after & (np.abs(rec.signal("rate_m_s", i)) >= scoring.truth_monitors.MOVING_RATE_M_S)
        expected["status"].append(0 if w["ok"] else 1)
        expected["peak_load_fraction"].append(nan_if_not_finite(largest(rec.signal("load_fraction", i), moving)))
        deflection = largest(np.abs(rec.signal("delta_rad", i)), after)
        expected["peak_deflection_deg"].append(nan_if_not_finite(deflection * (180.0 / np.pi)))
        for name in ("vcas", "altitude"):
            values = rec.signal(f"{name}_m_s" if name == "vcas" else "altitude_m", i)
            unit = "m_s" if name == "vcas" else "m"
            expected[f"{name}_min_{unit}"].append(values.min())
            expected[f"{name}_max_{unit}"].append(values.max())
    assert_columns(rec, expected)


def test_campaign_columns_equal_the_monitors_over_the_recorded_histories(harsh):
    """The campaign's scan (plant, FDD and monitors together) scores what the recorded histories score."""
    rec = harsh
    raw = campaign.run_batch(rec.model, rec.fdd_params, rec.settings, rec.scen, rec.truth, rec.keys, rec.n_steps,
                             rec.dt, rec.cfg.campaign.substeps, rec.kinds)
    assert set(raw) == set(rec.columns)
    for name, values in raw.items():
        if np.issubdtype(values.dtype, np.floating):
            np.testing.assert_allclose(values, rec.columns[name], rtol=1e-12, atol=0, err_msg=name)
        else:
            np.testing.assert_array_equal(values, rec.columns[name], err_msg=name)


def test_a_void_run_has_no_verdicts_and_nan_margins():
    cfg = config.parse(config.CampaignConfig, {"campaign": {"scenarios": 4, "duration_s": 1.0, "design": "random"},
                                               "evaluation": {"settle_s": 0.2}, "space": {"vcas_kt": [200.0, 300.0]}})
    cols, n = build.design(cfg)
    model = build.plant_model(cfg.plant)
    bank, _ = load_bank(cfg.fdd, np.float64)
    fdd = build.fdd_params(cfg.fdd, bank, model.actuator.r_arm_m)
    scen = scenarios.to_scenario(cols, np.float64)
    scen = scen._replace(noise_std_m=np.where(np.arange(n) == 2, np.nan, scen.noise_std_m))
    truth = scoring.Truth(np.full(n, np.inf), np.zeros((n, bank.k0.shape[0]), bool), np.zeros(n, np.int32))
    raw = campaign.run_batch(model, fdd, build.settings(cfg.evaluation, model.actuator.r_arm_m), scen, truth,
                             simulate.run_keys(0, range(n)), 100, 0.01, 4, (0,))
    assert list(raw["status"]) == [0, 0, scoring.Status.NON_FINITE, 0]
    for name, values in raw.items():
        if values.dtype == bool:
            assert not values[2], name
        elif name.endswith("_margin"):  # missed_margin: nan in fault-free runs, where no miss is possible
            assert np.isnan(values[2]) and (name == "missed_margin" or not np.isnan(values[[0, 1, 3]]).any()), name


def test_a_single_non_finite_measurement_voids_the_run(harsh):
    """The status is decided on the last sample: a non-finite measured position at any one sample leaves
    the detectors' theta non-finite to the end (the FDD over the recorded histories, one sample spoiled)."""
    rec = harsh
    u = np.array(rec.plant.u_m)
    u[0, 150], u[1, 200], u[2, rec.n_steps - 1] = np.nan, np.inf, -np.inf
    data = tuning.TrainingSet(rec.plant._replace(u_m=jnp.asarray(u)), rec.truth)
    columns = jax.jit(partial(tuning.training_columns, dt_s=rec.dt))(rec.fdd_params, rec.settings, data, None)
    status = np.asarray(columns["status"])
    assert status[:3].tolist() == [1, 1, 1] and (status[3:] == rec.columns["status"][3:]).all()
    for name in ("false_alarm", "detected", "missed", "eta_false_signal", "stall_false_detection"):
        assert not np.asarray(columns[name])[:3].any(), name
    assert np.isnan(np.asarray(columns["false_alarm_margin"])[:3]).all()


# ---------------------------------------------------------------------------------------------
# Every margin's sign is its flag, on a real campaign space


MARGINS = {"false_alarm": "false_alarm_margin", "missed": "missed_margin",
           "eta_false_signal": "eta_false_signal_margin",
           "eta_false_model": "eta_false_model_margin", "stall_missed_detection": "stall_missed_detection_margin",
           "stall_false_detection": "stall_false_detection_margin"}


@pytest.mark.parametrize("name", ["float32", "float64"])
def test_every_margin_is_positive_exactly_for_its_flag_on_2048_runs(name):
    """The space of stall_campaign.toml with LOE faults and 10 s runs busy with manoeuvres at high speed,
    and an FDD that alarms and identifies stalls readily: every flag is set in some runs and not in others."""
    cfg = mcfdd.load_config(CONFIGS / "stall_campaign.toml", overrides={
        "campaign.scenarios": 2048, "campaign.duration_s": 10.0, "campaign.precision": name,
        "space.fault_kind": ["none", "jamming", "surface_damage", "disconnection"],
        "space.surface_damage_size": [0.3, 1.0], "space.fault_onset_s": [1.5, 3.0], "space.t_start_s": [1.0, 3.0],
        "space.duration_s": [2.0, 6.0], "space.hold_s": [1.0, 3.0], "space.vcas_kt": [300.0, 380.0],
        "space.hinge_scale": [1.1, 1.4], "evaluation.settle_s": 1.0, "evaluation.stall_grace_s": 0.2,
        "fdd.loe.detection_tau": 0.04, "fdd.loe.detection_contrast": 0.0, "fdd.loe.detection_confirm_s": 0.2,
        "fdd.loe.excitation_floor_deg": 0.02, "fdd.loe.excitation_noise_factor": 0.0,
        "fdd.loe.load_gate": "fault_free", "fdd.stall.tau_deg": 1.4, "fdd.stall.model.tau_deg": 150.0,
        "fdd.stall.signal.rate_min_deg_s": 60.0, "fdd.stall.signal.command_min_deg": 2.0,
        "fdd.stall.signal.position_min_deg": 2.0, "fdd.stall.signal.error_min_deg": 0.2})
    with precision(name):
        setup = runner.campaign_setup(cfg)
        scen, truth, keys = runner.chunk_inputs(setup, cfg.campaign.seed, np.arange(setup.n), setup.n)
        c = cfg.campaign
        raw = {k: np.asarray(v) for k, v in campaign.device_batch(
            setup.model, setup.fdd_params, setup.settings, scen, truth, keys, c.n_steps, c.dt_s, c.substeps,
            setup.kinds).items()}
    assert raw["false_alarm_margin"].dtype == np.dtype(name)
    for flag, margin in MARGINS.items():
        positive = raw[margin] > 0
        np.testing.assert_array_equal(raw[flag], positive, err_msg=flag)
        applies = ~np.isnan(raw[margin])
        assert raw[flag].sum() >= 3 and (~raw[flag] & applies).sum() >= 3, (flag, raw[flag].sum())
        assert np.all(raw[margin][applies] != 0.0)


# ---------------------------------------------------------------------------------------------
# Smooth versions


def test_smooth_extremes_against_logsumexp():
    rng = np.random.default_rng(0)
    x = rng.normal(size=200)
    mask = rng.random(200) < 0.6
    temperature = 0.3
    acc = smooth.softmax_init(jnp.float64)
    for xi, mi in zip(x, mask):
        acc = smooth.softmax_step(temperature, acc, xi, mi)
    reference = temperature * logsumexp(x[mask] / temperature)
    assert float(smooth.softmax_value(temperature, acc)) == pytest.approx(reference, rel=1e-12)
    assert float(smooth.soft_max(jnp.asarray(x), jnp.asarray(mask), temperature)) == pytest.approx(reference, rel=1e-12)
    assert float(smooth.soft_min(jnp.asarray(x), jnp.asarray(mask), temperature)) == pytest.approx(
        -temperature * logsumexp(-x[mask] / temperature), rel=1e-12)
    assert float(smooth.softmax_value(temperature, smooth.softmax_init(jnp.float64))) == -np.inf
    # the gradient is the softmax weights on the masked values, zero elsewhere (no NaN from -inf)
    grad = jax.grad(lambda v: smooth.soft_max(v, jnp.asarray(mask), temperature))(jnp.asarray(x))
    weights = np.where(mask, np.exp((x - reference) / temperature), 0.0)
    np.testing.assert_allclose(np.asarray(grad), weights, rtol=1e-10, atol=1e-14)
    # tends to the hard extreme as the temperature goes to zero
    assert float(smooth.soft_max(jnp.asarray(x), jnp.asarray(mask), 1e-4)) == pytest.approx(x[mask].max(), abs=1e-3)
    # two accumulators merged: the log-sum-exp of both sets; not merged where the mask is off
    half = len(x) // 2
    a, b = smooth.softmax_init(jnp.float64), smooth.softmax_init(jnp.float64)
    for xi, mi in zip(x[:half], mask[:half]):
        a = smooth.softmax_step(temperature, a, xi, mi)
    for xi, mi in zip(x[half:], mask[half:]):
        b = smooth.softmax_step(temperature, b, xi, mi)
    merged = smooth.softmax_merge(temperature, a, b, True)
    assert float(smooth.softmax_value(temperature, merged)) == pytest.approx(reference, rel=1e-12)
    kept = smooth.softmax_merge(temperature, a, b, False)
    assert float(smooth.softmax_value(temperature, kept)) == pytest.approx(
        temperature * logsumexp(x[:half][mask[:half]] / temperature), rel=1e-12)


def test_smooth_margins_tend_to_the_signed_ones(harsh):
    """At a small temperature each smooth margin is within a few temperatures of its hard margin (the
    log-sum-exp of K values exceeds their maximum by at most T log K), through the tuner's FDD-only scan."""
    rec = harsh
    data = tuning.TrainingSet(rec.plant, rec.truth)
    columns = jax.jit(partial(tuning.training_columns, dt_s=rec.dt))
    hard = columns(rec.fdd_params, rec.settings, data, None)
    bound = np.log(rec.n_steps)
    for temperature in (1e-2, 1e-4):
        soft = columns(rec.fdd_params, rec.settings, data, temperature)
        for name in ("false_alarm_margin", "missed_margin", "eta_false_signal_margin", "eta_false_model_margin",
                     "stall_missed_detection_margin", "stall_false_detection_margin"):
            h, sm = np.asarray(hard[name]), np.asarray(soft[f"{name}_smooth"])
            both = np.isfinite(h) & np.isfinite(sm)
            np.testing.assert_array_equal(np.isfinite(h), np.isfinite(sm), err_msg=name)
            assert both.sum() >= 2, name
            scale = np.maximum(1.0, np.abs(h[both]))
            assert np.all(np.abs(sm[both] - h[both]) <= 3 * temperature * bound * scale + 1e-12), name

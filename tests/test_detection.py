"""Both FDD systems in closed loop on the nonlinear plant (issues 4 and 5), default parameters."""


import numpy as np
import pytest

import mcfdd
from mcfdd import config, io
from mcfdd.analysis import build, metrics
from mcfdd.fdd import lpv

CLOSED_LOOP = ("quiet", "doublet", "bank_to_bank", "roll_protection", "sideslip")


def simulate(runs, duration_s, fdd=None):
    cfg = config.parse(config.SimulateConfig, {"simulation": {"duration_s": duration_s, "seed": 3,
                                                              "precision": "float64"},
                                               "runs": runs, "fdd": fdd or {}})
    return cfg, mcfdd.simulate(cfg, progress=False).to_pandas()


def manoeuvre(kind, amplitude):
    return {"kind": kind, "amplitude": amplitude, "t_start_s": 4.0, "duration_s": 2.0, "hold_s": 2.0,
            "sideslip_deg": 6.0 * amplitude, "ramp_s": 1.0 if kind == "sideslip" else 0.3}


def test_fault_free_runs_never_decide_a_fault_model():
    """Every closed-loop manoeuvre at low, medium and high speed, nominal parameters, light turbulence."""
    runs = [{"name": f"{kind}-{v:.0f}-{h:.0f}-{a}", "vcas_kt": v, "altitude_m": h, "manoeuvre": manoeuvre(kind, a)}
            for kind in CLOSED_LOOP for v, h in ((170.0, 8000.0), (250.0, 3000.0), (330.0, 1000.0))
            for a in (-1.0, 0.6)]
    _, df = simulate(runs, 25.0)
    decided = df.groupby("run")["detected_model"].max()
    assert (decided <= 0).all(), decided[decided > 0]
    assert not df["eta_stall"].any()


FIG4_CASES = {"disconnection": ("disconnection", 1.0, 1), "surface-67": ("surface_damage", 0.67, 2),
              "leakage-27": ("leakage", 0.27, 5), "leakage-15": ("leakage", 0.15, 4), "fault-free": ("none", 0.0, 0)}


def fig4_runs():
    """The Fig. 4 point with faults at the bank's grid values: (decision histories of the runs, t, onset)."""
    sweep = config.load(config.SweepConfig, "configs/fig4.toml")
    base = build.run_columns(sweep.run)
    runs = []
    for name, (kind, size, _) in FIG4_CASES.items():
        run = {k: v for k, v in config.to_dict(sweep.run).items() if k not in ("fault",)}
        runs.append({**run, "name": name, "fault": {"kind": kind, "size": size, "onset_s": base["fault_onset_s"]}})
    _, df = simulate(runs, sweep.simulation.duration_s, config.to_dict(sweep.fdd))
    n = int(round(sweep.simulation.duration_s / sweep.simulation.dt_s))
    pick = {name: df.loc[df["run"] == name] for name in FIG4_CASES}
    return pick, df["t_s"].to_numpy()[:n], base["fault_onset_s"]


def test_fig4_grid_faults_detected_and_identified_where_separable():
    """At the Fig. 4 point (nominal plant, constant tau), the disconnection is detected within the paper's
    10 s, the 27 % pressure loss within 15 s (the second roll), and the fault-free run never is; an
    identification is never wrong
    and never switches; the 27 % pressure loss is identified. Inside the load gate the no-load and 67 %
    models differ by less than tau, so the surface losses are not identified (and the 67 % loss sits at
    the detection threshold here). The 15 % pressure loss is near the detection threshold at this point:
    over 16 noise realisations it is detected at the first or second roll (3-8 s after the onset) in 15
    and at the third (14.8 s) in one, the draws of this run; it must be detected by the third roll."""
    runs, t, onset = fig4_runs()
    for name, (_, _, model) in FIG4_CASES.items():
        fault = runs[name]["fault_detected"].to_numpy()
        decided = runs[name]["detected_model"].to_numpy()
        hist = metrics.decision_history(decided[None], t, np.array([onset]))
        if model == 0:
            assert not fault.any() and hist["first_model"][0] == -1, name
            continue
        assert not fault[t < onset].any(), name
        if name != "surface-67":
            limit = {"leakage-15": 20.0, "leakage-27": 15.0}.get(name, 10.0)
            assert fault.any() and t[fault.argmax()] - onset < limit, name
        assert hist["first_model"][0] in (model, -1) and hist["switches"][0] == 0, name
        if name == "leakage-27":
            assert hist["first_model"][0] == model, name


@pytest.fixture(scope="module")
def fig5():
    cfg = config.load(config.SimulateConfig, "configs/fig5.toml")
    cfg = config.replace(cfg, {"simulation.precision": "float64"})
    return mcfdd.simulate(cfg, progress=False).to_pandas()


def stall_events(stall):
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stall.astype(int), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def test_fig5_stall_events_are_identified_fast(fig5):
    stall = fig5["stall"].to_numpy(dtype=bool)
    events = stall_events(stall)
    assert len(events) == 2
    t = fig5["t_s"].to_numpy()
    for method, limit in (("signal", 0.5), ("model", 1.0)):
        eta = fig5[f"eta_{method}"].to_numpy(dtype=bool)
        for start, end in events:
            assert eta[start:end].any(), method
            assert t[start + eta[start:end].argmax()] - t[start] <= limit, method
    outside = fig5["eta_signal"].to_numpy(dtype=bool) & ~stall
    grace = np.zeros_like(stall)
    for start, end in events:
        grace[max(start - 50, 0):end + 50] = True
    assert not (outside & ~grace).any()


def test_jamming_and_stall_free_high_inputs_do_not_give_eta():
    """A jam at small deflection while the stick moves, and a full-stick roll at moderate speed."""
    runs = [
        {"name": "jam-small", "vcas_kt": 300.0, "altitude_m": 1000.0, "fault": {"kind": "jamming", "onset_s": 3.0},
         "manoeuvre": manoeuvre("doublet", 1.0)},
        {"name": "full-stick", "vcas_kt": 280.0, "altitude_m": 2000.0, "manoeuvre": manoeuvre("roll_protection", 1.0)},
        {"name": "sideslip", "vcas_kt": 260.0, "altitude_m": 2000.0,
         "manoeuvre": {**manoeuvre("sideslip", 1.0), "sideslip_deg": 8.0}},
    ]
    _, df = simulate(runs, 15.0)
    jam = df[df["run"] == "jam-small"]
    assert jam["iota_stall"].any(), "the jam is detected by the stall detector's residual"
    assert jam.loc[jam["t_s"] >= 3.0, "delta_deg"].abs().max() < 3.0  # jammed at a small deflection
    assert not df["stall"].any()
    assert not df["eta_signal"].any()
    assert not df["eta_model"].any()


def test_float32_histories_agree_with_float64():
    """The shipped precision: a deterministic run (no turbulence, no sensor noise) with a 27 % pressure
    loss in float32 against float64 (both levels decide: detection and identification of model 5).
    Tolerances are a few times what such a run measured (a 27 % pressure loss at 320 kt: deflection 6e-7
    of its peak, evaluations 1e-5, the small theta of the 27 % model 8e-5); the decisions are the same at
    every sample."""
    run = {"name": "b2b", "vcas_kt": 320.0, "altitude_m": 1000.0, "turbulence": "none", "noise_std_mm": 0.0,
           "fault": {"kind": "leakage", "size": 0.27, "onset_s": 1.0},
           "manoeuvre": {"kind": "bank_to_bank", "amplitude": 1.0, "t_start_s": 1.5, "duration_s": 2.0, "hold_s": 3.0,
                         "ramp_s": 0.2}}
    out = {p: mcfdd.simulate({"simulation": {"duration_s": 10.0, "precision": p}, "runs": [run],
                              "fdd": {"loe": {"tau": 0.06, "excitation_floor_deg": 0.05}}},
                             progress=False).to_pandas()
           for p in ("float32", "float64")}
    single, double = out["float32"], out["float64"]
    assert single["theta_0"].dtype == np.float32 and double["theta_0"].dtype == np.float64
    for column, tol in (("delta_deg", 1e-5), ("theta_u", 1e-4), ("theta_stall", 1e-4),
                        *((f"theta_{i}", 3e-4) for i in range(6))):
        peak = np.abs(double[column].to_numpy()).max()
        assert np.abs(single[column].to_numpy() - double[column].to_numpy()).max() <= tol * peak, column
    assert double["fault_detected"].any(), "the run should detect the fault"
    assert (double["detected_model"] >= 1).any(), "the run should identify a fault model"
    for column in ("fault_detected", "detected_model"):
        np.testing.assert_array_equal(single[column].to_numpy(), double[column].to_numpy())


def test_fault_free_saturated_slews_leave_no_residual_behind_the_gate():
    """Full-stick manoeuvres at low dynamic pressure on the nominal fault-free plant drive the servo
    valve into current saturation (tracking error beyond the 3.5 deg linear range, where residual
    evaluation is suspended); in the 3 s after every saturated sample the fault-free statistic
    theta_0 / ||u|| stays below detection_tau while excited, and no LOE fault is detected (floor 0.1 deg,
    so that the decaying excitation after each slew is evaluated at both speeds)."""
    runs = [{"name": f"{kind}-{v:.0f}-{a}", "vcas_kt": v, "altitude_m": h, "manoeuvre": manoeuvre(kind, a)}
            for kind in ("bank_to_bank", "roll_protection", "doublet") for v, h in ((140.0, 9400.0), (167.0, 8200.0))
            for a in (-1.0, 1.0)]
    cfg, df = simulate(runs, 16.0, {"loe": {"excitation_floor_deg": 0.1}})
    detection_tau = cfg.fdd.loe.detection_tau
    for name, run in df.groupby("run"):
        t = run["t_s"].to_numpy()
        saturated = np.abs(run["u_c_deg"] - run["u_deg"]).to_numpy() > cfg.fdd.loe.linear_range_deg
        assert saturated[t >= 4.0].any(), name
        after = np.zeros_like(saturated)
        for i in np.flatnonzero(saturated):
            after |= (t > t[i]) & (t <= t[i] + 3.0)
        excited = run["excited"].to_numpy() & after & ~saturated
        ratio = run["theta_0"].to_numpy()[excited] / run["theta_u"].to_numpy()[excited]
        assert excited.any() and ratio.max() < detection_tau, (name, ratio.max())
        assert not run["fault_detected"].to_numpy()[t >= 2.0].any(), name


def test_servo_gain_mismatch_shows_as_its_own_ratio_after_saturated_slews():
    """The witness condition of loe_campaign's fault-free tau_f: a plant whose servo gain is 10 % low
    (Kci 0.9) in full-stick doublets that saturate the servo valve on the way out and back, without
    sensor noise. theta_0 / ||u|| estimates the relative gain mismatch: in the 3 s after the last
    saturated sample (the manoeuvre's tail) it stays below the sampled mismatch
    (exp(-k0 T) - exp(-0.9 k0 T)) / (1 - exp(-k0 T)) = 0.089 at k0 = 25 1/s (a ratio growing on the
    tail, as with a model rod's ||u|| in its place, reached 0.093-0.104 here) and reaches half of it, and
    no LOE fault is detected."""
    runs = [{"name": f"doublet-{v:.0f}-{a}", "vcas_kt": v, "altitude_m": h, "kci_scale": 0.9, "noise_std_mm": 0.0,
             "manoeuvre": manoeuvre("doublet", a)}
            for v, h in ((140.0, 9400.0), (167.0, 8200.0)) for a in (-1.0, 1.0)]
    cfg, df = simulate(runs, 16.0, {"loe": {"excitation_floor_deg": 0.1}})
    for name, run in df.groupby("run"):
        t = run["t_s"].to_numpy()
        saturated = np.abs(run["u_c_deg"] - run["u_deg"]).to_numpy() > cfg.fdd.loe.linear_range_deg
        last = t[np.flatnonzero(saturated)[-1]]
        assert 5.0 < last < 12.0, name
        tail = run["excited"].to_numpy() & (t > last) & (t <= last + 3.0)
        ratio = run["theta_0"].to_numpy()[tail] / run["theta_u"].to_numpy()[tail]
        assert tail.any() and 0.045 < ratio.max() < 0.089, (name, ratio.max())
        assert not run["fault_detected"].to_numpy().any(), name


def test_load_gate_on_the_best_fitting_model_does_not_hide_a_disconnected_rod_at_its_stop():
    """A sideslip at 330 kt after a disconnection drives the rod to its 25 deg stop (the surface no longer rolls
    the aircraft); the same manoeuvre on the healthy actuator holds a deflection at high hinge load. The filters
    restart exactly where a numpy model of the gate says (tracking error beyond the linear range, or the gated
    load above 0.5, at this sample or the one before). The fault-free model's load estimate, the healthy
    surface's load, chatters between about +0.7 and -1.1 on the rod at its stop and its gate hides the
    disconnection (not detected); gated on the load of the best-fitting model (the no-load model's: none) the
    disconnected rod is never gated by load and is detected (4 s after the onset), while the healthy loaded rod
    is still gated and raises no alarm."""
    bank = lpv.from_dict(io.load_bank_dict())[0]
    nu2 = np.asarray(bank.nu)[:, 1]
    sideslip = {"kind": "sideslip", "amplitude": 1.0, "t_start_s": 4.0, "duration_s": 5.0, "hold_s": 2.0,
                "ramp_s": 1.0, "sideslip_deg": 10.0}
    runs = [{"name": kind, "vcas_kt": 330.0, "altitude_m": 1000.0, "manoeuvre": sideslip,
             "fault": {"kind": kind, "size": 0.0, "onset_s": 2.0}} for kind in ("disconnection", "none")]
    for gate in ("fault_free", "best_fit"):
        cfg, df = simulate(runs, 16.0, {"loe": {"load_gate": gate}})
        loe = cfg.fdd.loe
        for name, run in df.groupby("run"):
            u, u_c = run["u_deg"].to_numpy(), run["u_c_deg"].to_numpy()
            theta = run[[f"theta_{i}" for i in range(nu2.size)]].to_numpy()
            load = run["load_fraction"].to_numpy()
            gated_load = load * (nu2[np.argmin(theta, axis=1)] if gate == "best_fit" else 1.0)
            linear = np.abs(u_c - u) > loe.linear_range_deg
            by_load = np.abs(gated_load) > loe.max_load_fraction
            gated = linear | by_load
            restart = gated[1:] | gated[:-1]
            np.testing.assert_array_equal(run["r_0"].to_numpy()[1:] == 0.0, restart, err_msg=f"{gate} {name}")
            t = run["t_s"].to_numpy()
            detected = run["fault_detected"].to_numpy()
            at_stop = np.abs(u) > 24.5
            if name == "disconnection":
                assert at_stop.sum() > 50, name
                if gate == "fault_free":
                    assert load[at_stop].max() > 0.6 and load[at_stop].min() < -0.9
                    assert (by_load & ~linear).sum() > 100 and not detected.any()
                else:
                    assert not by_load.any() and detected[t > 2.0].any()
            else:
                assert (by_load & ~linear).sum() > 50 and not detected.any(), (gate, name)

"""FDD sections: the LOE model-detection bank and the stall-load detector (DESIGN.md section 4).

Residual thresholds and signal levels are in degrees of surface deflection (rod position /
r_arm); :mod:`mcfdd.analysis.build` turns them into rod positions in m.
"""

from __future__ import annotations

from mcfdd.config.base import Section, choice, spec


class EvaluatorConfig(Section):
    """Narendra evaluator of eq. (14)."""

    alpha: float = spec(0.0, lo=0.0, doc="weight of |r|")
    beta: float = spec(1.0, lo=0.0, doc="weight of the forgetting integral of |r|")
    gamma_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=1000.0, doc="forgetting factor")


class LoeDetectionConfig(Section):
    """Model-detection bank for parametric LOE faults (Section 4).

    Defaults are tuned for 0.05 mm position-sensor noise (see README): the paper's evaluator
    (alpha = 0, beta = 1, gamma = 0.1) averages sensor noise over 10 s against manoeuvre
    transients of a few seconds, so gamma = 1; a slow filter pole keeps the noise band narrow.
    Two levels: detection (``detection_tau``, ``detection_contrast``, ``detection_confirm_s``: the
    fault-free model rejected) and identification (``tau``, ``tau_schedule``, ``confirm_s``: the signature (15)).
    The gate on the best-fitting model's load and the noise-relative floor are the default since
    ``configs/tune_default.toml``'s held-out rule adopted them (README, "The default FDD tuned on its own space").
    """

    pole_1_s: float = spec(0.5, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of every filter")
    direction_pole_1_s: float = spec(20.0, lo=0.0, lo_open=True, hi=1e4, doc="sgn(xdot) of the LPV gains is the "
                                     "sign of the measured tracking error low-passed with this pole, up to the "
                                     "previous sample (so it does not rectify the current sample's sensor noise)")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=0.0, beta=1.0, gamma_1_s=1.0))
    tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                      doc="threshold on theta_i / ||u||, about the relative gain mismatch |k_j - k_i| / k0_i")
    tau_schedule: float = spec(0.0, lo=0.0, hi=1.0, doc="scheduled thresholds tau_i(rho) = max(tau, tau_schedule "
                               "x distance (16) from model i to its nearest model at the current point, in ratio "
                               "units); 0 keeps tau constant")
    detection_tau: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0, doc="detection: the fault-free model is "
                                "rejected while theta_0 / ||u|| is above this and ||u|| above the excitation floor")
    detection_confirm_s: float = spec(0.5, lo=0.0, hi=60.0, doc="detection: the rejection must persist this long")
    detection_contrast: float = spec(0.05, lo=0.0, hi=10.0, doc="detection: the fault-free model is rejected only "
                                     "while theta_0 / ||u|| is also this far above the smallest ratio of the fault "
                                     "models (a fault model explains the rod better; sensor noise at the excitation "
                                     "floor raises all ratios alike)")
    excitation_floor_deg: float = spec(0.05, lo=0.0, doc="no decision (detection or identification) while ||u|| "
                                       "(the evaluated low-passed |u_c - u|) is below this: sensor noise alone gives "
                                       "about 0.8 x its RMS (0.06 deg at 0.07 mm)")
    excitation_load_fraction: float = spec(0.0, lo=0.0, hi=1.0, doc="load-weighted excitation: the floor "
                                           "applies to ||u|| with each sample weighted by min(1, estimated hinge-load "
                                           "fraction / this), so decisions are made only where the fault-free and "
                                           "surface-loss models differ; 0 weighs every sample 1")
    excitation_noise_factor: float = spec(2.5, lo=0.0, hi=100.0, doc="noise-relative floor: the excitation floor "
                                          "is at least this many times the run's position-sensor noise RMS, estimated "
                                          "online from the measured position (in the units of ||u||, about 0.8 x the "
                                          "RMS for a rod at rest); 0 keeps the floor absolute")
    noise_gamma_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=100.0, doc="forgetting rate of the online "
                                  "sensor-noise estimate (excitation_noise_factor > 0)")
    confirm_s: float = spec(2.0, lo=0.0, hi=60.0, doc="identification: a decoded model must persist this long")
    max_load_fraction: float = spec(0.5, lo=0.0, hi=1.0, doc="residuals are not evaluated above this estimated "
                                    "hinge-load fraction (the healthy surface's, so the gate also hides a "
                                    "disconnected rod at large deflections); 1 builds no load gate")
    load_gate: choice(("fault_free", "best_fit")) = spec("best_fit", doc="the load the gate compares with "
                                                         "max_load_fraction: the fault-free model's estimate (the "
                                                         "healthy surface's load), or that times the surface "
                                                         "effectiveness nu2 of the bank model with the smallest "
                                                         "evaluated residual so far (the load the rod's motion "
                                                         "shows: none on a disconnected rod)")
    linear_range_deg: float = spec(3.5, lo=0.0, lo_open=True, doc="residuals are not evaluated while |u_c - u| "
                                   "exceeds this (servo-valve current saturation at i_max / Kp = 4 deg)")
    stall_hold_s: float = spec(3.0, lo=0.0, hi=60.0, doc="no LOE decision while a stall load is identified "
                               "and this long after")


class SignalRulesConfig(Section):
    """Signal-based stall identification, eqs. (32)-(35)."""

    rate_min_deg_s: float = spec(2.0, lo=0.0, lo_open=True, doc="u_dot_min of (33)")
    command_min_deg: float = spec(10.0, lo=0.0, doc="tau_uc,max of (34)")
    position_min_deg: float = spec(10.0, lo=0.0, doc="tau_u,max of (34)")
    window_s: float = spec(0.1, lo=0.0, lo_open=True, hi=10.0,
                           doc="shortest averaging time and re-anchoring window of the mean rate (32)")
    error_min_deg: float = spec(0.5, lo=0.0, doc="smallest |u_c - u| for which (35) counts")


class ModelRuleConfig(Section):
    """Stall identification by model detection with Q_sl, eq. (30).

    The residual left by the motion just before a stall decays at the pole a_sl, so a_sl sets the
    identification latency: on ``configs/stall_campaign.toml`` a_sl = 5 1/s (tau_sl 8 deg)
    identified 242 of 264 stall loads with a median worst latency of 0.52 s, a_sl = 20 1/s
    (tau_sl 15 deg) 262 with 0.24 s (95th percentile 0.36 s), with no identification outside
    stall loads in either. tau_sl grows with a_sl because sensor noise reaches r_sl amplified
    by about a_sl / k_sl.
    """

    k_sl_1_s: float = spec(0.1, lo=0.0, lo_open=True, hi=1.0, doc="stall-model gain (paper: 0.01..0.1)")
    pole_1_s: float = spec(20.0, lo=0.0, lo_open=True, hi=1000.0, doc="a_sl")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=0.0, beta=10.0, gamma_1_s=10.0))
    tau_deg: float = spec(15.0, lo=0.0, lo_open=True, doc="tau_sl: stall while theta_sl stays below")


class StallDetectionConfig(Section):
    """Stall-load detector (Section 5; paper evaluator alpha = beta = 1, gamma = 0.1)."""

    pole_1_s: float = spec(10.0, lo=0.0, lo_open=True, hi=1000.0, doc="filter pole a of eq. (20)")
    evaluator: EvaluatorConfig = spec(EvaluatorConfig(alpha=1.0, beta=1.0, gamma_1_s=0.1))
    tau_deg: float = spec(1.0, lo=0.0, lo_open=True, doc="threshold tau of eq. (25)")
    saturation_rate_fraction: float = spec(0.0, lo=0.0, hi=1.0, doc="rate-saturation gate: the detector is not "
                                           "evaluated (its filter restarts from equilibrium) while |u_c - u| exceeds "
                                           "saturation_error_deg and the rod moves towards the command at least this "
                                           "fraction of the fault-free model's saturated rate k x saturation_error_deg "
                                           "(a slew at the valve's saturated rate, which the first-order model (20) "
                                           "does not follow; a stalled rod does not move and is never gated); 0 "
                                           "builds no gate")
    saturation_error_deg: float = spec(3.5, lo=0.0, lo_open=True, hi=25.0, doc="rate-saturation gate: the servo "
                                       "valve's linear range of the tracking error (current saturation at i_max / Kp "
                                       "= 4 deg)")
    rate_pole_1_s: float = spec(100.0, lo=0.0, lo_open=True, hi=1e4, doc="rate-saturation gate: pole of the "
                                "low-pass of the measured rod rate (backward difference of the measured position); "
                                "fast, so the gate closes at the first sample of a saturated slew, before the "
                                "detector's residual has grown: 0.05 mm of sensor noise gives the rate an RMS "
                                "of about 5 deg/s, against a saturated rate near 90 deg/s")
    identification_tau_deg: float = spec(0.0, lo=0.0, doc="identification gate: both identification methods "
                                         "open while theta is at least this (deg), instead of the detector's "
                                         "tau_deg; 0: tau_deg (with identification_residual_deg 0 too, no gate is "
                                         "built and iota opens them, the paper's rule)")
    identification_residual_deg: float = spec(0.0, lo=0.0, doc="identification gate: ... and while the detector's "
                                              "residual now, signed outwards (-sgn(u) r: the rod short of the "
                                              "model's prediction towards a command beyond it, as in a stall), is at "
                                              "least this (deg), so that the evaluator's memory of an earlier stall "
                                              "load does not open identification by itself; 0: no residual condition")
    identification: choice(("signal", "model")) = spec("signal", doc="which eta is eta_stall")
    signal: SignalRulesConfig = spec(SignalRulesConfig())
    model: ModelRuleConfig = spec(ModelRuleConfig())


class FddConfig(Section):
    bank: str = spec("default", doc="LPV bank JSON file, or 'default' for the bank shipped with mcfdd")
    loe: LoeDetectionConfig = spec(LoeDetectionConfig())
    stall: StallDetectionConfig = spec(StallDetectionConfig())

"""Detectability: distance (16) on the plant's small-error gains, separability, the cell table and its figure."""

import math

import numpy as np
import pandas as pd
import pytest

from mcfdd import plots, report
from mcfdd.analysis import metrics
from mcfdd.plant import actuator

ACT = actuator.ActuatorParams()
STALL_FORCE_N = ACT.supply_pressure_pa * ACT.piston_area_m2


def _plant_gain(nu1, nu2, load_n, direction, params=ACT):
    """Gain of the plant's closed form at a 1e-9 m error towards ``direction`` (+1: against the load)."""
    x = 4e-3
    k, _ = actuator.gain(params, nu1, nu2, load_n, x, x + direction * 1e-9)
    return float(k)


@pytest.mark.parametrize("nu1, nu2", [(1.0, 0.0), (1.0, 0.33), (0.73, 1.0), (0.85, 0.66)])
@pytest.mark.parametrize("fraction", [0.0, 0.17, 0.46, 0.9])
def test_fault_distance_is_eq_16_on_the_plant_gains(nu1, nu2, fraction):
    """separability's fault distance equals (16) on actuator.gain at a vanishing error, worst direction."""
    load = fraction * nu1 * STALL_FORCE_N
    expected = 0.0
    for direction in (1.0, -1.0):
        k0, kf = _plant_gain(1.0, 1.0, load, direction), _plant_gain(nu1, nu2, load, direction)
        expected = max(expected, abs(kf - k0) / (kf + k0) if kf + k0 > 0 else 0.0)
    ranges = metrics.uncertainty_ranges({})
    got = metrics.separability(np.array([fraction]), np.array([nu1]), np.array([nu2]), np.array([1.0]), ranges)
    assert got["fault_distance"][0] == pytest.approx(expected, rel=1e-6, abs=1e-9)
    assert got["uncertainty_distance"][0] == 0.0
    assert bool(got["separable"][0]) == (expected > 0.0)


def test_uncertainty_distance_of_the_servo_gain_band():
    """+-10 % Kci alone: the largest distance is 0.1 / 1.9 whatever the load; a disconnection at a load
    fraction of 0.17 (about 0.047) is below it, at 0.46 (about 0.15) above it."""
    ranges = metrics.uncertainty_ranges({"kci_scale": np.array([0.9, 1.0, 1.1])})
    got = metrics.separability(np.array([0.0, 0.17, 0.46]), np.ones(3), np.zeros(3), np.ones(3), ranges)
    np.testing.assert_allclose(got["uncertainty_distance"], 0.1 / 1.9, rtol=1e-12)
    k0 = math.sqrt(1.0 - 0.17)
    assert got["fault_distance"][1] == pytest.approx((1.0 - k0) / (1.0 + k0), rel=1e-12)
    assert got["separable"].tolist() == [False, False, True]


def test_unknown_peak_load_is_not_separable():
    got = metrics.separability(np.array([np.nan]), np.ones(1), np.zeros(1), np.ones(1), metrics.uncertainty_ranges({}))
    assert np.isnan(got["fault_distance"][0]) and not got["separable"][0]


def _table():
    """Twelve disconnections (two cells) and six fault-free runs, with known misses and alarms."""
    rows = []
    for i in range(6):
        rows.append({"fault_kind": "disconnection", "qbar_kpa": 12.0, "peak_load_fraction": 0.45, "true_model": 1,
                     "missed": i < 1, "separable": True, "false_alarm": False})
        rows.append({"fault_kind": "disconnection", "qbar_kpa": 3.0, "peak_load_fraction": 0.05, "true_model": 1,
                     "missed": i < 5, "separable": i < 2, "false_alarm": False})
        rows.append({"fault_kind": "none", "qbar_kpa": 12.0 if i < 4 else 3.0, "peak_load_fraction": 0.45 if i < 4
                     else 0.05, "true_model": 0, "missed": False, "separable": False, "false_alarm": i == 0})
    df = pd.DataFrame(rows)
    df["status"] = 0
    df["must_detect"] = df["true_model"] > 0  # the scoring monitors' column: a miss counts
    df["fault_distance"] = np.where(df["fault_kind"] == "none", np.nan, 0.1)
    df["uncertainty_distance"] = 0.05
    return df


def test_detectability_cells_count_misses_and_alarms():
    df = _table()
    det = report.detectability(df).set_index("load_fraction_bin")
    high, low = det.loc["[0.4, 0.6)"], det.loc["[0.0, 0.1)"]
    assert (high["faulty_runs"], high["missed"], high["separable"], high["fault_free_runs"], high["false_alarms"]) \
        == (6, 1, True, 4, 1)
    assert (low["faulty_runs"], low["missed"], low["separable"], low["missed_separable"], low["fault_free_runs"]) \
        == (6, 5, False, 2, 2)
    lo, hi = metrics.clopper_pearson(5, 6)
    assert (low["mdr_lo"], low["mdr_hi"]) == pytest.approx((float(lo), float(hi)))
    text = report.detectability_markdown(report.detectability(df), df)
    assert "missed 3/8 = 0.375" in text and "3/4 = 0.75" in text


def test_detectability_figure_has_a_panel_per_fault_kind():
    df = _table()
    df = pd.concat([df, df.assign(fault_kind=df["fault_kind"].replace("disconnection", "leakage"))])
    fig = plots.detectability(report.detectability(df))
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title().split(":")[0] for ax in panels] == ["leakage", "disconnection"]
    assert sum(1 for p in panels[1].patches if p.get_edgecolor()[2] > 0.5) == 1  # one separable cell framed
    assert [t.get_text() for t in panels[0].get_xticklabels()] == ["0-5", "10-15"]
    assert [t.get_text() for t in panels[0].get_yticklabels()] == ["0-0.1", "0.4-0.6"]


def test_stall_scoring_counts_jams_taken_for_stalls():
    df = pd.DataFrame({"status": 0, "fault_kind": ["jamming"] * 4 + ["none"] * 2, "fault_onset_s": 10.0,
                       "jam_taken_for_stall": [True, False, True, False, False, False],
                       "jam_taken_for_stall_time_s": [11.0, np.nan, 14.0, np.nan, np.nan, np.nan],
                       "false_alarm": [False] * 5 + [True]})
    text = report.stall_scoring_markdown(df)
    assert "2/4 = 0.5" in text and "median 2.5 s, max 4 s" in text
    assert "LOE false alarms in fault-free runs: 1/2 = 0.5" in text


def test_campaign_without_parametric_faults_reports_no_cells():
    df = _table()
    df = df[df["fault_kind"] == "none"]
    det = report.detectability(df)
    assert det.empty and list(det.columns) == list(report.DETECTABILITY_COLUMNS)
    assert "No parametric faults in this campaign." in report.detectability_markdown(det, df)
    fig = plots.detectability(det)
    assert "no parametric faults" in fig.axes[0].texts[0].get_text()

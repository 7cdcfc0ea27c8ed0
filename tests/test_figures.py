"""Figures an engineer reads at a glance: rate scales and bounds, readable stratum labels, the stall
confusion and latency, Fig. 5's threshold, the worst-case legend, labels inside the figure."""

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from scipy.stats import binomtest

from mcfdd import plots, report


def _interval(k, n):
    if n == 0:
        return np.nan, np.nan, np.nan
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
    return k / n, ci.low, ci.high


def _summary():
    """A stratum of three cells: LOE false alarms in 2/1000 and 0/500 fault-free runs, MDR high; the first cell has
    no faulty runs."""
    labels = ["none", "leakage 10-20 %", "disconnection"]
    runs, alarms, faulty, missed = [1000, 500, 400], [2, 0, 15], [0, 500, 400], [0, 450, 380]
    rows = []
    for label, n, k, nf, km in zip(labels, runs, alarms, faulty, missed):
        far, mdr = _interval(k, n), _interval(km, nf)
        rows.append({"stratum": "fault", "label": label, "fault_free_runs": n, "false_alarms_loe": k, "far_loe": far[0],
                     "far_loe_lo": far[1], "far_loe_hi": far[2], "faulty_runs": nf, "missed": km, "mdr": mdr[0],
                     "mdr_lo": mdr[1], "mdr_hi": mdr[2]})
    return pd.DataFrame(rows)


def _inside(fig):
    """Every text of the drawn figure (tick labels, axis labels, titles, legends) lies inside it."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    box = fig.bbox
    for ax in fig.axes:
        ticks = [label for axis in (ax.xaxis, ax.yaxis) for loc, label in zip(axis.get_majorticklocs(),
                                                                              axis.get_majorticklabels())
                 if min(axis.get_view_interval()) <= loc <= max(axis.get_view_interval())]
        texts = [ax.xaxis.label, ax.yaxis.label, ax.title, *ticks, *ax.texts]
        for text in (t for t in texts if t.get_text() and t.get_visible()):
            extent = text.get_window_extent(renderer)
            assert box.x0 - 1 <= extent.x0 and extent.x1 <= box.x1 + 1, text.get_text()
            assert box.y0 - 1 <= extent.y0 and extent.y1 <= box.y1 + 1, text.get_text()


def test_rates_of_a_few_per_mille_are_on_a_log_scale_and_zero_counts_show_their_bound():
    summ = _summary()
    fig = plots.rates_by_stratum(summ, "fault", rates=("far_loe", "mdr"))
    far_ax, mdr_ax = fig.axes
    assert far_ax.get_xscale() == "log"
    left, right = far_ax.get_xlim()
    assert left <= summ.loc[0, "far_loe_lo"] and right == 1.0
    [bar] = far_ax.collections[1:]  # errorbar's vertical caps come first; the zero-count bar is the hlines
    (x0, y0), (x1, y1) = bar.get_segments()[0]
    assert (x0, x1, y0) == pytest.approx((left, _interval(0, 500)[2], 1.0))
    assert [t.get_text() for t in far_ax.texts] == ["2/1000", "0/500", "15/400"]
    assert mdr_ax.get_xscale() == "linear" and mdr_ax.get_xlim() == (0.0, 1.0)
    assert [t.get_text() for t in mdr_ax.texts] == ["no faulty runs", "450/500", "380/400"]
    assert [t.get_text() for t in far_ax.get_yticklabels()] == list(summ["label"])
    _inside(fig)


def test_rates_figure_without_mdr_has_one_panel():
    fig = plots.rates_by_stratum(_summary(), "fault", rates=("far_loe",))
    assert len(fig.axes) == 1 and "false alarms per fault-free run" in fig.axes[0].get_xlabel()


def test_envelope_cells_have_readable_labels_in_speed_then_altitude_order():
    df = pd.DataFrame({"vcas_kt": [150.0, 199.9, 200.0, 260.0, 300.0, 400.0],
                       "altitude_m": [0.0, 2999.0, 3000.0, 7000.0, 100.0, 12000.0]})
    cells = report.envelope_bin(df)
    assert list(cells.astype(str)) == ["< 200 kt, 0-3 km", "< 200 kt, 0-3 km", "200-250 kt, 3-7 km",
                                       "250-300 kt, >= 7 km", ">= 300 kt, 0-3 km", ">= 300 kt, >= 7 km"]
    speeds, heights = ["< 200 kt", "200-250 kt", "250-300 kt", ">= 300 kt"], ["0-3 km", "3-7 km", ">= 7 km"]
    assert list(cells.cat.categories) == [f"{v}, {h}" for v in speeds for h in heights]


def _runs():
    return pd.DataFrame({
        "status": 0, "fault_kind": ["none", "none", "jamming", "jamming", "leakage", "none"],
        "true_model": [0, 0, -1, -1, 1, 0], "identified_model": [-1, 1, -1, 1, 1, -1],
        "stall_events": [1, 2, 0, 0, 0, 1], "stall_identified_signal": [1, 2, 0, 0, 0, 0],
        "stall_worst_latency_signal_s": [0.1, 0.7, np.nan, np.nan, np.nan, np.nan],
        "stall_identified_model": [1, 1, 0, 0, 0, 1],
        "stall_worst_latency_model_s": [0.2, 0.3, np.nan, np.nan, np.nan, 0.4],
        "jam_taken_for_stall": [False, False, True, False, False, False],
        "eta_false_signal": [False, True, False, False, False, False],
    })


def test_confusion_keeps_the_jammed_runs():
    conf = report.confusion(_runs(), ["fault-free", "pressure-loss"])
    assert list(conf.index) == ["fault-free", "pressure-loss", "jamming"]
    assert conf.loc["jamming"].to_dict() == {"pressure-loss": 1, "no decision": 1}
    assert conf.loc["fault-free"].to_dict() == {"pressure-loss": 1, "no decision": 2}


def test_stall_confusion_counts_events_jams_and_other_runs():
    stall = report.stall_confusion(_runs(), "signal")
    assert stall.to_dict("index") == {
        "relevant stall loads (events)": {"eta = 1 (stall)": 3, "eta = 0": 1},
        "jammed rods (runs)": {"eta = 1 (stall)": 1, "eta = 0": 1},
        "other runs, outside stall loads": {"eta = 1 (stall)": 1, "eta = 0": 3}}
    fig = plots.confusion_matrix(report.confusion(_runs(), ["fault-free", "pressure-loss"]), stall)
    assert len(fig.axes) == 2
    _inside(fig)


def test_confusion_labels_fit_a_one_row_matrix():
    conf = pd.DataFrame([[256]], index=["fault-free"], columns=["no decision"])
    _inside(plots.confusion_matrix(conf))


def test_confusion_colours_by_share_of_the_identified_runs_not_by_the_no_decision_count():
    """'no decision' (in grey, count only) no longer sets the colour scale: each decided cell is its share of the
    row's identified runs, so three confusions among 1,000 undecided runs still show."""
    conf = pd.DataFrame([[9, 3, 1000], [0, 0, 50]], index=["surface-loss-100", "pressure-loss-27"],
                        columns=["surface-loss-100", "pressure-loss-27", "no decision"])
    fig = plots.confusion_matrix(conf)
    colours = fig.axes[0].images[0].get_array()
    np.testing.assert_allclose(colours[0, :2], [0.75, 0.25])
    assert colours.mask[:, 2].all() and colours.mask[1].all()  # no decision; a row with nothing identified
    assert [t.get_text() for t in fig.axes[0].texts] == ["9", "3", "1000", "0", "0", "50"]
    _inside(fig)


def test_a_fault_free_campaign_shows_its_false_identifications_per_model_or_no_confusion_at_all():
    """The confusion of a fault-free campaign lists every fault model as a column (its false identifications),
    and is left out, with the reason, when nothing was identified."""
    import mcfdd
    from test_campaign import ALARMING, FAULT_FREE, SHORT

    short = {**SHORT, "campaign.scenarios": 40}
    quiet = mcfdd.run_campaign(mcfdd.load_config(FAULT_FREE, overrides=short), progress=False)
    assert "no identification" in quiet.left_out()["confusion"]
    alarming = mcfdd.run_campaign(mcfdd.load_config(FAULT_FREE, overrides={**short, **ALARMING}), progress=False)
    assert (alarming.scenarios["identified_model"] >= 0).any() and "confusion" not in alarming.left_out()
    fig = alarming.plot("confusion")
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert labels == [*alarming.models[1:], "no decision"]
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["fault-free"]


def test_stall_latency_is_the_cdf_of_each_runs_worst_latency():
    """Signal rules: of the three runs with stall loads two identified all events (0.1 s, 0.7 s), one
    did not; model rules: 0.2 s and 0.4 s, and a run that identified one of its two events."""
    fig = plots.stall_latency(_runs(), 0.5)
    ax = fig.axes[0]
    signal, model = ax.lines[:2]
    np.testing.assert_allclose(signal.get_xdata(), [0.0, 0.1, 0.7])
    np.testing.assert_allclose(signal.get_ydata(), [0.0, 1 / 3, 2 / 3])
    np.testing.assert_allclose(model.get_xdata(), [0.0, 0.2, 0.4])
    np.testing.assert_allclose(model.get_ydata(), [0.0, 1 / 3, 2 / 3])
    assert ax.lines[2].get_xdata()[0] == 0.5
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "1/3 runs within 0.5 s, 1 with an event not identified" in labels[0]
    assert "2/3 runs within 0.5 s, 1 with an event not identified" in labels[1]
    _inside(fig)


def test_fig5_draws_the_threshold_beside_the_residual():
    t = np.arange(0.0, 2.0, 0.01)
    stall = (t > 0.5) & (t < 1.2)
    run = pd.DataFrame({"t_s": t, "u_c_deg": 20 * stall, "u_deg": 15 * stall, "dp_avail_norm": 1.0 - stall,
                        "r_stall_deg": 2.0 * stall, "theta_stall_deg": 1.5 * stall, "stall": stall})
    ax = plots.fig5(run, 1.25).axes[2]
    lines = {line.get_label(): line for line in ax.lines}
    threshold = next(line for label, line in lines.items() if label.startswith("threshold"))
    assert set(threshold.get_ydata()) == {1.25}
    np.testing.assert_array_equal(lines["evaluation theta (14)"].get_ydata(), run["theta_stall_deg"])


def test_worst_case_history_has_a_legend_entry_for_every_line():
    rows = [{"method": "gradient", "start": s, "iteration": i, "v": s + i, "v_smooth": s + i + 0.5}
            for s in (0, 1) for i in range(3)]
    rows += [{"method": m, "start": -1, "iteration": -1, "v": v, "v_smooth": v}
             for m, v in (("screening", 1.5), ("monte_carlo", 2.5), ("monte_carlo_extra", 3.5), ("monte_carlo", 0.1))]
    fig = plots.search_history(pd.DataFrame(rows), "v", "v_smooth", "bound", "free")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert len(labels) == len(ax.lines) == 7
    assert all(not label.startswith("_") for label in labels)
    equal_time = next(line for line in ax.lines if line.get_label().startswith("Monte Carlo, equal run time"))
    assert set(equal_time.get_ydata()) == {3.5}
    assert sum("smooth" in label for label in labels) == 2
    _inside(fig)

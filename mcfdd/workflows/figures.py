"""The paper's Figs. 3-6 from configs fig3/fig4/fig5.toml (``mcfdd figures``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mcfdd import config, io, plots
from mcfdd.analysis import build, metrics
from mcfdd.workflows.common import load_bank, save_figure
from mcfdd.workflows.simulate import histories, run_histories


def stall_latencies(run, dt_s: float):
    """Per stall event of one run's history: onset and end (s) and the eta latency (s) of both identification
    methods (NaN if not identified); and the time (s) each method's eta = 1 outside stall events."""
    stall = run["stall"].to_numpy(dtype=bool)
    t = run["t_s"].to_numpy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stall.astype(int), [0]])))
    rows = []
    for start, end in zip(edges[::2], edges[1::2]):
        row = {"onset_s": t[start], "end_s": t[end - 1] + dt_s}
        for method in ("signal", "model"):
            eta = run[f"eta_{method}"].to_numpy(dtype=bool)[start:end]
            row[f"latency_{method}_s"] = t[start + eta.argmax()] - t[start] if eta.any() else np.nan
        rows.append(row)
    outside = {method: float((run[f"eta_{method}"].to_numpy(dtype=bool) & ~stall).sum() * dt_s)
               for method in ("signal", "model")}
    return pd.DataFrame(rows, columns=["onset_s", "end_s", "latency_signal_s", "latency_model_s"]), outside


class FiguresResult:
    """The paper's figures and the numbers printed beside them.

    Attributes:
        figures: name ('fig3' .. 'fig6') -> matplotlib Figure.
        sweep: Fig. 4, one row per fault size: family, size, decided model, first fault model,
            detection time after the onset (s), switches.
        grid: per family the fault sizes of the bank's grid models.
        stall_events: Fig. 5's stall events with both methods' latencies (s).
        eta_outside_s: per method, time (s) with eta = 1 outside stall events in Fig. 5's run.
        meta: provenance of the sweep table.
    """

    def __init__(self, figures, sweep, grid, stall_events, eta_outside_s, meta):
        self.figures, self.sweep, self.grid, self.stall_events, self.eta_outside_s, self.meta = (
            figures, sweep, grid, stall_events, eta_outside_s, meta)

    def save(self, out) -> list[Path]:
        """Write ``fig3.png`` .. ``fig6.png`` and ``fig4.parquet`` into ``out``."""
        out = Path(out)
        written = [io.write_table(self.sweep, out / "fig4.parquet", self.meta)]
        written.extend(save_figure(fig, out / f"{name}.png") for name, fig in self.figures.items())
        return written


def paper_figures(folder="configs", progress: bool = True) -> FiguresResult:
    """Figs. 3-6 of the paper from ``fig3.toml``, ``fig4.toml`` and ``fig5.toml`` in ``folder``.

    Args:
        folder: the folder holding the three configs.
        progress: status lines on stderr; False for silence.

    Returns:
        A :class:`FiguresResult`.
    """
    folder = Path(folder)
    fig3_cfg = config.load_config(folder / "fig3.toml", "simulate")
    fig4_cfg = config.load_config(folder / "fig4.toml", "sweep")
    fig5_cfg = config.load_config(folder / "fig5.toml", "simulate")
    figures = {}
    df3, _ = run_histories(fig3_cfg.simulation, fig3_cfg.plant, fig3_cfg.fdd, fig3_cfg.runs, progress)
    free = next(r for r in fig3_cfg.runs if r.fault.kind == "none")
    faulty = next(r for r in fig3_cfg.runs if r.fault.kind != "none")
    figures["fig3"] = plots.fig3(df3, free.name, faulty.name, faulty.fault.onset_s)

    table, run_names, family, size = build.sweep_table(fig4_cfg)
    df4, names = histories(fig4_cfg.simulation, fig4_cfg.plant, fig4_cfg.fdd, table, run_names, progress)
    n_steps = fig4_cfg.simulation.n_steps
    detected = df4["detected_model"].to_numpy().reshape(len(run_names), n_steps)
    t = df4["t_s"].to_numpy()[:n_steps]
    onset = fig4_cfg.run.fault.onset_s
    hist = metrics.decision_history(detected, t, np.full(len(run_names), onset))
    sweep = pd.DataFrame({"family": family, "fault_size": size, "detected_model": hist["prevailing_model"],
                          "detected_model_name": [names[m] if m >= 0 else "no decision" for m in
                                                  hist["prevailing_model"]],
                          "first_fault_model": hist["first_model"],
                          "detection_time_s": hist["detection_time_s"] - onset,
                          "switches": hist["switches"]})
    meta = io.provenance(config.to_json(fig4_cfg), fig4_cfg.simulation.seed, models=list(names))
    bank, _ = load_bank(fig4_cfg.fdd, np.float32)
    nu = np.asarray(bank.nu)
    grid = {"surface": sorted(1.0 - nu[np.isclose(nu[:, 0], 1.0), 1]),
            "leakage": sorted(1.0 - nu[np.isclose(nu[:, 1], 1.0), 0])}
    figures["fig4"] = plots.fig4(sweep, names, grid)

    df5, _ = run_histories(fig5_cfg.simulation, fig5_cfg.plant, fig5_cfg.fdd, fig5_cfg.runs, progress)
    run5 = df5[df5["run"] == fig5_cfg.runs[0].name]
    figures["fig5"] = plots.fig5(run5, fig5_cfg.fdd.stall.tau_deg)
    figures["fig6"] = plots.fig6(run5, fig5_cfg.plant.actuator.max_deflection_deg)
    events, outside = stall_latencies(run5, fig5_cfg.simulation.dt_s)
    return FiguresResult(figures, sweep, grid, events, outside, meta)

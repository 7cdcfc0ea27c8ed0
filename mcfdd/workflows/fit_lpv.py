"""LPV gain models fitted by output error to the nonlinear actuator (eqs. 3-4; ``mcfdd fit-lpv``)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mcfdd import config, io
from mcfdd.analysis import build, lpv_fit
from mcfdd.fdd import lpv
from mcfdd.plant import atmosphere, closed_loop, manoeuvres
from mcfdd.progress import bar, note
from mcfdd.workflows.common import as_config, dtype_of, precision, save_figure


class LpvFitResult:
    """A fitted LPV bank with its errors on training and held-out runs.

    Attributes:
        bank: the fitted :class:`mcfdd.fdd.lpv.GainBank` (N models, 12 coefficients each).
        models: the N model names.
        bank_dict: the bank's versioned JSON form with its ``fit`` record (written as ``bank.json``).
        errors: one row per (model, run): split, flight point, manoeuvre, RMS and largest output
            error in % of the manoeuvre amplitude, smallest available pressure, in_domain.
        error_summary: per split, (N,) arrays ``rms``, ``max`` (fractions of amplitude), ``runs``,
            ``near_stall_runs``.
        distances: smallest H-inf distances between neighbouring models (eq. 16) over the envelope.
        responses: time histories of showcase validation runs (deg), nonlinear against LPV.
        gains: k of the LPV models and the nonlinear actuator (1/s) over Vcas, altitude, direction.
        meta: provenance.
    """

    def __init__(self, bank, models, bank_dict, errors, error_summary, distances, responses, gains, meta):
        self.bank, self.models, self.bank_dict, self.errors = bank, tuple(models), bank_dict, errors
        self.error_summary, self.distances, self.responses, self.gains, self.meta = (error_summary, distances,
                                                                                   responses, gains, meta)

    def plot(self, name: str):
        """'responses' (held-out runs, nonlinear against LPV) or 'gains' (k over the envelope), a Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if name == "responses":
            return plots.lpv_responses(self.responses, list(self.models))
        if name == "gains":
            return plots.lpv_gains(self.gains, list(self.models))
        raise ValueError(f"plot: {name!r} is not one of responses, gains")

    def save(self, out) -> list[Path]:
        """Write ``bank.json``, ``fit_errors.parquet``, ``responses.png``, ``gains.png`` into ``out``."""
        out = Path(out)
        return [io.save_bank(out / "bank.json", self.bank_dict),
                io.write_table(self.errors, out / "fit_errors.parquet", self.meta),
                save_figure(self.plot("responses"), out / "responses.png"),
                save_figure(self.plot("gains"), out / "gains.png")]


def fit_lpv(cfg, progress: bool = True) -> LpvFitResult:
    """Fit the LPV gain model of every fault model to the nonlinear actuator.

    Args:
        cfg: a 'fit-lpv' config (:func:`mcfdd.load_config`), or a TOML path or dict of one.
        progress: status lines and an iteration bar on stderr; False for silence.

    Returns:
        An :class:`LpvFitResult`; ``.save(dir)`` writes the ``bank.json`` a config's ``fdd.bank`` takes.

    >>> import mcfdd
    >>> cfg = {"models": [{"name": "fault-free"}], "runs": {"duration_s": 0.5}, "optimiser": {"iterations": 1},
    ...        "envelope": {"grid": [2, 2], "validation_points": 1},
    ...        "training": [{"kind": "ol_step", "amplitude": 0.5, "t_start_s": 0.1, "duration_s": 0.3}],
    ...        "validation": [{"kind": "ol_step", "amplitude": 0.5, "t_start_s": 0.1, "duration_s": 0.3}]}
    >>> mcfdd.fit_lpv(cfg, progress=False).models
    ('fault-free',)
    """
    source = cfg if isinstance(cfg, (str, Path)) else None
    cfg = as_config(cfg, "fit-lpv")
    with precision(cfg.precision):
        return _fit(cfg, source, progress)


def _fit(cfg: config.LpvFitConfig, source, progress: bool) -> LpvFitResult:
    dtype = dtype_of(cfg.precision)
    model = build.plant_model(cfg.plant)
    runs, opt, max_mach = cfg.runs, cfg.optimiser, cfg.plant.aircraft.max_mach
    nus, names = build.lpv_nus(cfg), [m.name for m in cfg.models]
    r_arm = model.actuator.r_arm_m
    points = {"training": build.lpv_training_points(cfg.envelope, max_mach),
              "validation": build.lpv_validation_points(cfg.envelope, max_mach, cfg.seed)}
    commands, problems = {}, {}
    start = time.perf_counter()
    for split, (v, h) in points.items():
        commands[split] = build.lpv_manoeuvre_params(cfg, split, dtype)
        problems[split] = lpv_fit.make_problem(model, nus, v, h, commands[split], runs.n_steps, runs.dt_s,
                                               runs.substeps)
        note(f"{split}: {len(v)} flight points x {len(commands[split].kind)} manoeuvres of {runs.duration_s} s, "
             f"{len(names)} models (nonlinear actuator simulated)", progress)
    bank, free = lpv_fit.initial_bank(model, nus, *points["training"], cfg.exact_disconnection, dtype)
    for i in np.flatnonzero(~free):
        note(f"{names[i]}: exact gain of eq. (36), {float(bank.k0[i]):.3f} 1/s, not fitted", progress)

    with bar(opt.iterations, "fit iterations", progress) as shown:
        def callback(i, losses):
            shown.set_postfix_str("training RMS % " + " ".join(f"{100 * math.sqrt(v):.3f}" for v in losses),
                                  refresh=False)
            shown.update(1)

        bank, _ = lpv_fit.fit(bank, problems["training"], runs.dt_s, margin=runs.min_pressure, free=free,
                              callback=callback, **config.to_dict(opt))
    note(f"fitted in {time.perf_counter() - start:.1f} s (simulation and compilation included)", progress)

    frames, summary, x_lpv = [], {}, {}
    for split, problem in problems.items():
        x_lpv[split] = lpv_fit.responses(bank, problem, runs.dt_s)
        rms, max_error = lpv_fit.output_errors(x_lpv[split], problem)
        domain = lpv_fit.in_domain(problem, runs.min_pressure)
        summary[split] = lpv_fit.error_summary(rms, max_error, domain)
        n_commands = len(commands[split].kind)
        v, h = points[split]
        run_columns = {
            "split": np.full(len(v) * n_commands, split), "run": np.arange(len(v) * n_commands),
            "vcas_kt": np.repeat(v / atmosphere.KT_TO_M_S, n_commands), "altitude_m": np.repeat(h, n_commands),
            "manoeuvre": np.tile(np.asarray(manoeuvres.KINDS)[np.asarray(commands[split].kind)], len(v)),
            "amplitude": np.tile(np.asarray(commands[split].amplitude), len(v)),
            "amplitude_deg": closed_loop.deflection_deg(np.asarray(problem.amplitude_m), r_arm),
        }
        frames.append(io.model_run_frame(names, run_columns, {
            "rms_error_pct": 100.0 * np.asarray(rms), "max_error_pct": 100.0 * np.asarray(max_error),
            "min_available_pressure": np.asarray(problem.min_pressure), "in_domain": np.asarray(domain)}))
    errors = pd.concat(frames, ignore_index=True)

    x_max = lpv_fit.stroke_m(model)
    v_grid = np.linspace(*cfg.envelope.vcas_kt, 26) * atmosphere.KT_TO_M_S
    h_grid = np.linspace(*cfg.envelope.altitude_m, 25)
    distances = lpv_fit.neighbour_distances(bank, model, v_grid, h_grid, np.linspace(-x_max, x_max, 51), max_mach,
                                            runs.min_pressure)
    meta = io.provenance(config.to_json(cfg), cfg.seed, models=names)
    fit_info = {
        "method": "output error against the nonlinear actuator (Adam, exponentially decaying step), started from a "
                  "least-squares match of the small-error gains; mcfdd.analysis.lpv_fit",
        "command": f"mcfdd fit-lpv {source}" if source is not None else "mcfdd.fit_lpv",
        "config": config.to_dict(cfg),
        "version": meta["version"],
        "git_revision": meta["git_revision"],
        "exact_gain_models": [names[i] for i in np.flatnonzero(~free)],
        "errors_pct_of_amplitude": {
            name: {split: {"rms": 100.0 * float(s["rms"][i]), "max": 100.0 * float(s["max"][i]),
                           "runs": int(s["runs"][i]), "near_stall_runs": int(s["near_stall_runs"][i])}
                   for split, s in summary.items()}
            for i, name in enumerate(names)},
        "neighbour_distances": [{"models": [names[d.i], names[d.j]], "overall": d.overall, "separated": d.separated,
                                 "nonlinear_at_separated": d.nonlinear} for d in distances],
    }

    problem, m = problems["validation"], commands["validation"]
    idx = np.asarray(lpv_fit.showcase_runs(problem, x_lpv["validation"], runs.min_pressure, len(m.kind)))
    labels = [f"{float(problem.vcas_m_s[b]) / atmosphere.KT_TO_M_S:.0f} kt, {float(problem.altitude_m[b]):.0f} m: "
              f"{manoeuvres.KINDS[int(m.kind[b % len(m.kind)])]} {float(m.amplitude[b % len(m.kind)]):+.2f}"
              for b in idx]

    def deg(x):
        return closed_loop.deflection_deg(np.asarray(x), r_arm)

    columns = {"u_c_deg": deg(problem.u_c_m[idx, :]),
               "amplitude_deg": np.repeat(deg(problem.amplitude_m[idx])[:, None], runs.n_steps, axis=1)}
    for i in range(len(names)):
        columns[f"x_nonlinear_deg_{i}"] = deg(problem.x_m[i, idx, :])
        columns[f"x_lpv_deg_{i}"] = deg(x_lpv["validation"][i, idx, :])
    history = io.history_frame(labels, np.arange(runs.n_steps) * runs.dt_s, columns)

    delta = 0.6 * model.actuator.max_deflection_rad
    h_shown = h_grid[[0, len(h_grid) // 2, -1]]
    k_lpv, k_nl = lpv_fit.gain_comparison(bank, model, v_grid, h_shown, np.array([delta * r_arm]), max_mach)
    gains = io.grid_frame(names, {"vcas_kt": v_grid / atmosphere.KT_TO_M_S, "altitude_m": h_shown,
                                  "delta_deg": [math.degrees(delta)], "direction": [-1.0, 1.0]},
                          {"k_lpv_1_s": k_lpv, "k_nonlinear_1_s": k_nl})
    return LpvFitResult(bank, names, lpv.to_dict(bank, names, {"fit": fit_info}), errors, summary, distances, history,
                        gains, meta)

"""Full time histories of a few named runs, plant and FDD in one batch (``mcfdd simulate``)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from mcfdd import config, io
from mcfdd.analysis import batch, build
from mcfdd.analysis.scenarios import to_scenario
from mcfdd.analysis.simulate import fdd_batch, run_keys
from mcfdd.plant import atmosphere, closed_loop, signals
from mcfdd.progress import note
from mcfdd.workflows import resources
from mcfdd.workflows.common import ResourceError, as_config, dtype_of, load_bank, precision, save_figure, slug


def runs_table(runs) -> dict:
    """Scenario columns (name -> (B,) array) of a config's ``[[runs]]``."""
    rows = [build.run_columns(run) for run in runs]
    return {k: np.array([r[k] for r in rows]) for k in rows[0]}


def run_histories(sim: config.SimulationConfig, plant_cfg: config.PlantConfig, fdd_cfg: config.FddConfig, runs,
                  progress: bool = True):
    """:func:`histories` of a config's ``[[runs]]``, each with its own ``seed`` where it sets one."""
    return histories(sim, plant_cfg, fdd_cfg, runs_table(runs), [r.name for r in runs], progress,
                     [r.seed for r in runs], [r.index for r in runs])


def histories(sim: config.SimulationConfig, plant_cfg: config.PlantConfig, fdd_cfg: config.FddConfig, table: dict,
              run_names, progress: bool = True, seeds=None, indices=None):
    """Simulate the runs of a scenario table with plant and FDD in one batch.

    Runs are paired: each draws its turbulence and sensor noise from ``run_keys(seed, [index])``
    with its entry of ``seeds`` (None, or no ``seeds`` at all, for ``sim.seed``) and of ``indices``
    (none: 0), so runs of one seed and index see the same random numbers and differ only by their
    parameters, and a run with a campaign's seed and row index replays that row.

    Returns (tidy DataFrame of time histories, LPV model names).
    """
    with precision(sim.precision):
        dtype = dtype_of(sim.precision)
        model = build.plant_model(plant_cfg)
        bank, names = load_bank(fdd_cfg, dtype)
        fdd_params = build.fdd_params(fdd_cfg, bank, model.actuator.r_arm_m)
        scenarios = to_scenario(table, dtype)
        kinds = batch.kinds_in(scenarios.manoeuvre.kind)
        seeds = [sim.seed if s is None else s for s in (seeds or [None] * len(run_names))]
        keys = jnp.concatenate([run_keys(int(s), [int(i)]) for s, i in zip(seeds, indices or [0] * len(run_names))])
        _check_memory(len(run_names), sim, jax.eval_shape(lambda s, k: fdd_batch(
            model, fdd_params, s, k, 1, sim.dt_s, sim.substeps, kinds), scenarios, keys))
        note(f"simulating {len(run_names)} run(s) of {sim.duration_s} s ({sim.n_steps} steps, {sim.precision})",
             progress)
        start = time.perf_counter()
        # on the host at once: indexing and scaling them as JAX arrays would compile a program per operation
        plant, fdd = jax.tree.map(np.asarray, fdd_batch(model, fdd_params, scenarios, keys, sim.n_steps,
                                                                 sim.dt_s, sim.substeps, kinds))
        note(f"  done in {time.perf_counter() - start:.1f} s (compilation included)", progress)
    r_arm = model.actuator.r_arm_m
    to_deg = 180.0 / math.pi

    def deg(x):
        return closed_loop.deflection_deg(np.asarray(x), r_arm)

    columns = {
        "u_c_m": plant.u_c_m, "u_m": plant.u_m, "x_m": plant.x_m, "u_c_deg": deg(plant.u_c_m), "u_deg": deg(plant.u_m),
        "delta_deg": deg(plant.x_m), "dp_avail_norm": plant.dp_avail_norm, "stall": plant.stall,
        "p_deg_s": plant.p_rad_s * to_deg, "phi_deg": plant.phi_rad * to_deg, "stick": plant.stick,
        "nu1": plant.nu1, "nu2": plant.nu2, "vcas_kt": plant.vcas_m_s / atmosphere.KT_TO_M_S,
        "altitude_m": plant.altitude_m,
    }
    for name in (n for n in signals.FULL_AIRCRAFT_SIGNALS if n in plant._fields):
        value = getattr(plant, name)
        columns[name.replace("_rad", "_deg")] = value if name == "nz_g" else value * to_deg
    for i in range(len(names)):
        columns[f"r_{i}"] = fdd.r[..., i]
        columns[f"theta_{i}"] = fdd.theta[..., i]
        columns[f"ratio_{i}"] = fdd.ratio[..., i]
        columns[f"iota_{i}"] = fdd.iota[..., i]
    eta = fdd.eta_signal if fdd_cfg.stall.identification == "signal" else fdd.eta_model
    columns.update({
        "theta_u": fdd.theta_u, "load_fraction": fdd.load_fraction, "excited": fdd.excited,
        "decoded_model": fdd.decoded, "detected_model": fdd.detected, "fault_detected": fdd.fault_detected,
        "detection_margin": fdd.detection_margin, "eta_signal_margin": fdd.eta_signal_margin,
        "eta_model_margin": fdd.eta_model_margin, "r_stall": fdd.r_stall,
        "r_stall_deg": deg(fdd.r_stall), "theta_stall": fdd.theta_stall, "theta_stall_deg": deg(fdd.theta_stall),
        "iota_stall": fdd.iota_stall,
        "eta_stall": eta, "eta_signal": fdd.eta_signal, "eta_model": fdd.eta_model, "theta_sl": fdd.theta_sl,
    })
    t = np.arange(sim.n_steps) * sim.dt_s
    return io.history_frame(list(run_names), t, {k: np.asarray(v) for k, v in columns.items()}), names


def _check_memory(runs: int, sim: config.SimulationConfig, one_step):
    """Refuse histories that would not fit in memory, before simulating (``one_step``: the output shapes of one
    step of every run)."""
    per_sample = resources.tree_bytes(one_step) / runs
    need, available = resources.history_bytes(runs * sim.n_steps, per_sample), resources.available_bytes()
    if need > available:
        raise ResourceError(f"simulation.duration_s: {runs} run(s) x {sim.n_steps} steps x {per_sample:.0f} "
                                 f"bytes of signals need about {resources.gib(need)} with their table, more than the "
                                 f"{resources.gib(available)} available; simulate fewer runs or shorter ones (a "
                                 f"campaign keeps no time histories)")


class Histories:
    """Time histories of named runs (plant and FDD signals at every sample).

    Attributes:
        models: names of the LPV bank's models (filter i = models[i]).
        meta: provenance of the table (resolved config, seed, version, git revision).
        dt_s: sample time (s).
    """

    def __init__(self, frame, models, meta: dict, dt_s: float):
        self._frame, self.models, self.meta, self.dt_s = frame, tuple(models), meta, dt_s

    @property
    def runs(self) -> list[str]:
        """The run names, in config order."""
        return list(dict.fromkeys(self._frame["run"]))

    def to_pandas(self):
        """Tidy table, one row per (run, sample): ``run``, ``t_s`` and one column per signal (units in the names;
        per filter i ``r_i``, ``theta_i``, ``iota_i`` and ``ratio_i`` = theta_i / ||u|| (decisions are made only where
        ``excited``); the signed margins of detection and of eta per method, positive where the decision is set)."""
        return self._frame

    def summary(self):
        """One row per run: largest |deflection| (deg), time in stall loads and with eta_stall = 1 (s), and the
        first time (s) each fault model was decided."""
        rows = []
        for name, group in self._frame.groupby("run", sort=False):
            detected = group["detected_model"].to_numpy()
            t = group["t_s"].to_numpy()
            first = {self.models[m]: float(t[detected == m][0]) for m in np.unique(detected) if m >= 0}
            rows.append({"run": name, "max_abs_delta_deg": group["delta_deg"].abs().max(),
                         "stall_s": group["stall"].sum() * self.dt_s,
                         "eta_stall_s": group["eta_stall"].sum() * self.dt_s,
                         "first_decisions_s": first})
        return pd.DataFrame(rows)

    def plot(self, run: str):
        """Deflections, residuals, evaluations and decisions of one run, a matplotlib Figure."""
        from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

        if run not in self.runs:
            raise ValueError(f"run: {run!r} is not one of {', '.join(self.runs)}")
        return plots.run_timeseries(self._frame[self._frame["run"] == run], run)

    def save(self, out) -> list[Path]:
        """Write ``timeseries.parquet`` and a PNG per run (as ``mcfdd simulate``) into ``out``; returns the paths."""
        out = Path(out)
        written = [io.write_table(self._frame, out / "timeseries.parquet", self.meta)]
        written.extend(save_figure(self.plot(run), out / f"{slug(run)}.png") for run in self.runs)
        if "alpha_deg" in self._frame:
            from mcfdd import plots  # deferred: matplotlib only when a figure is drawn

            written.extend(save_figure(plots.flight_state(self._frame[self._frame["run"] == run], run),
                                       out / f"{slug(run)}-flight.png") for run in self.runs)
        return written


def simulate(cfg, progress: bool = True) -> Histories:
    """Simulate the named runs of a config in one batch, keeping the full time histories.

    Args:
        cfg: a 'simulate' config (:func:`mcfdd.load_config`), or a TOML path or dict of one.
        progress: status lines on stderr; False for silence.

    Returns:
        :class:`Histories` of every run: ``duration_s / dt_s`` samples each.

    >>> import mcfdd
    >>> h = mcfdd.simulate({"simulation": {"duration_s": 0.05}, "runs": [{"name": "quiet"}]}, progress=False)
    >>> h.runs, len(h.to_pandas())
    (['quiet'], 5)
    """
    cfg = as_config(cfg, "simulate")
    frame, names = run_histories(cfg.simulation, cfg.plant, cfg.fdd, cfg.runs, progress)
    return Histories(frame, names, io.provenance(config.to_json(cfg), cfg.simulation.seed, models=list(names)),
                     cfg.simulation.dt_s)

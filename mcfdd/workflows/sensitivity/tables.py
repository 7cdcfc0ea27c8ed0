"""The tables of a sensitivity analysis: indices, gradient screen, regional sensitivity, witnesses (tidy).

Computed from the design's run table (:mod:`mcfdd.workflows.sensitivity.study`) by
:mod:`mcfdd.analysis.sensitivity`; :func:`regional_table` and :func:`witnesses` also serve every
campaign's summary.md, from the campaign's own runs.
"""

from __future__ import annotations

import math

import numpy as np

from mcfdd import columns, config
from mcfdd.analysis import build, scenarios, sensitivity as sens
from mcfdd.progress import bar
from mcfdd.workflows import campaign as campaign_wf
from mcfdd.workflows.sensitivity.study import EVENTS, OUTCOMES, Design, acts, applies, outcome_values, scored, strata

SCREEN_BATCH = 16  # gradient evaluations per compiled batch (reverse mode keeps every step of the scan)


def indices_table(d: Design, table, names, s: config.SensitivityConfig, notes: list):
    """First-order and total indices with intervals, one row per (outcome, stratum, factor); tidy."""
    import pandas as pd

    out, absent = [], {}
    for k, (name, (label, kind, rows)) in enumerate((n, st) for n in names for st in strata(d, table)):
        outcome = OUTCOMES[name]
        if not applies(outcome, kind):
            continue
        y = outcome_values(outcome, rows).reshape(d.blocks, d.samples)
        keep = np.isfinite(y).all(axis=0)
        used = int(keep.sum())
        if used == 0:
            absent.setdefault(name, []).append(label)
            continue
        if used < 8:
            notes.append(f"{name}, {label}: {used} of {d.samples} base points have the outcome in all their runs "
                         f"(8 needed); not analysed")
            continue
        if used < d.samples:
            notes.append(f"{name}, {label}: indices over the {used} of {d.samples} base points with the outcome in "
                         f"all their runs (conditional on it being defined)")
        try:
            r = sens.sobol_indices(y[0, keep], y[1, keep], y[2:, keep], s.bootstrap, s.confidence, [d.seed, k])
        except ValueError as err:
            notes.append(f"{name}, {label}: {err}; not analysed")
            continue
        out += [{"outcome": name, "stratum": label, "factor": f, "kind": d.kinds[i],
                 **{key: float(r[key][i])
                    for key in ("first", "first_lo", "first_hi", "total", "total_lo", "total_hi")},
                 "base_points": used, "runs": used * d.blocks, "mean": r["mean"], "std": math.sqrt(r["variance"])}
                for i, f in enumerate(d.factors) if acts(f, kind)]
    notes += [f"{name}: no base point has it in all its runs (it needs {OUTCOMES[name].what.rsplit('; ', 1)[-1]}) "
              f"in {', '.join(labels)}; not analysed" for name, labels in absent.items()]
    return _ranked(pd.DataFrame(out, columns=INDEX_COLUMNS), "total")


INDEX_COLUMNS = ("outcome", "stratum", "factor", "kind", "first", "first_lo", "first_hi", "total", "total_lo",
                 "total_hi", "base_points", "runs", "mean", "std")
SCREEN_COLUMNS = ("outcome", "stratum", "factor", "nu", "nu_lo", "nu_hi", "bound", "bound_lo", "bound_hi", "points")
REGIONAL_COLUMNS = ("outcome", "factor", "kind", "rank", "events", "runs", "statistic", "p_value", "test", "effect",
                    "effect_lo", "effect_hi", "median_event", "median_other", "rates")


def _ranked(df, by: str):
    """Rows ordered by outcome and stratum as given, then by ``by`` descending."""
    if df.empty:
        return df
    keys = [k for k in ("outcome", "stratum") if k in df]
    order = df[keys].drop_duplicates().reset_index(drop=True).reset_index().rename(columns={"index": "_group"})
    df = df.merge(order, on=keys).sort_values(["_group", by], ascending=[True, False], kind="stable")
    return df.drop(columns="_group").reset_index(drop=True)


def _column(rows, axis: config.Axis) -> np.ndarray:
    """An axis's values in a table's rows (a fault-size axis from ``fault_size`` where its kind is the run's)."""
    if axis.name in rows:
        return rows[axis.name].to_numpy()
    return np.where(rows["fault_kind"].to_numpy() == columns.SIZE_COLUMNS[axis.name], rows["fault_size"].to_numpy(),
                    scenarios.grid_values(axis)[0])


def _gradients(problem, u, categories: dict, keys, shown):
    """Smooth outcome Y (P,) and dY/du (P, d) at points u (P, d) of a worst-case problem, in padded batches."""
    import jax.numpy as jnp

    from mcfdd.analysis import worst_case as wc

    box = problem.space.box(problem.dtype)
    scores, grads = [], []
    for start in range(0, len(u), SCREEN_BATCH):
        idx = np.arange(start, min(start + SCREEN_BATCH, len(u)))
        padded = np.concatenate([idx, np.repeat(idx[-1:], SCREEN_BATCH - len(idx))])
        anchors = wc.anchors_at(problem, box, u[padded], {k: v[padded] for k, v in categories.items()})
        score, _, grad = wc.score_and_grad(problem.model, problem.fdd_params, problem.settings, box, anchors,
                                           jnp.asarray(u[padded], problem.dtype), keys[padded], problem.temperature,
                                           detector=problem.detector, bound=problem.bound, **problem.static())
        scores.append(np.asarray(score, dtype=float)[:len(idx)])
        grads.append(np.asarray(grad, dtype=float)[:len(idx)])
        shown.update(len(idx))
    sense = wc.sense(problem.bound)
    y = np.exp(sense * np.concatenate(scores))  # the score is sense x log Y
    return y, y[:, None] * sense * np.concatenate(grads)


def screen_table(d: Design, table, names, s: config.SensitivityConfig, notes: list, progress: bool):
    """DGSM nu and the bound on the total index per continuous factor, from gradients at each stratum's A points."""
    import pandas as pd

    from mcfdd.analysis import simulate, worst_case as wc

    smooth = [n for n in names if OUTCOMES[n].smooth]
    work = [(n, st) for n in smooth for st in strata(d, table) if applies(OUTCOMES[n], st[1])]
    out = []
    if not work:
        return pd.DataFrame(out, columns=SCREEN_COLUMNS)
    c = d.config.campaign
    setup = campaign_wf.campaign_setup(d.config, d.plan)
    space = build.search_space(d.config)
    cont = [d.factors.index(n) for n in space.names]
    with bar(len(work) * d.samples, "gradients", progress) as shown:
        for k, (name, (label, kind, rows)) in enumerate(work):
            outcome = OUTCOMES[name]
            problem = wc.Problem(setup.model, setup.fdd_params, setup.settings, space, setup.nu_bank, *outcome.smooth,
                                 s.temperature, c.n_steps, c.dt_s, c.substeps, setup.dtype)
            a = rows.iloc[:d.samples]
            keys = simulate.run_keys(d.seed, d.plan.keys[a["scenario_id"].to_numpy()])
            fixed = {ax.name: _column(a, ax) for ax in space.categorical}
            y, dy = _gradients(problem, d.unit[:d.samples][:, cont], fixed, keys, shown)
            if outcome.undefined is not None:
                dy[~np.isfinite(y)] = 0.0
                y = np.where(np.isfinite(y), y, outcome.undefined)
            hard = outcome_values(outcome, a)
            keep = np.isfinite(y) & np.all(np.isfinite(dy), axis=1)
            both = keep & np.isfinite(hard) & (hard != 0)
            if both.any():
                notes.append(f"screen of {name}, {label}: smooth statistic (temperature {s.temperature}) within "
                             f"{100 * np.median(np.abs(y[both] / hard[both] - 1)):.2g} % (median) of the runs' own")
            try:
                r = sens.dgsm(dy[keep], y[keep], s.bootstrap, s.confidence, [d.seed, 1000 + k])
            except ValueError as err:
                notes.append(f"screen of {name}, {label}: {err}; not screened")
                continue
            out += [{"outcome": name, "stratum": label, "factor": f,
                     **{key: float(r[key][i]) for key in ("nu", "nu_lo", "nu_hi", "bound", "bound_lo", "bound_hi")},
                     "points": int(keep.sum())} for i, f in enumerate(space.names) if acts(f, kind)]
    return _ranked(pd.DataFrame(out, columns=SCREEN_COLUMNS), "nu")


def regional_table(cfg: config.CampaignConfig, table, resamples: int, confidence: float, seed: int):
    """Regional sensitivity of the binary outcomes (:data:`EVENTS`) over the varying axes of ``cfg``'s space.

    Each axis's values in the runs with the event against the other runs where it can happen (a
    fault-size axis within its fault kind's runs); axes are ranked per outcome by the distance D
    (Kolmogorov-Smirnov for ranges, total variation for lists). Outcomes without an event, or
    where every run has it, and axes with one value in those runs give no rows. Returns a tidy
    table (:data:`REGIONAL_COLUMNS`).
    """
    import pandas as pd

    out = []
    axes = [a for a in cfg.space.axes if a.kind != "const"]
    for e, (name, event) in enumerate(EVENTS.items()):
        runs = event.runs(table)
        happened = table[event.column].to_numpy(dtype=bool) & runs
        for i, axis in enumerate(axes):
            rows = runs & ((table["fault_kind"] == columns.SIZE_COLUMNS[axis.name]).to_numpy()
                           if axis.name in columns.SIZE_COLUMNS else True)
            hit = happened[rows]
            x = _column(table[rows], axis)
            if not hit.any() or hit.all() or len(np.unique(x)) < 2:
                continue
            common = {"outcome": name, "factor": axis.name, "events": int(hit.sum()), "runs": int(rows.sum())}
            if axis.kind == "range":
                out.append({**common, "kind": "continuous", "test": "ks",
                            **sens.regional_continuous(x, hit, resamples, confidence, [seed, e, i]), "rates": ""})
            else:
                r = sens.regional_categorical(x, hit)
                out.append({**common, "kind": "categorical", "statistic": r["statistic"], "p_value": r["p_value"],
                            "test": r["test"], "rates": "; ".join(f"{v} {k}/{n}" for v, k, n in r["rates"])})
    df = _ranked(pd.DataFrame(out, columns=[c for c in REGIONAL_COLUMNS if c != "rank"]), "statistic")
    df.insert(3, "rank", df.groupby("outcome", sort=False).cumcount() + 1 if len(df) else [])
    return df


def witnesses(table, count: int = 3):
    """The worst runs of each binary outcome: false alarms with the largest fault-free ratio, misses of the
    most separable faults (distance (16) at the peak load, separable ones first). Tidy table."""
    import pandas as pd

    frames = []
    fa = table[scored(table) & table["false_alarm"].to_numpy(dtype=bool)]
    frames.append(fa.sort_values(["loe_ratio0_max_pre", "scenario_id"], ascending=[False, True]).head(count)
                  .assign(outcome="false_alarm", value=lambda t: t["loe_ratio0_max_pre"], measure="loe_ratio0_max_pre"))
    missed = table[table["missed"].to_numpy(dtype=bool)]
    frames.append(missed.sort_values(["separable", "fault_distance", "scenario_id"], ascending=[False, False, True])
                  .head(count).assign(outcome="missed", value=lambda t: t["fault_distance"], measure="fault_distance"))
    cols = ["outcome", "scenario_id", "measure", "value", "fault_kind"]
    return pd.concat([f[cols] for f in frames], ignore_index=True)

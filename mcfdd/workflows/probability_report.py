"""The text of ``mcfdd probability``: terminal lines and summary.md (strings only; the caller writes them)."""

from __future__ import annotations

import pandas as pd

from mcfdd.analysis import rare

AIRFRAME_COLUMNS = ("stratum", "point", "estimate", "cov", "lo", "hi", "simulations", "hits", "runs")


def _estimate_text(e: rare.Estimate, unit: str = "") -> str:
    bound = "" if e.reached else " (upper bound: the level cap was reached with no failure sample)"
    return (f"{e.estimate:.3g}{unit} (c.o.v. {e.cov:.2f}, {100 * e.confidence:.0f} % interval "
            f"[{e.interval[0]:.3g}, {e.interval[1]:.3g}]){bound}")


def lines(result) -> list[str]:
    """Terminal lines of a :class:`~mcfdd.workflows.probability.ProbabilityResult`."""
    out = [f"P({result.event}) per run: {_estimate_text(result.overall)}; "
           f"{int(result.strata['simulations'].sum())} simulations ({result.method})"]
    if len(result.groups) > 1:
        out += [f"  {label}: {_estimate_text(e)}" for label, e in result.groups.items()]
    if result.rate is not None:
        cls = rare.certification_class(result.rate)
        out.append(f"per flight hour: {_estimate_text(result.rate)}; AMC 25.1309 class whose limit the upper end "
                   f"meets: {cls or 'none (above 1e-5: minor only)'}")
    return out + airframe_lines(result)


def airframe_lines(result) -> list[str]:
    """The per-airframe view: the worst corner (with its rate per flight hour) or the quantile over airframes."""
    view = result.airframe
    if view is None:
        return []
    axes = [c for c in result.airframes.columns if c not in AIRFRAME_COLUMNS]
    if not view.quantile == view.quantile:  # nan: the corner view
        at = result.airframes[result.airframes["point"] == view.worst].iloc[0]
        corner = ", ".join(f"{name}={at[name]:.4g}" for name in axes)
        worst = _estimate_text(view.estimates[view.worst])
        out = [f"per airframe, worst of {len(view.points)} corners ({corner}): {worst} per run"]
        if result.airframe_rate is not None:
            out.append(f"  per flight hour at that corner: {_estimate_text(result.airframe_rate)}")
        return out
    return [f"per airframe ({', '.join(axes)}), {view.quantile:g} quantile over {len(view.points)} airframes: "
            f"{view.value:.3g} per run ({100 * result.overall.confidence:.0f} % interval [{view.interval[0]:.3g}, "
            f"{view.interval[1]:.3g}])"]


def _table(df: pd.DataFrame) -> str:
    if df.empty:
        return "(none)\n"
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    rule = "|" + "---|" * len(df.columns)
    rows = ["| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row) + " |"
            for row in df.itertuples(index=False)]
    return "\n".join([head, rule, *rows]) + "\n"


def markdown(title: str, result) -> str:
    """summary.md: the estimates, the strata, the levels, the most probable failure points, the assumptions."""
    parts = [f"# {title}: P({result.event})\n", "\n".join(f"- {line}" for line in lines(result)) + "\n",
             "## Strata\n", _table(result.strata), "## Estimator runs\n", _table(result.runs),
             *(["## Per airframe\n", _table(result.airframes)] if not result.airframes.empty else []),
             "## Levels (subset simulation)\n",
             _table(result.levels.head(60)) if not result.levels.empty else "(none)\n",
             "## Most probable failure points\n",
             "Rows of failures.parquet, smallest beta = ||u|| first; `point` is the row of failure_points.npy "
             "(replay with `ProbabilityResult.replay`).\n",
             _table(result.failures.sort_values("beta").head(10)) if not result.failures.empty else "(none)\n",
             "## What the numbers mean and what they assume\n", "\n".join(f"- {n}" for n in result.notes) + "\n",
             f"\nProvenance: version {result.meta.get('version')}, git {result.meta.get('git_revision')}, "
             f"seed {result.meta.get('seed')}.\n"]
    return "\n".join(parts)

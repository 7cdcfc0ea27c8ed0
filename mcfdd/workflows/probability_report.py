"""The text of ``mcfdd probability``: terminal lines and summary.md (strings only; the caller writes them)."""

from __future__ import annotations

import pandas as pd

from mcfdd.analysis import rare


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
    return out


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
             "## Strata\n", _table(result.strata), "## Levels (subset simulation)\n",
             _table(result.levels.head(60)) if not result.levels.empty else "(none)\n",
             "## Most probable failure points\n",
             "Rows of failures.parquet, smallest beta = ||u|| first; `point` is the row of failure_points.npy "
             "(replay with `ProbabilityResult.replay`).\n",
             _table(result.failures.sort_values("beta").head(10)) if not result.failures.empty else "(none)\n",
             "## What the numbers mean and what they assume\n", "\n".join(f"- {n}" for n in result.notes) + "\n",
             f"\nProvenance: version {result.meta.get('version')}, git {result.meta.get('git_revision')}, "
             f"seed {result.meta.get('seed')}.\n"]
    return "\n".join(parts)

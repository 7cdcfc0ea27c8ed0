"""Paired comparison of two campaigns of one scenario space (``mcfdd compare``, :func:`compare`).

Two campaigns of one space (the same scenario ids, design values and seed, so every run meets the
same flight, uncertainty, manoeuvre, turbulence and sensor noise) differ only in what was changed
between them, typically the FDD. Each run is then a matched pair, and per outcome of the scenario
table (:func:`mcfdd.analysis.metrics.paired_outcomes`) only the discordant runs (the event in one
campaign and not in the other) carry information about the difference: McNemar's exact test is the
two-sided binomial test of one campaign's discordant count at 1/2. The detection times of the runs
detected in both are compared by their differences (b - a) and the Wilcoxon signed-rank test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mcfdd import config, io
from mcfdd.analysis import metrics, scenarios
from mcfdd.workflows.campaign import CampaignResult


class CampaignMismatchError(config.ConfigError):
    """Two campaigns that are not of one space, or a folder that holds no campaign."""


def _campaign(source, name: str):
    """(scenario table sorted by id, provenance, label) of a CampaignResult or a campaign folder."""
    import pandas as pd

    if isinstance(source, CampaignResult):
        return source.scenarios, source.meta, name
    folder = Path(source)
    parts = sorted((folder / "scenarios").glob("part-*.parquet"))
    if not parts:
        raise CampaignMismatchError(f"{name}: {folder} holds no campaign (no scenarios/part-*.parquet)")
    try:
        table = pd.concat([io.read_checked_table(p) for p in parts], ignore_index=True)
    except ValueError as err:
        raise CampaignMismatchError(f"{name}: {folder} holds a damaged scenario part ({err})") from None
    return table.sort_values("scenario_id", ignore_index=True), io.read_metadata(parts[0]), folder.name


def check_pair(a, b, meta_a: dict, meta_b: dict):
    """Refuse (:class:`CampaignMismatchError`, one line naming what differs) two scenario tables that are
    not of one space: other seeds, other scenario ids, other design columns or values."""
    if meta_a.get("seed") != meta_b.get("seed"):
        raise CampaignMismatchError(f"compare: the campaigns have other seeds ({meta_a.get('seed')} and "
                                    f"{meta_b.get('seed')}): their runs draw other noise and turbulence")
    ids_a, ids_b = a["scenario_id"].to_numpy(), b["scenario_id"].to_numpy()
    if not np.array_equal(ids_a, ids_b):
        only_a, only_b = np.setdiff1d(ids_a, ids_b), np.setdiff1d(ids_b, ids_a)
        raise CampaignMismatchError(f"compare: the campaigns hold other scenarios ({len(ids_a)} and {len(ids_b)} runs; "
                                    f"{len(only_a)} ids only in a, {len(only_b)} only in b)")
    for column in scenarios.DEFAULTS:
        if (column in a) != (column in b):
            raise CampaignMismatchError(f"compare: design column {column} is in campaign {'a' if column in a else 'b'} "
                                        f"only")
        if column in a and not np.array_equal(a[column].to_numpy(), b[column].to_numpy()):
            i = int(np.flatnonzero(a[column].to_numpy() != b[column].to_numpy())[0])
            raise CampaignMismatchError(f"compare: design column {column} differs (first at scenario "
                                        f"{int(ids_a[i])}: {a[column].iloc[i]} and {b[column].iloc[i]})")


class CompareResult:
    """A paired comparison of campaigns a and b.

    Attributes:
        outcomes: one row per outcome (:func:`mcfdd.analysis.metrics.paired_outcomes`): ``outcome``,
            ``counted_on`` (which runs), ``runs`` (counted in both), ``events_a``, ``rate_a`` (with
            ``rate_a_lo``, ``rate_a_hi``: Clopper-Pearson 95 %), the same for b, ``only_a`` and
            ``only_b`` (discordant runs) and ``p_value`` (McNemar's exact test).
        detection_times: per fault kind and ``all``: ``runs`` detected in both, median detection
            latency in a and in b (s), median of the paired difference b - a (s) and the Wilcoxon
            signed-rank ``p_value``.
        discordant: one row per discordant run and outcome: ``outcome``, ``scenario_id``, ``event_in``
            (``a`` or ``b``).
        labels: names of the two campaigns (folder names, or 'a' and 'b').
        meta: provenance of the comparison (both configs, seed, version and revisions).
    """

    def __init__(self, outcomes, detection_times, discordant, labels: tuple, meta: dict):
        self.outcomes, self.detection_times, self.discordant = outcomes, detection_times, discordant
        self.labels, self.meta = labels, meta

    def lines(self) -> list[str]:
        """The printed summary of ``mcfdd compare``."""
        from mcfdd import report

        return report.compare_lines(self.outcomes, self.detection_times, self.labels)

    def save(self, out) -> list[Path]:
        """Write ``outcomes.parquet``, ``detection_times.parquet``, ``discordant.parquet`` (provenance in
        their metadata) and ``compare.md`` into folder ``out``; returns the paths."""
        from mcfdd import report

        out = Path(out)
        written = [io.write_table(frame, out / f"{name}.parquet", self.meta) for name, frame in (
            ("outcomes", self.outcomes), ("detection_times", self.detection_times), ("discordant", self.discordant))]
        written.append(io.write_text(out / "compare.md", report.compare_markdown(
            self.outcomes, self.detection_times, self.discordant, self.labels, self.meta)))
        return written


def compare(a, b, labels: tuple | None = None) -> CompareResult:
    """Paired comparison of two campaigns of one scenario space.

    Args:
        a, b: each a :class:`CampaignResult` or the folder of a campaign (``mcfdd campaign --out``).
        labels: names of the two in the tables and the report (default the folder names, or 'a', 'b').

    Returns:
        A :class:`CompareResult`. Runs whose numbers went non-finite in either campaign are left out.

    Raises:
        CampaignMismatchError: the campaigns are not of one space (seed, scenario ids, design columns
            or values differ), or a folder holds no campaign; the message names what differs.
    """
    import pandas as pd

    (ta, meta_a, name_a), (tb, meta_b, name_b) = _campaign(a, "a"), _campaign(b, "b")
    check_pair(ta, tb, meta_a, meta_b)
    labels = tuple(labels) if labels is not None else (name_a, name_b) if name_a != name_b else ("a", "b")
    ok = (ta["status"].to_numpy() == 0) & (tb["status"].to_numpy() == 0)
    ids = ta["scenario_id"].to_numpy()
    rows, discordant = [], []
    pa, pb = metrics.paired_outcomes(ta), metrics.paired_outcomes(tb)
    for name, (counted_on, runs_a, event_a) in pa.items():
        _, runs_b, event_b = pb[name]
        runs = ok & runs_a & runs_b
        rows.append({"outcome": name, "counted_on": counted_on, **metrics.paired_counts(event_a[runs], event_b[runs])})
        for side, only in (("a", runs & event_a & ~event_b), ("b", runs & event_b & ~event_a)):
            discordant += [{"outcome": name, "scenario_id": int(i), "event_in": side} for i in ids[only]]
    times = []
    detected = ok & ta["must_detect"].to_numpy() & ta["detected"].to_numpy() & tb["detected"].to_numpy()
    kinds = ta["fault_kind"].to_numpy()
    for kind in ["all"] + sorted(set(kinds[detected])):
        rows_k = detected & ((kinds == kind) | (kind == "all"))
        times.append({"fault_kind": kind, **metrics.paired_differences(
            ta["detection_latency_s"].to_numpy()[rows_k], tb["detection_latency_s"].to_numpy()[rows_k])})
    configs = {label: json.loads(m["config"]) if m.get("config") else None
               for label, m in zip(labels, (meta_a, meta_b))}
    meta = io.provenance(json.dumps(configs), None if not meta_a.get("seed") else int(meta_a["seed"]),
                         campaigns=list(labels), revisions=[meta_a.get("git_revision"), meta_b.get("git_revision")])
    return CompareResult(pd.DataFrame(rows), pd.DataFrame(times),
                         pd.DataFrame(discordant, columns=["outcome", "scenario_id", "event_in"]), labels, meta)

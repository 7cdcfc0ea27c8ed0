"""Paired comparison of two campaigns: McNemar's exact test, the signed-rank test, refusal of other spaces.

McNemar against a hand-computed binomial tail and an independent enumeration of the binomial
distribution; the Wilcoxon signed-rank p-value against an enumeration of all sign flips; the
counts of :func:`mcfdd.compare` against the scenario tables of two real campaigns of one space
(two FDDs); and a one-line refusal, from the API and the command, of campaigns of other spaces.
"""

import itertools
import json
import math

import numpy as np
import pandas as pd
import pytest

import mcfdd
from helpers import small_config
from mcfdd import cli, io
from mcfdd.analysis import metrics


def binomial_two_sided(k: int, n: int) -> float:
    """Two-sided binomial test at 1/2 by enumeration: the probability of every count no more likely than k."""
    pmf = [math.comb(n, i) / 2.0**n for i in range(n + 1)]
    return min(1.0, sum(p for p in pmf if p <= pmf[k] * (1.0 + 1e-12)))


def test_mcnemar_matches_a_hand_computed_binomial_tail():
    """1 discordant run one way and 7 the other: p = 2 (C(8,0) + C(8,1)) / 2^8 = 18 / 256, either way round."""
    assert metrics.mcnemar_exact(1, 7) == pytest.approx(18.0 / 256.0, rel=1e-12)
    assert metrics.mcnemar_exact(7, 1) == pytest.approx(18.0 / 256.0, rel=1e-12)
    assert metrics.mcnemar_exact(0, 0) == 1.0
    assert metrics.mcnemar_exact(5, 5) == pytest.approx(1.0)


@pytest.mark.parametrize("only_a, only_b", [(0, 1), (0, 6), (2, 9), (13, 4), (30, 12), (40, 41)])
def test_mcnemar_matches_an_enumerated_binomial(only_a, only_b):
    assert metrics.mcnemar_exact(only_a, only_b) == pytest.approx(binomial_two_sided(only_a, only_a + only_b),
                                                                   rel=1e-9)


def test_paired_counts_and_differences():
    """Counts and discordant runs against numpy; the signed-rank p against all 2^n sign flips of the ranks."""
    rng = np.random.default_rng(3)
    a, b = rng.random(200) < 0.3, rng.random(200) < 0.4
    c = metrics.paired_counts(a, b)
    assert (c["runs"], c["events_a"], c["events_b"]) == (200, a.sum(), b.sum())
    assert (c["only_a"], c["only_b"]) == ((a & ~b).sum(), (b & ~a).sum())
    assert c["rate_a_lo"] < c["rate_a"] < c["rate_a_hi"]
    assert c["p_value"] == pytest.approx(binomial_two_sided(c["only_a"], c["only_a"] + c["only_b"]), rel=1e-9)

    x_a = rng.normal(10.0, 2.0, 11)
    d = np.array([0.31, -0.12, 0.57, 0.08, -0.44, 0.95, 0.23, -0.05, 0.66, 0.14, 0.0])  # one zero: dropped
    r = metrics.paired_differences(x_a, x_a + d)
    nonzero = d[d != 0.0]
    ranks = np.argsort(np.argsort(np.abs(nonzero))) + 1.0
    t_obs = ranks[nonzero > 0].sum()
    totals = np.array([sum(rk for rk, s in zip(ranks, signs) if s) for signs in
                       itertools.product([0, 1], repeat=nonzero.size)])
    mean = ranks.sum() / 2.0
    p_enumerated = np.mean(np.abs(totals - mean) >= abs(t_obs - mean) - 1e-9)
    assert r["runs"] == 11 and r["median_difference"] == pytest.approx(np.median(d))
    assert r["median_a"] == pytest.approx(np.median(x_a)) and r["median_b"] == pytest.approx(np.median(x_a + d))
    assert r["p_value"] == pytest.approx(p_enumerated, rel=1e-9)
    assert metrics.paired_differences(x_a, x_a)["p_value"] == 1.0
    assert math.isnan(metrics.paired_differences([], [])["p_value"])


@pytest.fixture(scope="module")
def two_fdds(tmp_path_factory):
    """One small space run with the default FDD (a) and with a low detection threshold and floor (b)."""
    folder = tmp_path_factory.mktemp("compare")
    path = small_config(folder, n=128)
    low = {"fdd.loe.detection_tau": 0.03, "fdd.loe.detection_contrast": 0.0, "fdd.loe.excitation_floor_deg": 0.01,
           "fdd.loe.excitation_noise_factor": 0.0, "fdd.loe.load_gate": "fault_free"}
    a = mcfdd.run_campaign(mcfdd.load_config(path), out=folder / "a", progress=False)
    b = mcfdd.run_campaign(mcfdd.load_config(path, overrides=low), out=folder / "b", progress=False)
    return folder, a, b


def test_compare_counts_the_discordant_runs_of_two_fdds(two_fdds):
    """From the result objects and from the folders alike: per outcome the runs, events and discordant ids of
    the two scenario tables, McNemar's p of those counts; detection latency on the runs detected by both."""
    folder, a, b = two_fdds
    result = mcfdd.compare(a, b)
    again = mcfdd.compare(folder / "a", folder / "b")
    pd.testing.assert_frame_equal(result.outcomes, again.outcomes)
    assert again.labels == ("a", "b") and result.labels == ("a", "b")
    ta, tb = a.scenarios, b.scenarios
    free = (ta["fault_kind"] == "none").to_numpy()
    faulty = ta["must_detect"].to_numpy()
    rows = result.outcomes.set_index("outcome")
    for name, runs, column in (("loe_false_alarm", free, "false_alarm"), ("missed", faulty, "missed")):
        ea, eb = ta[column].to_numpy()[runs], tb[column].to_numpy()[runs]
        r = rows.loc[name]
        assert (r["runs"], r["events_a"], r["events_b"]) == (runs.sum(), ea.sum(), eb.sum())
        assert (r["only_a"], r["only_b"]) == ((ea & ~eb).sum(), (eb & ~ea).sum())
        assert r["p_value"] == pytest.approx(binomial_two_sided(r["only_a"], r["only_a"] + r["only_b"]), rel=1e-9)
        ids = result.discordant[result.discordant["outcome"] == name]
        assert set(ids.loc[ids["event_in"] == "b", "scenario_id"]) == set(ta["scenario_id"][runs][eb & ~ea])
    assert rows.loc["loe_false_alarm", "only_b"] > 0 and rows.loc["missed", "only_a"] > 0  # the low threshold
    both = faulty & ta["detected"].to_numpy() & tb["detected"].to_numpy()
    t = result.detection_times.set_index("fault_kind").loc["all"]
    d = tb["detection_latency_s"].to_numpy()[both] - ta["detection_latency_s"].to_numpy()[both]
    assert t["runs"] == both.sum() > 0 and t["median_difference"] == pytest.approx(np.median(d))
    written = result.save(folder / "cmp")
    assert {p.name for p in written} == {"outcomes.parquet", "detection_times.parquet", "discordant.parquet",
                                         "compare.md"}
    meta = io.read_metadata(folder / "cmp" / "outcomes.parquet")
    assert meta["seed"] == "7" and set(json.loads(meta["config"])) == {"a", "b"}
    assert "McNemar" in (folder / "cmp" / "compare.md").read_text()


def test_compare_refuses_campaigns_of_other_spaces(two_fdds, tmp_path, capsys):
    """Another seed, other scenarios, another design value: one line naming what differs (exit 2 from the
    command); a folder without a campaign is named too."""
    folder, a, _ = two_fdds
    other_seed = mcfdd.run_campaign(mcfdd.load_config(small_config(tmp_path, n=128), overrides={"campaign.seed": 8}),
                                    progress=False)
    with pytest.raises(mcfdd.CampaignMismatchError, match="other seeds"):
        mcfdd.compare(a, other_seed)
    fewer = mcfdd.run_campaign(mcfdd.load_config(small_config(tmp_path, n=64)), progress=False)
    with pytest.raises(mcfdd.CampaignMismatchError, match="other scenarios"):
        mcfdd.compare(a, fewer)
    moved = mcfdd.run_campaign(mcfdd.load_config(small_config(tmp_path, n=128),
                                                 overrides={"space.noise_std_mm": [0.03, 0.08]}), progress=False)
    with pytest.raises(mcfdd.CampaignMismatchError, match="design column noise_std_mm differs"):
        mcfdd.compare(a, moved)
    assert cli.main(["compare", str(folder / "a"), str(tmp_path), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds no campaign" in err[0] and str(tmp_path) in err[0]

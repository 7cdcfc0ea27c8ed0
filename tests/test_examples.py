"""Every script in ``examples/`` runs, at a small size (environment variables the scripts read).

32 scenarios in all: 8 per fault kind of the LOE campaigns, 16 per fault kind of held_out_validation.py and
per manoeuvre family of python_space.py.
"""

import runpy
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SMALL = {"MCFDD_EXAMPLE_SCENARIOS": "32", "MCFDD_EXAMPLE_DURATION_S": "4", "MCFDD_EXAMPLE_ITERATIONS": "2"}


def test_every_example_is_listed():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(
        ["held_out_validation.py", "python_space.py", "threshold_tradeoff.py", "tune_and_validate.py"])


@pytest.mark.parametrize("name", ["threshold_tradeoff.py", "python_space.py", "tune_and_validate.py",
                                  "held_out_validation.py"])
def test_example_runs(name, tmp_path, monkeypatch, capsys):
    for key, value in SMALL.items():
        monkeypatch.setenv(key, value)
    monkeypatch.setenv("MCFDD_EXAMPLE_OUT", str(tmp_path))
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    printed = capsys.readouterr().out
    if name == "threshold_tradeoff.py":
        assert "no false alarm in" in printed and (tmp_path / "threshold_tradeoff.png").stat().st_size > 0
    elif name == "held_out_validation.py":
        assert "fault-free LOE false alarms:" in printed and "of 16 runs" in printed
        assert "disconnection missed" in printed
        assert (tmp_path / "held_out_validation" / "summary.md").stat().st_size > 0
    elif name == "python_space.py":
        assert "overall" in printed and "bank_to_bank" in printed
    else:
        assert "before tuning: FAR" in printed and "after tuning: FAR" in printed

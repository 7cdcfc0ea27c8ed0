"""Every code block of README.md is checked as written: Python run, commands parsed and run, TOML parsed.

The blocks run in a scratch folder whose ``configs/`` holds the shipped configs, the expensive ones
shrunk (fewer scenarios, iterations, flight points; the keys and their meaning unchanged), so each
line runs as the README writes it at a small size. What cannot run here is checked as far as it
goes: the SLURM script's mcfdd calls and the summary keys it reads, the flags of commands that need
a cluster or another host.
"""

from __future__ import annotations

import ast
import contextlib
import inspect
import os
import re
import shlex
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import pytest
import tomli_w

import mcfdd
from mcfdd import cli

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
BLOCKS = [(lang, body) for lang, body in re.findall(r"^```(\w*)\n(.*?)^```", README, re.S | re.M)]
SHRINK = {  # config file -> changes (a list keeps its first entries)
    "loe_campaign.toml": {"campaign": {"scenarios": 16, "chunk_size": 16, "duration_s": 20.0},
                          "space": {"fault_onset_s": [6.0, 10.0], "t_start_s": [5.0, 15.0]}},
    "lpv_aileron.toml": {"envelope": {"grid": [2, 2], "validation_points": 1},
                         "optimiser": {"iterations": 2}, "training": 2, "validation": 1},
    "validation.toml": {"campaign": {"duration_s": 20.0}, "space": {"manoeuvre_kind": ["doublet"],
                                                                    "turbulence": ["moderate"]},
                        "probability": {"samples": 50, "max_levels": 2, "budget": 50, "repeats": 1,
                                        "airframe": {"axes": ["kci_scale"]}}},
    "tune_loe.toml": {"tune": {"iterations": 2}, "training": {"scenarios": 8, "duration_s": 20.0},
                      "validation": {"scenarios": 8, "chunk_size": 8, "duration_s": 20.0}},
    "worst_case_stall.toml": {"search": {"screening": 8, "starts": 1, "iterations": 2}},
}


def _shrunk(data: dict, changes: dict) -> dict:
    for key, change in changes.items():
        if isinstance(change, int) and isinstance(data[key], list):
            data[key] = data[key][:change]
        else:
            data[key] = {**data.get(key, {}), **change}
    return data


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """A folder with ``configs/`` (the shipped configs, the expensive ones shrunk), made the working folder."""
    folder = tmp_path_factory.mktemp("readme")
    (folder / "configs").mkdir()
    for path in (ROOT / "configs").glob("*.toml"):
        data = tomllib.loads(path.read_text())
        text = tomli_w.dumps(_shrunk(data, SHRINK[path.name])) if path.name in SHRINK else path.read_text()
        (folder / "configs" / path.name).write_text(text)
    old = Path.cwd()
    os.chdir(folder)
    try:
        yield folder
    finally:
        os.chdir(old)


def _python(name: str) -> str:
    [body] = [b for lang, b in BLOCKS if lang == "python" and (name in b)]
    return body


def _commands() -> list[str]:
    """The shell lines of the README's command blocks, prompts and comments removed, continuations joined."""
    lines = []
    for lang, body in BLOCKS:
        if lang:
            continue
        for line in body.replace("\\\n", " ").splitlines():
            line = re.sub(r"^\w+\$\s+", "", line.split("  #")[0]).strip()
            if line:
                lines.append(line)
    return lines


def test_every_block_is_one_the_suite_checks():
    kinds = {"python": 0, "": 0, "toml": 0}
    for lang, _ in BLOCKS:
        kinds[lang] += 1
    assert kinds == {"python": 4, "": 6, "toml": 3}, kinds


@pytest.fixture(scope="module")
def api(scratch):
    """The Python API block, run as written (in the scratch folder); its names."""
    names: dict = {}
    exec(compile(_python("mcfdd.load_config(\"configs/fault_free.toml\""), "README.md", "exec"), names)
    return names


def test_the_python_api_block_runs_as_written(api, scratch):
    assert len(api["result"].scenarios) == 320 and api["result"].overall()["fault_free_runs"] == 320
    assert (scratch / "rates.png").stat().st_size > 0
    assert (scratch / "results" / "fault-free-detection-tau-0.07" / "summary.md").is_file()
    assert api["histories"].runs and len(api["bank"].models) == 6
    assert list(api["tuned"].validation["fdd"]) == ["before", "after"] and len(api["worst"].points) > 0


def test_the_api_example_changes_what_false_alarms_depend_on(api):
    """Its second campaign lowers fdd.loe.detection_tau, the detection threshold: every false alarm of the first
    stays and more come; lowering fdd.loe.tau (the identification threshold) as much leaves them as they were."""
    first, again = api["result"].scenarios, api["again"].scenarios
    assert api["lower"].fdd.loe.detection_tau == 0.07 < api["cfg"].fdd.loe.detection_tau
    assert (again["false_alarm"] | ~first["false_alarm"]).all()
    assert again["false_alarm"].sum() > first["false_alarm"].sum()
    identification = mcfdd.load_config("configs/fault_free.toml", overrides={
        "campaign.scenarios": 320, "campaign.duration_s": 40.0, "fdd.loe.tau": api["cfg"].fdd.loe.tau - 0.03})
    same = mcfdd.run_campaign(identification, progress=False).scenarios
    assert (same["false_alarm"] == first["false_alarm"]).all()


def test_the_rare_event_block_runs_and_brackets_its_closed_form():
    """The estimators' block, run as written: subset simulation's interval within a decade of its limit state's
    probability Phi(-4.75) (the comment's 1.02e-6; one run at n = 1000 has a c.o.v. of about 0.35, and the
    coverage of its intervals is tests/test_rare.py's), importance sampling's estimate within 20 % of it; plain
    Monte Carlo's 100,000 runs see no hit; the per-flight-hour rate is the weighted per-run rates over 60 s."""
    from scipy.stats import norm

    names: dict = {}
    exec(compile(_python("rare.subset_simulation"), "README.md", "exec"), names)
    truth = norm.sf(4.75)
    assert f"{truth:.3g}" == "1.02e-06"
    lo, hi = names["est"].interval
    assert truth / 10.0 < lo < names["est"].estimate < hi < truth * 10.0
    assert abs(names["near"].estimate / truth - 1.0) < 0.2
    assert names["plain"].hits == 0
    expected = (0.7 * names["est"].estimate + 0.3 * names["near"].estimate) * 3600.0 / 60.0
    assert names["rate"].estimate == pytest.approx(expected, rel=1e-12)


def test_the_probability_block_runs_as_written(scratch):
    """mcfdd.probability on the (shrunk) validation config: one stratum, its files, the numbers it states."""
    names: dict = {}
    exec(compile(_python("mcfdd.probability("), "README.md", "exec"), names)
    result = names["result"]
    assert result.event == "false_alarm" and len(result.strata) == 1 and result.rate is not None
    assert result.overall.n_simulations == int(result.strata["simulations"].sum()) <= 50 + 2 * 45
    assert len(result.airframes) == 2 and len(result.runs) == 1  # the two corners of kci_scale, one run each
    assert (scratch / "results" / "p" / "summary.md").is_file()


def test_the_slurm_script_uses_what_mcfdd_has(api):
    """No SLURM here: its mcfdd names, run_campaign's keywords and the summary keys it reads must exist."""
    tree = ast.parse(_python("SLURMCluster"))
    used = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and getattr(n.value, "id", "") == "mcfdd"}
    assert used and used <= set(mcfdd.__all__)
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "attr", "") == "run_campaign"]
    keywords = {k.arg for n in calls for k in n.keywords}
    assert keywords <= set(inspect.signature(mcfdd.run_campaign).parameters)
    read = {n.slice.value for n in ast.walk(tree) if isinstance(n, ast.Subscript) and isinstance(n.slice, ast.Constant)}
    assert read and read <= set(api["result"].overall())


def _run(command: str, scratch: Path):
    """``mcfdd ...`` in process; ``> FILE`` writes its standard output there."""
    argv, target = shlex.split(command), None
    if ">" in argv:
        argv, target = argv[:argv.index(">")], argv[argv.index(">") + 1]
    output = contextlib.redirect_stdout(open(scratch / target, "w")) if target else contextlib.nullcontext()
    with output:
        assert cli.main(argv[1:]) == 0, command


def test_every_mcfdd_command_parses_and_the_local_ones_run(scratch, capsys):
    """Each ``mcfdd`` line's flags exist; those needing no cluster or other host run, at the scratch configs' size.
    (``pip``, ``pytest``, ``cp`` into the package and ``dask`` are not run.)"""
    commands = [c for c in _commands() if c.split()[0] == "mcfdd" or " && mcfdd " in c]
    assert len(commands) >= 6
    ran = []
    for command in commands:
        command = command.split(" && ")[-1]
        cli.build_parser().parse_args(shlex.split(command.split(" > ")[0])[1:])
        if "--workers" not in command and "--scheduler" not in command:
            _run(command, scratch)
            ran.append(command.split()[1])
    assert sorted(set(ran)) == ["campaign", "fit-lpv", "schema"]
    assert (scratch / "results" / "fit-lpv-lpv_aileron" / "bank.json").is_file()  # what the cp line copies
    capsys.readouterr()


def test_the_toml_blocks_parse_and_the_taplo_rule_matches_the_campaign_configs(scratch, capsys):
    tomls = [body for lang, body in BLOCKS if lang == "toml"]
    parsed = [tomllib.loads(body) for body in tomls]
    [rule] = [d["rule"][0] for d in parsed if "rule" in d]
    configs = [p.name for p in (ROOT / "configs").glob("*.toml")]
    matched = {name for name in configs for pattern in rule["include"] if fnmatch(f"configs/{name}", pattern)}
    kinds = {name: mcfdd.config.infer_kind(tomllib.loads((ROOT / "configs" / name).read_text())) for name in matched}
    assert "loe_campaign.toml" in matched and set(kinds.values()) == {"campaign"}, kinds
    assert "#:schema " + rule["schema"]["path"] in tomls[0]
    assert cli.main(["schema", "campaign"]) == 0 and '"$schema"' in capsys.readouterr().out


def test_the_summary_columns_scripts_read_are_all_listed(api):
    """README lists every column of the summary (and no other), in the section scripts read."""
    section = README[README.index("The summary's columns"):README.index("Detectability: each scenario row")]
    listed = set(re.findall(r"`([a-z_0-9]+)`", section)) - {"k", "n", "_lo", "_hi"}
    assert listed == set(api["result"].summary.columns), sorted(listed ^ set(api["result"].summary.columns))


def test_every_timing_says_under_which_conditions_it_holds():
    """A time taken on this project's machine (a duration stated with its cores) says whether the cores were idle
    or loaded; the first command's and the test suite's time say the state of the compilation cache too."""
    prose = re.sub(r"^```.*?^```", "", README, flags=re.S | re.M).replace("\n", " ")
    sentences = re.split(r"(?<=[.;:])\s+(?=[A-Z(`])", prose)
    duration = re.compile(r"\b(half a minute|a minute|[\d.,]+ ?(s|min)|[a-z]+ (to [a-z]+ )?minutes?|tens of seconds)\b")
    timed = [x for x in sentences if "core" in x and duration.search(x)]
    assert len(timed) >= 4  # the sentences found: the pattern still matches how README states timings
    for sentence in timed:
        assert "idle" in sentence or "loaded" in sentence, sentence
    for start in ("The first command installs", "The second installs the test dependencies"):
        [sentence] = [x for x in timed if x.startswith(start)]
        assert "compilation cache" in sentence, sentence

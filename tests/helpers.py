"""What several test modules share: paths, a small campaign, a campaign folder's table, compile counts,
tolerances.

Test modules import from here (``from helpers import SMALL``), never from each other.
"""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import psutil

from mcfdd import cli
from mcfdd.workflows.common import CompileCounter

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
FAULT_FREE = CONFIGS / "fault_free.toml"

# Tolerances, named by what they allow.
ROUNDING = {"rtol": 1e-12, "atol": 1e-15}  # one float64 quantity computed two ways: rounding only

# A campaign of every fault kind and three manoeuvre families in 4 s runs, ``n`` scenarios: small enough
# for several chunks in a test, rich enough that every column of the table varies.
SMALL = """
[campaign]
scenarios = {n}
design = "lhs"
seed = 7
chunk_size = 64
duration_s = 4.0

[evaluation]
settle_s = 0.5
t_detec_s = 120.0

[space]
vcas_kt = [200.0, 360.0]
altitude_m = [0.0, 6000.0]
noise_std_mm = [0.03, 0.07]
hinge_scale = [0.9, 1.4]
fault_kind = ["none", "leakage", "surface_damage", "disconnection", "jamming"]
leakage_size = [0.1, 0.3]
surface_damage_size = [0.3, 1.0]
fault_onset_s = [1.0, 2.0]
manoeuvre_kind = ["doublet", "ol_doublet", "sideslip"]
amplitude = [0.5, 1.0]
t_start_s = [0.2, 1.0]
duration_s = [0.5, 1.0]
sideslip_deg = [8.0, 14.0]
"""


def small_config(folder: Path, n: int = 40, extra: str = "") -> Path:
    """The :data:`SMALL` campaign of ``n`` scenarios (plus ``extra`` TOML) written to ``folder``/small.toml."""
    path = Path(folder) / "small.toml"
    path.write_text(SMALL.format(n=n) + extra)
    return path


def scenario_table(out: Path) -> pd.DataFrame:
    """The scenario table of a campaign folder: its parts in scenario order."""
    parts = sorted((Path(out) / "scenarios").glob("part-*.parquet"))
    return pd.concat([pd.read_parquet(p) for p in parts]).sort_values("scenario_id", ignore_index=True)


def compiles(call) -> int:
    """The number of XLA compilations ``call()`` makes (JAX's own compile events)."""
    with CompileCounter() as counter:
        call()
    return counter.count


def refused(capsys, *argv) -> str:
    """Runs the command, checks it is refused with one line and no traceback; returns the line."""
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("mcfdd: ")]
    assert len(lines) == 1, err
    return lines[0]


# ``python -m mcfdd.cli`` as a terminal's foreground job starts it: Ctrl-C raises KeyboardInterrupt. A process
# started in the background by a shell without job control (as a test runner may be) inherits SIGINT ignored,
# and Python keeps it ignored, as a background job should.
AT_A_TERMINAL = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                 "runpy.run_module('mcfdd.cli', run_name='__main__', alter_sys=True)")


def interrupted(cfg, out, after: str, delay_s: float, *flags, children: list | None = None):
    """``mcfdd campaign`` in its own process (``flags``, default ``--compile-cache off``) with Ctrl-C as at a
    terminal, SIGINT ``delay_s`` after the stderr line starting with ``after`` (None: after the start); ``children``
    gets its child processes then."""
    proc = subprocess.Popen([sys.executable, "-c", AT_A_TERMINAL, "campaign", str(cfg), "--out", str(out),
                             *(flags or ("--compile-cache", "off"))], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, text=True)
    seen = []
    for line in proc.stderr if after is not None else ():
        seen.append(line)
        if line.startswith(after):
            break
    time.sleep(delay_s)
    if children is not None:
        children.extend(psutil.Process(proc.pid).children(recursive=True))
    proc.send_signal(signal.SIGINT)
    seen.append(proc.stderr.read())
    proc.wait()
    return proc.returncode, "".join(seen)

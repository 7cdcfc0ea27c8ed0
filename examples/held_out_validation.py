"""Held-out check of the paper's validation claims (issue 11): the space of configs/validation.toml
with another seed, fault-free and disconnected runs only, and the validation FDD.

Prints the two numbers the check asks for: LOE false alarms in the fault-free runs (should be 0)
and the share of disconnections missed among the runs whose peak load fraction is 0.4 or more
(should be at most 15 %).

    python examples/held_out_validation.py                      # 4,096 runs of 30 s (2 x 2,048), seed 77
    MCFDD_EXAMPLE_SCENARIOS=32 MCFDD_EXAMPLE_DURATION_S=4 python examples/held_out_validation.py

``MCFDD_EXAMPLE_SCENARIOS`` is the total number of runs (``campaign.scenarios``), half of them
fault-free. Writes the campaign's files into MCFDD_EXAMPLE_OUT/held_out_validation (default
results/examples).
"""

import os
import shutil
from pathlib import Path

import mcfdd

SCENARIOS = int(os.environ.get("MCFDD_EXAMPLE_SCENARIOS", 4096))  # in all, over the two fault kinds
DURATION_S = float(os.environ.get("MCFDD_EXAMPLE_DURATION_S", 30.0))
OUT = Path(os.environ.get("MCFDD_EXAMPLE_OUT", "results/examples")) / "held_out_validation"
CONFIG = Path(__file__).resolve().parent.parent / "configs" / "validation.toml"
SEED = 77
LOAD_FRACTION = 0.4

scale = DURATION_S / 30.0  # the validation timeline (onset 10-12 s, manoeuvre 13-16 s) shrunk with the run
cfg = mcfdd.load_config(CONFIG, overrides={
    "campaign.scenarios": SCENARIOS, "campaign.seed": SEED, "campaign.duration_s": DURATION_S,
    "evaluation.settle_s": 5.0 * scale, "space.fault_kind": ["none", "disconnection"],
    "space.fault_onset_s": [10.0 * scale, 12.0 * scale], "space.t_start_s": [13.0 * scale, 16.0 * scale]})
if OUT.exists():
    shutil.rmtree(OUT)
table = mcfdd.run_campaign(cfg, out=OUT).scenarios
ok = table["status"] == mcfdd.Status.OK
free = ok & (table["fault_kind"] == "none")
loaded = ok & (table["fault_kind"] == "disconnection") & (table["peak_load_fraction"] >= LOAD_FRACTION)
alarms = int(table.loc[free, "false_alarm"].sum())
missed = int(table.loc[loaded, "missed"].sum())
print(f"fault-free LOE false alarms: {alarms} of {int(free.sum())} runs")
print(f"disconnection missed where peak_load_fraction >= {LOAD_FRACTION}: {missed} of {int(loaded.sum())} runs"
      f" ({missed / max(int(loaded.sum()), 1):.1%})")
print(f"files: {OUT}")

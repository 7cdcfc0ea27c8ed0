"""Threshold trade-off of LOE detection: false alarms and misses against ``fdd.loe.detection_tau`` from ONE campaign.

Detection (the level FAR and MDR are scored on) rejects the fault-free model when its ratio
theta_0 / ||u|| exceeds ``fdd.loe.detection_tau`` (with the contrast and the confirmation time on
top). A campaign stores, per scenario, the fault-free filter's largest ratio before the fault
(``loe_ratio0_max_pre``: no false detection while it stays below the threshold) and its peak ratio
within the detection window (``loe_ratio0_max_post``: no detection unless it reaches the threshold).
So for any ``detection_tau`` the table bounds the rates without simulating again: the false alarms
per fault-free run from above, MDR from below (contrast and confirmation only remove detections).
The threshold with no false alarm on the training half of the fault-free runs is then checked on the
held-out half. (``fdd.loe.tau`` is the identification threshold: it changes which fault model is
named, not whether a fault is detected.)

    python examples/threshold_tradeoff.py                       # 4 x 256 runs of 60 s
    MCFDD_EXAMPLE_SCENARIOS=16 MCFDD_EXAMPLE_DURATION_S=4 python examples/threshold_tradeoff.py

Writes threshold_tradeoff.png into MCFDD_EXAMPLE_OUT (default results/examples).
"""

import os
from pathlib import Path

import numpy as np

import mcfdd

SCENARIOS = int(os.environ.get("MCFDD_EXAMPLE_SCENARIOS", 1024))  # in all, 256 per fault kind
DURATION_S = float(os.environ.get("MCFDD_EXAMPLE_DURATION_S", 60.0))
OUT = Path(os.environ.get("MCFDD_EXAMPLE_OUT", "results/examples"))
CONFIG = Path(__file__).resolve().parent.parent / "configs" / "loe_campaign.toml"

cfg = mcfdd.load_config(CONFIG, overrides={
    "campaign.scenarios": SCENARIOS, "campaign.duration_s": DURATION_S, "evaluation.settle_s": 0.08 * DURATION_S,
    "space.fault_onset_s": [0.17 * DURATION_S, 0.25 * DURATION_S],
    "space.t_start_s": [0.3 * DURATION_S, 0.75 * DURATION_S]})
table = mcfdd.run_campaign(cfg).scenarios
ok = table["status"] == mcfdd.Status.OK
free = ok & (table["fault_kind"] == "none")
faulty = ok & table["fault_kind"].isin(["leakage", "surface_damage", "disconnection"]) & (table["true_model"] > 0)
before = table["loe_ratio0_max_pre"].fillna(0.0).to_numpy()  # NaN: never excited, no decision possible
within = table["loe_ratio0_max_post"].fillna(0.0).to_numpy()

taus = np.linspace(0.02, 0.3, 57)
far = [(before[free] >= tau).mean() for tau in taus]
mdr = [(within[faulty] < tau).mean() for tau in taus]

training = (table["scenario_id"] % 2 == 0).to_numpy()
tau_0 = np.nextafter(before[free & training].max(), np.inf)  # smallest detection_tau without a training false alarm
held_out = free & ~training
held_out_alarms = int((before[held_out] >= tau_0).sum())
print(f"fdd.loe.detection_tau = {tau_0:.4f}: no false alarm in {int((free & training).sum())} training runs; "
      f"at most {held_out_alarms} of {int(held_out.sum())} held-out runs would alarm; "
      f"MDR at least {(within[faulty] < tau_0).mean():.3f} over {int(faulty.sum())} faulty runs")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(6.4, 4.0))
ax.plot(taus, far, label="false alarms per fault-free run (upper bound)")
ax.plot(taus, mdr, label="MDR of the faulty runs (lower bound)")
ax.axvline(tau_0, color="k", ls="--", lw=0.8, label=f"no training false alarm: {tau_0:.3f}")
ax.set_xlabel("fdd.loe.detection_tau (theta_0 / ||u||)")
ax.set_ylabel("rate")
ax.set_title(f"LOE detection threshold trade-off, {len(table)} runs of {DURATION_S:g} s")
ax.legend()
fig.tight_layout()
OUT.mkdir(parents=True, exist_ok=True)
fig.savefig(OUT / "threshold_tradeoff.png", dpi=110)
print(f"wrote {OUT / 'threshold_tradeoff.png'}")

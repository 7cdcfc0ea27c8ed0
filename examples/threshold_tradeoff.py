"""Threshold trade-off of the LOE bank: FAR and MDR against tau_m from ONE campaign.

A campaign stores, per scenario, the largest ratio theta_0 / ||u|| of the fault-free filter before
the fault (no fault model can be decided while it stays below tau_m) and, over the detection
window, the peak of the smallest ratio among the filters that must fire (all of them exceed tau_m
only if this peak does). So FAR(tau_m) and MDR(tau_m) of any threshold follow from the table
without simulating again (ignoring the 2 s confirmation time, so FAR is an upper bound). The tau_m
with no false alarm on the training half of the runs is then checked on the held-out half.

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
ratio_free = table["loe_ratio0_max_pre"].fillna(0.0).to_numpy()  # NaN: never excited, no decision possible
ratio_fire = table["loe_others_min_peak"].fillna(0.0).to_numpy()

taus = np.linspace(0.02, 0.3, 57)
far = [(ratio_free[free] >= tau).mean() for tau in taus]
mdr = [(ratio_fire[faulty] < tau).mean() for tau in taus]

training = (table["scenario_id"] % 2 == 0).to_numpy()
tau_0 = np.nextafter(ratio_free[free & training].max(), np.inf)  # smallest tau_m without a training false alarm
held_out = free & ~training
held_out_alarms = int((ratio_free[held_out] >= tau_0).sum())
print(f"tau_m = {tau_0:.4f}: no false alarm in {int((free & training).sum())} training runs; "
      f"{held_out_alarms} of {int(held_out.sum())} held-out runs would alarm; "
      f"MDR {(ratio_fire[faulty] < tau_0).mean():.3f} over {int(faulty.sum())} faulty runs")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(6.4, 4.0))
ax.plot(taus, far, label="FAR (fault-free runs)")
ax.plot(taus, mdr, label="MDR (faulty runs)")
ax.axvline(tau_0, color="k", ls="--", lw=0.8, label=f"no training false alarm: {tau_0:.3f}")
ax.set_xlabel("tau_m (theta / ||u||)")
ax.set_ylabel("rate")
ax.set_title(f"LOE bank threshold trade-off, {len(table)} runs of {DURATION_S:g} s")
ax.legend()
fig.tight_layout()
OUT.mkdir(parents=True, exist_ok=True)
fig.savefig(OUT / "threshold_tradeoff.png", dpi=110)
print(f"wrote {OUT / 'threshold_tradeoff.png'}")

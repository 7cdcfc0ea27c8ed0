"""A scenario space built in Python, no TOML file: surface damage in roll manoeuvres at high speed.

The dict has the tables of a campaign config; ``mcfdd.load_config`` checks it exactly like a file.

    python examples/python_space.py
    MCFDD_EXAMPLE_SCENARIOS=16 MCFDD_EXAMPLE_DURATION_S=4 python examples/python_space.py
"""

import os

import mcfdd

SCENARIOS = int(os.environ.get("MCFDD_EXAMPLE_SCENARIOS", 1024))  # in all, 512 per manoeuvre family
DURATION_S = float(os.environ.get("MCFDD_EXAMPLE_DURATION_S", 40.0))

space = {
    "vcas_kt": [280.0, 350.0],
    "altitude_m": [0.0, 3000.0],
    "turbulence": ["light", "moderate"],
    "kci_scale": [0.9, 1.1],
    "hinge_scale": [0.9, 1.2],
    "fault_kind": "surface_damage",
    "surface_damage_size": [0.3, 1.0],
    "fault_onset_s": [0.2 * DURATION_S, 0.3 * DURATION_S],
    "manoeuvre_kind": ["doublet", "bank_to_bank"],
    "amplitude": [0.5, 1.0],
    "t_start_s": [0.35 * DURATION_S, 0.7 * DURATION_S],
}
cfg = mcfdd.load_config({
    "campaign": {"scenarios": SCENARIOS, "design": "lhs", "grid": ["manoeuvre_kind"], "seed": 5,
                 "duration_s": DURATION_S},
    "evaluation": {"settle_s": 0.1 * DURATION_S},
    "space": space,
})
result = mcfdd.run_campaign(cfg)
rates = result.summary[result.summary["stratum"].isin(["overall", "manoeuvre"])]
print(rates[["stratum", "label", "runs", "mdr", "mdr_lo", "mdr_hi", "detection_time_median_s"]].to_string(index=False))

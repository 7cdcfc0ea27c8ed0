"""Tune the LOE bank's evaluator and threshold, then validate the tuned FDD on a held-out campaign.

``mcfdd.tune`` already checks on the config's validation campaign; here the tuned FDD settings are
taken further to a campaign of their own (another seed, the full LOE campaign space), before and
after, through dotted-path overrides.

    python examples/tune_and_validate.py
    MCFDD_EXAMPLE_SCENARIOS=4 MCFDD_EXAMPLE_DURATION_S=4 MCFDD_EXAMPLE_ITERATIONS=2 python examples/tune_and_validate.py
"""

import os
from pathlib import Path

import mcfdd

SCENARIOS = int(os.environ.get("MCFDD_EXAMPLE_SCENARIOS", 256))  # in all, 64 per fault kind
DURATION_S = float(os.environ.get("MCFDD_EXAMPLE_DURATION_S", 30.0))
ITERATIONS = int(os.environ.get("MCFDD_EXAMPLE_ITERATIONS", 60))
CONFIGS = Path(__file__).resolve().parent.parent / "configs"

timing = {"evaluation.settle_s": 0.1 * DURATION_S, "space.fault_onset_s": [0.2 * DURATION_S, 0.3 * DURATION_S],
          "space.t_start_s": [0.2 * DURATION_S, 0.5 * DURATION_S]}
tune_cfg = mcfdd.load_config(CONFIGS / "tune_loe.toml", overrides={
    "tune.iterations": ITERATIONS, "training.scenarios": SCENARIOS, "training.duration_s": DURATION_S,
    "validation.scenarios": SCENARIOS, "validation.duration_s": DURATION_S, **timing})
tuned = mcfdd.tune(tune_cfg)
print(tuned.parameters.to_string(index=False))

KEYS = {"alpha": "fdd.loe.evaluator.alpha", "beta": "fdd.loe.evaluator.beta",
        "gamma_1_s": "fdd.loe.evaluator.gamma_1_s", "pole_1_s": "fdd.loe.pole_1_s", "tau": "fdd.loe.tau"}
tuned_keys = {KEYS[row.parameter]: row.after for row in tuned.parameters.itertuples()}
held_out = {"campaign.scenarios": SCENARIOS, "campaign.seed": 99, "campaign.duration_s": DURATION_S, **timing}
for label, fdd in (("before", {}), ("after", tuned_keys)):
    cfg = mcfdd.load_config(CONFIGS / "loe_campaign.toml", overrides={**held_out, **fdd})
    overall = mcfdd.run_campaign(cfg).overall()
    print(f"{label} tuning: FAR {overall['false_alarms_loe']}/{overall['fault_free_runs']} fault-free runs "
          f"[{overall['far_loe_lo']:.3g}, {overall['far_loe_hi']:.3g}], "
          f"MDR {overall['missed']}/{overall['faulty_runs']}")

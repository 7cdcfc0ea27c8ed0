"""How hard each manoeuvre family works the monitored aileron on the full aircraft, against the roll axis.

Fault-free campaigns of the space of ``configs/validation_rcam.toml`` (its envelope, uncertainties,
turbulence and manoeuvre sizes) with the manoeuvre family on the grid, flown by the full aircraft
(all its families) and, in the same run, by the roll axis (the families it can fly; level flight
as its quiet flight). Per family: the peak |deflection| of the monitored aileron and the peak
hinge-load fraction ``|F_aero| / (nu1 dP S)`` while the rod moves, each run's largest after the
settling time (the campaign's ``peak_deflection_deg`` and ``peak_load_fraction``), as median,
95th percentile and maximum over the runs, and the false alarms of the config's FDD.

    python benchmarks/rcam_families.py [--per-family 32] [--duration-s 40]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import mcfdd

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "validation_rcam.toml"
ROLL_AXIS = ("level_flight", "doublet", "bank_to_bank", "roll_protection", "sideslip")


def campaign(model: str, families, per_family: int, duration_s: float):
    overrides = {"campaign.scenarios": per_family * len(families), "campaign.grid": ["manoeuvre_kind"],
                 "campaign.duration_s": duration_s, "plant.aircraft.model": model, "space.fault_kind": "none",
                 "space.manoeuvre_kind": list(families)}
    if model == "roll_axis":
        overrides["space.manoeuvre_kind"] = ["quiet" if f == "level_flight" else f for f in families]
        overrides["space.mass_scale"] = 1.0
    return mcfdd.run_campaign(mcfdd.load_config(CONFIG, overrides=overrides), progress=False).scenarios


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-family", type=int, default=32, help="fault-free runs per family and model")
    parser.add_argument("--duration-s", type=float, default=40.0)
    args = parser.parse_args(argv)
    families = mcfdd.load_config(CONFIG).space.axis("manoeuvre_kind").values
    tables = {"rcam": campaign("rcam", families, args.per_family, args.duration_s),
              "roll_axis": campaign("roll_axis", ROLL_AXIS, args.per_family, args.duration_s)}
    print(f"{CONFIG.name} space, fault-free, {args.per_family} runs per family and model, {args.duration_s:.0f} s")
    print()
    print("| family | aircraft | peak deflection (deg) median / p95 / max | peak load fraction median / p95 / max "
          "| false alarms |")
    print("|---|---|---|---|---|")
    for family in families:
        for model, table in tables.items():
            name = "quiet" if model == "roll_axis" and family == "level_flight" else family
            rows = table[table["manoeuvre_kind"] == name]
            if rows.empty:
                continue
            defl, load = rows["peak_deflection_deg"].to_numpy(), rows["peak_load_fraction"].to_numpy()
            print(f"| {family} | {model} | {np.median(defl):.1f} / {np.percentile(defl, 95):.1f} / {defl.max():.1f} | "
                  f"{np.median(load):.2f} / {np.percentile(load, 95):.2f} / {load.max():.2f} | "
                  f"{int(rows['false_alarm'].sum())}/{len(rows)} |")
    for model, table in tables.items():
        defl = table["peak_deflection_deg"].to_numpy()
        print(f"\n{model}, all families: median peak deflection {np.median(defl):.1f} deg, "
              f"median peak load fraction {np.median(table['peak_load_fraction']):.2f}")


if __name__ == "__main__":
    main()

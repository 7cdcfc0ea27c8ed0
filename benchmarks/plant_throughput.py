"""Per-step cost and throughput of both aircraft models in one run, in float32.

Element-ops (deterministic; counted as ``campaign_throughput.py`` counts them: elementwise
operations executed per step of the compiled step loop, each weighted by its elements per
scenario) for each ``plant.aircraft.model`` (the roll axis and the full RCAM aircraft):

- plant step: the step loop of :func:`mcfdd.analysis.simulate.plant_batch` (plant alone, its
  normals included) on the same scenarios for both models, a mix of the families both can fly
  (``FAMILIES``); for the full aircraft also on a mix of all its families (``RCAM_FAMILIES``);
- campaign step: the step loop of :func:`mcfdd.analysis.campaign.device_batch` (plant, both FDD
  systems and the online reductions) on ``campaign_throughput.py``'s mixed space at 150-250 kt.

Throughput (a rough indication on a shared machine): batches of 1,000 and 10,000 scenarios of
60 s at 100 Hz flown by each model; compile time (first call minus the second), run time of the
second call (``block_until_ready``), scenario-steps per second, the CPU time the run used per
second of wall time (2 = both cores busy) and the peak resident memory of the process so far.
``plant_batch`` returns full time histories (about 220 kB per scenario at 6,000 steps for the
roll axis, the full aircraft's 22 signals about 530 kB), so 10,000 scenarios need over 2 GB;
``plant_batch`` is a plain ``jit(vmap)``, not split over devices as ``campaign.run_batch`` is.

    python benchmarks/plant_throughput.py [--sizes 1000 10000] [--duration-s 60] [--models roll_axis rcam]
    python benchmarks/plant_throughput.py --ops-only          # element-ops only, no timing
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
from pathlib import Path

import mcfdd  # first: one JAX CPU device per core, before JAX creates its backend

# isort: split

import jax  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from campaign_throughput import SPACE, hlo_stats  # noqa: E402

from mcfdd.analysis import batch, campaign, simulate  # noqa: E402
from mcfdd.plant import actuator, atmosphere, closed_loop, manoeuvres  # noqa: E402
from mcfdd.workflows import campaign as campaign_runner  # noqa: E402

DT_S = 0.01
SUBSTEPS = 2
FAMILIES = ("quiet", "doublet", "bank_to_bank", "roll_protection", "sideslip", "ol_sweep", "ol_step")
RCAM_FAMILIES = ("level_flight", "doublet", "bank_to_bank", "roll_protection", "sideslip", "pitch_doublet",
                 "pedal_doublet", "nose_up", "nose_down", "fpa_change", "heading_change", "speed_change",
                 "coordinated_turn")
HLO_BATCH, HLO_STEPS = 128, 200  # the small batch whose compiled program is counted


def scenarios(n: int, duration_s: float, families=FAMILIES, seed: int = 0) -> closed_loop.Scenario:
    """``n`` random scenarios as one float32 pytree with a leading batch axis."""
    rng = np.random.default_rng(seed)

    def uniform(lo, hi):
        return rng.uniform(lo, hi, n).astype(np.float32)

    kind = np.array([manoeuvres.KIND_CODE[f] for f in families], np.int32)[rng.integers(len(families), size=n)]
    fault_kind = rng.integers(4, size=n)  # none, leakage, surface damage, jamming
    size = uniform(0.1, 0.5)
    onset = uniform(0.1, 0.5) * np.float32(duration_s)
    never = np.full(n, np.inf, np.float32)
    fault = actuator.ActuatorFault(
        nu1=np.where(fault_kind == 1, 1.0 - size, 1.0).astype(np.float32),
        nu2=np.where(fault_kind == 2, 1.0 - size, 1.0).astype(np.float32),
        onset_s=np.where((fault_kind == 1) | (fault_kind == 2), onset, never),
        jam_onset_s=np.where(fault_kind == 3, onset, never),
    )
    manoeuvre = manoeuvres.ManoeuvreParams(
        kind=kind, amplitude=uniform(-1.0, 1.0), t_start_s=uniform(2.0, 10.0), duration_s=uniform(1.0, 4.0),
        hold_s=uniform(1.0, 4.0), ramp_s=uniform(0.1, 0.5), freq_lo_hz=uniform(0.05, 0.2),
        freq_hi_hz=uniform(1.0, 3.0), sideslip_rad=np.radians(uniform(-10.0, 10.0)),
        fpa_rad=np.radians(uniform(-4.0, 4.0)), heading_change_rad=np.radians(uniform(-90.0, 90.0)),
        bank_rad=np.radians(uniform(-40.0, 40.0)),
        delta_vcas_m_s=uniform(-15.0, 15.0) * np.float32(atmosphere.KT_TO_M_S),
    )
    ones = np.ones(n, np.float32)
    return closed_loop.Scenario(
        vcas_m_s=uniform(150.0, 250.0) * np.float32(atmosphere.KT_TO_M_S), altitude_m=uniform(0.0, 9000.0),
        supply_pressure_scale=uniform(0.9, 1.1), kci_scale=uniform(0.9, 1.1), kd_scale=uniform(0.8, 1.2),
        hinge_scale=uniform(0.8, 1.2), roll_inertia_scale=uniform(0.9, 1.1), mass_scale=ones, noise_std_m=5e-5 * ones,
        turbulence_level=rng.choice([0.0, 1.0, 2.0], n).astype(np.float32), fault=fault, manoeuvre=manoeuvre,
    )


def plant_ops(model, families) -> dict:
    """Fusions and element-ops per scenario-step of plant_batch's step loop (HLO_BATCH x HLO_STEPS)."""
    scenario_batch = scenarios(HLO_BATCH, HLO_STEPS * DT_S, families)
    text = simulate.plant_batch.lower(model, scenario_batch, simulate.run_keys(0, range(HLO_BATCH)), HLO_STEPS, DT_S,
                                      SUBSTEPS, batch.kinds_in(scenario_batch.manoeuvre.kind)).compile().as_text()
    return hlo_stats(text, HLO_BATCH, HLO_STEPS)


def campaign_ops(aircraft_model: str) -> dict:
    """Fusions and element-ops per scenario-step of a campaign's device program (plant, FDD and reductions) on
    campaign_throughput.py's mixed space at 150-250 kt, flown by ``aircraft_model``."""
    cfg = mcfdd.load_config({
        "campaign": {"scenarios": 4 * HLO_BATCH, "design": "lhs", "grid": ["fault_kind"], "seed": 1,
                     "chunk_size": HLO_BATCH, "duration_s": HLO_STEPS * DT_S},
        "evaluation": {"settle_s": 0.5},
        "plant": {"aircraft": {"model": aircraft_model}},
        "space": {**SPACE, "vcas_kt": [150.0, 250.0], "fault_onset_s": [0.5, 1.5], "t_start_s": [0.2, 1.0]},
    }, "campaign")
    setup, c = campaign_runner.campaign_setup(cfg), cfg.campaign
    args = campaign_runner.chunk_inputs(setup, c.seed, np.arange(HLO_BATCH), HLO_BATCH)
    text = campaign.device_batch.lower(setup.model, setup.fdd_params, setup.settings, *args, HLO_STEPS, c.dt_s,
                                       c.substeps, setup.kinds).compile().as_text()
    return hlo_stats(text, HLO_BATCH, HLO_STEPS)


def measure(model, n: int, duration_s: float) -> dict:
    scenario_batch = scenarios(n, duration_s)
    kinds = batch.kinds_in(scenario_batch.manoeuvre.kind)
    keys = simulate.run_keys(0, range(n))
    n_steps = int(round(duration_s / DT_S))

    def cpu_s():
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    def call():
        cpu, start = cpu_s(), time.perf_counter()
        jax.block_until_ready(simulate.plant_batch(model, scenario_batch, keys, n_steps, DT_S, SUBSTEPS, kinds))
        wall = time.perf_counter() - start
        return wall, (cpu_s() - cpu) / wall

    first, _ = call()
    run, cpu_per_wall = call()
    return {"scenarios": n, "steps": n_steps, "compile_s": first - run, "run_s": run,
            "throughput": n * n_steps / run, "cpu_per_wall": cpu_per_wall,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000], help="batch sizes")
    parser.add_argument("--duration-s", type=float, default=60.0, help="simulated time per scenario")
    parser.add_argument("--models", nargs="+", default=["roll_axis", "rcam"], choices=["roll_axis", "rcam"],
                        help="aircraft models (plant.aircraft.model)")
    parser.add_argument("--ops-only", action="store_true", help="only count element-ops, no timing")
    args = parser.parse_args(argv)
    assert not jax.config.jax_enable_x64, "the benchmark measures float32"
    print(f"jax {jax.__version__}, {jax.device_count()} {jax.devices()[0].platform} device(s), {os.cpu_count()} CPU "
          f"cores, {platform.processor() or platform.machine()}, float32, dt {DT_S} s, {SUBSTEPS} actuator sub-steps, "
          f"families {', '.join(FAMILIES)}")
    print()
    print("| aircraft | scenarios' families | plant step: element-ops per scenario-step | fusions | "
          "campaign step: element-ops per scenario-step | fusions |")
    print("|---|---|---:|---:|---:|---:|")
    ops = {}
    for name in args.models:
        model = closed_loop.build_model(aircraft_model=name)
        plant, camp = plant_ops(model, FAMILIES), campaign_ops(name)
        ops[name] = (plant["element_ops"], camp["element_ops"])
        print(f"| {name} | {len(FAMILIES)} shared | {plant['element_ops']:.0f} | {plant['fusions']} | "
              f"{camp['element_ops']:.0f} | {camp['fusions']} |", flush=True)
        if name == "rcam":
            everything = plant_ops(model, RCAM_FAMILIES)
            print(f"| {name} | all {len(RCAM_FAMILIES)} of its own | {everything['element_ops']:.0f} | "
                  f"{everything['fusions']} | | |", flush=True)
    if len(ops) == 2:
        print(f"\nrcam / roll_axis: plant step {ops['rcam'][0] / ops['roll_axis'][0]:.2f}x, "
              f"campaign step {ops['rcam'][1] / ops['roll_axis'][1]:.2f}x")
    if args.ops_only:
        return
    print(f"\nload average before timing: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print()
    print("| aircraft | scenarios | steps | compile (s) | run (s) | scenario-steps/s | CPU/wall | peak RSS (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name in args.models:
        model = closed_loop.build_model(aircraft_model=name)
        for n in args.sizes:
            r = measure(model, n, args.duration_s)
            print(f"| {name} | {r['scenarios']:,} | {r['steps']:,} | {r['compile_s']:.1f} | {r['run_s']:.2f} | "
                  f"{r['throughput']:.3g} | {r['cpu_per_wall']:.2f} | {r['peak_rss_mb']:.0f} |", flush=True)


if __name__ == "__main__":
    main()

"""Throughput of the batched closed-loop plant (``mcfdd.analysis.simulate.plant_batch``) in float32.

Batches of 1,000 and 10,000 scenarios of 60 s at 100 Hz, a mix of manoeuvre families, flight
points, turbulence levels and faults, flown by each aircraft model in the same run (the roll
axis and the full RCAM aircraft, ``plant.aircraft.model``). For each model and batch size:
compile time (first call minus the
second), run time of the second call (``block_until_ready``), scenario-steps per second, the
CPU time the run used per second of wall time (2 = both cores busy) and the peak resident memory
of the process so far. ``plant_batch`` returns full time histories (about 220 kB per scenario at
6,000 steps; the full aircraft's 19 signals about 460 kB), so 10,000 scenarios need over 2 GB;
``plant_batch`` is a plain ``jit(vmap)``, not split over devices as ``campaign.run_batch`` is.

    python benchmarks/plant_throughput.py [--sizes 1000 10000] [--duration-s 60] [--models roll_axis rcam]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time

import mcfdd  # noqa: F401  (first: one JAX CPU device per core, before JAX creates its backend)

# isort: split

import jax  # noqa: E402
import numpy as np  # noqa: E402

from mcfdd.analysis import batch, simulate  # noqa: E402
from mcfdd.plant import actuator, atmosphere, closed_loop, manoeuvres  # noqa: E402

DT_S = 0.01
SUBSTEPS = 2
FAMILIES = ("quiet", "doublet", "bank_to_bank", "roll_protection", "sideslip", "ol_sweep", "ol_step")


def scenarios(n: int, duration_s: float, seed: int = 0) -> closed_loop.Scenario:
    """``n`` random scenarios as one float32 pytree with a leading batch axis."""
    rng = np.random.default_rng(seed)

    def uniform(lo, hi):
        return rng.uniform(lo, hi, n).astype(np.float32)

    kind = np.array([manoeuvres.KIND_CODE[f] for f in FAMILIES], np.int32)[rng.integers(len(FAMILIES), size=n)]
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
        freq_hi_hz=uniform(1.0, 3.0), sideslip_rad=np.radians(uniform(-10.0, 10.0)), fpa_rad=np.zeros(n, np.float32),
        heading_change_rad=np.zeros(n, np.float32), bank_rad=np.zeros(n, np.float32),
        delta_vcas_m_s=np.zeros(n, np.float32),
    )
    ones = np.ones(n, np.float32)
    return closed_loop.Scenario(
        vcas_m_s=uniform(150.0, 250.0) * np.float32(atmosphere.KT_TO_M_S), altitude_m=uniform(0.0, 9000.0),
        supply_pressure_scale=uniform(0.9, 1.1), kci_scale=uniform(0.9, 1.1), kd_scale=uniform(0.8, 1.2),
        hinge_scale=uniform(0.8, 1.2), roll_inertia_scale=uniform(0.9, 1.1), mass_scale=ones, noise_std_m=5e-5 * ones,
        turbulence_level=rng.choice([0.0, 1.0, 2.0], n).astype(np.float32), fault=fault, manoeuvre=manoeuvre,
    )


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
    args = parser.parse_args(argv)
    assert not jax.config.jax_enable_x64, "the benchmark measures float32"
    print(f"jax {jax.__version__}, {jax.device_count()} {jax.devices()[0].platform} device(s), {os.cpu_count()} CPU "
          f"cores, {platform.processor() or platform.machine()}, float32, dt {DT_S} s, {SUBSTEPS} actuator sub-steps, "
          f"families {', '.join(FAMILIES)}")
    print(f"load average before start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
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

"""Batched Monte-Carlo simulation with online scoring (DESIGN.md sections 2 and 5).

Each scenario is one run of the composed plant and FDD (:func:`mcfdd.analysis.simulate.run`)
observed by the scoring monitors (:func:`mcfdd.analysis.scoring.monitors`): the scan carry holds,
besides the dynamic states, the monitors' running reductions, so memory is O(batch), not
O(batch x steps), and a run returns its table columns. One jit around the vmapped batch, per
device (:func:`on_devices`).
"""

from __future__ import annotations

from functools import partial

import jax
import numpy as np

from mcfdd.analysis import scoring, simulate
from mcfdd.fdd import system
from mcfdd.plant import closed_loop


def run_one(model: closed_loop.PlantModel, fdd_params: system.FddParams, settings: scoring.Settings,
            scenario: closed_loop.Scenario, truth: scoring.Truth, key, n_steps: int, dt_s: float, substeps: int,
            kinds: tuple[int, ...]) -> dict:
    """The scoring columns of one scenario (no time histories kept)."""
    monitor = scoring.monitors(settings, truth, fdd_params, dt_s)
    state, _ = simulate.run(model, fdd_params, scenario, key, n_steps, dt_s, substeps, kinds,
                            scoring.observer(settings, truth, monitor))
    return scoring.finalize(settings, monitor, state, n_steps * dt_s)


# XLA CPU options of the campaign program (per function, not global flags): AVX-512-wide vectors
# where the CPU has them, and no YNNPACK library fusions (the step has no dot or reduction large
# enough to gain from them). Measured faster with bit-identical outcomes (benchmarks/RESULTS.md).
XLA_CPU_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": ""}


@partial(jax.jit, static_argnames=("n_steps", "dt_s", "substeps", "kinds"), compiler_options=XLA_CPU_OPTIONS)
def device_batch(model, fdd_params, settings, scenarios, truths, keys, n_steps: int, dt_s: float, substeps: int,
                 kinds: tuple[int, ...]) -> dict:
    """:func:`run_one` over a batch (leading axis of scenarios, truths and keys), one jit, on one device."""
    def one(scenario, truth, key):
        return run_one(model, fdd_params, settings, scenario, truth, key, n_steps, dt_s, substeps, kinds)

    return jax.vmap(one)(scenarios, truths, keys)


def on_devices(fn, *args, batched: tuple[bool, ...], lanes: int | None = None) -> dict:
    """``fn(*args)`` with the arguments marked in ``batched`` split evenly over the devices.

    Each device gets an equal share of the leading axis and runs ``fn`` (a single-device jitted
    function) on it; the other arguments are copied to every device. Dispatch is asynchronous, so
    the devices run at the same time; ``fn`` compiles once for each device it runs on. With
    ``lanes``, the batch goes to as many devices as give each a whole number of ``lanes``
    scenarios (one device if none does); without, a batch that does not divide among all the devices
    runs on the first one. Returns ``fn``'s outputs as NumPy arrays, the shares concatenated in order.

    Every device thus runs the same program as a single device would, whatever the number of
    devices. Splitting inside one jit with ``shard_map`` does not: XLA compiles a program with
    several partitions through its SPMD partitioner, and the optimised per-device program then
    differs from the single-device one in how floating-point constants are folded and
    reassociated (the Dryden pole ``exp(-pi V dt / (4 b))`` is evaluated in another order, for
    one), so results depended on the device count in their last bits.
    """
    devices = jax.devices()
    n = next(jax.tree.leaves(a)[0].shape[0] for a, b in zip(args, batched) if b)
    if lanes is not None:
        devices = devices[:max((d for d in range(1, len(devices) + 1) if n % (d * lanes) == 0), default=1)]
    elif n % len(devices):
        devices = devices[:1]
    size = n // len(devices)

    outs = []
    for i, device in enumerate(devices):
        share = [jax.tree.map(lambda x: x[i * size:(i + 1) * size], a) if b else a for a, b in zip(args, batched)]
        outs.append(fn(*jax.device_put(share, device)))
    return jax.tree.map(lambda *parts: np.concatenate([np.asarray(p) for p in parts]), *outs)


def run_batch(model, fdd_params, settings, scenarios, truths, keys, n_steps: int, dt_s: float, substeps: int,
              kinds: tuple[int, ...], lanes: int | None = None) -> dict:
    """:func:`device_batch` with the batch split over the devices by :func:`on_devices`.

    With several devices (on a CPU: ``--xla_force_host_platform_device_count``) each runs the
    single-device program on its share, so a scenario's numbers are the same to the last bit
    whatever the number of devices, provided no share is a single scenario (XLA then drops the
    batch axis and compiles other code): ``mcfdd campaign`` gives each device a whole number of
    ``lanes`` (``mcfdd.workflows.campaign.LANE_BLOCK``). Returns NumPy arrays, batch axis first.
    """
    return on_devices(partial(device_batch, n_steps=n_steps, dt_s=dt_s, substeps=substeps, kinds=kinds), model,
                      fdd_params, settings, scenarios, truths, keys, batched=(False, False, False, True, True, True),
                      lanes=lanes)

"""One JAX CPU device per core, set up when ``mcfdd`` is imported (before JAX starts its backends).

Campaign batches are split over the devices with ``shard_map``; results do not depend on the
number of devices, only the speed does.
"""

from __future__ import annotations

import os
import sys
import warnings

FLAG = "--xla_force_host_platform_device_count"
# XLA CPU runs a program's step loop one fusion after another, and one program per core leaves the
# core idle between them (CPU/wall 1.57 on 2 cores); two programs per core fill those gaps: 2.06e7
# against 1.62e7 scenario-steps/s on 4,096 x 6,000 (benchmarks/RESULTS.md), for one more compile
# per device when the compilation cache is cold.
DEVICES_PER_CORE = 2


def use_all_cores() -> int | None:
    """Expose DEVICES_PER_CORE JAX devices per CPU core, unless ``XLA_FLAGS`` already sets the count.

    Returns:
        The device count requested, or None when the caller's ``XLA_FLAGS`` decide, or when
        JAX had started its backends already (then a warning says how many devices it has).
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if FLAG in flags:
        return None
    count = DEVICES_PER_CORE * (os.cpu_count() or 1)
    if "jax" in sys.modules:
        if _backends_started():
            import jax

            if jax.device_count() < count:
                warnings.warn(f"mcfdd: JAX started before mcfdd was imported and has {jax.device_count()} device(s) "
                              f"where it would use {count}; results are the same, campaigns only slower. Import mcfdd "
                              f"before using JAX, or set XLA_FLAGS={FLAG}={count} before starting Python.",
                              stacklevel=3)
            return None
    os.environ["XLA_FLAGS"] = f"{flags} {FLAG}={count}".strip()
    return count


def use_cores(count: int) -> int | None:
    """Expose ``count`` CPU devices instead of the default (a process sharing its host, e.g. a Dask worker).

    Only the count mcfdd chose at import is changed, and only before JAX starts its backends; the
    caller's own ``XLA_FLAGS`` always win. Returns the count requested, or None when unchanged.
    """
    global REQUESTED
    if REQUESTED is None or "jax" in sys.modules and _backends_started():
        return None
    os.environ["XLA_FLAGS"] = xla_flags(count)
    REQUESTED = count
    return count


def xla_flags(count: int) -> str:
    """This process's ``XLA_FLAGS`` with the host device count set to ``count``."""
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(FLAG))
    return f"{flags} {FLAG}={count}".strip()


def _backends_started() -> bool:
    from jax._src import xla_bridge

    return xla_bridge.backends_are_initialized()


REQUESTED = use_all_cores()

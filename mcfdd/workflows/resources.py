"""What a command will need, estimated before it starts: memory, time and worker processes.

Memory is estimated from the shapes of what the command holds (``jax.eval_shape``: traced, not
compiled) and from footprints measured on this project's programs (``benchmarks/memory_guard.py``
measures them again, with each estimate beside the measured peak resident memory):

- a process running the simulation (Python, JAX, mcfdd and the compiled programs of its devices):
  peak 0.45-0.85 GiB measured with small batches on one to four devices, counted as
  :data:`RUNTIME_BYTES`;
- a campaign chunk: the batch's parameters, scan carry, inputs and outputs per scenario (1.4 kB
  in float32 on the roll axis, 205 kB on the full aircraft, whose parameters carry tables), which
  the compiled program held about 1.2 times (1.6 kB per scenario measured from 16,384 to 262,144
  scenarios on one device), counted :data:`CHUNK_FACTOR` times;
- the campaign's scenario table, held whole by the driver (and once more while it is sorted):
  :data:`TABLE_ROW_BYTES` per scenario and copy;
- ``simulate``'s histories: the raw outputs per sample (149 bytes on the roll axis), the tidy
  table and its copies: peak 2.6 times the raw outputs plus 16 bytes per row measured (40 and
  200 runs of 300 s), counted :data:`HISTORY_FACTOR` times plus 32 bytes.

Time is estimated from scenario-steps at a cautious :data:`CAUTIOUS_RATE` per core, about a fifth
of the roll axis's measured throughput; the full aircraft is slower, so a warning errs early.
"""

from __future__ import annotations

import os

import numpy as np

from mcfdd import config
from mcfdd.workflows.common import ResourceError

GIB = 2.0**30
RUNTIME_BYTES = 1.0 * GIB  # one process with JAX, mcfdd and its compiled programs
CHUNK_FACTOR = 2.0  # times the per-scenario bytes of parameters, carry, inputs and outputs a chunk holds
TABLE_ROW_BYTES = 1024  # one scenario row of the campaign table in pandas (measured 521: 80 columns, strings)
HISTORY_FACTOR = 3.0  # times the raw simulated outputs that simulate holds at its peak
HISTORY_ROW_BYTES = 32  # per (run, sample) row: run name and time, twice
CAUTIOUS_RATE = 2.0e6  # scenario-steps per second and core that a chunk surely reaches
LONG_CHUNK_S = 60.0  # a chunk expected to take longer than this is announced


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def available_bytes() -> float:
    """Memory the system can give without swapping (``psutil``: the kernel's estimate of available memory)."""
    import psutil

    return float(psutil.virtual_memory().available)


def gib(nbytes: float) -> str:
    return f"{nbytes / GIB:.3g} GiB"


def tree_bytes(tree) -> int:
    """Bytes of the arrays (or shape-dtype structs) of a pytree; a random key counts as its key data."""
    import jax

    def nbytes(leaf) -> int:
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.eval_shape(jax.random.key_data, leaf)
        return int(np.prod(leaf.shape)) * np.dtype(leaf.dtype).itemsize

    return sum(nbytes(leaf) for leaf in jax.tree.leaves(tree))


def check_workers(workers: int, available: float | None = None, host_cores: int | None = None):
    """Refuse a local cluster this machine cannot hold: more workers than cores, or than memory allows at
    :data:`RUNTIME_BYTES` each. Errors name ``--workers``."""
    host_cores = cores() if host_cores is None else host_cores
    if workers < 1:
        raise config.ConfigError(f"--workers: {workers} is not allowed; expected a positive number of processes")
    if workers > host_cores:
        raise ResourceError(f"--workers: {workers} is more than this machine's {host_cores} cores; at most "
                                 f"{host_cores} (each worker computes on its share of the cores)")
    available = available_bytes() if available is None else available
    fits = int(available // RUNTIME_BYTES)
    if workers > fits:
        raise ResourceError(f"--workers: {workers} workers need about {gib(workers * RUNTIME_BYTES)} "
                                 f"({gib(RUNTIME_BYTES)} each with JAX and the compiled program), more than the "
                                 f"{gib(available)} available; at most {max(fits, 0)}")


def table_bytes(n: int) -> float:
    """Memory of a campaign's table of ``n`` scenarios in the driver (held once, and once more while sorted)."""
    return 2.0 * n * TABLE_ROW_BYTES


def chunk_bytes(size: int, per_scenario: float) -> float:
    """Memory of a process running chunks of ``size`` scenarios of ``per_scenario`` bytes (:func:`tree_bytes`)."""
    return RUNTIME_BYTES + CHUNK_FACTOR * per_scenario * size


def largest_chunk(room: float, per_scenario: float) -> int:
    """The most scenarios a chunk may have for its process to fit in ``room`` bytes (0 if none fits)."""
    return int(max(0.0, (room - RUNTIME_BYTES) // (CHUNK_FACTOR * per_scenario)))


def chunk_seconds(size: int, n_steps: int, chunk_cores: int) -> float:
    """A cautious bound of one chunk's run time (compilation aside)."""
    return size * n_steps / (CAUTIOUS_RATE * max(chunk_cores, 1))


def long_chunk_note(size: int, n_steps: int, chunk_cores: int) -> str | None:
    """A line for a chunk expected to take more than :data:`LONG_CHUNK_S`, else None."""
    seconds = chunk_seconds(size, n_steps, chunk_cores)
    if seconds <= LONG_CHUNK_S:
        return None
    shown = f"{seconds / 3600:.3g} h" if seconds >= 3600 else f"{seconds / 60:.3g} min"
    return (f"campaign: a chunk of {size} scenarios x {n_steps} steps may take up to {shown} (at a cautious "
            f"{CAUTIOUS_RATE:.0e} scenario-steps/s per core, {chunk_cores} core(s)); progress moves once per chunk, "
            f"so a smaller --chunk-size (campaign.chunk_size) shows it sooner, with the same results")


def history_bytes(samples: int, raw_per_sample: float) -> float:
    """Peak memory of ``simulate`` keeping ``samples`` (runs x steps) of ``raw_per_sample`` bytes of outputs."""
    return RUNTIME_BYTES + samples * (HISTORY_FACTOR * raw_per_sample + HISTORY_ROW_BYTES)

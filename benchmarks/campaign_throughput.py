"""Throughput of the full campaign pipeline (plant + both FDD systems + online reductions) in float32.

What is timed is :func:`mcfdd.analysis.campaign.run_batch` run the way ``mcfdd campaign`` runs it
(:func:`mcfdd.run_campaign`): the scenarios of a realistic mixed space (``SPACE`` below: four fault
kinds on a grid, four closed-loop manoeuvre families, turbulence, uncertainties, Latin hypercube
over the rest) set up by ``campaign_setup``, split into chunks of ``--chunk-size`` padded to a
multiple of ``LANE_BLOCK`` scenarios per device by ``chunk_inputs``, each chunk's outcomes brought
back to host arrays. Scoring and Parquet writing are not timed. Every measurement runs in its own
subprocess, so its peak resident memory (``ru_maxrss``) and its start-up are its own.

Per pipeline measurement (default 4,096 scenarios x 6,000 steps, one chunk):

- start-up (s): from the subprocess's start (Python, imports, JAX) to the end of the first chunk
  (compilation included; cold: no persistent compilation cache), and the number of XLA
  compilations during ``campaign_setup`` (``CompileCounter``);
- compile (s): first call on the first chunk minus a timed second call on the same chunk;
- run (s): the best of ``--repeats`` timed passes over all chunks; scenario-steps/s counts real
  scenarios;
- from the compiled HLO of the device program (``device_batch`` on a small batch): fusions and
  copies in the body of the step loop and element-ops per scenario-step (elementwise operations
  executed per step, inside fusions or not, each weighted by its elements per scenario; a
  reduction by its input's elements). A regression of the compute-once rule shows here;
  ``--hlo-lines N`` lists, without any timing, the N source lines with the most element-ops and
  the number of fusions each is computed in (more than one: duplicated work, or several calls).

``--baseline PATH`` measures another checkout of mcfdd (a git worktree) as a peer in the same run:
its package is imported first (``PYTHONPATH``) in its own subprocesses, alternating with this
checkout's ``--rounds`` times. Ratios in one run are what counts on a shared machine.

Peers, in the same run: the same pipeline as a Python ``for`` loop over time around ONE jitted,
vmapped step with the state in NumPy host arrays (outcomes checked against ``run_batch``: each
discrete difference with the decision nearest to its threshold, continuous columns by their largest
relative difference; ``--peer-precision float64`` repeats the check in float64); and
the machine's ceiling, a fused C kernel of a toy step of the same shape (``ceiling_kernel.c``,
compiled here with gcc and OpenMP, called through ctypes), IEEE and ``-ffast-math``.

Breakdown, in the same run: one chunk of 20 s, the scan cut after each stage of the step, each
with its fusions and element-ops, and the campaign with its random numbers replaced by a
constant (what the normals cost, the step's fusions unchanged).

    python benchmarks/campaign_throughput.py                                  # 4,096 x 6,000 and the peers
    python benchmarks/campaign_throughput.py --baseline /work/base-a96c20f    # and the revision before, same run
    python benchmarks/campaign_throughput.py --scenarios 1024 --steps 2000 --no-peer --no-breakdown
    python benchmarks/campaign_throughput.py --family-chunks --rounds 1       # mixed against family-sorted chunks

On a shared machine, ``--wait-quiet 600`` waits (up to 600 s) before each measurement until both
cores have been idle for 10 s. The CPU/wall column (CPU time of the measuring process per second
of wall time) shows whether a measurement had the cores to itself: 2.0 on two idle cores.
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections import Counter
from functools import partial
from pathlib import Path

START = time.time()  # the subprocess's start: start-up is measured from here

import mcfdd  # noqa: E402  first: one JAX CPU device per core, before JAX creates its backend

# isort: split

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from mcfdd import config, flags, io  # noqa: E402
from mcfdd.analysis import campaign, noise, scoring, simulate  # noqa: E402
from mcfdd.compute import once  # noqa: E402
from mcfdd.fdd import lpv  # noqa: E402
from mcfdd.plant import closed_loop  # noqa: E402
from mcfdd.workflows import campaign as campaign_runner  # noqa: E402
from mcfdd.workflows.common import CompileCounter, precision as precision_context  # noqa: E402

HERE = Path(__file__).resolve().parent
SPACE = {
    "vcas_kt": [160.0, 350.0], "altitude_m": [0.0, 10000.0], "turbulence": ["light", "moderate"],
    "supply_pressure_scale": [0.95, 1.05], "kci_scale": [0.9, 1.1], "kd_scale": [0.7, 1.3],
    "hinge_scale": [0.8, 1.2], "roll_inertia_scale": [0.9, 1.1], "noise_std_mm": [0.03, 0.07],
    "fault_kind": ["none", "leakage", "surface_damage", "disconnection"], "leakage_size": [0.1, 0.3],
    "surface_damage_size": [0.3, 1.0], "fault_onset_s": [10.0, 30.0],
    "manoeuvre_kind": ["doublet", "bank_to_bank", "roll_protection", "sideslip"], "amplitude": [0.3, 1.0],
    "t_start_s": [5.0, 25.0], "duration_s": [1.0, 3.0], "hold_s": [1.0, 4.0], "sideslip_deg": [-6.0, 6.0],
}
GRID_CELLS = len(SPACE["fault_kind"])  # fault_kind is gridded: scenarios = samples x 4
DT_S = 0.01
HLO_BATCH, HLO_STEPS = 128, 600  # the small batch whose compiled program is counted


def campaign_config(n_scenarios: int, duration_s: float, chunk_size: int,
                    precision: str = "float32", overrides: dict | None = None) -> config.CampaignConfig:
    if n_scenarios % GRID_CELLS:
        raise SystemExit(f"--scenarios: must be a multiple of {GRID_CELLS} (fault kinds on a grid)")
    # revisions before campaign.scenarios became the total (a --baseline checkout) count per grid cell
    total = hasattr(config.CampaignConfig, "grid_cells")
    # shorter runs (the peer, the HLO count) keep their onsets and manoeuvres inside the run
    scale = min(1.0, duration_s / 60.0)
    space = {**SPACE, **{k: [v * scale for v in SPACE[k]] for k in ("fault_onset_s", "t_start_s")}}
    return mcfdd.load_config({
        "campaign": {"scenarios": n_scenarios if total else n_scenarios // GRID_CELLS, "design": "lhs",
                     "grid": ["fault_kind"], "seed": 1, "chunk_size": chunk_size, "duration_s": duration_s,
                     "precision": precision},
        "space": space,
    }, "campaign", overrides or {})


class Problem:
    """The campaign of :func:`campaign_config` set up as ``run_campaign`` sets it up, and its chunks."""

    def __init__(self, n_scenarios: int, n_steps: int, chunk_size: int, precision: str = "float32",
                 overrides: dict | None = None):
        cfg = campaign_config(n_scenarios, n_steps * DT_S, chunk_size, precision, overrides)
        self.c = cfg.campaign
        start = time.perf_counter()
        with CompileCounter() as compiles:
            self.setup = campaign_runner.campaign_setup(cfg)
        self.setup_s, self.setup_compiles = time.perf_counter() - start, compiles.count
        self.n = self.setup.n
        assert self.n == n_scenarios, (self.n, n_scenarios)
        self.size = campaign_runner.chunk_size(self.c.chunk_size, self.n)
        self.chunks = [np.arange(i, min(i + self.size, self.n)) for i in range(0, self.n, self.size)]

    def inputs(self, ids, size=None):
        """Padded scenarios, truths and keys of a chunk, as ``run_campaign`` builds them."""
        return campaign_runner.chunk_inputs(self.setup, self.c.seed, ids, size or self.size)

    def run_chunk(self, ids, n_steps=None, kinds=None, size=None):
        """One chunk as ``run_campaign`` runs it: gather, pad, run_batch, outcomes back to host arrays.

        ``kinds``: the manoeuvre families the chunk's program evaluates (default: all of the campaign's);
        ``size``: the padded batch (default: the campaign's chunk size).
        """
        s, c = self.setup, self.c
        raw = campaign.run_batch(s.model, s.fdd_params, s.settings, *self.inputs(ids, size), n_steps or c.n_steps,
                                 c.dt_s, c.substeps, kinds or s.kinds)
        return {k: np.asarray(v)[:len(ids)] for k, v in jax.block_until_ready(raw).items()}

    def family_chunks(self):
        """(kinds, ids, padded size) of chunks homogeneous in the manoeuvre family: each family's ids split by the
        chunk size, each chunk padded only to its own multiple of LANE_BLOCK per device."""
        family = campaign_runner.chunk_inputs(self.setup, self.c.seed, np.arange(self.n), self.n)[0].manoeuvre.kind
        return [((code,), part, campaign_runner.chunk_size(len(part), len(part))) for code in self.setup.kinds
                for ids in [np.flatnonzero(np.asarray(family) == code)]
                for part in (ids[i:i + self.size] for i in range(0, len(ids), self.size))]

    def device_program(self):
        """Optimised HLO text of ``device_batch`` on HLO_BATCH scenarios x HLO_STEPS steps."""
        s, c = self.setup, self.c
        args = self.inputs(self.chunks[0][:HLO_BATCH], HLO_BATCH)
        return campaign.device_batch.lower(s.model, s.fdd_params, s.settings, *args, HLO_STEPS, c.dt_s, c.substeps,
                                           s.kinds).compile().as_text()


# --- counting the compiled program -------------------------------------------------------------

ELEMENTWISE = frozenset("""abs add and atan2 cbrt ceil clamp compare convert cosine divide erf exponential
exponential-minus-one floor is-finite log log-plus-one logistic maximum minimum multiply negate not or popcnt power
remainder round-nearest-afz round-nearest-even rsqrt select shift-left shift-right-arithmetic shift-right-logical
sign sine sqrt subtract tan tanh xor""".split())
_INSTRUCTION = re.compile(r"^\s*(?:ROOT )?%(\S+) = (.*)$")


def _split_shape(text: str):
    """(result shape, rest) of the right-hand side of an HLO instruction."""
    if text.startswith("("):
        depth = 0
        for i, ch in enumerate(text):
            depth += (ch == "(") - (ch == ")")
            if depth == 0:
                return text[:i + 1], text[i + 2:]
    shape, _, rest = text.partition(" ")
    return shape, rest


def _elements(shape: str) -> int:
    m = re.match(r"\w+\[([\d,]*)\]", shape)
    return int(np.prod([int(d) for d in m.group(1).split(",") if d])) if m else 0


def parse_hlo(text: str) -> dict:
    """Computation name -> its instructions (dicts of name, shape, op, called computations, trip count)."""
    comps, current = {}, None
    for line in text.splitlines():
        if line and not line.startswith(" ") and line.endswith("{"):
            words = line.split()
            current = (words[1] if words[0] == "ENTRY" else words[0]).lstrip("%")
            comps[current] = []
        elif line.startswith("}"):
            current = None
        elif current is not None and (m := _INSTRUCTION.match(line)):
            shape, rest = _split_shape(m.group(2))
            trip = re.search(r'"known_trip_count":\{"n":"(\d+)"', rest)
            comps[current].append({
                "shape": shape, "op": rest.split("(", 1)[0], "rest": rest,
                "calls": re.findall(r"(?:calls|to_apply)=%([\w.\-]+)", rest),
                "body": (re.search(r"body=%([\w.\-]+)", rest) or [None, None])[1],
                "trip": int(trip.group(1)) if trip else 1})
    return comps


def _ops(comps: dict, name: str, batch: int, loops: bool) -> float:
    """Element-ops per scenario of one execution of computation ``name`` (nested loops x their trip counts)."""
    total = 0.0
    for ins in comps[name]:
        if ins["op"] in ELEMENTWISE:
            total += _elements(ins["shape"]) / batch
        elif ins["op"] in ("reduce", "reduce-window"):
            total += _elements(ins["rest"].split("(", 1)[1]) / batch
        elif ins["op"] == "fusion":
            total += _ops(comps, ins["calls"][0], batch, loops)
        elif ins["op"] == "while" and loops:
            total += ins["trip"] * _ops(comps, ins["body"], batch, loops)
    return total


def step_loop(comps: dict) -> dict:
    """The while instruction of the step loop: the one carrying the most arrays, or the loop nested in it
    that carries nearly as many (the steps of a block of random numbers, at the revision before)."""
    def arrays(ins):
        return ins["shape"].count("[")

    loop = max((ins for body in comps.values() for ins in body if ins["op"] == "while"), key=arrays)
    while True:
        inner = [ins for ins in comps[loop["body"]] if ins["op"] == "while" and arrays(ins) >= 0.8 * arrays(loop)]
        if not inner:
            return loop
        loop = max(inner, key=arrays)


def hlo_stats(text: str, batch: int, n_steps: int) -> dict:
    """Fusions, copies and element-ops per scenario-step of the step loop of a compiled campaign program.

    The step loop (:func:`step_loop`) carries plant, FDD and reduction states. ``element_ops`` counts one pass of
    its body per scenario; ``element_ops_total`` the whole program (set-up, random numbers drawn outside the step
    loop, ...) per scenario-step.
    """
    comps = parse_hlo(text)
    step = step_loop(comps)
    entry = re.search(r"^ENTRY %?([\w.\-]+)", text, re.M).group(1)
    ops = Counter(ins["op"] for ins in comps[step["body"]])
    return {"fusions": ops["fusion"], "copies": ops["copy"],
            "element_ops": _ops(comps, step["body"], batch, loops=False),
            "element_ops_total": _ops(comps, entry, batch, loops=True) / n_steps}


def _source_locations(text: str) -> dict:
    """Stack-frame id -> "file:line function" of the optimised HLO's frame tables (innermost frame)."""
    tables, table = {}, None
    for line in text.splitlines():
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            table = tables.setdefault(line, {})
        elif line.startswith(("ENTRY", "%")):
            break
        elif table is not None and (m := re.match(r"(\d+) (.*)", line)):
            table[int(m.group(1))] = m.group(2)
    def field(entry, name):
        return int(re.search(name + r"=(\d+)", entry).group(1))

    def location(entry):
        file = tables["FileNames"][field(entry, "file_name_id")].strip('"').rsplit("/", 1)[-1]
        function = tables["FunctionNames"][field(entry, "function_name_id")].strip('"')
        return f"{file}:{field(entry, 'line')} {function}"

    locations = {i: location(e) for i, e in tables.get("FileLocations", {}).items()}
    return {i: locations[field(e, "file_location_id")] for i, e in tables.get("StackFrames", {}).items()}


def hlo_lines(text: str, batch: int) -> list[dict]:
    """Element-ops per scenario-step of the step loop by source line, with the fusions each line is computed in.

    A line computed in several fusions is duplicated work (XLA CPU recomputes it in every loop
    that uses it), unless it is a different call of the same function (a filter of each model).
    """
    frames = _source_locations(text)
    comps = parse_hlo(text)
    ops, fusions = Counter(), {}

    def visit(instructions, top=None):
        for i, ins in enumerate(instructions):
            fusion = i if top is None else top
            if ins["op"] == "fusion":
                visit(comps[ins["calls"][0]], fusion)
                continue
            if ins["op"] in ELEMENTWISE:
                n = _elements(ins["shape"])
            elif ins["op"] in ("reduce", "reduce-window"):
                n = _elements(ins["rest"].split("(", 1)[1])
            else:
                continue
            frame = re.search(r"stack_frame_id=(\d+)", ins["rest"])
            where = frames.get(int(frame.group(1)), "?") if frame else "?"
            ops[where] += n / batch
            fusions.setdefault(where, set()).add(fusion)

    visit(comps[step_loop(comps)["body"]])
    return [{"source": k, "element_ops": v, "fusions": len(fusions[k])} for k, v in ops.most_common()]


def barrier_check() -> list[dict]:
    """Fusions and element-ops of a toy scan step: shared work plain, behind an optimization barrier, once.

    The step carries three values that all use one shared expression (several cheap elementwise
    operations). XLA CPU fuses the shared expression into each carried value's loop; the
    optimisation barrier does not survive to fusion; :func:`mcfdd.compute.once` does.
    """
    def program(mode):
        def run(x, one):
            def body(c, _):
                a, b, d = c
                shared = jnp.clip(a * 1.1 + b * 0.3, -1.0, 1.0) * (a - b) + jnp.abs(a) * jnp.minimum(b, 0.5)
                if mode == "barrier":
                    shared = jax.lax.optimization_barrier(shared)
                elif mode == "once":
                    shared = once(shared, one)
                return (a + 0.01 * shared, b - 0.02 * shared, jnp.maximum(d, shared)), None
            return jax.lax.scan(body, (x, 0.5 * x, x), None, length=100)[0]
        return jax.jit(jax.vmap(run, in_axes=(0, None)))

    rows = []
    for mode in ("plain", "barrier", "once"):
        text = program(mode).lower(jnp.zeros(256, jnp.float32), jnp.float32(1.0)).compile().as_text()
        stats = hlo_stats(text, 256, 100)
        rows.append({"variant": mode, "fusions": stats["fusions"], "element_ops": stats["element_ops"],
                     "barrier_in_optimised_hlo": "opt-barrier" in text})
    return rows


# --- measurements, each in its own subprocess --------------------------------------------------

def source_digest() -> str:
    """Short digest of the package's Python sources: which code a measurement ran."""
    digest = hashlib.sha1()
    root = Path(mcfdd.__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + path.read_bytes())
    return digest.hexdigest()[:10]


def _cpu_s():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def measure_pipeline(n_scenarios: int, n_steps: int, chunk_size: int, repeats: int) -> dict:
    p = Problem(n_scenarios, n_steps, chunk_size)
    rss_before = _peak_rss_mb()
    start = time.perf_counter()
    p.run_chunk(p.chunks[0])
    first = time.perf_counter() - start
    startup = time.time() - START
    start = time.perf_counter()
    p.run_chunk(p.chunks[0])
    second = time.perf_counter() - start
    passes = []
    for _ in range(repeats):
        cpu0, start = _cpu_s(), time.perf_counter()
        for ids in p.chunks:
            p.run_chunk(ids)
        wall = time.perf_counter() - start
        passes.append({"run_s": wall, "cpu_per_wall": (_cpu_s() - cpu0) / wall})
    best = min(passes, key=lambda r: r["run_s"])
    peak = _peak_rss_mb()
    return {
        "kind": "pipeline", "scenarios": p.n, "steps": n_steps, "devices": jax.device_count(), "chunk": p.size,
        "chunks": len(p.chunks), "setup_s": p.setup_s, "setup_compiles": p.setup_compiles, "startup_s": startup,
        "compile_s": first - second, "run_s": best["run_s"], "all_runs_s": [r["run_s"] for r in passes],
        "cpu_per_wall": best["cpu_per_wall"], "throughput": p.n * n_steps / best["run_s"],
        "rss_before_mb": rss_before, "peak_rss_mb": peak, **hlo_stats(p.device_program(), HLO_BATCH, HLO_STEPS),
    }


def measure_families(n_scenarios: int, n_steps: int, chunk_size: int, repeats: int, sort: bool, save=None) -> dict:
    """The campaign in chunks of mixed manoeuvre families (every chunk's program evaluates all four) or
    sorted into chunks of one family (one program per family, each evaluating its own profile only).

    Cold (no persistent compilation cache): the first pass compiles every program it needs. ``save``: a
    path to write the scenario outcomes to (``.npz``), for comparing the two tables.
    """
    p = Problem(n_scenarios, n_steps, chunk_size)
    chunks = p.family_chunks() if sort else [(p.setup.kinds, ids, p.size) for ids in p.chunks]
    start = time.perf_counter()
    tables = [(ids, p.run_chunk(ids, kinds=kinds, size=size)) for kinds, ids, size in chunks]
    first = time.perf_counter() - start
    passes = []
    for _ in range(repeats):
        start = time.perf_counter()
        for kinds, ids, size in chunks:
            p.run_chunk(ids, kinds=kinds, size=size)
        passes.append(time.perf_counter() - start)
    order = np.argsort(np.concatenate([ids for ids, _ in tables]), kind="stable")
    table = {k: np.concatenate([t[k] for _, t in tables])[order] for k in tables[0][1]}
    digest = hashlib.sha1(b"".join(np.ascontiguousarray(v).tobytes() for _, v in sorted(table.items())))
    if save:
        np.savez(save, **table)
    programs = sorted({(kinds, size) for kinds, _, size in chunks})
    ops = {",".join(map(str, kinds)): hlo_stats(campaign.device_batch.lower(
        p.setup.model, p.setup.fdd_params, p.setup.settings, *p.inputs(ids[:HLO_BATCH], HLO_BATCH), HLO_STEPS, p.c.dt_s,
        p.c.substeps, kinds).compile().as_text(), HLO_BATCH, HLO_STEPS)["element_ops"]
        for kinds, ids in {kinds: ids for kinds, ids, _ in chunks}.items()}
    return {"kind": "families", "sort": sort, "scenarios": p.n, "steps": n_steps, "chunks": len(chunks),
            "padded": sum(size for _, _, size in chunks),
            "programs": len(programs), "first_pass_s": first, "run_s": min(passes), "all_runs_s": passes,
            "compile_s": first - min(passes), "throughput": p.n * n_steps / min(passes),
            "overall": p.n * n_steps / first, "element_ops": ops, "table_digest": digest.hexdigest()[:12]}


def peer_functions(p: Problem, n_steps: int):
    """Jitted pieces of the Python-loop peer: init, one batched step (noise drawn inside), finalize."""
    kinds, dt_s, substeps = p.setup.kinds, p.c.dt_s, p.c.substeps

    def observer(settings, truth, fdd_params):
        monitor = scoring.monitors(settings, truth, fdd_params, dt_s)
        return monitor, scoring.observer(settings, truth, monitor)

    def init_one(model, fdd_params, settings, scenario, truth, key):
        return simulate.start(model, fdd_params, scenario, key, dt_s, observer(settings, truth, fdd_params)[1])

    def step_one(model, fdd_params, settings, params, truth, carry, key, k):
        plant = closed_loop.loop(model)
        normals = noise.normals(noise.key_words(key), k, plant.noise_dim, jnp.result_type(float), plant.normals)
        return simulate.advance(model, params, fdd_params, carry, k, normals, dt_s, substeps, kinds,
                                observer(settings, truth, fdd_params)[1])[0]

    def finalize_one(fdd_params, settings, truth, seen):
        return scoring.finalize(settings, observer(settings, truth, fdd_params)[0], seen, n_steps * dt_s)

    def split(fn, batched):
        """Parameters are arguments (not closed over), as in run_batch, so ``compute.once`` stays in effect."""
        return partial(campaign.on_devices, jax.jit(jax.vmap(fn, in_axes=tuple(0 if b else None for b in batched))),
                       batched=batched)

    init = split(init_one, (False, False, False, True, True, True))
    step = split(step_one, (False, False, False, True, True, True, True, False))
    finalize = split(finalize_one, (False, False, True, True))
    return init, step, finalize


def run_peer(p: Problem, fns, ids, n_steps: int):
    """Python loop over time; the state goes back to NumPy host arrays after every step."""
    init, step, finalize = fns
    s = p.setup
    scen, truth, keys = p.inputs(ids)
    params, carry = init(s.model, s.fdd_params, s.settings, scen, truth, keys)
    for k in range(n_steps):
        carry = step(s.model, s.fdd_params, s.settings, params, truth, carry, keys, np.int32(k))
    out = finalize(s.fdd_params, s.settings, truth, carry[2])
    return {k: np.asarray(v)[:len(ids)] for k, v in out.items()}


def is_event_time(column: str) -> bool:
    """Columns that hold the time of an event on the sample grid (inf: none); compared exactly."""
    return column.endswith("_time_s") or "_latency_" in column


def _plain(value):
    """A table entry as JSON-ready Python: float32 times to their shortest decimal (4.2, not 4.199999809)."""
    value = np.asarray(value)
    if np.issubdtype(value.dtype, np.floating):
        return [float(str(v)) for v in value.ravel()] if value.ndim else float(str(value))
    return value.tolist()


def compare(a: dict, b: dict) -> dict:
    """Outcomes of two runs column by column.

    Discrete outcomes (integers, booleans, event times) must be equal: each difference is listed
    with both values. Continuous columns (float measures such as ratios and peaks) differ in
    their last bits between two compiled programs: each gets its largest relative difference.
    """
    discrete, continuous = [], {}
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        floats = np.issubdtype(x.dtype, np.floating)
        if floats and not is_event_time(k):
            finite = np.isfinite(x) & np.isfinite(y)
            rel = np.abs(x[finite] - y[finite]) / np.maximum(np.abs(x[finite]), 1e-12)
            continuous[k] = float(rel.max(initial=0.0))
            same = finite | (np.isnan(x) & np.isnan(y)) | (x == y)
        else:
            same = (x == y) | (np.isnan(x) & np.isnan(y)) if floats else x == y
        for i in np.flatnonzero(~same.reshape(len(x), -1).all(axis=1)):
            discrete.append({"column": k, "scenario": int(i), "values": [_plain(x[i]), _plain(y[i])]})
    return {"discrete": discrete, "continuous": continuous}


def decision_margins(p: Problem, scenario: int, n_steps: int):
    """Signed relative distance (statistic / threshold - 1) of each fixed-threshold FDD decision of one scenario
    at every step, from its plant and FDD history (``simulate.fdd_batch``, a third compiled program).

    Returns {decision: (n_steps,) array}. The signature (15) is included only for constant thresholds
    (``tau_schedule`` = 0).
    """
    s, c = p.setup, p.c
    scen, _, keys = p.inputs(np.array([scenario]), 1)
    _, fo = simulate.fdd_batch(s.model, s.fdd_params, scen, keys, n_steps, c.dt_s, c.substeps, s.kinds)
    loe, stl = s.fdd_params.loe, s.fdd_params.stall
    theta, theta_u = np.asarray(fo.theta)[0], np.asarray(fo.theta_u)[0]
    with np.errstate(divide="ignore", invalid="ignore"):  # ||u|| = 0 before the first excitation
        out = {"theta_0 / (detection_tau ||u||)": theta[:, 0] / (float(loe.detection_tau) * theta_u),
               "theta_w / excitation_floor": np.asarray(fo.theta_w)[0] / float(loe.excitation_floor),
               "theta_stall / stall tau": np.asarray(fo.theta_stall)[0] / float(stl.tau)}
        if float(loe.tau_schedule) == 0.0:
            tau = np.broadcast_to(np.asarray(loe.tau), theta.shape[1:])
            out.update({f"theta_{i} / (tau_{i} ||u||)": theta[:, i] / (tau[i] * theta_u)
                        for i in range(theta.shape[1])})
    return {name: ratio - 1.0 for name, ratio in out.items()}


def nearest_decision(p: Problem, diff: dict, n_steps: int) -> dict | None:
    """For an event time that two runs put on different steps: the decision closest to its threshold in the
    steps that decide it (from the earlier time less its confirmation window to the later time)."""
    if not diff["column"].endswith("_time_s") or not np.isscalar(diff["values"][0]):
        return None
    times = [t for t in diff["values"] if np.isfinite(t)]
    if not times:
        return None
    loe, dt = p.setup.fdd_params.loe, p.c.dt_s
    detection = diff["column"] in ("detection_time_s", "false_alarm_time_s")
    identification = diff["column"] in ("identification_time_s", "false_identification_time_s")
    confirm = float(loe.detection_confirm_s if detection else loe.confirm_s if identification
                    else max(loe.detection_confirm_s, loe.confirm_s))
    lo = max(int(np.floor((min(times) - confirm) / dt)) - 1, 0)
    hi = min(int(np.ceil(max(times) / dt)) + 1, n_steps)
    margins = decision_margins(p, diff["scenario"], n_steps)
    margins = {k: np.where(np.isfinite(v), v, np.inf) for k, v in margins.items()}
    if detection:
        margins = {k: v for k, v in margins.items() if k.startswith(("theta_0 / (detection", "theta_w"))}
    elif identification:
        margins = {k: v for k, v in margins.items() if "(tau_" in k or k.startswith("theta_w")}
    name, step = min(((k, lo + int(np.argmin(np.abs(v[lo:hi])))) for k, v in margins.items()),
                     key=lambda ks: abs(margins[ks[0]][ks[1]]))
    return {"decision": name, "t_s": step * dt, "margin": float(margins[name][step])}


def measure_peer(n_scenarios: int, n_steps: int, repeats: int, precision: str = "float32") -> dict:
    with precision_context(precision):
        p = Problem(n_scenarios, n_steps, n_scenarios, precision)
        ids = p.chunks[0]
        fns = peer_functions(p, n_steps)
        start = time.perf_counter()
        run_peer(p, fns, ids, 1)  # compiles init, step and finalize
        first_one_step = time.perf_counter() - start
        start = time.perf_counter()
        run_peer(p, fns, ids, 1)
        one_step = time.perf_counter() - start
        runs = []
        for _ in range(repeats):
            cpu0, start = _cpu_s(), time.perf_counter()
            out = run_peer(p, fns, ids, n_steps)
            wall = time.perf_counter() - start
            runs.append((wall, (_cpu_s() - cpu0) / wall))
        wall, cpu = min(runs)
        check = compare(p.run_chunk(ids, n_steps), out)
        for diff in check["discrete"]:
            diff["nearest_decision"] = nearest_decision(p, diff, n_steps)
    return {"kind": "peer", "scenarios": p.n, "steps": n_steps, "devices": jax.device_count(), "precision": precision,
            "compile_s": first_one_step - one_step, "run_s": wall, "cpu_per_wall": cpu,
            "throughput": p.n * n_steps / wall, "step_ms": 1e3 * wall / n_steps, "dt_s": p.c.dt_s,
            "check": check, "peak_rss_mb": _peak_rss_mb()}


def check_lines(peer: dict) -> list[str]:
    """The peer's outcomes against run_batch, in words: discrete differences with the decision behind each."""
    chk = peer["check"]
    worst = sorted(chk["continuous"].items(), key=lambda kv: -kv[1])[:3]
    lines = [f"  outcomes vs run_batch ({peer['precision']}): {len(chk['discrete'])} discrete difference(s) in "
             f"{len({d['scenario'] for d in chk['discrete']})} of {peer['scenarios']:,} scenarios; continuous "
             f"columns: largest relative differences " + ", ".join(f"{k} {v:.2g}" for k, v in worst)]
    for d in chk["discrete"]:
        a, b = d["values"]
        unit = " s" if is_event_time(d["column"]) else ""
        text = f"  - {d['column']} of scenario {d['scenario']}: run_batch {a}{unit}, peer {b}{unit}"
        if unit and np.isscalar(a) and np.isfinite([a, b]).all():
            text += f" ({abs(a - b) / peer['dt_s']:.0f} step(s))"
        near = d.get("nearest_decision")
        if near is not None:
            text += (f"; nearest decision in the deciding steps: {near['decision']} - 1 = {near['margin']:+.2g} "
                     f"at t = {near['t_s']:.2f} s")
        lines.append(text)
    return lines


STAGES = ("random numbers", "+ plant", "+ both FDD systems", "+ online reductions (the campaign)",
          "the campaign, random numbers replaced by a constant")


def measure_breakdown(n_scenarios: int, n_steps: int, repeats: int) -> dict:
    """Run time, fusions and element-ops of the campaign scan cut after each stage of its step, on one chunk.

    Each cut keeps a running sum of its last stage's outputs in the carry so that XLA cannot
    drop the stage; the fourth row is the campaign's step (``simulate.advance`` with the scoring monitors) in the same
    scan; the last is that step fed a constant instead of the normals (the random numbers'
    cost, by ablation: the rest of the step compiles to the same fusions).
    """
    p = Problem(n_scenarios, n_steps, n_scenarios)
    s, c = p.setup, p.c
    scen, truth, keys = p.inputs(p.chunks[0])

    def cut(stage, model, fdd_params, settings, scenario, truth, key):
        monitor = scoring.monitors(settings, truth, fdd_params, c.dt_s)
        observer = scoring.observer(settings, truth, monitor)
        params, carry = simulate.start(model, fdd_params, scenario, key, c.dt_s, observer)
        words = noise.key_words(key)

        def body(state, k):
            (plant_state, fdd_state, seen), acc = state
            plant = closed_loop.loop(model)
            draws = (jnp.full(plant.noise_dim, 0.5, params.qbar_pa.dtype) if stage == 4 else
                     noise.normals(words, k, plant.noise_dim, params.qbar_pa.dtype, plant.normals))
            if stage == 0:
                return ((plant_state, fdd_state, seen), acc + draws.sum()), None
            if stage >= 3:
                carry, _ = simulate.advance(model, params, fdd_params, (plant_state, fdd_state, seen), k, draws,
                                            c.dt_s, c.substeps, s.kinds, observer)
                return (carry, acc), None
            t = k * c.dt_s
            plant_state, out = closed_loop.loop(model).step(params, plant_state, t, draws, c.dt_s, c.substeps,
                                                            s.kinds)
            if stage == 1:
                return ((plant_state, fdd_state, seen), acc + out.u_m), None
            fdd_state, fo = simulate.fdd_step(fdd_params, fdd_state, out, t, c.dt_s)
            sink = fo.theta.sum() + fo.theta_stall + fo.detected + fo.eta_signal + fo.eta_model
            return ((plant_state, fdd_state, seen), acc + sink), None

        zero = jnp.zeros((), params.qbar_pa.dtype)
        (carry, acc), _ = jax.lax.scan(body, (carry, zero), jnp.arange(n_steps))
        return acc if stage < 3 else scoring.finalize(settings, monitor, carry[2], n_steps * c.dt_s)

    rows = []
    params = (s.model, s.fdd_params, s.settings)  # arguments, as in run_batch: compute.once stays in effect
    for stage, name in enumerate(STAGES):
        fn = jax.jit(jax.vmap(partial(cut, stage), in_axes=(None, None, None, 0, 0, 0)),
                     compiler_options=campaign.XLA_CPU_OPTIONS)
        run = partial(campaign.on_devices, fn, *params, scen, truth, keys, batched=(False,) * 3 + (True,) * 3)
        small = jax.tree.map(lambda x: x[:HLO_BATCH], (scen, truth, keys))
        stats = hlo_stats(fn.lower(*params, *small).compile().as_text(), HLO_BATCH, n_steps)
        jax.block_until_ready(run())
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            jax.block_until_ready(run())
            times.append(time.perf_counter() - start)
        rows.append({"stage": name, "run_s": min(times), "throughput": p.size * n_steps / min(times), **stats})
    return {"kind": "breakdown", "scenarios": p.size, "steps": n_steps, "devices": jax.device_count(), "rows": rows}


def ceiling_inputs(n: int, seed: int = 0) -> dict:
    """Per-scenario inputs of the C toy step: realistic ranges, LPV coefficients of the default bank."""
    rng = np.random.default_rng(seed)
    bank, _ = lpv.from_dict(io.load_bank_dict(None), np.float32)
    vcas, alt = rng.uniform(82.0, 180.0, n), rng.uniform(0.0, 10000.0, n)
    basis = np.stack([np.ones(n), (vcas - bank.norm.vcas_ref_m_s) / bank.norm.vcas_scale_m_s,
                      (alt - bank.norm.altitude_ref_m) / bank.norm.altitude_scale_m])  # (3, n)
    coef = np.einsum("ijm,mn->ijn", np.asarray(bank.coef, np.float64), basis)  # (NM, 4, n)
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return {
        "amp": f32(rng.uniform(0.3, 1.0, n)), "t0": f32(rng.uniform(5.0, 25.0, n)),
        "dur": f32(rng.uniform(1.0, 3.0, n)),
        "kp_law": f32(rng.uniform(0.3, 0.6, n)), "ki_law": f32(rng.uniform(0.5, 1.0, n)),
        "load0": f32(rng.uniform(-3e3, 3e3, n)), "slope": f32(rng.uniform(-6e4, -2e4, n)),
        "lp": f32(rng.uniform(-2.0, -1.0, n)), "lda": f32(rng.uniform(3.0, 6.0, n)),
        "gust_a": f32(rng.uniform(0.98, 0.999, n)), "gust_b": f32(rng.uniform(0.001, 0.01, n)),
        "coef": f32(coef), "k0": f32(bank.k0), "keys": np.ascontiguousarray(rng.integers(0, 2**32, (2, n)), np.uint32),
    }


def measure_ceiling(n_scenarios: int, n_steps: int, repeats: int, fast_math: bool) -> dict:
    """The fused C toy step (``ceiling_kernel.c``) on n scenarios x n steps, OpenMP over the cores."""
    flags = ["-O3", "-march=native", "-fopenmp", "-fno-math-errno"] + (["-ffast-math"] if fast_math else [])
    with tempfile.TemporaryDirectory() as tmp:
        lib_path = Path(tmp) / "ceiling.so"
        subprocess.run(["gcc", *flags, "-shared", "-fPIC", "-o", str(lib_path), str(HERE / "ceiling_kernel.c"), "-lm"],
                       check=True)
        lib = ctypes.CDLL(str(lib_path))
    x = ceiling_inputs(n_scenarios)
    outs = {"ratio_max": np.zeros((6, n_scenarios), np.float32), "det_time": np.zeros(n_scenarios, np.float32),
            "stall_max": np.zeros(n_scenarios, np.float32)}
    ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
    args = [ptr(x[k]) for k in ("amp", "t0", "dur", "kp_law", "ki_law", "load0", "slope", "lp", "lda", "gust_a",
                                "gust_b", "coef", "k0", "keys")] + [ptr(v) for v in outs.values()]
    lib.run.restype = None
    times = []
    for _ in range(repeats + 1):
        cpu0, start = _cpu_s(), time.perf_counter()
        lib.run(ctypes.c_int(n_scenarios), ctypes.c_int(n_steps), *args)
        times.append((time.perf_counter() - start, _cpu_s() - cpu0))
    wall, cpu = min(times[1:])
    return {"kind": "ceiling", "fast_math": fast_math, "flags": " ".join(flags), "scenarios": n_scenarios,
            "steps": n_steps, "threads": int(os.environ.get("OMP_NUM_THREADS", os.cpu_count())), "run_s": wall,
            "cpu_per_wall": cpu / wall, "throughput": n_scenarios * n_steps / wall,
            "finite": bool(np.isfinite(outs["stall_max"]).all())}


def worker(spec: dict) -> dict:
    assert not jax.config.jax_enable_x64, "the benchmark measures float32"
    kind = spec["kind"]
    if kind == "pipeline":
        result = measure_pipeline(spec["scenarios"], spec["steps"], spec["chunk_size"], spec["repeats"])
    elif kind == "breakdown":
        result = measure_breakdown(spec["scenarios"], spec["steps"], spec["repeats"])
    elif kind == "families":
        result = measure_families(spec["scenarios"], spec["steps"], spec["chunk_size"], spec["repeats"], spec["sort"],
                                  spec["save"])
    elif kind == "ceiling":
        result = measure_ceiling(spec["scenarios"], spec["steps"], spec["repeats"], spec["fast_math"])
    else:
        result = measure_peer(spec["scenarios"], spec["steps"], spec["repeats"], spec["precision"])
    return {**result, "source": source_digest(), "package": str(Path(mcfdd.__file__).parent)}


def _idle_fraction(seconds: float) -> float:
    """Share of CPU time spent idle over the next ``seconds`` (Linux /proc/stat)."""
    def sample():
        with open("/proc/stat") as f:
            values = [int(v) for v in f.readline().split()[1:]]
        return values[3] + values[4], sum(values)

    idle0, total0 = sample()
    time.sleep(seconds)
    idle1, total1 = sample()
    return (idle1 - idle0) / max(total1 - total0, 1)


def wait_quiet(max_wait_s: float):
    """Wait until the cores have been at least 90 % idle over 10 s, at most ``max_wait_s``."""
    if max_wait_s <= 0 or not os.path.exists("/proc/stat"):
        return
    start = time.perf_counter()
    while True:
        idle = _idle_fraction(10.0)
        if idle >= 0.9:
            return
        if time.perf_counter() - start > max_wait_s:
            print(f"  (machine still busy after {max_wait_s:.0f} s, {100 * idle:.0f} % idle: measuring anyway)",
                  flush=True)
            return


def spawn(spec: dict, max_wait_s: float = 0.0, checkout: Path | None = None) -> dict:
    """Run one measurement in a fresh process; ``checkout``: import that checkout's mcfdd instead."""
    wait_quiet(max_wait_s)
    load = os.getloadavg()
    env = dict(os.environ, OMP_NUM_THREADS=str(os.cpu_count()))
    if checkout is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(checkout)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(spec)], capture_output=True, text=True,
                          check=False, env=env)
    if proc.returncode:
        sys.stderr.write(proc.stderr)
        raise SystemExit(f"measurement {spec} failed")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["load_before"] = load
    return result


def _pipeline_line(label: str, r: dict) -> str:
    return (f"| {label} | {r['compile_s']:.1f} | {r['run_s']:.2f} | {r['throughput']:.3g} | {r['cpu_per_wall']:.2f} | "
            f"{r['fusions']} | {r['copies']} | {r['element_ops']:.0f} | {r['element_ops_total']:.0f} | "
            f"{r['startup_s']:.1f} | {r['setup_compiles']} | {r['peak_rss_mb']:.0f} |")


def family_chunks(args):
    """Mixed against family-sorted chunks, alternating ``--rounds`` times, each in a fresh process (cold compile)."""
    print(f"{args.scenarios:,} scenarios x {args.steps:,} steps, chunks of {args.chunk_size}, float32, "
          f"{jax.device_count()} device(s); load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    rows, saved = [], {}
    work = tempfile.mkdtemp()
    for _ in range(args.rounds):
        for sort in (False, True):
            saved[sort] = os.path.join(work, f"sort{int(sort)}.npz")
            r = spawn({"kind": "families", "scenarios": args.scenarios, "steps": args.steps,
                       "chunk_size": args.chunk_size, "repeats": args.repeats, "sort": sort, "save": saved[sort]},
                      args.wait_quiet)
            rows.append(r)
            print(f"  {'sorted' if sort else 'mixed'}: first pass {r['first_pass_s']:.1f} s, runs "
                  f"{', '.join(f'{t:.2f}' for t in r['all_runs_s'])} s, load before {r['load_before'][0]:.2f}",
                  flush=True)
    print("| chunks | programs | chunks run | padded scenarios | first pass incl. compile (s) | compile (s) | "
          "run (s) | scenario-steps/s (run) | (first pass) | element-ops per scenario-step per program | "
          "table digest |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for r in rows:
        ops = ", ".join(f"{k}: {v:.0f}" for k, v in r["element_ops"].items())
        print(f"| {'sorted by family' if r['sort'] else 'mixed'} | {r['programs']} | {r['chunks']} | {r['padded']} | "
              f"{r['first_pass_s']:.1f} | {r['compile_s']:.1f} | {r['run_s']:.2f} | {r['throughput']:.3g} | "
              f"{r['overall']:.3g} | {ops} | {r['table_digest']} |")
    mixed, sorted_ = np.load(saved[False]), np.load(saved[True])
    for name in mixed.files:
        x, y = mixed[name], sorted_[name]
        if not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            if x.dtype.kind == "f":
                both = np.isfinite(x) & np.isfinite(y)
                rel = np.abs(x[both] - y[both]) / np.maximum(np.abs(x[both]), 1e-30)
                print(f"  {name}: {int((x != y).sum())} of {x.size} values differ, largest relative "
                      f"{rel.max() if rel.size else 0.0:.2g}, non-finite pattern "
                      f"{'same' if np.array_equal(np.isfinite(x), np.isfinite(y)) else 'differs'}")
            else:
                print(f"  {name}: {int((x != y).sum())} of {x.size} values differ (discrete)")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=4096, help="scenarios of the pipeline (default 4096)")
    parser.add_argument("--steps", type=int, default=6000, help="steps of 0.01 s (default 6000: 60 s)")
    parser.add_argument("--chunk-size", type=int, default=4096, help="scenarios per chunk, as campaign.chunk_size")
    parser.add_argument("--repeats", type=int, default=2, help="timed passes per measurement; the best is reported")
    parser.add_argument("--baseline", type=Path, help="another checkout of mcfdd, measured in the same run")
    parser.add_argument("--rounds", type=int, default=2, help="with --baseline: alternating measurements of each")
    parser.add_argument("--peer-scenarios", type=int, default=1024)
    parser.add_argument("--peer-steps", type=int, default=600)
    parser.add_argument("--no-peer", action="store_true", help="skip the Python-loop peer")
    parser.add_argument("--peer-precision", choices=("float32", "float64"), default="float32",
                        help="precision of the peer and of the run_batch it is checked against (default float32)")
    parser.add_argument("--no-breakdown", action="store_true", help="skip the stage breakdown")
    parser.add_argument("--no-ceiling", action="store_true", help="skip the C kernel")
    parser.add_argument("--barrier-check", action="store_true",
                        help="only show what optimization_barrier and mcfdd.compute.once do to a toy step's fusions")
    parser.add_argument("--hlo-lines", type=int, metavar="N",
                        help="only list the N source lines with the most element-ops in the compiled step loop")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                        help="with --hlo-lines: a config override of the counted program, e.g. --set "
                             "fdd.loe.excitation_noise_factor=2 (repeatable)")
    parser.add_argument("--wait-quiet", type=float, default=0.0, metavar="S",
                        help="before each measurement wait up to S seconds for idle cores (shared machines)")
    parser.add_argument("--family-chunks", action="store_true",
                        help="only compare chunks of mixed manoeuvre families with chunks sorted by family")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))), flush=True)
        return
    if args.barrier_check:
        print("| toy step | fusions per step | element-ops per scenario-step | opt-barrier in optimised HLO |")
        print("|---|---:|---:|---|")
        for r in barrier_check():
            print(f"| {r['variant']} | {r['fusions']} | {r['element_ops']:.0f} | {r['barrier_in_optimised_hlo']} |")
        return
    if args.family_chunks:
        family_chunks(args)
        return
    if args.hlo_lines is not None:
        overrides = flags.campaign_overrides(args.set, {}, None)
        rows = hlo_lines(Problem(args.scenarios, args.steps, args.chunk_size, overrides=overrides).device_program(),
                         HLO_BATCH)
        print(f"step loop of device_batch ({HLO_BATCH} scenarios x {HLO_STEPS} steps): "
              f"{sum(r['element_ops'] for r in rows):.0f} element-ops per scenario-step")
        print("| source line | element-ops per scenario-step | fusions |")
        print("|---|---:|---:|")
        for r in rows[:args.hlo_lines]:
            print(f"| {r['source']} | {r['element_ops']:.0f} | {r['fusions']} |")
        return
    if args.baseline is not None and not (args.baseline / "mcfdd" / "__init__.py").is_file():
        raise SystemExit(f"--baseline: {args.baseline} holds no mcfdd package")
    print(f"jax {jax.__version__}, {jax.device_count()} {jax.devices()[0].platform} device(s) "
          f"({os.cpu_count()} cores, XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}), "
          f"{platform.processor() or platform.machine()}, float32, dt {DT_S} s, {args.scenarios:,} scenarios x "
          f"{args.steps:,} steps in chunks of {args.chunk_size}, best of {args.repeats}")
    print(f"mcfdd {io.git_revision()}, sources {source_digest()}")
    print(f"load average before start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    spec = {"kind": "pipeline", "scenarios": args.scenarios, "steps": args.steps, "chunk_size": args.chunk_size,
            "repeats": args.repeats}
    checkouts = [("this", None)] + ([("baseline", args.baseline.resolve())] if args.baseline else [])
    results = {label: [] for label, _ in checkouts}
    for _ in range(args.rounds if args.baseline else 1):
        for label, checkout in checkouts:
            r = spawn(spec, args.wait_quiet, checkout)
            results[label].append(r)
            print(f"  {label} ({r['package']}, sources {r['source']}): compile {r['compile_s']:.1f} s, runs "
                  f"{', '.join(f'{t:.2f}' for t in r['all_runs_s'])} s, CPU/wall {r['cpu_per_wall']:.2f}, "
                  f"start-up {r['startup_s']:.1f} s (set-up {r['setup_s']:.1f} s, {r['setup_compiles']} compiles), "
                  f"load before {r['load_before'][0]:.2f}", flush=True)
    best = {label: max(rs, key=lambda r: r["throughput"]) for label, rs in results.items()}
    peer = None if args.no_peer else spawn({"kind": "peer", "scenarios": args.peer_scenarios,
                                            "steps": args.peer_steps, "repeats": args.repeats,
                                            "precision": args.peer_precision}, args.wait_quiet)
    ceilings = [] if args.no_ceiling else [
        spawn({"kind": "ceiling", "scenarios": args.scenarios, "steps": args.steps, "repeats": args.repeats,
               "fast_math": fast}, args.wait_quiet) for fast in (False, True)]
    parts = None if args.no_breakdown else spawn({"kind": "breakdown", "scenarios": args.chunk_size, "steps": 2000,
                                                  "repeats": args.repeats + 1}, args.wait_quiet)
    print()
    print("| pipeline | compile (s) | run (s) | scenario-steps/s | CPU/wall | fusions per step | copies per step | "
          "element-ops per scenario-step (step loop) | (whole program) | start-up to first chunk (s) | "
          "compiles in set-up | peak RSS (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label, r in best.items():
        print(_pipeline_line(label, r))
    this = best["this"]["throughput"]
    print()
    if "baseline" in best:
        print(f"this / baseline: {this / best['baseline']['throughput']:.2f}x (best of {args.rounds} alternating "
              f"measurements each)")
    print(f"aim 2e7 scenario-steps/s: {this / 2e7:.2f} of it;  1e8: {this / 1e8:.2f} of it")
    if peer is not None:
        print(f"peer (python loop over time, jitted vectorised step, state in NumPy host arrays): "
              f"{peer['scenarios']:,} x {peer['steps']:,} steps, compile {peer['compile_s']:.1f} s, run "
              f"{peer['run_s']:.2f} s ({peer['step_ms']:.2f} ms per step), {peer['throughput']:.3g} scenario-steps/s, "
              f"CPU/wall {peer['cpu_per_wall']:.2f};  pipeline / peer: {this / peer['throughput']:.0f}x")
        print("\n".join(check_lines(peer)))
    for c in ceilings:
        print(f"ceiling (fused C toy step, {c['flags']}, {c['threads']} threads): {c['run_s']:.2f} s, "
              f"{c['throughput']:.3g} scenario-steps/s, CPU/wall {c['cpu_per_wall']:.2f};  pipeline / ceiling: "
              f"{this / c['throughput']:.2f}")
    if parts is not None:
        print()
        print(f"where the time goes ({parts['scenarios']:,} scenarios x {parts['steps']:,} steps):")
        print("| stage | run (s) | scenario-steps/s | fusions per step | element-ops per scenario-step |")
        print("|---|---:|---:|---:|---:|")
        for r in parts["rows"]:
            print(f"| {r['stage']} | {r['run_s']:.3f} | {r['throughput']:.3g} | {r['fusions']} | "
                  f"{r['element_ops']:.0f} |")
    digests = {r["source"] for r in results["this"] + [x for x in [peer, parts] if x]}
    if len(digests) > 1:
        print(f"WARNING: the package sources changed during the run ({', '.join(sorted(digests))})")
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()

"""Files out: Parquet tables with provenance metadata, output folders (the edge of the package)."""

from __future__ import annotations

import json
import subprocess
from importlib import metadata as importlib_metadata, resources
from pathlib import Path

import filelock
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

META_PREFIX = "mcfdd."
LOCK_NAME = ".mcfdd.lock"  # in an output folder: held (an OS lock) by the one run writing there


def package_version() -> str:
    try:
        return importlib_metadata.version("mcfdd")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def git_revision() -> str:
    """Commit of the source tree the package runs from, with ``-dirty`` if it has local changes."""
    root = Path(__file__).resolve().parent.parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True,
                             timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev + ("-dirty" if dirty else "")


def provenance(config_json: str, seed: int | None, **extra) -> dict[str, str]:
    """Key-value metadata every output table carries."""
    meta = {"config": config_json, "seed": "" if seed is None else str(seed), "version": package_version(),
            "git_revision": git_revision()}
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in extra.items()})
    return meta


def write_table(df: pd.DataFrame, path, meta: dict[str, str]) -> Path:
    """Write ``df`` as Parquet with ``meta`` in the schema's key-value metadata (keys prefixed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pandas(df, preserve_index=False)
    merged = dict(table.schema.metadata or {})
    merged.update({(META_PREFIX + k).encode(): str(v).encode() for k, v in meta.items()})
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table.replace_schema_metadata(merged), tmp, write_page_checksum=True)
    tmp.replace(path)
    return path


def read_checked_table(path) -> pd.DataFrame:
    """A Parquet table read in full, its page checksums verified; a damaged or unreadable file raises ``ValueError``."""
    try:
        return pq.read_table(path, page_checksum_verification=True).to_pandas()
    except (pa.ArrowException, OSError, ValueError) as err:
        raise ValueError(str(err)) from None


def read_metadata(path) -> dict[str, str]:
    """The ``mcfdd.*`` key-value metadata of a Parquet file, prefix removed."""
    raw = pq.read_schema(path).metadata or {}
    return {k.decode()[len(META_PREFIX):]: v.decode() for k, v in raw.items() if k.decode().startswith(META_PREFIX)}


def default_out_dir(command: str, config_path) -> Path:
    return Path("results") / f"{command}-{Path(config_path).stem}"


def unused_out_dir(command: str, config_path) -> Path:
    """``results/<command>-<config>``, or the first of ``...-2``, ``...-3``, ... not yet there."""
    base = default_out_dir(command, config_path)
    candidate, i = base, 1
    while candidate.exists():
        i += 1
        candidate = base.with_name(f"{base.name}-{i}")
    return candidate


def out_dir(command: str, config_path, out=None, new: bool = False) -> Path:
    """The output folder of a command: ``out`` if given, else ``results/<command>-<config>`` (``new``: the
    first of it, ``...-2``, ... not yet there)."""
    if out:
        return Path(out)
    return unused_out_dir(command, config_path) if new else default_out_dir(command, config_path)


def lock_folder(folder):
    """An exclusive lock on ``folder`` (made if missing), or None while another process holds it.

    The lock is an OS lock on the folder's :data:`LOCK_NAME` file (``filelock``), so the kernel
    releases it when its holder dies, even by SIGKILL; call ``.release()`` when done.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock = filelock.FileLock(folder / LOCK_NAME)
    try:
        lock.acquire(timeout=0)
    except filelock.Timeout:
        return None
    return lock


def folder_entries(folder) -> list[Path]:
    """What ``folder`` holds besides its lock file (nothing if it does not exist)."""
    folder = Path(folder)
    return [p for p in folder.iterdir() if p.name != LOCK_NAME] if folder.is_dir() else []


def write_text(path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def history_frame(run_names, t_s, columns: dict) -> pd.DataFrame:
    """Tidy table of time histories: one row per (run, time), ``columns`` maps name to (runs, steps) arrays."""
    n_runs, n_steps = len(run_names), len(t_s)
    data = {"run": np.repeat(np.asarray(run_names, dtype=object), n_steps), "t_s": np.tile(t_s, n_runs)}
    data.update({name: np.asarray(values).reshape(n_runs * n_steps) for name, values in columns.items()})
    return pd.DataFrame(data)


DEFAULT_BANK = "default_bank.json"


def save_bank(path, bank_dict: dict) -> Path:
    """Write an LPV bank in its versioned JSON form (:func:`mcfdd.fdd.lpv.to_dict`)."""
    return write_text(path, json.dumps(bank_dict, indent=2) + "\n")


def load_bank_dict(path=None) -> dict:
    """Read an LPV bank's JSON form; ``None`` reads the bank shipped with the package."""
    if path is None:
        return json.loads(resources.files("mcfdd.data").joinpath(DEFAULT_BANK).read_text())
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such LPV bank file")
    return json.loads(path.read_text())


def model_run_frame(model_names, runs: dict, per_model: dict) -> pd.DataFrame:
    """Tidy table of per-model results on B runs: one row per (model, run), models outermost.

    ``runs`` maps column names to (B,) arrays describing the runs, ``per_model`` to (N, B) arrays.
    """
    n_models = len(model_names)
    n_runs = len(next(iter(runs.values())))
    data = {"model": np.repeat(np.asarray(model_names, dtype=object), n_runs)}
    data.update({name: np.tile(np.asarray(values), n_models) for name, values in runs.items()})
    data.update({name: np.asarray(values).reshape(n_models * n_runs) for name, values in per_model.items()})
    return pd.DataFrame(data)


def grid_frame(model_names, axes: dict, values: dict) -> pd.DataFrame:
    """Tidy table of per-model values on a grid: one row per (model, grid point).

    ``axes`` maps column names to 1-D grids in order, ``values`` to arrays of shape
    (N, *grid shape).
    """
    mesh = np.meshgrid(*[np.asarray(a) for a in axes.values()], indexing="ij")
    runs = {name: m.ravel() for name, m in zip(axes, mesh)}
    return model_run_frame(model_names, runs, {k: np.asarray(v).reshape(len(model_names), -1)
                                               for k, v in values.items()})

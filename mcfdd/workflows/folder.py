"""A campaign's output folder: its state file, resume checks, damaged parts, the one-writer rule.

``campaign.json`` holds the resolved configuration (the chunk size aside: it does not change results),
``scenarios/part-<first id>.parquet`` one part per chunk; every table carries the resolved config in
its metadata, so a lost state file is rebuilt from them.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np

from mcfdd import config, io
from mcfdd.analysis import build
from mcfdd.progress import note
from mcfdd.workflows.common import OutputFolderError, check_folder

CAMPAIGN_STATE = "campaign.json"


def resolved(cfg: config.CampaignConfig) -> dict:
    """Resolved config without the chunk size, which does not change results."""
    data = config.to_dict(cfg)
    data["campaign"].pop("chunk_size")
    return json.loads(json.dumps(data, default=str))


def state_text(cfg: config.CampaignConfig) -> str:
    """campaign.json: the resolved config in its own order (the order of [space]'s axes orders the design's
    columns, so the scenarios are rebuilt from this file alone, :mod:`mcfdd.workflows.replay`)."""
    return json.dumps(resolved(cfg), indent=1)


@contextlib.contextmanager
def writing(out: Path, advice: str):
    """Turns a failed write under ``out`` (no space, read-only, ...) into one line naming the file."""
    try:
        yield
    except OSError as err:
        raise OutputFolderError(f"--out: cannot write {err.filename or out}: {err.strerror or err}; {advice}") from None


def check_out(out: Path, resume: bool):
    """Refuse an output path that cannot hold this campaign, before anything is made."""
    check_folder(out, "--out")
    if resume and not (out / CAMPAIGN_STATE).is_file() and not written_tables(out):
        raise OutputFolderError(f"--resume: {out} holds no campaign to resume ({CAMPAIGN_STATE} missing and no "
                                f"scenario part to rebuild it from); run without --resume into a new folder")


def written_tables(out: Path) -> list[Path]:
    """The Parquet tables of a campaign folder (parts first), each carrying the resolved config in its metadata."""
    return sorted((out / "scenarios").glob("part-*.parquet")) + sorted(out.glob("*.parquet"))


def rebuilt_state(out: Path) -> str:
    """The text of a lost ``campaign.json``, from the resolved config the folder's tables carry (``mcfdd.config``).

    Every readable table must carry the same campaign (the chunk size aside); a damaged one is skipped here and
    dealt with by the resume itself.
    """
    states = {}
    for path in written_tables(out):
        try:
            text = io.read_metadata(path).get("config")
            state = state_text(config.parse(config.CampaignConfig, json.loads(text)))
        except (OSError, ValueError, TypeError, config.ConfigError):
            continue
        states.setdefault(state, path)
    if len(states) != 1:
        found = ", ".join(p.relative_to(out).as_posix() for p in states.values()) or "none"
        raise OutputFolderError(f"--resume: {out / CAMPAIGN_STATE} is missing and the folder's tables carry "
                                f"{len(states)} campaign configurations (first carriers: {found}); keep the parts of "
                                f"one campaign there, or run into a new folder")
    return next(iter(states))


def stored_differences(state: Path, cfg: config.CampaignConfig) -> list:
    """(key, stored value, value of ``cfg``) for each key where the campaign state ``state`` differs from ``cfg``."""
    try:
        stored = json.loads(state.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise OutputFolderError(f"--resume: {state} is not a readable campaign state ({err})") from None
    return config.differences(stored, resolved(cfg))


def remove_if_unused(out: Path):
    """Remove a folder this run made and left holding nothing but its lock file (the run failed before it began)."""
    if out.is_dir() and not io.folder_entries(out):
        (out / io.LOCK_NAME).unlink(missing_ok=True)
        out.rmdir()


def in_use(out: Path) -> OutputFolderError:
    return OutputFolderError(f"--out: {out} is in use by another mcfdd run ({io.LOCK_NAME} is locked); wait for it "
                             f"to end or choose another folder")


def prepare_dir(out: Path, cfg: config.CampaignConfig, resume: bool):
    state = out / CAMPAIGN_STATE
    if resume:
        if not state.is_file():
            with writing(out, "choose a folder you can write to"):
                io.write_text(state, rebuilt_state(out))
            note(f"--resume: {CAMPAIGN_STATE} was missing; rebuilt from the configuration the parts carry", True)
        changed = stored_differences(state, cfg)
        if changed:
            raise OutputFolderError(f"--resume: the configuration differs from the one {out} was started with: "
                                    + "; ".join(f"{key} was {json.dumps(a)}, now {json.dumps(b)}"
                                                for key, a, b in changed))
        return
    if io.folder_entries(out):
        raise OutputFolderError(f"--out: {out} exists and is not empty; resume it or choose another folder")
    with writing(out, "choose a folder you can write to"):
        io.write_text(state, state_text(cfg))


def part_name(first_id: int) -> str:
    return f"part-{first_id:08d}.parquet"


def part_damage(part: Path, setup, done: np.ndarray):
    """(table, None) for a sound part of this campaign, (None, what is wrong) for a damaged one.

    Sound: readable in full with its page checksums, named after its first scenario id, holding
    ids of this campaign that no other part holds, with exactly the design values of those ids.
    """
    try:
        df = io.read_checked_table(part)
    except ValueError as err:
        return None, f"unreadable: {err}"
    if "scenario_id" not in df.columns:
        return None, "column scenario_id missing"
    ids = df["scenario_id"].to_numpy()
    if not len(ids) or ids.dtype.kind not in "iu" or ids.min() < 0 or ids.max() >= setup.n:
        return None, f"scenario ids outside 0..{setup.n - 1}"
    if part.name != part_name(int(ids[0])) or len(np.unique(ids)) != len(ids) or done[ids].any():
        return None, "scenario ids repeated or not those of its name"
    for column, values in build.design_chunk(setup.config, setup.plan, ids).items():
        if column not in df.columns:
            return None, f"column {column} missing"
        if not np.array_equal(df[column].to_numpy(), np.asarray(values)):
            return None, f"column {column} differs from the campaign's design"
    return df, None


def read_parts(parts_dir: Path, setup):
    """Sound tables already written under ``parts_dir`` with their part numbers, and which ids they hold.

    A damaged part (:func:`part_damage`) is renamed ``*.damaged`` and named on stderr; its
    scenarios are run again.
    """
    frames, labels, done = [], [], np.zeros(setup.n, dtype=bool)
    for part in sorted(parts_dir.glob("part-*.parquet")):
        df, damage = part_damage(part, setup, done)
        if damage is not None:
            aside = part.with_name(part.name + ".damaged")
            part.replace(aside)
            note(f"--resume: {part} is damaged ({damage}); moved to {aside.name}, its scenarios are run again", True)
            continue
        frames.append(df)
        labels.append(np.full(len(df), int(part.stem.split("-")[1])))
        done[df["scenario_id"].to_numpy()] = True
    return frames, labels, done

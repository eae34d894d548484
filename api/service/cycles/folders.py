"""Where an axis' raw runs live, whose a folder is, and the move from the old name-based folders.

Up to this version a dataset folder was named from the machine and axis names made
file-system safe, so machines "m a" and "m_a" (axis y) shared ``datasets/m_a_y``.
Folders are now named by the database's ids, ``machine-<id>_axis-<id>`` (plus
``_rejected`` for failed cycles' traces and ``@<time>`` after a change of mechanics).
:func:`migrate_legacy_folders` moves old folders at start-up: a folder only one axis
can own is renamed; a folder two look-alike axes wrote into is split run by run, each
run going to the axis of the cycle that measured it (``cycle_uuid`` in the run).

Ids repeat across databases: a new database on an old data directory (a move to
PostgreSQL, a database created anew) numbers its machines and axes from 1 again, so
``machine-1_axis-1`` may hold another machine's runs. A folder therefore records its
owner in dataset.json (``owner``: the uuids of the machine and axis, which the database
keeps for each), and the service appends only to a folder that records its axis as
owner (:func:`storage.dataset.append_runs` checks it under the folder's lock).

A folder of the axis' name that records no owner (written before owners were recorded,
or put there by hand) is judged by :func:`judge_folder`:

- it is **adopted** (its owner is written) when every run in it that the service
  measured (a run with a ``cycle_uuid``) is a cycle of this axis in this database;
  runs without a ``cycle_uuid`` (``mebm import``, ``mebm sim`` into the folder) do not
  count either way, and a folder with no such run is adopted too;
- otherwise (a run of a cycle this database does not hold for this axis) it cannot be
  shown to belong: it is **moved aside**, renamed ``<name>.of-unknown-database``, as is
  a folder that records another owner (``<name>.of-machine-<uuid>``). Nothing in it is
  changed or deleted; the start report and the log say where it went. The operator
  keeps it as the archive of the machine it names, or starts the service on the
  database it belongs to (that database holds its cycles) after moving it back.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path

from core.dataset import Dataset, Run
from core.errors import MebmError
from storage.dataset import (
    LOCK_FILE,
    append_runs,
    dataset_lock,
    describe_owner,
    folder_owner,
    next_run_name,
    read_dataset,
    same_owner,
    set_owner,
    write_dataset,
)
from storage.db import AxisRecord

log = logging.getLogger("mebm.cycles")
_NEW = re.compile(r"machine-\d+_axis-\d+(_rejected)?(@.*)?")
ASIDE = ".of-"  # a folder moved aside: "<name>.of-machine-<uuid>" or "<name>.of-unknown-database"


def dataset_folder_name(axis: AxisRecord) -> str:
    return f"machine-{axis.machine_id}_axis-{axis.id}"


def axis_owner(axis: AxisRecord) -> dict | None:
    """The ``owner`` an axis' folders record (None for a record without identities)."""
    if not axis.uuid or not axis.machine_uuid:
        return None
    return {"machine_uuid": axis.machine_uuid, "axis_uuid": axis.uuid, "machine": axis.machine_name,
            "axis": axis.name}


def axis_folders(datasets_dir: Path, axis: AxisRecord) -> list[Path]:
    """The axis' dataset folders: its own, ``_rejected`` and ``@<time>`` ones (not those
    moved aside)."""
    base = dataset_folder_name(axis)
    if not datasets_dir.is_dir():
        return []
    return sorted(p for p in datasets_dir.glob(f"{base}*")
                  if p.is_dir() and (p.name == base or p.name[len(base)] in "_@") and ASIDE not in p.name)


@dataclass(frozen=True)
class Verdict:
    """Whose a dataset folder is, for an axis: ``own`` (records the axis as owner),
    ``adoptable`` (records none, and nothing in it is another's), ``foreign`` (another
    owner, or runs of cycles that are not the axis'), ``absent`` (no dataset.json)."""

    kind: str
    reason: str = ""
    owner: dict | None = None  # the owner the folder records


def judge_folder(folder: Path, axis: AxisRecord, cycles_of_axis: Callable[[list[str]], set[str]]) -> Verdict:
    """Whose ``folder`` is (the rule is in the module docstring). ``cycles_of_axis(uuids)``:
    those of the uuids that are cycles of the axis in this database. Raises DatasetError
    for a folder whose dataset.json cannot be read (it is then left as it is)."""
    if not (folder / "dataset.json").is_file():
        return Verdict("absent")
    meta = read_dataset(folder, load_runs=False)
    recorded = folder_owner(meta.extra)
    mine = axis_owner(axis)
    if recorded is not None:
        if mine is None or same_owner(recorded, mine):
            return Verdict("own", owner=recorded)
        return Verdict("foreign", f"it belongs to {describe_owner(recorded)}", recorded)
    uuids = [str(r.spec.extra["cycle_uuid"]) for r in meta.runs if r.spec.extra.get("cycle_uuid")]
    strangers = [u for u in uuids if u not in cycles_of_axis(uuids)] if uuids else []
    if strangers:
        return Verdict("foreign", f"it records no owner and {len(strangers)} of its {len(uuids)} measured run(s) "
                                  f"are no cycle of axis {axis.id} in this database (cycle {strangers[0]}, ...)")
    return Verdict("adoptable")


def aside_name(folder: Path, owner: dict | None) -> Path:
    """Where a folder that is not the axis' goes: a free ``<name>.of-...`` next to it."""
    whose = f"machine-{owner['machine_uuid']}" if owner else "unknown-database"
    target = folder.with_name(f"{folder.name}{ASIDE}{whose}")
    n = 2
    while target.exists():
        target = folder.with_name(f"{folder.name}{ASIDE}{whose}-{n}")
        n += 1
    return target


def claim_folder(folder: Path, axis: AxisRecord,
                 cycles_of_axis: Callable[[list[str]], set[str]]) -> tuple[Path, str] | None:
    """Make ``folder`` the axis' or move it out of the way, under the folder's lock: an
    adoptable one gets the axis as owner; a foreign one is renamed (:func:`aside_name`)
    and (new path, why) is returned. None when the folder is (now) the axis' or absent."""
    owner = axis_owner(axis)
    if owner is None or not (folder / "dataset.json").is_file():
        return None
    with dataset_lock(folder):
        verdict = judge_folder(folder, axis, cycles_of_axis)
        if verdict.kind == "adoptable":
            set_owner(folder, owner)
            log.info("dataset folder %s adopted by axis %s (%s/%s): it records it as owner now",
                     folder.name, axis.id, axis.machine_name, axis.name)
            return None
        if verdict.kind != "foreign":
            return None
        target = aside_name(folder, verdict.owner)
        folder.rename(target)
    log.warning("dataset folder %s moved aside to %s: %s. Axis %s (%s/%s) starts a new folder; the runs "
                "moved aside are unchanged (see docs/operations.md, 'Dataset folders and their owner')",
                folder.name, target.name, verdict.reason, axis.id, axis.machine_name, axis.name)
    return target, verdict.reason


def legacy_folder_name(axis: AxisRecord) -> str:
    """The folder name of versions before ids were used (kept to find old folders)."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in f"{axis.machine_name}_{axis.name}")


def _split_name(name: str) -> tuple[str, str]:
    base, at, stamp = name.partition("@")
    suffix = ""
    if base.endswith("_rejected"):
        base, suffix = base[: -len("_rejected")], "_rejected"
    return base, suffix + (at + stamp if at else "")


def migrate_legacy_folders(datasets_dir: Path, axes: Iterable[AxisRecord],
                           axis_of_cycles: Callable[[list[str]], dict[str, int]]) -> dict[Path, Path]:
    """Move name-based dataset folders to id-based ones. ``axis_of_cycles(uuids)`` maps
    cycle uuids to axis ids (the database). Returns {old folder: new folder} for folders
    moved whole. Runs that cannot be attributed to one axis stay where they are (logged): a
    run of a cycle this database does not hold is attributed to no axis, and a run is
    appended only to a folder that records its axis as owner."""
    moved: dict[Path, Path] = {}
    if not datasets_dir.is_dir():
        return moved
    axes = list(axes)
    by_id = {a.id: a for a in axes}
    by_legacy: dict[str, list[AxisRecord]] = {}
    for a in axes:
        by_legacy.setdefault(legacy_folder_name(a), []).append(a)
    for folder in sorted(p for p in datasets_dir.iterdir() if p.is_dir()):
        if _NEW.fullmatch(folder.name) or ASIDE in folder.name or not (folder / "dataset.json").is_file():
            continue
        base, suffix = _split_name(folder.name)
        candidates = by_legacy.get(base, [])
        if not candidates:
            log.warning("dataset folder %s matches no configured axis: left as it is", folder)
            continue
        try:
            meta = read_dataset(folder, load_runs=False)
            uuids = [str(r.spec.extra.get("cycle_uuid")) for r in meta.runs if r.spec.extra.get("cycle_uuid")]
            owners = axis_of_cycles(uuids) if uuids else {}
            plan: dict[int, list[str]] = {}
            for r in meta.runs:
                cycle = r.spec.extra.get("cycle_uuid")
                owner = owners.get(str(cycle)) if cycle else None
                if owner is None and not cycle and len(candidates) == 1:  # a run put there by hand
                    owner = candidates[0].id
                # (a run of a cycle this database does not hold is another database's: it is not attributed)
                if owner is not None and owner in by_id and by_id[owner] in candidates:
                    plan.setdefault(owner, []).append(r.spec.file)
            if not plan:
                log.warning("dataset folder %s: none of its %d run(s) is a cycle of this database's axes: left as "
                            "it is (another database's runs?)", folder, len(meta.runs))
                continue
            if len(plan) == 1 and len(candidates) == 1 and sum(map(len, plan.values())) == len(meta.runs):
                target = datasets_dir / (dataset_folder_name(candidates[0]) + suffix)
                if not target.exists():
                    folder.rename(target)
                    moved[folder] = target
                    log.info("dataset folder %s renamed to %s", folder.name, target.name)
                    continue
            _split(folder, suffix, plan, by_id, datasets_dir)
        except (MebmError, OSError) as exc:
            log.error("dataset folder %s could not be migrated (%s): left as it is", folder, exc)
    return moved


def _split(folder: Path, suffix: str, plan: dict[int, list[str]], by_id: dict[int, AxisRecord],
           datasets_dir: Path) -> None:
    """Copy each attributed run to its axis' folder, then drop it from the old one."""
    with dataset_lock(folder):
        ds = read_dataset(folder)
        runs = {r.spec.file: r for r in ds.runs}
        done: set[str] = set()
        for axis_id, files in plan.items():
            target = datasets_dir / (dataset_folder_name(by_id[axis_id]) + suffix)
            with dataset_lock(target):
                for file in files:
                    run = runs[file]
                    machine = replace(ds.machine, axes={k: v for k, v in ds.machine.axes.items() if k in run.spec.axes})
                    stem = file[: -len(".csv")].rsplit("_", 1)[0] if file.endswith(".csv") else file
                    new_name = file if not (target / file).exists() else next_run_name(target, stem)
                    append_runs(target, machine, [Run(replace(run.spec, file=new_name), run.columns)],
                                owner=axis_owner(by_id[axis_id]))
                    done.add(file)
            log.info("dataset folder %s: %d run(s) moved to %s", folder.name, len(files), target.name)
        left = tuple(r for r in ds.runs if r.spec.file not in done)
        write_dataset(folder, Dataset(ds.machine, left, ds.extra))
        for file in done:
            (folder / file).unlink(missing_ok=True)
    if left:
        log.warning("dataset folder %s: %d run(s) of no known cycle left in place", folder.name, len(left))
    else:
        for name in ("dataset.json", LOCK_FILE):
            (folder / name).unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            folder.rmdir()

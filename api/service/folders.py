"""Where an axis' raw runs live, and the move from the old name-based folders.

Up to this version a dataset folder was named from the machine and axis names made
file-system safe, so machines "m a" and "m_a" (axis y) shared ``datasets/m_a_y``.
Folders are now named by the database's ids, ``machine-<id>_axis-<id>`` (plus
``_rejected`` for failed cycles' traces and ``@<time>`` after a change of mechanics).
:func:`migrate_legacy_folders` moves old folders at start-up: a folder only one axis
can own is renamed; a folder two look-alike axes wrote into is split run by run, each
run going to the axis of the cycle that measured it (``cycle_uuid`` in the run).
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path

from core.dataset import Dataset, Run
from core.errors import MebmError
from storage.dataset import LOCK_FILE, append_runs, dataset_lock, next_run_name, read_dataset, write_dataset
from storage.db import AxisRecord

log = logging.getLogger("mebm.cycles")
_NEW = re.compile(r"machine-\d+_axis-\d+(_rejected)?(@.*)?")


def dataset_folder_name(axis: AxisRecord) -> str:
    return f"machine-{axis.machine_id}_axis-{axis.id}"


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
    moved whole. Runs that cannot be attributed to one axis stay where they are (logged)."""
    moved: dict[Path, Path] = {}
    if not datasets_dir.is_dir():
        return moved
    axes = list(axes)
    by_id = {a.id: a for a in axes}
    by_legacy: dict[str, list[AxisRecord]] = {}
    for a in axes:
        by_legacy.setdefault(legacy_folder_name(a), []).append(a)
    for folder in sorted(p for p in datasets_dir.iterdir() if p.is_dir()):
        if _NEW.fullmatch(folder.name) or not (folder / "dataset.json").is_file():
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
                owner = owners.get(str(r.spec.extra.get("cycle_uuid")))
                if owner is None and len(candidates) == 1:
                    owner = candidates[0].id
                if owner is not None and owner in by_id and by_id[owner] in candidates:
                    plan.setdefault(owner, []).append(r.spec.file)
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
                    append_runs(target, machine, [Run(replace(run.spec, file=new_name), run.columns)])
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

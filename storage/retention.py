"""Retention of raw runs in a dataset folder, so a year of cycles fits on the disk.

Policy (:class:`RetentionPolicy`), applied to the runs listed in ``dataset.json`` in
measurement order:

- the newest ``keep_last_runs`` stay as they are (plain CSV: the gap diagnosis and
  anyone with a spreadsheet read them);
- runs within ``keep_around_events`` runs of an event (an alert raised or cleared: the
  caller names their cycle uuids) are never deleted;
- older runs are compressed (``<file>.gz``, gzip; about 2.4x smaller; readers take
  either form, see :func:`storage.dataset.read_run_csv`);
- beyond ``max_runs`` in the folder, the oldest unprotected runs are deleted and taken
  out of ``dataset.json``. Database rows (results, curves, criteria) are never touched.

Deletions happen under the folder's lock and ``dataset.json`` is rewritten atomically;
compression runs after the lock is released (file names in ``dataset.json`` do not change).
"""

from __future__ import annotations

import contextlib
import gzip
import json
import os
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from core.errors import InputError
from storage.dataset import atomic_write_text, load_dataset_json, dataset_lock, fsync_dir


@dataclass(frozen=True)
class RetentionPolicy:
    keep_last_runs: int = 200
    keep_around_events: int = 5
    max_runs: int = 5000

    def __post_init__(self):
        for name in ("keep_last_runs", "keep_around_events", "max_runs"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 0:
                raise InputError(f"retention.{name} (={v!r}) must be an integer >= 0")
        if self.max_runs < self.keep_last_runs:
            raise InputError(f"retention.max_runs (={self.max_runs}) must be >= keep_last_runs "
                             f"(={self.keep_last_runs})")


@dataclass(frozen=True)
class RetentionReport:
    compressed: int
    deleted: int
    runs: int
    bytes_on_disk: int
    deleted_cycle_uuids: tuple[str, ...] = ()  # of the deleted runs that name their cycle


def folder_bytes(folder: Path) -> int:
    """Bytes of the regular files in ``folder`` (not recursive)."""
    total = 0
    with contextlib.suppress(OSError), os.scandir(folder) as it:
        for e in it:
            with contextlib.suppress(OSError):
                if e.is_file(follow_symlinks=False):
                    total += e.stat(follow_symlinks=False).st_size
    return total


def _compress(path: Path) -> None:
    gz = path.with_name(path.name + ".gz")
    tmp = gz.with_name(f".{gz.name}.tmp")
    with open(path, "rb") as src, open(tmp, "wb") as raw:
        with gzip.GzipFile(filename=path.name, mode="wb", fileobj=raw, compresslevel=6, mtime=0) as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
        raw.flush()
        os.fsync(raw.fileno())
    os.replace(tmp, gz)
    fsync_dir(gz.parent)
    path.unlink()  # only once the compressed copy is durable


def apply_retention(folder: str | os.PathLike, policy: RetentionPolicy, event_uuids: Iterable[str] = (),
                    before_delete: Callable[[tuple[str, ...]], None] | None = None) -> RetentionReport:
    """Apply ``policy`` to the dataset folder. ``before_delete(cycle_uuids)`` is called with
    the cycles whose runs are about to be deleted, before any file goes: if it raises
    (their cycles could not be marked), nothing is deleted in this pass and it raises on."""
    root = Path(folder)
    if not (root / "dataset.json").is_file():
        return RetentionReport(0, 0, 0, folder_bytes(root) if root.is_dir() else 0)
    events = set(event_uuids)
    compressed = deleted = 0
    with dataset_lock(root):
        doc = load_dataset_json(root / "dataset.json")
        runs = [r for r in doc.get("runs", []) if isinstance(r, dict)]
        n = len(runs)
        protected: set[int] = set(range(max(n - policy.keep_last_runs, 0), n))
        for i, r in enumerate(runs):
            if str(r.get("cycle_uuid")) in events:
                protected.update(range(max(i - policy.keep_around_events, 0),
                                       min(i + policy.keep_around_events + 1, n)))
        excess = n - policy.max_runs
        drop: set[int] = set()
        for i in range(n):
            if excess <= 0:
                break
            if i not in protected:
                drop.add(i)
                excess -= 1
        gone = tuple(str(runs[i]["cycle_uuid"]) for i in sorted(drop) if runs[i].get("cycle_uuid"))
        if gone and before_delete is not None:
            before_delete(gone)  # raises: nothing deleted
        to_compress = []
        for i, r in enumerate(runs):
            plain = root / str(r.get("file", ""))
            if i in drop:
                for p in (plain, plain.with_name(plain.name + ".gz")):
                    p.unlink(missing_ok=True)
                deleted += 1
            elif i < n - policy.keep_last_runs:
                to_compress.append(plain)
        if drop:
            doc["runs"] = [r for i, r in enumerate(runs) if i not in drop]
            atomic_write_text(root / "dataset.json", json.dumps(doc, indent=2) + "\n")
    # outside the lock (a cycle's write does not wait for it): the names in dataset.json do
    # not change, and readers take the .gz once the plain file is gone
    for plain in to_compress:
        if plain.is_file():
            _compress(plain)
            compressed += 1
    return RetentionReport(compressed, deleted, n - len(drop), folder_bytes(root), gone)

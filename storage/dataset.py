"""Read and write `mebm-dataset/1` folders (dataset.json + one CSV per run).

Every malformation ends in :class:`core.errors.DatasetError` naming the file and,
for CSV content, the row. Unknown JSON fields survive a read-write round trip.
"""

from __future__ import annotations

import contextlib
import csv
import gzip
import json
import os
import tempfile
import threading
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import asdict, fields, replace
from pathlib import Path

import numpy as np

from core.dataset import (
    AXIS_FIELDS,
    FORMAT,
    OPTIONAL_AXIS_FIELDS,
    AxisSpec,
    Dataset,
    MachineSpec,
    Run,
    RunSpec,
    axis_differences,
    validate_columns,
    validate_run_spec,
)
from core.errors import DatasetError

_RUN_FIELDS = [f.name for f in fields(RunSpec) if f.name != "extra"]
_TUPLE_FIELDS = ("axes", "centre_mm", "start_mm")


OWNER_KEY = "owner"  # dataset.json's optional record of the machine and axis the folder belongs to
OWNER_FIELDS = ("machine_uuid", "axis_uuid")  # what identifies the owner; its other fields only inform


class FolderOwnerError(DatasetError):
    """A writer that names its owner met a folder that records another owner, or none
    while it holds runs: the folder is not appended to (see :func:`append_runs`)."""


def folder_owner(doc: Mapping) -> dict | None:
    """The ``owner`` a dataset.json document (or a :class:`Dataset`'s ``extra``) records,
    or None when it records none (folders written without one) or a malformed one."""
    owner = doc.get(OWNER_KEY)
    if not isinstance(owner, dict) or not all(isinstance(owner.get(k), str) and owner[k] for k in OWNER_FIELDS):
        return None
    return owner


def same_owner(a: Mapping | None, b: Mapping | None) -> bool:
    """Whether two owner records name the same machine and axis (by their uuids)."""
    return a is not None and b is not None and all(a.get(k) == b.get(k) for k in OWNER_FIELDS)


def describe_owner(owner: Mapping | None) -> str:
    """An owner for a message: "machine 'vmc-850' (uuid ...), axis 'y' (uuid ...)"."""
    if owner is None:
        return "no recorded owner"
    return (f"machine {owner.get('machine', '?')!r} (uuid {owner.get('machine_uuid')}), "
            f"axis {owner.get('axis', '?')!r} (uuid {owner.get('axis_uuid')})")


REWRITE_JSON = "the file is cut short or not JSON: restore it from a copy or write it again"


def load_dataset_json(path: Path) -> dict:
    """A dataset folder's ``dataset.json``, or a :class:`DatasetError` that says what is wrong with it."""
    if not path.is_file():
        raise DatasetError("dataset.json not found (is this a dataset folder?)", source=str(path))
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        # json's messages end in "at" ("Unterminated string starting at") when the
        # position they point at is where the problem starts, not where parsing stopped
        what = exc.msg if exc.msg.endswith(" at") else f"{exc.msg} at"
        raise DatasetError(f"{what} line {exc.lineno}, column {exc.colno}: {REWRITE_JSON}", source=str(path)) from exc
    except UnicodeDecodeError as exc:
        raise DatasetError(f"byte {exc.start} is not UTF-8 text: {REWRITE_JSON}", source=str(path)) from exc
    if not isinstance(doc, dict):
        raise DatasetError("top level must be a JSON object", source=str(path))
    return doc


def _parse_machine(doc: dict, src: str) -> MachineSpec:
    m = doc.get("machine")
    if not isinstance(m, dict) or not isinstance(m.get("axes"), dict) or not m["axes"]:
        raise DatasetError("machine.axes must be an object with at least one axis", source=src)
    axes = {}
    for name, a in m["axes"].items():
        if not isinstance(a, dict):
            raise DatasetError(f"machine.axes.{name} must be an object", source=src)
        missing = [k for k in AXIS_FIELDS if k not in a and k not in OPTIONAL_AXIS_FIELDS]  # lead, K: see AxisSpec
        if missing:
            raise DatasetError(f"machine.axes.{name} lacks {missing}", source=src)
        try:
            axes[name] = AxisSpec(
                name=name,
                transmission_mm_per_rev=float(a["transmission_mm_per_rev"]),
                screw_lead_mm=float(a["screw_lead_mm"]) if a.get("screw_lead_mm") is not None else None,
                position_gain_per_s=float(a["position_gain_per_s"]) if a.get("position_gain_per_s") is not None
                else None,
                travel_mm=tuple(float(x) for x in a["travel_mm"]),
                extra={k: v for k, v in a.items() if k not in AXIS_FIELDS},
            )
        except (TypeError, ValueError) as exc:
            if isinstance(exc, DatasetError):
                raise DatasetError(str(exc), source=src) from None
            raise DatasetError(f"machine.axes.{name}: {exc}", source=src) from exc
    return MachineSpec(
        id=str(m.get("id", "")),
        axes=axes,
        extra={k: v for k, v in m.items() if k not in ("id", "axes")},
    )


def parse_machine(doc: dict, src: str) -> MachineSpec:
    """``doc["machine"]`` checked as dataset.json's (a trace-import profile has the same table)."""
    return _parse_machine(doc, src)


def parse_run_spec(r: object, src: str) -> RunSpec:
    """One run's fields checked as dataset.json's ``runs[i]``."""
    return _parse_run_spec(r, 0, src)


def _parse_run_spec(r: object, i: int, src: str) -> RunSpec:
    if not isinstance(r, dict):
        raise DatasetError(f"runs[{i}] must be an object", source=src)
    for key in ("file", "kind", "axes", "feed_mm_min", "temperature_c"):
        if key not in r:
            raise DatasetError(f"runs[{i}] ({r.get('file', '?')!r}) lacks required field {key!r}", source=src)
    kw = {}
    for key in _RUN_FIELDS:
        if key in r and r[key] is not None:
            v = r[key]
            if key in _TUPLE_FIELDS:
                if key == "start_mm" and isinstance(v, (int, float)):
                    v = [v]  # a round trip's start on its one axis
                if not isinstance(v, list):
                    raise DatasetError(f"runs[{i}].{key} must be a list", source=src)
                v = tuple(str(x).lower() if key == "axes" else float(x) for x in v)
            elif key in ("file", "kind", "split", "direction"):
                v = str(v)
            else:
                try:
                    v = float(v)
                except (TypeError, ValueError) as exc:
                    raise DatasetError(f"runs[{i}].{key} (={v!r}) must be a number", source=src) from exc
            kw[key] = v
    if os.sep in kw["file"] or kw["file"].startswith(".."):
        raise DatasetError(f"runs[{i}].file (={kw['file']!r}) must be a plain file name", source=src)
    return RunSpec(**kw, extra={k: v for k, v in r.items() if k not in _RUN_FIELDS})


def _open_text(path: Path):
    if path.suffix == ".gz":
        return gzip.open(path, "rt", newline="", encoding="utf-8")
    return path.open(newline="", encoding="utf-8")


def read_run_csv(path: Path, spec: RunSpec) -> dict[str, np.ndarray]:
    """Read one run CSV into float columns and validate them against ``spec``. A run
    compressed by retention (``<file>.gz`` next to where ``<file>`` was) is read as well."""
    if not path.is_file() and path.with_name(path.name + ".gz").is_file():
        path = path.with_name(path.name + ".gz")
    if not path.is_file():
        raise DatasetError("run file is missing from the dataset folder", source=str(path))
    with _open_text(path) as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise DatasetError("file is empty (no header row)", source=str(path)) from None
        if len(set(header)) != len(header):
            raise DatasetError(f"duplicate column names in header {header}", source=str(path))
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, dtype=float, ndmin=2)
    except ValueError:
        data = None
    if data is None or (data.size and data.shape[1] != len(header)):
        _raise_bad_row(path, len(header))
    if data.size == 0:
        data = np.empty((0, len(header)))
    columns = {name: np.ascontiguousarray(data[:, j]) for j, name in enumerate(header)}
    try:
        validate_columns(spec, columns)
    except DatasetError as exc:
        raise DatasetError(str(exc).split(": ", 1)[1] if exc.source else str(exc), source=str(path), row=exc.row) from None
    return columns


def _raise_bad_row(path: Path, n_cols: int) -> None:
    with _open_text(path) as fh:
        reader = csv.reader(fh)
        next(reader)
        for row_no, row in enumerate(reader, start=1):
            if len(row) != n_cols:
                raise DatasetError(f"has {len(row)} fields, the header has {n_cols}", source=str(path), row=row_no)
            for cell in row:
                try:
                    float(cell)
                except ValueError:
                    raise DatasetError(f"value {cell!r} is not a number", source=str(path), row=row_no) from None
    raise DatasetError("could not be parsed as numbers", source=str(path))  # pragma: no cover


def read_dataset(folder: str | os.PathLike, *, load_runs: bool = True) -> Dataset:
    """Read and validate a dataset folder. ``load_runs=False`` reads metadata only."""
    root = Path(folder)
    if not root.is_dir():
        raise DatasetError("not a folder", source=str(root))
    json_path = root / "dataset.json"
    doc = load_dataset_json(json_path)
    src = str(json_path)
    if doc.get("format") != FORMAT:
        raise DatasetError(f"format (={doc.get('format')!r}) must be {FORMAT!r}", source=src)
    machine = _parse_machine(doc, src)
    runs_doc = doc.get("runs")
    if not isinstance(runs_doc, list):
        raise DatasetError("runs must be a list", source=src)
    specs = [_parse_run_spec(r, i, src) for i, r in enumerate(runs_doc)]
    seen = set()
    for spec in specs:
        if spec.file in seen:
            raise DatasetError(f"run file {spec.file!r} listed twice", source=src)
        seen.add(spec.file)
        validate_run_spec(spec, machine, source=src)
    runs = tuple(
        Run(spec, read_run_csv(root / spec.file, spec) if load_runs else {}) for spec in specs
    )
    return Dataset(machine, runs, extra={k: v for k, v in doc.items() if k not in ("format", "machine", "runs")})



def machine_to_json(machine: MachineSpec) -> dict:
    axes = {}
    for name, a in machine.axes.items():
        axes[name] = {
            "transmission_mm_per_rev": a.transmission_mm_per_rev,
            **({"screw_lead_mm": a.screw_lead_mm} if a.screw_lead_mm is not None else {}),
            **({"position_gain_per_s": a.position_gain_per_s} if a.position_gain_per_s is not None else {}),
            "travel_mm": list(a.travel_mm),
            **dict(a.extra),
        }
    return {"id": machine.id, "axes": axes, **dict(machine.extra)}


def run_spec_to_json(spec: RunSpec) -> dict:
    out = {}
    for key, v in asdict(spec).items():
        if key == "extra" or v is None:
            continue
        out[key] = list(v) if isinstance(v, tuple) else v
    out.update(dict(spec.extra))
    return out


try:  # POSIX: an advisory lock file, so a second process (the CLI) is excluded too
    import fcntl
except ImportError:  # pragma: no cover - Windows: the in-process lock only
    fcntl = None

LOCK_FILE = ".dataset.lock"
_locks: dict[str, threading.RLock] = {}
_depth: dict[str, int] = {}
_locks_guard = threading.Lock()


@contextlib.contextmanager
def dataset_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold the folder's lock: one writer of ``dataset.json`` at a time, across threads
    (a re-entrant lock per folder) and processes (``flock`` on ``.dataset.lock``).
    Creates the folder. Re-entrant within a thread, so ``append_runs`` can be called
    inside a ``with dataset_lock(folder):`` that picked the run's name."""
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    key = str(root.resolve())
    with _locks_guard:
        lock = _locks.setdefault(key, threading.RLock())
    with lock:
        outer = _depth.get(key, 0) == 0
        fd = None
        if outer and fcntl is not None:
            fd = os.open(root / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o600)
            fcntl.flock(fd, fcntl.LOCK_EX)
        _depth[key] = _depth.get(key, 0) + 1
        try:
            yield root
        finally:
            _depth[key] -= 1
            if fd is not None:
                fcntl.flock(fd, fcntl.LOCK_UN)
                os.close(fd)


def fsync_dir(path: Path) -> None:
    """Make a rename or an unlink in ``path`` durable (POSIX; a no-op where folders
    cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - file systems that refuse fsync on a folder
        pass
    finally:
        os.close(fd)


def atomic_write_text(path: Path, text: str) -> None:
    """Temporary file, fsync, rename, fsync of the folder: the old or the new text,
    never a torn one, and the new one survives a power cut once this returns."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def write_run_csv(path: Path, columns: Mapping[str, np.ndarray]) -> None:
    """Write columns as CSV with full float precision (repr round-trips exactly)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.17g")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def write_dataset(folder: str | os.PathLike, dataset: Dataset) -> Path:
    """Write a whole dataset folder (creating it); runs first, dataset.json last."""
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    for run in dataset.runs:
        validate_run_spec(run.spec, dataset.machine)
        validate_columns(run.spec, run.columns)
        write_run_csv(root / run.spec.file, run.columns)
    doc = {
        "format": FORMAT,
        "machine": machine_to_json(dataset.machine),
        "runs": [run_spec_to_json(r.spec) for r in dataset.runs],
        **dict(dataset.extra),
    }
    atomic_write_text(root / "dataset.json", json.dumps(doc, indent=2) + "\n")
    return root


class AxisMismatchError(DatasetError):
    """The folder's stored description of an axis differs from the one given: the
    message says which fields differ, in words and units, and what to do."""

    def __init__(self, name: str, stored: AxisSpec, given: AxisSpec, n_runs: int, source: str | None = None):
        self.axis, self.stored, self.given = name, stored, given
        self.differences = axis_differences(stored, given)
        super().__init__(f"axis {name!r} differs from the one its {n_runs} stored run(s) were recorded with "
                         f"({'; '.join(self.differences)}): write to a new folder, or replace the stored "
                         "description if it was wrong", source=source)  # fmt: skip


def append_runs(folder: str | os.PathLike, machine: MachineSpec, runs: Iterable[Run], *,
                owner: Mapping[str, str] | None = None, replace_axes: Iterable[str] = ()) -> Path:
    """Append runs to a dataset folder, creating it if absent.

    An existing folder must describe the same axes (same k_a, lead, gain, travel)
    or :class:`DatasetError` is raised; a run file name already listed (or a file of
    that name already in the folder) is an error, so nothing stored is overwritten.
    The whole read-modify-write holds :func:`dataset_lock`.

    ``owner`` (``machine_uuid``, ``axis_uuid`` and informative fields): the machine and
    axis the runs belong to. A new folder records it as its ``owner``; an existing one
    must record the same owner, or record none and hold no run, else
    :class:`FolderOwnerError` is raised and nothing is written. Without ``owner`` (the
    CLI) the folder's recorded owner, if any, is kept as it is.

    ``replace_axes``: names of axes whose stored description ``machine``'s replaces (a
    corrected k_a, say; the stored runs are then read with it) instead of the
    :class:`AxisMismatchError`.
    """
    with dataset_lock(folder) as root:
        return _append_runs_locked(root, machine, list(runs), owner, frozenset(replace_axes))


def _check_owner(json_path: Path, recorded: dict | None, owner: Mapping[str, str], n_runs: int) -> None:
    if recorded is None and n_runs:
        raise FolderOwnerError(f"records no owner and holds {n_runs} run(s), so they cannot be shown to be "
                               f"{describe_owner(owner)}'s: not appended to", source=str(json_path))
    if recorded is not None and not same_owner(recorded, owner):
        raise FolderOwnerError(f"belongs to {describe_owner(recorded)}, not to {describe_owner(owner)}: "
                               "not appended to", source=str(json_path))


def set_owner(folder: str | os.PathLike, owner: Mapping[str, str]) -> None:
    """Record ``owner`` in the folder's dataset.json (adopting a folder written without
    one). Raises :class:`FolderOwnerError` if it records another owner already."""
    with dataset_lock(folder) as root:
        json_path = root / "dataset.json"
        doc = load_dataset_json(json_path)
        recorded = folder_owner(doc)
        if recorded is not None:
            _check_owner(json_path, recorded, owner, 0)
            return
        read_dataset(root, load_runs=False)  # a malformed file is not rewritten
        atomic_write_text(json_path, json.dumps(_ordered({**doc, OWNER_KEY: dict(owner)}), indent=2) + "\n")


def _ordered(doc: dict) -> dict:
    """format, owner, machine, runs, then the rest (as read): dataset.json's key order."""
    head = {k: doc[k] for k in ("format", OWNER_KEY, "machine", "runs") if k in doc}
    return {**head, **{k: v for k, v in doc.items() if k not in head}}


def _append_runs_locked(root: Path, machine: MachineSpec, runs: list[Run], owner: Mapping[str, str] | None,
                        replace_axes: frozenset[str] = frozenset()) -> Path:
    json_path = root / "dataset.json"
    if json_path.exists():
        existing = read_dataset(root, load_runs=False)
        if owner is not None:
            _check_owner(json_path, folder_owner(existing.extra), owner, len(existing.runs))
        merged_axes = dict(existing.machine.axes)
        for name, axis in machine.axes.items():
            if name in merged_axes and merged_axes[name] != axis and name not in replace_axes:
                raise AxisMismatchError(name, merged_axes[name], axis, len(existing.runs), source=str(json_path))
            merged_axes[name] = axis
        machine = replace(existing.machine, axes=merged_axes)
        listed = {r.spec.file for r in existing.runs}
        doc = load_dataset_json(json_path)
        run_docs = doc["runs"]
    else:
        root.mkdir(parents=True, exist_ok=True)
        listed, run_docs, doc = set(), [], {}
    if owner is not None and folder_owner(doc) is None:
        doc = {**doc, OWNER_KEY: dict(owner)}
    for run in runs:
        if run.spec.file in listed or (root / run.spec.file).exists():
            raise DatasetError(f"run file {run.spec.file!r} is already in the dataset", source=str(json_path))
        validate_run_spec(run.spec, machine)
        validate_columns(run.spec, run.columns)
        write_run_csv(root / run.spec.file, run.columns)
        run_docs.append(run_spec_to_json(run.spec))
        listed.add(run.spec.file)
    out = {k: v for k, v in doc.items() if k not in ("format", "machine", "runs")}
    new_doc = _ordered({"format": FORMAT, "machine": machine_to_json(machine), "runs": run_docs, **out})
    atomic_write_text(json_path, json.dumps(new_doc, indent=2) + "\n")
    return root


def next_run_name(folder: str | os.PathLike, stem: str) -> str:
    """A run file name ``<stem>_NN.csv`` neither in the folder (plain or compressed)
    nor listed in its ``dataset.json``. Unique among concurrent writers only when
    called and used under :func:`dataset_lock`."""
    root = Path(folder)
    listed: set[str] = set()
    with contextlib.suppress(DatasetError, OSError, KeyError, TypeError):
        listed = {str(r.get("file")) for r in load_dataset_json(root / "dataset.json")["runs"] if isinstance(r, dict)}
    i = 0
    while True:
        name = f"{stem}_{i:02d}.csv"
        if name not in listed and not (root / name).exists() and not (root / f"{name}.gz").exists():
            return name
        i += 1

"""The `mebm-dataset/1` data model (docs/dataset-format.md), pure and validated.

Files are read and written by ``storage.dataset``; this module holds the frozen
types and the checks that need no file system, so the simulator, the drivers and
the diagnosis all exchange the same validated objects.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from core.errors import DatasetError

FORMAT = "mebm-dataset/1"
RUN_KINDS = ("round_trip", "circle", "line")
SPLITS = ("train", "test")
AXIS_FIELDS = ("transmission_mm_per_rev", "screw_lead_mm", "position_gain_per_s", "travel_mm")
OPTIONAL_AXIS_FIELDS = ("screw_lead_mm", "position_gain_per_s")  # absent or null: not known
AXIS_FIELD_WORDS = {"transmission_mm_per_rev": ("transmission ratio k_a", "mm/rev"),
                    "screw_lead_mm": ("screw lead", "mm"), "position_gain_per_s": ("position-loop gain K", "1/s"),
                    "travel_mm": ("useful travel", "mm")}


def _shown(v) -> str:
    """A value as a person reads it in a message: a number with :g (never numpy's
    ``np.float64(...)`` repr), anything else as its repr."""
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        return f"{float(v):g}"
    return repr(v)


@dataclass(frozen=True)
class AxisSpec:
    """One axis of the machine: k_a (mm/rev), screw lead (mm), K (1/s), useful travel (mm).

    ``screw_lead_mm`` may be None (not known, as for a trace imported from a controller
    whose screw is not documented): it is the window of v_2π only, which is then not
    computed; the simulator and the gap diagnosis need it. ``position_gain_per_s`` may be
    None too (the drive's K not known): b̄, b(x) and the lead criteria do not need it; the
    TBE, the simulator and the gap diagnosis do, and say so."""

    name: str
    transmission_mm_per_rev: float
    screw_lead_mm: float | None
    position_gain_per_s: float | None
    travel_mm: tuple[float, float]
    extra: Mapping = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for key in ("transmission_mm_per_rev", "screw_lead_mm", "position_gain_per_s"):
            v = getattr(self, key)
            if key in OPTIONAL_AXIS_FIELDS and v is None:
                continue
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise DatasetError(f"axis {self.name!r}: {key} (={_shown(v)}) must be a number > 0")
        t = self.travel_mm
        if len(t) != 2 or not all(np.isfinite(t)) or not t[1] > t[0]:
            shown = ", ".join(_shown(x) for x in t)
            raise DatasetError(f"axis {self.name!r}: travel_mm (=[{shown}]) must be [start, end] with end > start")

    @property
    def travel_length_mm(self) -> float:
        return self.travel_mm[1] - self.travel_mm[0]


def axis_differences(old: AxisSpec, new: AxisSpec) -> list[str]:
    """How ``new`` differs from ``old``, one phrase per field in words and units
    (``"transmission ratio k_a (transmission_mm_per_rev): 10 mm/rev stored, 5 mm/rev given"``);
    empty when the two describe the same axis."""
    out = []
    for key in AXIS_FIELDS:
        a, b = getattr(old, key), getattr(new, key)
        if a == b:
            continue
        words, unit = AXIS_FIELD_WORDS[key]

        def shown(v, unit=unit):
            if v is None:
                return "not known"
            if isinstance(v, tuple):
                return f"{_shown(v[0])}..{_shown(v[1])} {unit}"
            return f"{_shown(v)} {unit}"

        out.append(f"{words} ({key}): {shown(a)} stored, {shown(b)} given")
    return out


@dataclass(frozen=True)
class MachineSpec:
    id: str
    axes: Mapping[str, AxisSpec]
    extra: Mapping = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class RunSpec:
    """One entry of ``runs`` in dataset.json. Unknown fields are kept in ``extra``."""

    file: str
    kind: str
    axes: tuple[str, ...]
    feed_mm_min: float
    temperature_c: float
    utility_day: float | None = None
    acceleration_mm_s2: float | None = None
    split: str | None = None
    radius_mm: float | None = None
    centre_mm: tuple[float, float] | None = None
    direction: str | None = None
    start_angle_deg: float | None = None
    sweep_deg: float | None = None
    angle_deg: float | None = None
    length_mm: float | None = None
    start_mm: tuple[float, ...] | None = None
    extra: Mapping = field(default_factory=dict, compare=False)

    @property
    def temperature_measured(self) -> bool:
        """Whether a thermometer read ``temperature_c``: not where the run says
        ``temperature_measured: false`` (an import without a temperature, a cycle whose
        sensor failed), which stores the reference 20 °C as a stand-in."""
        return self.extra.get("temperature_measured", True) is not False

    def columns_required(self) -> tuple[str, ...]:
        cols = ["time_s"]
        for a in self.axes:
            cols += [f"{a}_motor_rev", f"{a}_table_mm"]
        return tuple(cols)


@dataclass(frozen=True)
class Run:
    """A run's spec and its sample columns (each a float array, same length)."""

    spec: RunSpec
    columns: Mapping[str, np.ndarray]

    @property
    def time_s(self) -> np.ndarray:
        return self.columns["time_s"]

    def motor_rev(self, axis: str) -> np.ndarray:
        return self.columns[f"{axis}_motor_rev"]

    def table_mm(self, axis: str) -> np.ndarray:
        return self.columns[f"{axis}_table_mm"]

    def command_mm(self, axis: str) -> np.ndarray | None:
        return self.columns.get(f"{axis}_command_mm")

    def __len__(self) -> int:
        return int(self.time_s.shape[0])


@dataclass(frozen=True)
class Dataset:
    machine: MachineSpec
    runs: tuple[Run, ...]
    extra: Mapping = field(default_factory=dict, compare=False)

    def run(self, file: str) -> Run:
        for r in self.runs:
            if r.spec.file == file:
                return r
        raise DatasetError(f"no run {file!r} in dataset of machine {self.machine.id!r}")


def validate_run_spec(spec: RunSpec, machine: MachineSpec, *, source: str = "dataset.json") -> None:
    """Check a run's metadata against the machine; raise :class:`DatasetError` naming the run."""
    where = f"{source}: run {spec.file!r}"
    if spec.kind not in RUN_KINDS:
        raise DatasetError(f"{where}: kind (={spec.kind!r}) must be one of {RUN_KINDS}")
    if not spec.axes:
        raise DatasetError(f"{where}: axes is empty")
    for a in spec.axes:
        if a not in machine.axes:
            raise DatasetError(f"{where}: axis {a!r} is not in machine.axes {sorted(machine.axes)}")
    n_axes = 1 if spec.kind == "round_trip" else 2
    if len(spec.axes) != n_axes:
        raise DatasetError(f"{where}: a {spec.kind} run needs {n_axes} axis/axes, got {list(spec.axes)}")
    if not (np.isfinite(spec.feed_mm_min) and spec.feed_mm_min > 0):
        raise DatasetError(f"{where}: feed_mm_min (={_shown(spec.feed_mm_min)}) must be > 0")
    if not np.isfinite(spec.temperature_c):
        raise DatasetError(f"{where}: temperature_c (={_shown(spec.temperature_c)}) must be finite")
    if spec.split is not None and spec.split not in SPLITS:
        raise DatasetError(f"{where}: split (={spec.split!r}) must be one of {SPLITS}")
    if spec.kind == "circle":
        if spec.radius_mm is None or not spec.radius_mm > 0:
            raise DatasetError(f"{where}: a circle run needs radius_mm > 0")
        if spec.direction is not None and spec.direction not in ("cw", "ccw"):
            raise DatasetError(f"{where}: direction (={spec.direction!r}) must be 'cw' or 'ccw'")


def validate_columns(spec: RunSpec, columns: Mapping[str, np.ndarray]) -> None:
    """Check the samples of a run: required columns, equal lengths, finite, time increasing.

    Row numbers in errors count the CSV's data rows from 1 (the header is row 0).
    """
    src = spec.file
    for name in spec.columns_required():
        if name not in columns:
            raise DatasetError(f"missing column {name!r} (have {sorted(columns)})", source=src)
    lengths = {name: np.shape(col)[0] for name, col in columns.items()}
    if len(set(lengths.values())) != 1:
        raise DatasetError(f"columns differ in length: {lengths}", source=src)
    n = next(iter(lengths.values()))
    if n < 2:
        raise DatasetError(f"has {n} sample(s); a run needs at least 2", source=src)
    for name, col in columns.items():
        bad = ~np.isfinite(col)
        if bad.any():
            i = int(np.argmax(bad))
            what = "is not a number (nan)" if np.isnan(col[i]) else f"is infinite ({col[i]:g})"
            raise DatasetError(f"column {name} {what}: the sample was not read; remove the row or measure again",
                               source=src, row=i + 1)
    step = np.diff(columns["time_s"])
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise DatasetError(
            f"time_s not strictly increasing ({columns['time_s'][i - 1]:g} s then {columns['time_s'][i]:g} s)",
            source=src,
            row=i + 1,
        )

"""Runs of a dataset prepared for the gap diagnosis, and the train/test split.

A round trip becomes :class:`RoundTrip` (nut travel u = k_a x_m aligned to table
coordinates, table x, decimated fit indices); a circle or line becomes
:class:`Contour` (the commanded program rebuilt from the run's fields, samples aligned
to the program's time). :func:`choose_split` uses the runs' ``split`` or, when none is
given, holds out whole runs at the most extreme conditions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from core.dataset import Dataset, Run
from core.errors import InputError
from core.sim import circle as circle_program
from core.sim import line as line_program
from core.sim.programs import Program

MAX_FIT_SAMPLES = 8000  # per run, for the least-squares fits (the models run on all samples)


class GapError(InputError):
    """A dataset the gap diagnosis cannot work on (no test runs, a single run, unknown axis...)."""


@dataclass(frozen=True)
class RoundTrip:
    file: str
    axis: str
    split: str
    t_s: np.ndarray
    u_mm: np.ndarray  # k_a x_m, shifted so that it is close to table coordinates
    x_mm: np.ndarray  # table
    temperature_c: float
    feed_mm_min: float
    acceleration_mm_s2: float | None
    side0: int  # +1 if the first motion is positive
    fit_idx: np.ndarray
    command_mm: np.ndarray | None = None
    start: int = 0  # first sample compared: the table state before the first motion is unknown

    @property
    def dt_s(self) -> float:
        return float(np.median(np.diff(self.t_s)))


@dataclass(frozen=True)
class Contour:
    file: str
    kind: str  # circle | line
    axes: tuple[str, str]
    split: str
    t_s: np.ndarray  # program time of each sample
    table_mm: dict = field(repr=False)  # axis -> table positions
    program: Program = field(repr=False)
    temperature_c: float = 20.0
    feed_mm_min: float = 0.0
    acceleration_mm_s2: float | None = None
    fit_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    rate_hz: float = 500.0
    meta: dict = field(default_factory=dict)

    def deviation_um(self, pos: dict) -> np.ndarray:
        """Contour error of positions ``pos`` (axis -> mm): radial deviation for a circle,
        perpendicular deviation for a line (µm)."""
        a, b = self.axes
        if self.kind == "circle":
            cx, cy = self.meta["centre_mm"]
            return (np.hypot(pos[a] - cx, pos[b] - cy) - self.meta["radius_mm"]) * 1e3
        th = math.radians(self.meta["angle_deg"])
        x0, y0 = self.meta["start_mm"]
        return (-(pos[a] - x0) * math.sin(th) + (pos[b] - y0) * math.cos(th)) * 1e3

    def angle_deg(self) -> np.ndarray:
        """Angle of each measured sample about the centre (circle) or distance along (line)."""
        a, b = self.axes
        if self.kind == "circle":
            cx, cy = self.meta["centre_mm"]
            return np.degrees(np.arctan2(self.table_mm[b] - cy, self.table_mm[a] - cx)) % 360.0
        th = math.radians(self.meta["angle_deg"])
        x0, y0 = self.meta["start_mm"]
        return (self.table_mm[a] - x0) * math.cos(th) + (self.table_mm[b] - y0) * math.sin(th)


def _fit_idx(n: int) -> np.ndarray:
    step = max(1, int(math.ceil(n / MAX_FIT_SAMPLES)))
    return np.arange(0, n, step)


def _first_direction(u: np.ndarray) -> int:
    span = float(np.ptp(u))
    d = u - u[0]
    moved = np.flatnonzero(np.abs(d) > 0.05 * span)
    return 1 if moved.size == 0 or d[moved[0]] > 0 else -1


def prepare_round_trip(run: Run, axis_spec, split: str) -> RoundTrip:
    a = run.spec.axes[0]
    m = np.asarray(run.motor_rev(a), float)
    x = np.asarray(run.table_mm(a), float)
    u = m * axis_spec.transmission_mm_per_rev
    if float(np.ptp(u)) < 1.0:
        raise GapError(f"round trip {run.spec.file!r}: the motor of axis {a!r} moves {np.ptp(u):.3f} mm (< 1 mm)")
    u = u + float(np.median(x - u))
    cmd = run.command_mm(a)
    # compare from the first engagement on: before it, the table's place in the backlash
    # depends on the unrecorded history
    moved_u = np.abs(u - u[0]) > 0.5
    moved_x = np.abs(x - x[0]) > 0.005
    k = np.flatnonzero(moved_u & (np.maximum.accumulate(moved_x)))
    start = int(k[0]) if k.size else 0
    idx = _fit_idx(u.size - start) + start
    return RoundTrip(
        file=run.spec.file, axis=a, split=split, t_s=np.asarray(run.time_s, float), u_mm=u, x_mm=x,
        temperature_c=float(run.spec.temperature_c), feed_mm_min=float(run.spec.feed_mm_min),
        acceleration_mm_s2=run.spec.acceleration_mm_s2, side0=_first_direction(u), fit_idx=idx,
        command_mm=None if cmd is None else np.asarray(cmd, float), start=start,
    )


def _program_of(run: Run) -> Program:
    s = run.spec
    if s.kind == "circle":
        return circle_program(
            s.radius_mm, tuple(s.centre_mm or (0.0, 0.0)), s.feed_mm_min, s.direction or "ccw",
            -90.0 if s.start_angle_deg is None else s.start_angle_deg,
            360.0 if s.sweep_deg is None else s.sweep_deg,
            axes=tuple(s.axes), acceleration_mm_s2=s.acceleration_mm_s2,
        )  # fmt: skip
    if s.angle_deg is None or s.length_mm is None:
        raise GapError(f"line run {s.file!r} needs angle_deg and length_mm")
    return line_program(s.angle_deg, s.length_mm, s.feed_mm_min, tuple(s.start_mm or (0.0, 0.0)), axes=tuple(s.axes))


def _align_time(run: Run, prog: Program) -> np.ndarray:
    """Program time of each sample: the recorded time, shifted so that the recorded
    commands match the program's (a controller's clock has its own zero)."""
    t = np.asarray(run.time_s, float)
    cols = [run.command_mm(a) for a in run.spec.axes]
    if any(c is None for c in cols):
        return t
    # shift search: coarse grid over one tenth of the run, then parabolic refinement
    sel = _fit_idx(t.size)[:: max(1, t.size // 400)]
    rec = np.stack([np.asarray(c, float)[sel] for c in cols])

    def cost(d):
        return float(np.sum((prog.positions(t[sel] + d) - rec) ** 2))

    if cost(0.0) < 1e-10 * sel.size:
        return t
    span = 0.1 * (t[-1] - t[0]) + 2.0
    grid = np.linspace(-span, span, 401)
    costs = np.array([cost(d) for d in grid])
    k = int(np.argmin(costs))
    d = grid[k]
    if 0 < k < grid.size - 1:
        c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
        den = c0 - 2 * c1 + c2
        if den > 0:
            d += 0.5 * (c0 - c2) / den * (grid[1] - grid[0])
    return t + d


def prepare_contour(run: Run, split: str) -> Contour:
    prog = _program_of(run)
    t = _align_time(run, prog)
    dt = float(np.median(np.diff(t)))
    s = run.spec
    meta = {"radius_mm": s.radius_mm, "centre_mm": tuple(s.centre_mm or (0.0, 0.0)),
            "angle_deg": s.angle_deg, "start_mm": tuple(s.start_mm or (0.0, 0.0))}  # fmt: skip
    return Contour(
        file=s.file, kind=s.kind, axes=tuple(s.axes), split=split, t_s=t,
        table_mm={a: np.asarray(run.table_mm(a), float) for a in s.axes}, program=prog,
        temperature_c=float(s.temperature_c), feed_mm_min=float(s.feed_mm_min),
        acceleration_mm_s2=s.acceleration_mm_s2, fit_idx=_fit_idx(t.size),
        rate_hz=min(1000.0, 1.0 / dt), meta=meta,
    )  # fmt: skip


@dataclass(frozen=True)
class Split:
    train: tuple[str, ...]
    test: tuple[str, ...]
    how: str  # "given" or a sentence saying which runs were held out and why


def choose_split(dataset: Dataset) -> Split:
    """The runs' ``split`` when any run has one; else hold out whole runs at the most
    extreme condition (temperature, then feed) per kind, never random samples."""
    runs = dataset.runs
    if len(runs) < 2:
        raise GapError(f"the dataset has {len(runs)} run(s); a diagnosis needs at least 2 (one to fit, one to test)")
    if any(r.spec.split is not None for r in runs):
        train = tuple(r.spec.file for r in runs if r.spec.split != "test")
        test = tuple(r.spec.file for r in runs if r.spec.split == "test")
        if not test:
            raise GapError("no run has split 'test': mark the runs the diagnosis must predict, or drop 'split'")
        if not train:
            raise GapError("every run has split 'test': at least one run must be 'train'")
        return Split(train, test, "given by the runs' split fields")
    test: list[str] = []
    reasons = []
    groups: dict[tuple, list[Run]] = {}
    for r in runs:
        groups.setdefault((r.spec.kind, r.spec.axes if r.spec.kind == "round_trip" else ()), []).append(r)
    for (kind, _), rs in groups.items():
        if len(rs) < 2:
            continue
        temps = np.array([r.spec.temperature_c for r in rs])
        feeds = np.array([r.spec.feed_mm_min for r in rs])
        if np.ptp(temps) > 0.5:
            dev = np.abs(temps - np.median(temps))
            what = "temperature"
            vals = temps
        else:
            dev = np.abs(np.log(feeds) - np.median(np.log(feeds)))
            what = "feed"
            vals = feeds
        n_out = max(1, len(rs) // 4)
        order = np.argsort(-dev, kind="stable")[:n_out]
        for i in order:
            test.append(rs[i].spec.file)
        unit = "°C" if what == "temperature" else " mm/min"
        reasons.append(
            f"{kind} {', '.join(rs[i].spec.file for i in order)} (most extreme {what}: "
            f"{', '.join(f'{vals[i]:g}{unit}' for i in order)})"
        )
    if not test:
        raise GapError("cannot hold out a run: every kind of run has a single run (need two of a kind)")
    train = tuple(r.spec.file for r in runs if r.spec.file not in test)
    return Split(train, tuple(test), "held out by the diagnosis: " + "; ".join(reasons))

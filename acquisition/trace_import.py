"""Controller scope traces (CSV) into mebm runs: the trace-import profile and the reader.

Controllers' own trace tools (servo trace, oscilloscope functions) export a recorded round
trip as a CSV with their own column names, units, separators and a preamble. A profile
(TOML, ``format = "mebm-trace-profile/1"``, see docs/controllers.md) says where each value
is and in which unit; :func:`read_trace` turns a file into the columns of a mebm run
(``time_s``, ``<a>_motor_rev``, ``<a>_table_mm``, optional ``<a>_command_mm`` and
``temperature_c``). Nothing is guessed: a value that is not a number, a time that does not
increase, a column that is not there, each is a :class:`TraceImportError` naming the file,
the line (as an editor counts it) and the column. No sample is dropped or interpolated.

:func:`steady_feed_mm_min` reads the feed a round trip ran at from its positions (the
strokes' steady speed), for a trace whose programmed feed the user does not have.

Vendors' binary formats are not read: export CSV from the tool.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.files import MIB, FileRefused, open_regular
from core.errors import InputError

FORMAT = "mebm-trace-profile/1"
MAX_TRACE_BYTES = 512 * MIB  # a trace file larger than this is refused before it is read
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
LINEAR_UNITS = {"mm": 1.0, "um": 1e-3, "nm": 1e-6, "m": 1e3, "in": 25.4}
ROTARY_UNITS = {"rev": 1.0, "deg": 1.0 / 360.0, "rad": 1.0 / (2.0 * math.pi)}
TEMPERATURE_UNITS = ("degC", "K")


class TraceImportError(InputError):
    """A trace file or a trace-import profile is unusable; the message says where."""


@dataclass(frozen=True)
class ColumnSpec:
    """One value of the trace: the file's column ``name``, its ``unit``, and a linear map
    ``(raw * scale + offset)`` applied before the unit (counts to the unit, a zero shift)."""

    target: str  # time_s, <a>_motor_rev, <a>_table_mm, <a>_command_mm, temperature_c
    name: str
    unit: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class TraceProfile:
    columns: tuple[ColumnSpec, ...]
    delimiter: str = ","
    decimal: str = "."
    header_line: int = 1  # 1-based line of the column names; lines before are the tool's preamble
    encoding: str = "utf-8"
    transmission_mm_per_rev: Mapping[str, float] = field(default_factory=dict)  # for motor positions given in mm


def _target_kind(target: str, axes: tuple[str, ...]) -> str:
    if target in ("time_s", "temperature_c"):
        return target
    for a in axes:
        for kind in ("motor_rev", "table_mm", "command_mm"):
            if target == f"{a}_{kind}":
                return kind
    raise TraceImportError(f"columns.{target}: not a run column (time_s, temperature_c, or <axis>_motor_rev, "
                           f"<axis>_table_mm, <axis>_command_mm for the axes {list(axes)})")  # fmt: skip


def parse_profile(doc: Mapping, axes: tuple[str, ...], transmission_mm_per_rev: Mapping[str, float] | None = None,
                  src: str = "profile") -> TraceProfile:  # fmt: skip
    """The ``[csv]`` and ``[columns]`` tables of a profile, checked; errors name the field."""
    if doc.get("format", FORMAT) != FORMAT:
        raise TraceImportError(f"{src}: format (={doc.get('format')!r}) must be {FORMAT!r}")
    c = doc.get("csv", {})
    if not isinstance(c, Mapping):
        raise TraceImportError(f"{src}: [csv] must be a table")
    delimiter = str(c.get("delimiter", ","))
    decimal = str(c.get("decimal", "."))
    if len(delimiter) != 1 or delimiter in ".\"\n\r":
        raise TraceImportError(f"{src}: csv.delimiter (={delimiter!r}) must be one character such as ',', ';' or '\\t'")
    if decimal not in (".", ","):
        raise TraceImportError(f"{src}: csv.decimal (={decimal!r}) must be '.' or ','")
    if decimal == delimiter:
        raise TraceImportError(f"{src}: csv.decimal and csv.delimiter are both {decimal!r}")
    header_line = c.get("header_line", 1)
    if not isinstance(header_line, int) or isinstance(header_line, bool) or header_line < 1:
        raise TraceImportError(f"{src}: csv.header_line (={header_line!r}) must be a line number >= 1")
    cols = doc.get("columns")
    if not isinstance(cols, Mapping) or not cols:
        raise TraceImportError(f"{src}: [columns] must map run columns to the file's columns")
    specs = []
    ka = dict(transmission_mm_per_rev or {})
    for target, spec in cols.items():
        kind = _target_kind(target, axes)
        if not isinstance(spec, Mapping) or not isinstance(spec.get("name"), str) or not spec["name"]:
            raise TraceImportError(f"{src}: columns.{target}.name must be the column's name in the file")
        unit = spec.get("unit")
        allowed = {"time_s": TIME_UNITS, "temperature_c": TEMPERATURE_UNITS, "motor_rev": (*ROTARY_UNITS, "mm"),
                   "table_mm": LINEAR_UNITS, "command_mm": LINEAR_UNITS}[kind]  # fmt: skip
        if unit not in allowed:
            raise TraceImportError(f"{src}: columns.{target}.unit (={unit!r}) must be one of {list(allowed)}")
        if kind == "motor_rev" and unit == "mm":
            axis = target[: -len("_motor_rev")]
            if not ka.get(axis, 0) > 0:
                raise TraceImportError(f"{src}: columns.{target} is in mm of nominal travel, which needs the axis' "
                                       "transmission_mm_per_rev")  # fmt: skip
        try:
            scale, offset = float(spec.get("scale", 1.0)), float(spec.get("offset", 0.0))
        except (TypeError, ValueError) as exc:
            raise TraceImportError(f"{src}: columns.{target}.scale and .offset must be numbers") from exc
        if not (math.isfinite(scale) and scale != 0 and math.isfinite(offset)):
            raise TraceImportError(f"{src}: columns.{target}.scale (={scale!r}) must be finite and not 0, "
                                   f"offset (={offset!r}) finite")  # fmt: skip
        specs.append(ColumnSpec(target, spec["name"], unit, scale, offset))
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise TraceImportError(f"{src}: the file column(s) {dup} are mapped to more than one run column")
    need = ["time_s"] + [f"{a}_{k}" for a in axes for k in ("motor_rev", "table_mm")]
    missing = [t for t in need if t not in {s.target for s in specs}]
    if missing:
        raise TraceImportError(f"{src}: [columns] lacks {missing}")
    return TraceProfile(tuple(specs), delimiter, decimal, header_line, str(c.get("encoding", "utf-8")), ka)


def _convert(spec: ColumnSpec, raw: np.ndarray, profile: TraceProfile) -> np.ndarray:
    v = raw * spec.scale + spec.offset
    if spec.target == "time_s":
        return v * TIME_UNITS[spec.unit]
    if spec.target == "temperature_c":
        return v - 273.15 if spec.unit == "K" else v
    if spec.target.endswith("_motor_rev"):
        if spec.unit == "mm":
            return v / profile.transmission_mm_per_rev[spec.target[: -len("_motor_rev")]]
        return v * ROTARY_UNITS[spec.unit]
    return v * LINEAR_UNITS[spec.unit]


def read_trace(path: str | Path, profile: TraceProfile) -> dict[str, np.ndarray]:
    """The run columns of the trace file ``path`` (see the module docstring)."""
    path = Path(path)
    src = str(path)
    try:  # a regular file of bounded size only: a FIFO or /dev/zero is refused, not read forever
        f = open_regular(path, MAX_TRACE_BYTES, "trace file", encoding=profile.encoding, newline="")
    except FileRefused as exc:
        raise TraceImportError(str(exc)) from exc
    except LookupError as exc:
        raise TraceImportError(f"csv.encoding (={profile.encoding!r}) is not a known encoding") from exc
    with f:
        try:
            lines = iter(f)
            for _ in range(profile.header_line - 1):
                if next(lines, None) is None:
                    raise TraceImportError(f"{src}: ends before its header line {profile.header_line}")
            reader = csv.reader(lines, delimiter=profile.delimiter)
            header = next(reader, None)
            if header is None:
                raise TraceImportError(f"{src}: ends before its header line {profile.header_line}")
            header = [h.strip().lstrip("\ufeff") for h in header]
            idx = {}
            for spec in profile.columns:
                if spec.name not in header:
                    raise TraceImportError(f"{src}, line {profile.header_line}: no column {spec.name!r} "
                                           f"(for {spec.target}); the header has {header}"
                                           + layout_hint(path, profile))  # fmt: skip
                idx[spec.target] = header.index(spec.name)
            cols: dict[str, list[float]] = {t: [] for t in idx}
            width = max(idx.values()) + 1
            for row in reader:
                line = reader.line_num + profile.header_line - 1
                if not row or all(not c.strip() for c in row):
                    continue  # a blank line (many tools end the file with one)
                if len(row) < width:
                    raise TraceImportError(f"{src}, line {line}: {len(row)} field(s), the mapped columns need "
                                           f"{width}")  # fmt: skip
                for t, i in idx.items():
                    cell = row[i].strip()
                    if profile.decimal == ",":
                        cell = cell.replace(",", ".")
                    try:
                        x = float(cell)
                    except ValueError:
                        x = math.nan
                    if not math.isfinite(x):
                        hint = ""
                        if profile.decimal == "." and _is_number(cell.replace(",", ".")):
                            hint = "; the file writes decimal commas: set csv.decimal = ','"
                        raise TraceImportError(f"{src}, line {line}, column {header[i]!r}: {row[i]!r} is not a "
                                               "finite number (no sample is dropped or filled in: fix or cut the "
                                               f"file){hint}")  # fmt: skip
                    cols[t].append(x)
        except UnicodeDecodeError as exc:
            raise TraceImportError(f"{src}: not {profile.encoding} text ({exc.reason}); set csv.encoding"
                                   + (" = 'latin-1' (or 'cp1252')" if profile.encoding.lower().replace("-", "")
                                      == "utf8" else "")) from exc  # fmt: skip
        except csv.Error as exc:
            raise TraceImportError(f"{src}, line {reader.line_num + profile.header_line - 1}: {exc}") from exc
    n = len(cols["time_s"])
    if n < 2:
        raise TraceImportError(f"{src}: {n} sample(s) after the header; a round trip needs many")
    out = {t: _convert(next(s for s in profile.columns if s.target == t), np.asarray(v, dtype=float), profile)
           for t, v in cols.items()}  # fmt: skip
    step = np.diff(out["time_s"])
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        line = _data_line(path, profile, i)
        raise TraceImportError(f"{src}, line {line}: time does not increase ({out['time_s'][i - 1]!r} s, then "
                               f"{out['time_s'][i]!r} s)")  # fmt: skip
    out["time_s"] = out["time_s"] - out["time_s"][0]
    return out


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


LAYOUT_SCAN_LINES = 50  # how far into a file a header line is looked for


def layout_hint(path: Path, profile: TraceProfile) -> str:
    """Where the file has all the profile's column names, as the ``[csv]`` settings that
    would read them (``"; line 4 has all the profile's columns: csv.header_line = 4,
    csv.delimiter = '\\t' read(s) it"``);
    empty when no line within the first :data:`LAYOUT_SCAN_LINES` has them."""
    names = [c.name for c in profile.columns]
    encodings = list(dict.fromkeys([profile.encoding, "utf-8", "cp1252"]))
    delimiters = list(dict.fromkeys([profile.delimiter, "\t", ";", ","]))
    for enc in encodings:
        try:
            with path.open("rb") as f:
                head = f.read(1 << 16)
            lines = head[: head.rfind(b"\n") + 1 or None].decode(enc).splitlines()[:LAYOUT_SCAN_LINES]
        except (OSError, UnicodeDecodeError, LookupError):
            continue
        for delim in delimiters:
            for n, text in enumerate(lines, start=1):
                cells = [c.strip().strip('"').lstrip("\ufeff") for c in text.split(delim)]
                if all(name in cells for name in names):
                    settings = [(key, value, now) for key, value, now in (
                        ("header_line", n, profile.header_line), ("delimiter", delim, profile.delimiter),
                        ("encoding", enc, profile.encoding)) if value != now]  # fmt: skip
                    if not settings:
                        return ""
                    shown = ", ".join(f"csv.{k} = {v!r}" for k, v, _ in settings)
                    return f"; line {n} has all the profile's columns: {shown} read(s) it"
    return ""


def _data_line(path: Path, profile: TraceProfile, index: int) -> int:
    """The line number of the ``index``-th data row (0-based), blank lines skipped."""
    with path.open(encoding=profile.encoding, newline="") as f:
        lines = iter(f)
        for _ in range(profile.header_line - 1):
            next(lines, None)
        reader = csv.reader(lines, delimiter=profile.delimiter)
        next(reader, None)
        k = -1
        for row in reader:
            if row and any(c.strip() for c in row):
                k += 1
                if k == index:
                    return reader.line_num + profile.header_line - 1
    return -1


@dataclass(frozen=True)
class SteadyFeed:
    """The feed a round trip ran at, read from its positions: each stroke's steady speed
    (mm/min, the slope of a straight line through the middle of its constant-speed part)
    and their mean."""

    feed_mm_min: float
    stroke_speeds_mm_min: tuple[float, float]  # the positive stroke's, then the negative's


def steady_feed_mm_min(time_s: np.ndarray, position_mm: np.ndarray, src: str = "trace") -> SteadyFeed:
    """The feed of a round trip from its table positions (see :class:`SteadyFeed`).

    A stroke's constant-speed part is where its speed, averaged over 20 ms, is within 5 %
    of the stroke's top speed; the middle 80 % of the longest such stretch is fitted. A
    trace without two opposite strokes of constant speed is refused: the feed is then
    to be given."""
    from scipy.ndimage import uniform_filter1d

    t, x = np.asarray(time_s, dtype=float), np.asarray(position_mm, dtype=float)
    advice = "give the programmed feed with --feed-mm-min or the profile's run.feed_mm_min"
    if t.size < 20:
        raise TraceImportError(f"{src}: {t.size} samples are too few to read the feed from; {advice}")
    dt = float(np.median(np.diff(t)))
    v = uniform_filter1d(np.gradient(x, t), size=max(1, round(0.02 / dt)), mode="nearest")
    tops = {sign: float(np.percentile(sign * v, 99.5)) for sign in (1.0, -1.0)}
    speeds = []
    for sign, name in ((1.0, "positive"), (-1.0, "negative")):
        sv, top = sign * v, tops[sign]
        if not top > 0.5 * max(tops.values()):  # noise on a still axis is not a stroke
            raise TraceImportError(f"{src}: no {name} stroke to read the feed from (the trace is not a round "
                                   f"trip: its {name} speed stays below {max(top, 0.0) * 60.0:.0f} mm/min); "
                                   f"{advice}")  # fmt: skip
        steady = np.concatenate(([False], sv >= 0.95 * top, [False]))
        edges = np.flatnonzero(np.diff(steady.astype(np.int8)))
        starts, ends = edges[::2], edges[1::2]
        k = int(np.argmax(ends - starts))
        i0, i1 = int(starts[k]), int(ends[k])
        cut = (i1 - i0) // 10
        i0, i1 = i0 + cut, i1 - cut
        if i1 - i0 < 10 or t[i1 - 1] - t[i0] < 0.1:
            raise TraceImportError(f"{src}: the {name} stroke has no stretch of constant speed of 0.1 s or more "
                                   f"to read the feed from (its top speed is {top * 60.0:.0f} mm/min); "
                                   f"{advice}")  # fmt: skip
        slope = np.polyfit(t[i0:i1] - t[i0], x[i0:i1], 1)[0]
        speeds.append(abs(float(slope)) * 60.0)
    return SteadyFeed(float(np.mean(speeds)), (speeds[0], speeds[1]))

"""Exported circular tests (CSV) into mebm: the circle-import profile and the readers.

A profile (TOML, ``format = "mebm-circle-profile/1"``, docs/controllers.md) says how an
export is laid out; :func:`read_circle` turns a file into a :class:`core.circle.CircularTest`.
Two layouts:

- ``layout = "radial"``: a ballbar's export, the radial deviation against the angle, both
  directions. The direction is either a column whose values the profile names
  (``direction = {name = "Dir", ccw = "CCW", cw = "CW"}``) or each direction has its own
  columns (``[columns.ccw]``, ``[columns.cw]``; the shorter group may end in blank cells).
  The rows are in the order the machine ran them.
- ``layout = "positions"``: a trace tool's export, both axes' positions against time,
  holding one circle per direction. Each circle is found about the profile's centre (the
  samples on the circle, turning one way); its start from rest is left out (the arc of the
  first second at the feed, or ``test.lead_in_deg``, extended to midway between quadrant
  points, as mebm's own circle program does) and the next 360° kept.

As in the drive-trace import nothing is guessed, dropped or filled in: a value that is
not a number, a direction value the profile does not name, a direction the test needs
and the file lacks, values whose size says the unit is wrong, an arc that does not cover
the circle: each is a :class:`CircleImportError` naming the file, the line and column or
the profile's field, and the value that fixes it where one can be read from the file.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.circle import MIN_LEAD_IN_DEG, lead_in_deg
from acquisition.files import MIB, FileRefused, open_regular
from acquisition.trace_import import LINEAR_UNITS, TIME_UNITS, ColumnSpec, TraceProfile, layout_hint
from core.circle import DIRECTIONS, CircularTest, Instrument, pass_from_positions
from core.circle.test import CirclePass
from core.errors import InputError

FORMAT = "mebm-circle-profile/1"
LAYOUTS = ("radial", "positions")
MAX_CIRCLE_BYTES = 256 * MIB
ANGLE_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi, "grad": 0.9}
DEVIATION_UNITS = {"um": 1.0, "mm": 1e3, "nm": 1e-3, "in": 25400.0}
#: How far a sample may be off the nominal radius to count as on the circle (positions layout).
ON_CIRCLE_FRACTION = 0.02
#: The start-up left out of each circle of a positions export, unless test.lead_in_deg says.
LEAD_IN_S = 1.0


class CircleImportError(InputError):
    """An exported circular test or a circle-import profile is unusable; the message says where."""


@dataclass(frozen=True)
class Column:
    """A value of the file: its column ``name``, ``unit`` and ``raw * scale + offset``."""

    name: str
    unit: str
    scale: float = 1.0
    offset: float = 0.0

    def convert(self, raw: np.ndarray, units: Mapping[str, float]) -> np.ndarray:
        return (raw * self.scale + self.offset) * units[self.unit]


@dataclass(frozen=True)
class CircleProfile:
    layout: str
    delimiter: str = ","
    decimal: str = "."
    header_line: int = 1
    encoding: str = "utf-8"
    # radial: {"ccw"/"cw"/"all": {"angle": Column, "deviation": Column}}; positions: {"all": {time, first, second}}
    groups: Mapping[str, Mapping[str, Column]] = field(default_factory=dict)
    direction_column: str | None = None
    direction_values: Mapping[str, str] = field(default_factory=dict)  # "ccw"/"cw" -> the file's text
    test: Mapping = field(default_factory=dict)  # radius_mm, feed_mm_min, plane, directions, centre_mm, ...
    instrument: Instrument | None = None

    def names(self) -> list[str]:
        out = [c.name for g in self.groups.values() for c in g.values()]
        return out + ([self.direction_column] if self.direction_column else [])


def _column(spec, where: str, units) -> Column:
    if not isinstance(spec, Mapping) or not isinstance(spec.get("name"), str) or not spec["name"]:
        raise CircleImportError(f"{where}.name must be the column's name in the file")
    unit = spec.get("unit")
    if unit not in units:
        raise CircleImportError(f"{where}.unit (={unit!r}) must be one of {list(units)}")
    try:
        scale, offset = float(spec.get("scale", 1.0)), float(spec.get("offset", 0.0))
    except (TypeError, ValueError) as exc:
        raise CircleImportError(f"{where}.scale and .offset must be numbers") from exc
    if not (math.isfinite(scale) and scale != 0 and math.isfinite(offset)):
        raise CircleImportError(f"{where}.scale (={scale!r}) must be finite and not 0, offset (={offset!r}) finite")
    return Column(spec["name"], unit, scale, offset)


def parse_profile(doc: Mapping, src: str = "profile") -> CircleProfile:
    """A circle-import profile, checked; errors name the field."""
    if doc.get("format") != FORMAT:
        raise CircleImportError(f"{src}: format (={doc.get('format')!r}) must be {FORMAT!r}")
    layout = doc.get("layout")
    if layout not in LAYOUTS:
        raise CircleImportError(f"{src}: layout (={layout!r}) must be 'radial' (angle and radial deviation, a "
                                "ballbar's export) or 'positions' (both axes against time, a trace tool's export)")
    c = doc.get("csv", {})
    if not isinstance(c, Mapping):
        raise CircleImportError(f"{src}: [csv] must be a table")
    delimiter, decimal = str(c.get("delimiter", ",")), str(c.get("decimal", "."))
    if len(delimiter) != 1 or delimiter in ".\"\n\r":
        raise CircleImportError(f"{src}: csv.delimiter (={delimiter!r}) must be one character such as ',', ';' or "
                                "'\\t'")
    if decimal not in (".", ",") or decimal == delimiter:
        raise CircleImportError(f"{src}: csv.decimal (={decimal!r}) must be '.' or ',' and not the delimiter")
    header_line = c.get("header_line", 1)
    if not isinstance(header_line, int) or isinstance(header_line, bool) or header_line < 1:
        raise CircleImportError(f"{src}: csv.header_line (={header_line!r}) must be a line number >= 1")
    cols = doc.get("columns")
    if not isinstance(cols, Mapping) or not cols:
        raise CircleImportError(f"{src}: [columns] must say where the values are")
    groups: dict[str, dict[str, Column]] = {}
    direction_column, direction_values = None, {}
    if layout == "radial":
        units = {"angle": ANGLE_UNITS, "deviation": DEVIATION_UNITS}
        if any(d in cols for d in DIRECTIONS):
            extra = sorted(set(cols) - set(DIRECTIONS))
            if extra:
                raise CircleImportError(f"{src}: [columns] has direction groups [columns.ccw]/[columns.cw] and also "
                                        f"{extra}: use one or the other")
            for d in DIRECTIONS:
                if d in cols:
                    g = cols[d]
                    if not isinstance(g, Mapping):
                        raise CircleImportError(f"{src}: [columns.{d}] must be a table with angle and deviation")
                    groups[d] = {k: _column(g.get(k), f"{src}: columns.{d}.{k}", units[k]) for k in units}
        else:
            groups["all"] = {k: _column(cols.get(k), f"{src}: columns.{k}", units[k]) for k in units}
            dspec = cols.get("direction")
            if not isinstance(dspec, Mapping) or not isinstance(dspec.get("name"), str) or not dspec["name"]:
                raise CircleImportError(f"{src}: columns.direction = {{name = ..., ccw = ..., cw = ...}} must name the "
                                        "column that says each row's direction, or give each direction its own "
                                        "columns ([columns.ccw], [columns.cw])")
            direction_column = dspec["name"]
            for d in DIRECTIONS:
                v = dspec.get(d)
                if v is not None and (not isinstance(v, str) or not v.strip()):
                    raise CircleImportError(f"{src}: columns.direction.{d} (={v!r}) must be the text the file writes")
                direction_values[d] = (v if v is not None else d).strip()
            if direction_values["ccw"].lower() == direction_values["cw"].lower():
                raise CircleImportError(f"{src}: columns.direction.ccw and .cw are both {direction_values['cw']!r}")
    else:
        spec = {"time": TIME_UNITS, "first": LINEAR_UNITS, "second": LINEAR_UNITS}
        extra = sorted(set(cols) - set(spec))
        if extra:
            raise CircleImportError(f"{src}: columns {extra}: the positions layout takes time, first and second")
        groups["all"] = {k: _column(cols.get(k), f"{src}: columns.{k}", u) for k, u in spec.items()}
    names = [col.name for g in groups.values() for col in g.values()]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise CircleImportError(f"{src}: the file column(s) {dup} are mapped to more than one value")
    test = doc.get("test", {})
    if not isinstance(test, Mapping):
        raise CircleImportError(f"{src}: [test] must be a table")
    ins = doc.get("instrument")
    instrument = None
    if ins is not None:
        if not isinstance(ins, Mapping):
            raise CircleImportError(f"{src}: [instrument] must be a table (kind, resolution_um, accuracy_um, name)")
        try:
            instrument = Instrument(kind=str(ins.get("kind", "ballbar" if layout == "radial" else "trace")),
                                    resolution_um=ins.get("resolution_um", -1.0),
                                    accuracy_um=ins.get("accuracy_um", 0.0), name=str(ins.get("name", "")))
        except InputError as exc:
            raise CircleImportError(f"{src}: {exc} (e.g. resolution_um = 0.1 for a ballbar of 0.1 µm "
                                    "resolution)") from None
    return CircleProfile(layout, delimiter, decimal, header_line, str(c.get("encoding", "utf-8")), groups,
                         direction_column, direction_values, dict(test), instrument)


@dataclass(frozen=True)
class Table:
    """The mapped columns of a file: each column's cells (text, stripped) and each row's line."""

    header: list[str]
    cells: dict[str, list[str]]
    lines: list[int]


def read_table(path: Path, profile: CircleProfile) -> Table:
    src = str(path)
    try:
        f = open_regular(path, MAX_CIRCLE_BYTES, "circle file", encoding=profile.encoding, newline="")
    except FileRefused as exc:
        raise CircleImportError(str(exc)) from exc
    except LookupError as exc:
        raise CircleImportError(f"csv.encoding (={profile.encoding!r}) is not a known encoding") from exc
    names = profile.names()
    with f:
        try:
            lines = iter(f)
            for _ in range(profile.header_line - 1):
                if next(lines, None) is None:
                    raise CircleImportError(f"{src}: ends before its header line {profile.header_line}")
            reader = csv.reader(lines, delimiter=profile.delimiter)
            header = next(reader, None)
            if header is None:
                raise CircleImportError(f"{src}: ends before its header line {profile.header_line}")
            header = [h.strip().lstrip("\ufeff") for h in header]
            idx = {}
            for name in names:
                if name not in header:
                    hint = layout_hint(path, _as_trace_profile(profile))
                    raise CircleImportError(f"{src}, line {profile.header_line}: no column {name!r}; the header has "
                                            f"{header}{hint}")
                idx[name] = header.index(name)
            cells: dict[str, list[str]] = {n: [] for n in names}
            rows: list[int] = []
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue
                line = reader.line_num + profile.header_line - 1
                rows.append(line)
                for n, i in idx.items():
                    cells[n].append(row[i].strip() if i < len(row) else "")
        except UnicodeDecodeError as exc:
            raise CircleImportError(f"{src}: not {profile.encoding} text ({exc.reason}); set csv.encoding"
                                    + (" = 'latin-1' (or 'cp1252')" if profile.encoding.lower().replace("-", "")
                                       == "utf8" else "")) from exc
        except csv.Error as exc:
            raise CircleImportError(f"{src}, line {reader.line_num + profile.header_line - 1}: {exc}") from exc
    return Table(header, cells, rows)


def _as_trace_profile(p: CircleProfile) -> TraceProfile:
    """The profile as the drive-trace reader's, for its header-layout hint."""
    return TraceProfile(tuple(ColumnSpec("time_s", n, "s") for n in p.names()), p.delimiter, p.decimal,
                        p.header_line, p.encoding)


def _numbers(src: str, table: Table, column: Column, profile: CircleProfile, rows: np.ndarray,
             units: Mapping[str, float]) -> np.ndarray:
    out = np.empty(rows.size)
    for k, i in enumerate(rows):
        cell = table.cells[column.name][i]
        text = cell.replace(",", ".") if profile.decimal == "," else cell
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        if not math.isfinite(x):
            hint = ""
            if profile.decimal == "." and "," in cell and _is_number(cell.replace(",", ".")):
                hint = "; the file writes decimal commas: set csv.decimal = ','"
            raise CircleImportError(f"{src}, line {table.lines[i]}, column {column.name!r}: {cell!r} is not a finite "
                                    f"number (no sample is dropped or filled in: fix or cut the file){hint}")
        out[k] = x
    return column.convert(out, units)


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


@dataclass(frozen=True)
class CircleFields:
    """What the test is, from the profile's ``[test]`` and the command line's overrides."""

    radius_mm: float
    feed_mm_min: float
    plane: tuple[str, str]
    directions: tuple[str, ...]
    centre_mm: tuple[float, float] | None
    lead_in_deg: float | None  # None: the arc of LEAD_IN_S at the feed
    temperature_c: float | None
    utility_day: float | None



def fields_of(profile: CircleProfile, src: str, **overrides) -> CircleFields:
    """The test's fields: ``overrides`` (radius_mm, feed_mm_min, plane, directions,
    centre_mm, temperature_c, utility_day; None = not given) win over ``[test]``."""
    t = {**profile.test, **{k: v for k, v in overrides.items() if v is not None}}
    flags = {"radius_mm": "--radius-mm", "feed_mm_min": "--feed-mm-min"}
    vals = {}
    for key, flag in flags.items():
        v = t.get(key)
        if v is None:
            raise CircleImportError(f"{src}: the test's {key} is needed (the nominal circle): give test.{key} in the "
                                    f"profile or {flag} on the command line")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise CircleImportError(f"{src}: test.{key} (={v!r}) must be a number > 0")
        vals[key] = float(v)
    plane = t.get("plane", ["x", "y"])
    plane = tuple(plane) if not isinstance(plane, str) else tuple(plane.lower())
    if len(plane) != 2 or not all(isinstance(a, str) and a.strip() for a in plane) or plane[0] == plane[1]:
        raise CircleImportError(f"{src}: test.plane (={t.get('plane')!r}) must name two axes, the first at 0° "
                                "(e.g. ['x', 'y'] or --plane xy)")
    dirs = t.get("directions", list(DIRECTIONS))
    dirs = tuple(str(d).strip().lower() for d in (dirs.split(",") if isinstance(dirs, str) else dirs))
    if not dirs or any(d not in DIRECTIONS for d in dirs) or len(set(dirs)) != len(dirs):
        raise CircleImportError(f"{src}: test.directions (={t.get('directions')!r}) must be one or both of "
                                f"{list(DIRECTIONS)}")
    centre = t.get("centre_mm")
    if centre is not None:
        try:
            centre = (float(centre[0]), float(centre[1]))
        except (TypeError, ValueError, IndexError):
            raise CircleImportError(f"{src}: test.centre_mm (={centre!r}) must be two numbers") from None
        if not all(math.isfinite(c) for c in centre) or len(t["centre_mm"]) != 2:
            raise CircleImportError(f"{src}: test.centre_mm (={t['centre_mm']!r}) must be two finite numbers")
    lead_in = t.get("lead_in_deg")
    if lead_in is not None and (isinstance(lead_in, bool) or not isinstance(lead_in, (int, float))
                                or not 0 <= lead_in < 360):
        raise CircleImportError(f"{src}: test.lead_in_deg (={lead_in!r}) must be 0..360")
    out = {}
    for key in ("temperature_c", "utility_day"):
        v = t.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise CircleImportError(f"{src}: test.{key} (={v!r}) must be a number")
        out[key] = None if v is None else float(v)
    return CircleFields(vals["radius_mm"], vals["feed_mm_min"], tuple(a.strip().lower() for a in plane), dirs, centre,
                      None if lead_in is None else float(lead_in), out["temperature_c"], out["utility_day"])


def _radial_passes(src: str, table: Table, profile: CircleProfile, fields: CircleFields) -> list[CirclePass]:
    n = len(table.lines)
    rows_of: dict[str, np.ndarray] = {}
    if "all" in profile.groups:
        col = profile.direction_column
        lookup = {v.lower(): d for d, v in profile.direction_values.items()}
        labels = []
        for i, cell in enumerate(table.cells[col]):
            d = lookup.get(cell.lower())
            if d is None:
                what = "no direction" if not cell else f"{cell!r} is not a direction the profile names"
                raise CircleImportError(
                    f"{src}, line {table.lines[i]}, column {col!r}: {what} (columns.direction.ccw = "
                    f"{profile.direction_values['ccw']!r}, .cw = {profile.direction_values['cw']!r})")
            labels.append(d)
        labels = np.array(labels)
        for d in DIRECTIONS:
            rows_of[d] = np.flatnonzero(labels == d)
        seen = {d: profile.direction_values[d] for d in DIRECTIONS if rows_of[d].size}
        missing = [d for d in fields.directions if rows_of[d].size == 0]
        if missing:
            raise CircleImportError(
                f"{src}: no {missing[0]} samples: column {col!r} holds only {sorted(seen.values())} (the profile's "
                f"columns.direction.{missing[0]} is {profile.direction_values[missing[0]]!r}); export both directions, "
                "or import the one there is with --directions "
                + ",".join(d for d in fields.directions if d not in missing))
        groups = {d: profile.groups["all"] for d in fields.directions}
    else:
        missing = [d for d in fields.directions if d not in profile.groups]
        if missing:
            raise CircleImportError(f"{src}: the profile has no [columns.{missing[0]}] for the {missing[0]} "
                                    f"direction; add them, or import with --directions "
                                    f"{','.join(d for d in fields.directions if d not in missing) or 'ccw'}")
        groups = {d: profile.groups[d] for d in fields.directions}
        for d, g in groups.items():
            filled = np.array([bool(table.cells[g["angle"].name][i] or table.cells[g["deviation"].name][i])
                               for i in range(n)], dtype=bool)
            # a group shorter than the other ends in blank cells; a blank inside it is refused below
            last = int(np.flatnonzero(filled)[-1]) + 1 if filled.any() else 0
            if last == 0:
                raise CircleImportError(f"{src}: no {d} samples: columns {g['angle'].name!r} and "
                                        f"{g['deviation'].name!r} are empty; export both directions, or import "
                                        f"the other with --directions {'cw' if d == 'ccw' else 'ccw'}")
            rows_of[d] = np.arange(last)
    passes = []
    for d in fields.directions:
        g, rows = groups[d], rows_of[d]
        angle = _numbers(src, table, g["angle"], profile, rows, ANGLE_UNITS) % 360.0
        angle[angle >= 360.0] = 0.0
        radial = _numbers(src, table, g["deviation"], profile, rows, DEVIATION_UNITS)
        _check_size(src, d, radial, g["deviation"], fields, profile)
        try:
            passes.append(CirclePass(direction=d, angle_deg=angle, radial_um=radial))
        except InputError as exc:
            hint = ""
            if "the angles run" in str(exc):
                where = f"columns.{d}.angle" if d in profile.groups else "columns.angle"
                hint = (f"; if the export counts the angle clockwise (or the direction's name means the other way), "
                        f"set {where}.scale = -1 (or swap columns.direction's values)")
            raise CircleImportError(f"{src}: the {d} direction (lines {table.lines[rows[0]]}.."
                                    f"{table.lines[rows[-1]]}): {exc}{hint}") from None
    return passes


def _check_size(src: str, direction: str, radial_um: np.ndarray, column: Column, fields: CircleFields,
                profile: CircleProfile) -> None:
    """Radial deviations whose size says their unit is wrong (a ballbar reads µm about a
    radius of tens of mm)."""
    worst = float(np.max(np.abs(radial_um)))
    if worst > 0.1 * fields.radius_mm * 1e3:
        raw = worst / DEVIATION_UNITS[column.unit]
        better = [u for u, f in DEVIATION_UNITS.items() if raw * f <= 0.1 * fields.radius_mm * 1e3 and u != column.unit]
        raise CircleImportError(
            f"{src}: the {direction} radial deviation reaches {worst:.6g} µm read as {column.unit!r}, beyond 10 % of "
            f"the {fields.radius_mm:g} mm radius: the unit is wrong (column {column.name!r}: columns.deviation.unit "
            f"= {better[0] if better else 'um'!r}?) or the file is not about the nominal radius")
    ins = profile.instrument
    spread = float(np.ptp(radial_um))
    if ins is not None and ins.resolution_um > 0 and spread < ins.resolution_um:
        raise CircleImportError(
            f"{src}: the {direction} radial deviation spans {spread:.3g} µm read as {column.unit!r}, less than the "
            f"instrument's resolution ({ins.resolution_um:g} µm): the unit is wrong (column {column.name!r}: "
            "columns.deviation.unit = 'mm'?)")


def _positions_passes(src: str, table: Table, profile: CircleProfile, fields: CircleFields) -> list[CirclePass]:
    g = profile.groups["all"]
    rows = np.arange(len(table.lines))
    if rows.size < 10:
        raise CircleImportError(f"{src}: {rows.size} sample(s) after the header; a circle needs many")
    t = _numbers(src, table, g["time"], profile, rows, TIME_UNITS)
    a = _numbers(src, table, g["first"], profile, rows, LINEAR_UNITS)
    b = _numbers(src, table, g["second"], profile, rows, LINEAR_UNITS)
    step = np.diff(t)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise CircleImportError(f"{src}, line {table.lines[i]}: time does not increase ({t[i - 1]!r} s, then "
                                f"{t[i]!r} s)")
    r_nom = fields.radius_mm
    fit_c, fit_r = _kasa_circle(a, b)
    for band in (0.1, 0.01, 0.001):  # again without the approach from the centre and the rests
        near = np.abs(np.hypot(a - fit_c[0], b - fit_c[1]) - r_nom) < band * r_nom
        if near.sum() < 10:
            break
        fit_c, fit_r = _kasa_circle(a[near], b[near])
    centre = fields.centre_mm
    if centre is None:
        raise CircleImportError(f"{src}: the circle's centre in the file's coordinates is needed: the samples circle "
                                f"about ({fit_c[0]:.4f}, {fit_c[1]:.4f}) mm: give --centre-mm {fit_c[0]:.4f} "
                                f"{fit_c[1]:.4f} (the programmed centre) or test.centre_mm")
    dx, dy = a - centre[0], b - centre[1]
    on = np.abs(np.hypot(dx, dy) - r_nom) < ON_CIRCLE_FRACTION * r_nom
    if on.sum() < 10:
        raise CircleImportError(f"{src}: no samples on a circle of radius {r_nom:g} mm about ({centre[0]:g}, "
                                f"{centre[1]:g}) mm; the samples circle about ({fit_c[0]:.4f}, {fit_c[1]:.4f}) mm "
                                f"with radius {fit_r:.3f} mm: give --centre-mm {fit_c[0]:.4f} {fit_c[1]:.4f} and "
                                "the radius the program ran")
    omega_deg_s = math.degrees(fields.feed_mm_min / 60.0 / r_nom)
    theta = np.degrees(np.unwrap(np.arctan2(dy, dx)))
    rate = np.gradient(theta, t)
    moving = on & (np.abs(rate) > 0.2 * omega_deg_s)
    sense = np.sign(rate) * moving
    # runs of samples on the circle turning one way
    edges = np.flatnonzero(np.diff(sense) != 0) + 1
    runs = [(s, e) for s, e in zip(np.r_[0, edges], np.r_[edges, sense.size]) if sense[s] != 0]
    found: dict[str, list[tuple[int, int]]] = {"ccw": [], "cw": []}
    for s, e in runs:
        found["ccw" if sense[s] > 0 else "cw"].append((s, e))
    passes = []
    min_lead = fields.lead_in_deg
    if min_lead is None:  # the first second of arc: many times any position loop's 1/K
        min_lead = max(MIN_LEAD_IN_DEG, omega_deg_s * LEAD_IN_S)
    for d in fields.directions:
        sign = 1.0 if d == "ccw" else -1.0
        cands = []
        for s, e in found[d]:
            lead = lead_in_deg(float(theta[s]) % 360.0, d, min_lead)
            cands.append((s, e, sign * (theta[e - 1] - theta[s]), lead))
        full = [c for c in cands if c[2] >= c[3] + 360.0]
        if not full:
            if math.hypot(fit_c[0] - centre[0], fit_c[1] - centre[1]) > ON_CIRCLE_FRACTION * r_nom:
                raise CircleImportError(
                    f"{src}: no {d} circle about ({centre[0]:g}, {centre[1]:g}) mm: the samples circle about "
                    f"({fit_c[0]:.4f}, {fit_c[1]:.4f}) mm with radius {fit_r:.3f} mm: give --centre-mm "
                    f"{fit_c[0]:.4f} {fit_c[1]:.4f} (or test.centre_mm) if that is the programmed centre")
            if not cands:
                raise CircleImportError(f"{src}: no {d} arc about ({centre[0]:g}, {centre[1]:g}) mm: export both "
                                        f"directions, or import with --directions {'cw' if d == 'ccw' else 'ccw'}")
            _, _, longest, lead = max(cands, key=lambda c: c[2])
            raise CircleImportError(
                f"{src}: the longest {d} arc about ({centre[0]:g}, {centre[1]:g}) mm runs {longest:.1f}°, and the "
                f"test needs {lead + 360.0:.0f}°: a lead-in of {lead:.0f}° (the start-up's first {min_lead:.0f}°, "
                "test.lead_in_deg, extended to midway between quadrant points) and the 360° analysed; record a "
                "longer arc, or give a smaller test.lead_in_deg if the start-up is over sooner")
        if len(full) > 1:
            raise CircleImportError(f"{src}: {len(full)} {d} circles in one file: cut it so it holds one per "
                                    "direction")
        s, e, _, lead = full[0]
        progress = sign * (theta[s:e] - theta[s])
        keep = s + np.flatnonzero((progress >= lead) & (progress < lead + 360.0))
        try:
            passes.append(pass_from_positions(a[keep], b[keep], radius_mm=r_nom, centre_mm=centre, direction=d))
        except InputError as exc:
            raise CircleImportError(f"{src}: the {d} circle (lines {table.lines[keep[0]]}..{table.lines[keep[-1]]}): "
                                    f"{exc}") from None
    return passes


def _kasa_circle(x: np.ndarray, y: np.ndarray) -> tuple[tuple[float, float], float]:
    """The algebraic least-squares circle through the points (for a hint only)."""
    A = np.column_stack([x, y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    cx, cy = sol[0] / 2.0, sol[1] / 2.0
    return (float(cx), float(cy)), float(math.sqrt(max(sol[2] + cx * cx + cy * cy, 0.0)))


def read_circle(path: str | Path, profile: CircleProfile, **overrides) -> CircularTest:
    """The circular test exported in ``path`` (see the module docstring); ``overrides``
    as :func:`fields_of`."""
    path = Path(path)
    src = str(path)
    fields = fields_of(profile, src, **overrides)
    if profile.instrument is None:
        raise CircleImportError(f"{src}: the profile's [instrument] is needed for the uncertainty: kind, "
                                "resolution_um, accuracy_um (e.g. kind = 'ballbar', resolution_um = 0.1, "
                                "accuracy_um = 0.5 from its calibration certificate)")
    table = read_table(path, profile)
    if not table.lines:
        raise CircleImportError(f"{src}: no samples after the header line {profile.header_line}")
    if profile.layout == "radial":
        passes = _radial_passes(src, table, profile, fields)
    else:
        passes = _positions_passes(src, table, profile, fields)
    try:
        return CircularTest(fields.radius_mm, fields.feed_mm_min, fields.plane, tuple(passes), profile.instrument,
                            temperature_c=fields.temperature_c, utility_day=fields.utility_day,
                            source=f"imported: {path.name}")
    except InputError as exc:
        raise CircleImportError(f"{src}: {exc}") from None

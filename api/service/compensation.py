"""Compensation tables for the controller: LinuxCNC, Beckhoff/ISG TwinCAT CNC, CSV.

``core.compensation`` builds one bidirectional table (x_k, e+, e-; e = actual - nominal,
µm); this module only writes it out, per format, and is shared by ``mebm export-comp``
and ``GET /axes/{id}/compensation``. What each controller expects, with the pages the
conventions were taken from, is in docs/compensation.md. In short:

* LinuxCNC ``[JOINT_n]COMP_FILE``: lines ``nominal a b`` in machine units (mm here),
  ascending, at most 256 per joint. ``COMP_FILE_TYPE = 0``: a, b are the actual
  positions moving + and - (nominal + e). ``COMP_FILE_TYPE = 1``: a, b are the trims
  LinuxCNC adds to the motor command, ``nominal - actual`` = -e (usrmotLoadComp takes
  them as they are; type 0 is converted to them as nominal - a). LinuxCNC stops reading
  the file at the first line that is not three numbers, so the comment goes *after*
  the table: a comment first would load an empty table.
* Beckhoff/ISG lead-screw error compensation list (``kw.ssfk.*``), bilateral,
  equidistant, metric: ``table[i].pos`` / ``.neg`` = actual - setpoint in 0.1 µm, the
  CNC subtracts them from the position setpoint. It replaces the scalar backlash
  ``getriebe[i].lose`` (P-AXIS-00103, selected by P-AXIS-00021
  ``lr_param.anwahl_losekomp``), which must be 0 while the list is active.
* CSV: position_mm, forward_um, reverse_um, backlash_um (e+, e-, b = e- - e+).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.compensation import LOOP_ENCODERS, CompensationTable, compensation_table
from core.criteria.roundtrip import RoundTripResult
from core.dataset import AxisSpec, Run
from core.errors import DatasetError, InputError
from storage.dataset import read_dataset, read_run_csv

# points per table: LinuxCNC holds 256 triplets per joint (EMCMOT_COMP_SIZE, ini-config
# docs); ISG needs kw_nr_max < kw.ssfk.max_points (P-COMP-00059, default 1500); a CSV is
# for people and spreadsheets: 10,000 rows (0.03 mm over 300 mm) is finer than b(x) is known
MAX_POINTS = {"linuxcnc": 256, "beckhoff": 1499, "csv": 10_000}
FORMATS = tuple(MAX_POINTS)
COMP_TYPES = (0, 1)
MEDIA_TYPES = {"linuxcnc": "text/plain", "beckhoff": "text/plain", "csv": "text/csv"}
SUFFIX = {"linuxcnc": "comp", "beckhoff": "lis", "csv": "csv"}


class LoopOnScaleError(InputError):
    """The axis closes its position loop on the linear scale: a table would fight it."""


@dataclass(frozen=True)
class CompExport:
    """A written table: ``text`` for the file, its media type and a file name to offer."""

    text: str
    media_type: str
    filename: str
    table: CompensationTable


def _check(fmt: str, comp_type: int, loop_encoder: str) -> None:
    if fmt not in MAX_POINTS:
        raise InputError(f"format (={fmt!r}) must be one of {', '.join(FORMATS)}")
    if comp_type not in COMP_TYPES:
        raise InputError(f"comp_type (={comp_type!r}) must be 0 or 1")
    if loop_encoder not in LOOP_ENCODERS:
        raise InputError(f"loop_encoder (={loop_encoder!r}) must be one of {', '.join(LOOP_ENCODERS)}")
    if loop_encoder == "table":
        raise LoopOnScaleError(
            "the axis closes its position loop on the linear scale (loop_encoder=table): the scale already "
            "positions the table, and a lead/backlash table would move it off the measured position; "
            "export a table only for an axis whose loop is closed on the motor encoder"
        )


def _facts(t: CompensationTable, loop_encoder: str, source: str | None,
           temperature_c: float | None = None) -> list[str]:
    """The lines every export states: what was measured, b̄, the loop, the grid."""
    u = "" if t.backlash_mean_uncertainty_um is None else f" +/- {t.backlash_mean_uncertainty_um:.2f} (U, k = 2)"
    lines = [
        f"mebm compensation table, axis {t.axis}" + (f", from {source}" if source else "")
        + (f", measured at {temperature_c:g} degC (lead error and backlash change with temperature)"
           if temperature_c is not None else ""),
        f"mean backlash b = {t.backlash_mean_um:.1f}{u} um (single value; the table carries b(x) itself)",
        f"position loop closed on: the {loop_encoder} encoder (semi-closed loop); nominal = k_a x motor "
        "position, actual = linear scale",
        "error e = actual - nominal; forward = moving +, reverse = moving -; b(x) = e(reverse) - e(forward)",
        f"{t.n_points} points from {t.position_mm[0]:.4f} to {t.position_mm[-1]:.4f} mm, step {t.step_mm:.4f} mm"
        + (f" (coarsened from {t.requested_step_mm:g} mm to fit the format's point limit)" if t.coarsened else ""),
        f"between points the interpolated table differs from the measured curves by up to "
        f"{t.interpolation_error_um:.2f} um",
    ]
    lines.append("zero of e: midline (forward + reverse)/2 = 0 at " + (
        f"{t.reference_mm:g} mm" if t.reference_mm is not None else "its median over the travel (the analysis')"))
    return lines


def linuxcnc(t: CompensationTable, *, comp_type: int = 1, joint: int | None = None,
             loop_encoder: str = "motor", source: str | None = None, temperature_c: float | None = None) -> str:
    """A LinuxCNC COMP_FILE (machine units mm). Type 0: nominal, actual moving +, actual
    moving -. Type 1: nominal, trim moving +, trim moving - with trim = nominal - actual."""
    nom = t.position_mm
    e_f, e_r = t.forward_error_um * 1e-3, t.reverse_error_um * 1e-3
    a, b = (nom + e_f, nom + e_r) if comp_type == 0 else (-e_f, -e_r)
    rows = [f"{x:.4f} {p:.7f} {q:.7f}" for x, p, q in zip(nom, a, b)]
    sec = f"[JOINT_{joint}]" if joint is not None else "[JOINT_n]"
    cols = ("actual position moving + and moving - (mm)" if comp_type == 0 else
            "trim moving + and moving - = nominal - actual (mm), added to the motor command")
    notes = [
        *_facts(t, loop_encoder, source, temperature_c),
        f"LinuxCNC COMP_FILE_TYPE = {comp_type}: columns nominal (mm), {cols}",
        f"INI: {sec} COMP_FILE = <this file>, COMP_FILE_TYPE = {comp_type}; machine units mm",
        f"BACKLASH is ignored while a COMP_FILE is set for the joint: this table carries b(x) (b = "
        f"{t.backlash_mean_um:.1f} um on average)",
        "This comment follows the table on purpose: LinuxCNC stops reading at the first line that is not "
        "three numbers.",
    ]
    return "\n".join(rows + ["#"] + [f"# {n}" for n in notes]) + "\n"


def beckhoff(t: CompensationTable, *, axis_number: int | None = None, loop_encoder: str = "motor",
             source: str | None = None, temperature_c: float | None = None) -> str:
    """A Beckhoff/ISG TwinCAT CNC axis compensation list: bilateral lead-screw error
    compensation, equidistant, metric (0.1 µm), pos/neg = actual - setpoint."""
    q = 1e-4  # mm per unit (kw.ssfk.unit 1: 0.1 µm)
    setpoints = np.rint(t.position_mm / q).astype(np.int64)
    start, interval = int(setpoints[0]), int(round(t.step_mm / q))
    if not np.array_equal(setpoints, start + interval * np.arange(setpoints.size)):
        raise InputError("the table's positions are not equidistant in 0.1 um")  # _grid guarantees they are
    pos = np.rint(t.forward_error_um * 10.0).astype(np.int64)
    neg = np.rint(t.reverse_error_um * 10.0).astype(np.int64)
    notes = [
        *_facts(t, loop_encoder, source, temperature_c),
        "TwinCAT CNC leadscrew error compensation (SSFK), bilateral: pos/neg = actual - setpoint in 0.1 um,",
        "the CNC subtracts them from the position setpoint. Activate with lr_param.ssfk 1 (P-AXIS-00175).",
        "It replaces the scalar backlash compensation getriebe[i].lose (P-AXIS-00103, selected by",
        "lr_param.anwahl_losekomp, P-AXIS-00021): set that to 0 while this list is active, or backlash",
        f"is compensated twice (mean b = {t.backlash_mean_um:.1f} um = {round(t.backlash_mean_um * 10)} x 0.1 um).",
    ]
    out = [f"# {n}" for n in notes]
    if axis_number is not None:
        out += [f"kopf.log_achs_nr {axis_number}"]
    out += [f"kopf.log_achs_name {t.axis.upper()}",
            "kw.ssfk.unit 1",
            f"kw.ssfk.interval {interval}",
            f"kw.ssfk.kw_startpos {start}",
            f"kw.ssfk.kw_nr_max {setpoints.size}",
            "kw.ssfk.bilateral 1",
            "kw.ssfk.modulo 0"]
    out += [f"kw.ssfk.table[{i}].setpoint {s}" for i, s in enumerate(setpoints)]
    out += [f"kw.ssfk.table[{i}].pos {v}" for i, v in enumerate(pos)]
    out += [f"kw.ssfk.table[{i}].neg {v}" for i, v in enumerate(neg)]
    return "\n".join(out) + "\n"


def csv(t: CompensationTable, *, loop_encoder: str = "motor", source: str | None = None,
        temperature_c: float | None = None) -> str:
    """position_mm, forward_um (e+), reverse_um (e-), backlash_um (e- - e+), after '#' notes."""
    rows = [f"{x:.4f},{f:.3f},{r:.3f},{r - f:.3f}"
            for x, f, r in zip(t.position_mm, t.forward_error_um, t.reverse_error_um)]
    return "\n".join([f"# {n}" for n in _facts(t, loop_encoder, source, temperature_c)]
                     + ["position_mm,forward_um,reverse_um,backlash_um"] + rows) + "\n"


def export(result: RoundTripResult, fmt: str, *, step_mm: float = 5.0, comp_type: int = 1,
           joint: int | None = None, loop_encoder: str = "motor", reference_mm: float | None = None,
           source: str | None = None, stem: str | None = None, temperature_c: float | None = None) -> CompExport:
    """The table of ``result`` written in ``fmt`` (linuxcnc, beckhoff or csv)."""
    _check(fmt, comp_type, loop_encoder)
    if joint is not None and not (isinstance(joint, int) and joint >= 0):
        raise InputError(f"joint (={joint!r}) must be an integer >= 0")
    if not (isinstance(step_mm, (int, float)) and math.isfinite(step_mm) and step_mm > 0):
        raise InputError(f"step_mm (={step_mm!r}) must be a number > 0")
    table = compensation_table(result, step_mm=step_mm, max_points=MAX_POINTS[fmt], reference_mm=reference_mm)
    common = {"loop_encoder": loop_encoder, "source": source, "temperature_c": temperature_c}
    if fmt == "linuxcnc":
        text = linuxcnc(table, comp_type=comp_type, joint=joint, **common)
    elif fmt == "beckhoff":
        text = beckhoff(table, axis_number=joint, **common)
    else:
        text = csv(table, **common)
    base = stem or f"comp_{table.axis}"
    kind = f"_type{comp_type}" if fmt == "linuxcnc" else ""
    return CompExport(text, MEDIA_TYPES[fmt], f"{base}_{fmt}{kind}.{SUFFIX[fmt]}", table)


def load_round_trip(folder: Path, run_file: str, axis: str | None = None) -> tuple[AxisSpec, Run]:
    """One round-trip run of a dataset folder and the spec of its axis (only that run's
    CSV is read). ``axis`` may be omitted when the run has a single axis."""
    meta = read_dataset(folder, load_runs=False)
    spec = next((r.spec for r in meta.runs if r.spec.file == run_file), None)
    if spec is None:
        names = ", ".join(r.spec.file for r in meta.runs) or "none"
        raise DatasetError(f"no run {run_file!r} in the dataset (runs: {names})", source=str(folder))
    if spec.kind != "round_trip":
        raise DatasetError(f"run {run_file!r} is a {spec.kind}, not a round trip", source=str(folder))
    if axis is None:
        if len(spec.axes) != 1:
            raise DatasetError(f"run {run_file!r} moves axes {', '.join(spec.axes)}: name one with --axis",
                               source=str(folder))
        axis = spec.axes[0]
    if axis not in spec.axes:
        raise DatasetError(f"run {run_file!r} has no axis {axis!r} (axes: {', '.join(spec.axes)})",
                           source=str(folder))
    run = Run(spec, read_run_csv(folder / spec.file, spec))
    return meta.machine.axes[axis], run

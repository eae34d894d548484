"""``mebm import FILE.csv --profile PROFILE.toml --out DATASET``: a controller's scope
trace (CSV) into a mebm dataset run, for ``mebm analyze`` and ``mebm gap``.

The profile (TOML) holds the machine's axes as dataset.json does (``[machine]``), where
each value is in the file and in which unit (``[csv]``, ``[columns]``: see
acquisition.trace_import and docs/controllers.md) and the run's fields (``[run]``:
kind, axes, feed, temperature, ...); options on the command line override them.

A round trip is analysed at once and its result printed. An import asks only for what
the figures it computes need: b̄, b(x) and the ISO 3408-3 criteria need the axis'
transmission ratio and the columns. What the user may not know is optional, and the
result says what it was not computed for:

- ``position_gain_per_s`` (the drive's K): the TBE only; without it the TBE is not
  computed and the dataset's axis carries no K;
- ``screw_lead_mm``: v_2π's window only;
- ``travel_mm``: by default what both strokes cover outside their reversal transients
  (reported and kept);
- the feed: read from the strokes' steady speed (reported, and the run says
  ``feed_from_data``);
- the temperature: without a column or a value it is not recorded (the run says
  ``temperature_measured: false``; nothing is normalised to 20 °C).
"""

from __future__ import annotations

import argparse
import math
import re
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from acquisition.files import KIB, FileRefused, read_regular
from acquisition.trace_import import TraceImportError, parse_profile, read_trace, steady_feed_mm_min
from core.criteria import CRITERION_NAMES, CRITERION_SYMBOLS, analyze_round_trip
from core.criteria.roundtrip import COVERED, TBE_NEEDS_POSITION_GAIN
from core.criteria.uncertainty import inputs_of_run
from core.dataset import Run
from core.errors import DatasetError, InputError
from storage.dataset import (AxisMismatchError, append_runs, dataset_lock, next_run_name, parse_machine,
                             parse_run_spec, read_dataset)  # fmt: skip

AXIS_OPTIONS = (("transmission_mm_per_rev", "--transmission-mm-per-rev"),
                ("position_gain_per_s", "--position-gain-per-s"), ("screw_lead_mm", "--screw-lead-mm"))

MAX_TRACE_PROFILE_BYTES = 256 * KIB  # a trace-import profile larger than this is not one


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="a controller's scope trace (CSV) into a mebm dataset run",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("file", help="the trace file (CSV, as the controller's trace tool exports it)")
    p.add_argument("--profile", required=True, help="trace-import profile (TOML, mebm-trace-profile/1)")
    p.add_argument("--out", required=True, help="dataset folder; created, or the run is added to it")
    p.add_argument("--run-name", help="file name of the run in the dataset (default: from the trace's name)")
    p.add_argument("--feed-mm-min", type=float, help="programmed feed (overrides [run].feed_mm_min; default for a "
                   "round trip: read from the strokes' steady speed)")
    p.add_argument("--temperature-c", type=float,
                   help="ambient temperature (overrides [run].temperature_c and the mean of a temperature column; "
                        "default: not recorded)")
    p.add_argument("--transmission-mm-per-rev", type=float,
                   help="k_a of the run's axis, table mm per motor revolution (overrides the profile's)")
    p.add_argument("--position-gain-per-s", type=float,
                   help="the drive's position-loop gain K (1/s) of the run's axis, for the TBE (overrides the "
                        "profile's; default: not known, the TBE is not computed)")
    p.add_argument("--screw-lead-mm", type=float,
                   help="the ball screw's lead of the run's axis, for v_2π (overrides the profile's)")
    p.add_argument("--utility-day", type=float, help="days in service since the first measurement")
    p.add_argument("--split", choices=("train", "test"), help="for `mebm gap`: a train or a test run")
    p.add_argument("--useful-travel-mm", type=float, nargs=2, metavar=("START", "END"),
                   help="the round trip's useful travel in table mm (overrides the axis' travel_mm; default: "
                        "travel_mm, else what both strokes cover outside the reversal transients)")
    p.add_argument("--replace-axis", action="store_true",
                   help="when --out holds runs recorded with another description of the run's axis: replace "
                        "the stored description with this one (its runs are then read with it)")
    p.set_defaults(func=run)


def load_trace_profile(path: Path) -> dict:
    """The trace profile's TOML as a table; a :class:`TraceImportError` naming the file when
    it cannot be read or is not TOML."""
    try:
        return tomllib.loads(read_regular(path, MAX_TRACE_PROFILE_BYTES, "trace profile").decode("utf-8"))
    except FileRefused as exc:
        raise TraceImportError(str(exc)) from exc
    except UnicodeDecodeError as exc:
        raise TraceImportError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise TraceImportError(f"{path}: not valid TOML ({exc})") from exc


def _apply_axis_options(doc: dict, a: argparse.Namespace, src: str) -> None:
    """The axis options (``--transmission-mm-per-rev``, ...) written into the profile's
    axis of the run, before it is checked; a missing k_a is refused naming both places."""
    given = [(key, flag, getattr(a, key)) for key, flag in AXIS_OPTIONS]
    m = doc.get("machine")
    axes = m.get("axes") if isinstance(m, dict) else None
    if not isinstance(axes, dict) or not axes:
        return  # parse_machine says what is missing
    run_axes = (doc.get("run") or {}).get("axes") if isinstance(doc.get("run"), dict) else None
    names = [str(x) for x in run_axes] if isinstance(run_axes, list) else list(axes) if len(axes) == 1 else []
    if any(v is not None for _, _, v in given) and len(names) != 1:
        flags = [f for _, f, v in given if v is not None]
        raise TraceImportError(f"{src}: {', '.join(flags)} set(s) the run's one axis, and this run has "
                               f"{len(names) or 'no named'} axes; set the fields in the profile's machine.axes")
    for name in names:
        ax = next((v for k, v in axes.items() if str(k).lower() == name.lower()), None)
        if not isinstance(ax, dict):
            continue  # parse_profile names the axis
        for key, _, value in given:
            if value is not None:
                ax[key] = value
        if "transmission_mm_per_rev" not in ax:
            raise TraceImportError(f"{src}: machine.axes.{name}.transmission_mm_per_rev (k_a, table mm per motor "
                                   "revolution) is needed for b̄, b(x) and the lead criteria; give it in the "
                                   "profile or with --transmission-mm-per-rev")  # fmt: skip


def run(a: argparse.Namespace) -> int:
    src = str(a.profile)
    doc = load_trace_profile(Path(a.profile))
    _apply_axis_options(doc, a, src)
    # an axis without travel_mm gets it from the trace (below); the profile is checked
    # with the field there, so that every other field gets the dataset's checks
    no_travel = _axes_without_travel(doc)
    measure_travel = set() if a.useful_travel_mm is not None else set(no_travel)
    machine = parse_machine(doc, src)
    run_doc = dict(doc.get("run") or {})
    if "axes" not in run_doc and len(machine.axes) == 1:
        run_doc["axes"] = list(machine.axes)
    run_doc.setdefault("kind", "round_trip")
    axes = tuple(str(x).lower() for x in run_doc.get("axes") or ())
    if not axes:
        raise TraceImportError(f"{src}: run.axes must name the run's axes (the machine has {sorted(machine.axes)})")
    ka = {n: ax.transmission_mm_per_rev for n, ax in machine.axes.items()}
    profile = parse_profile(doc, axes, ka, src)
    cols = read_trace(a.file, profile)
    for key, value in (("feed_mm_min", a.feed_mm_min), ("temperature_c", a.temperature_c),
                       ("utility_day", a.utility_day), ("split", a.split)):  # fmt: skip
        if value is not None:
            run_doc[key] = value
    round_trip = run_doc["kind"] == "round_trip" and len(axes) == 1
    feed = None
    if "feed_mm_min" not in run_doc:
        if not round_trip:
            raise TraceImportError(f"{src}: run.feed_mm_min is needed for a {run_doc['kind']} run (read from the "
                                   "data for a round trip only): give --feed-mm-min on the command line")  # fmt: skip
        feed = steady_feed_mm_min(cols["time_s"], cols[f"{axes[0]}_table_mm"], str(a.file))
        run_doc["feed_mm_min"] = round(feed.feed_mm_min, 1)
        run_doc["feed_from_data"] = True
    temperature = "given"
    if "temperature_c" not in run_doc and "temperature_c" in cols:
        run_doc["temperature_c"] = float(np.mean(cols["temperature_c"]))
        temperature = "column"
    elif "temperature_c" not in run_doc:
        # the format wants a number: the reference temperature, which no reader
        # normalises away from, marked as not measured (as the service marks its runs)
        run_doc["temperature_c"] = 20.0
        run_doc["temperature_measured"] = False
        temperature = None
    result, not_analysed, suggestion = None, None, None
    if round_trip:
        axis = machine.axes[axes[0]]
        if a.useful_travel_mm is not None:
            axis = replace(axis, travel_mm=tuple(a.useful_travel_mm))
        elif axes[0] in measure_travel and (Path(a.out) / "dataset.json").is_file() and not a.replace_axis:
            known = read_dataset(a.out, load_runs=False).machine.axes.get(axes[0])
            if known is not None:  # the dataset's axis keeps its travel: every run on one grid
                axis = replace(axis, travel_mm=known.travel_mm)
                measure_travel = measure_travel - {axes[0]}
        measured_c = run_doc["temperature_c"] if temperature is not None else None
        budget = inputs_of_run({}, None, None if measured_c is None else float(measured_c))
        t, motor, table = cols["time_s"], cols[f"{axes[0]}_motor_rev"], cols[f"{axes[0]}_table_mm"]
        try:
            result = analyze_round_trip(t, motor, table, axis, uncertainty=budget,
                                        useful_travel_mm=COVERED if axes[0] in measure_travel else None)
        except InputError as exc:
            if axes[0] in measure_travel:  # the travel would come from this analysis: nothing to write
                raise TraceImportError(f"{a.file}: the useful travel cannot be taken from the trace ({exc}); the "
                                       f"table moves over {table.min():.2f}..{table.max():.2f} mm: give a travel "
                                       "within it with --useful-travel-mm START END") from exc  # fmt: skip
            not_analysed = str(exc)
            suggestion = _travel_that_works(t, motor, table, axis, budget)
        else:
            machine = replace(machine, axes={**machine.axes, axes[0]: replace(axis, travel_mm=result.useful_travel_mm)})
    elif no_travel & set(axes):
        raise TraceImportError(f"{src}: machine.axes.{sorted(no_travel & set(axes))[0]} lacks travel_mm "
                               f"(measured from the trace for a round trip only; a {run_doc['kind']} run needs it)")
    # a profile axis without travel that this run does not move is not written: its
    # travel is unknown until a round trip of it is imported (a stored axis is kept)
    machine = replace(machine, axes={n: ax for n, ax in machine.axes.items() if n not in no_travel - set(axes)})
    out = Path(a.out)
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(a.file).stem).strip("._") or "trace"
    with dataset_lock(out):  # the name and the append under one lock: concurrent imports get their own names
        name = a.run_name or next_run_name(out, stem)
        if not name.endswith(".csv"):
            name += ".csv"
        run_doc["file"] = name
        run_doc["imported_from"] = Path(a.file).name
        try:
            spec = parse_run_spec(run_doc, f"{src} [run]")
        except DatasetError as exc:
            raise TraceImportError(str(exc)) from None
        try:
            append_runs(out, machine, [Run(spec, cols)], replace_axes=axes if a.replace_axis else ())
        except AxisMismatchError as exc:
            raise TraceImportError(
                f"{out}: axis {exc.axis!r} of the profile and options differs from the one the folder's runs were "
                f"recorded with: {'; '.join(exc.differences)}. Import into a new folder (--out NEW_FOLDER), "
                "or, if the stored description is wrong, give --replace-axis to replace it (the stored runs are "
                "then read with the new one)") from None  # fmt: skip
    t = cols["time_s"]
    print(f"imported {a.file} -> {out / name}: {t.size} samples over {t[-1]:.2f} s "
          f"({t.size / t[-1] if t[-1] > 0 else float('nan'):.0f} Hz), {spec.kind} of axis/axes {', '.join(spec.axes)}")
    for ax_name in spec.axes:
        m, tb = cols[f"{ax_name}_motor_rev"], cols[f"{ax_name}_table_mm"]
        print(f"  {ax_name}: motor {m.min():.4f}..{m.max():.4f} rev, table {tb.min():.4f}..{tb.max():.4f} mm")
    if feed is not None:
        v_pos, v_neg = feed.stroke_speeds_mm_min
        print(f"  feed {spec.feed_mm_min:g} mm/min: read from the data (the strokes' steady speed, {v_pos:.1f} and "
              f"{v_neg:.1f} mm/min; --feed-mm-min gives the programmed one)")  # fmt: skip
    else:
        print(f"  feed {spec.feed_mm_min:g} mm/min: given")
    if temperature is None:
        print("  temperature: not recorded (no temperature column, --temperature-c or run.temperature_c), so b̄ is "
              "not normalised to 20 °C; the uncertainty budget takes the thermometer's tolerance at 20 °C")
    else:
        print(f"  temperature {spec.temperature_c:.1f} °C: " + ("the mean of the temperature column"
                                                              if temperature == "column" else "given"))
    if result is not None:
        how = ("what both strokes cover outside the reversal transients" if axes[0] in measure_travel
               else "--useful-travel-mm" if a.useful_travel_mm is not None else "the axis' travel_mm")
        _print_result(result, machine.axes[axes[0]], how=how)
    elif not_analysed is not None:
        print(f"  imported, but not analysed: {not_analysed}")
        if suggestion is not None:
            lo, hi = suggestion
            print(f"  both strokes cover {lo:.2f}..{hi:.2f} mm outside their reversal transients: "
                  f"`mebm analyze {out} --useful-travel-mm {lo:.2f} {hi:.2f}` analyses the run; to store that travel, "
                  f"import into a new folder with --useful-travel-mm {lo:.2f} {hi:.2f} (or with no travel_mm in "
                  "the profile)")  # fmt: skip
    for ax_name in spec.axes if result is not None else ():
        gain = machine.axes[ax_name].position_gain_per_s
        if gain is None:
            print(f"  {TBE_NEEDS_POSITION_GAIN} (give --position-gain-per-s or the profile's "
                  f"machine.axes.{ax_name}.position_gain_per_s; b̄, b(x) and the lead criteria do not need it)")
        else:
            print(f"  TBE of a task, with K = {gain:g} 1/s: mebm tbe circle --backlash-um "
                  f"{result.backlash_mean_um:.2f} --gain-per-s {gain:g} --radius-mm R --feed-mm-min F")
    print(f"next: mebm analyze {out}" + ("" if spec.kind == "round_trip" else f"   or   mebm gap diagnose {out}"))
    return 0


def _travel_that_works(t, motor, table, axis, budget) -> tuple[float, float] | None:
    """What both strokes cover outside their reversal transients, rounded inward to
    0.01 mm, if the round trip analyses over it; else None."""
    try:
        covered = analyze_round_trip(t, motor, table, axis, uncertainty=budget, useful_travel_mm=COVERED)
        lo, hi = covered.useful_travel_mm
        lo, hi = math.ceil(lo * 100.0) / 100.0, math.floor(hi * 100.0) / 100.0
        analyze_round_trip(t, motor, table, axis, uncertainty=budget, useful_travel_mm=(lo, hi))
    except InputError:
        return None
    return lo, hi


def _axes_without_travel(doc: dict) -> set[str]:
    """Names of the profile's axes that have no ``travel_mm``; each is given a placeholder
    the round trip's covered travel replaces before anything is written."""
    axes = (doc.get("machine") or {}).get("axes") if isinstance(doc.get("machine"), dict) else None
    if not isinstance(axes, dict):
        return set()
    missing = {str(n).lower() for n, ax in axes.items() if isinstance(ax, dict) and "travel_mm" not in ax}
    for n, ax in axes.items():
        if str(n).lower() in missing:
            ax["travel_mm"] = [0.0, 1.0]  # placeholder: see above
    return missing


def _print_result(res, axis, *, how: str) -> None:
    lo, hi = res.useful_travel_mm
    print(f"  useful travel {lo:g}..{hi:g} mm ({hi - lo:g} mm): {how}")
    print(f"  mean backlash b̄ {res.backlash_mean_um:.2f} ± {res.backlash_mean_uncertainty_um:.2f} µm (k = 2)")
    pos = res.strokes["positive"]
    for key in CRITERION_NAMES:
        value = getattr(pos, f"{key}_um")
        shown = f"{value:.2f} µm" if value is not None else "not computed"
        print(f"  {CRITERION_SYMBOLS[key]} ({CRITERION_NAMES[key]}, positive stroke): {shown}")
    if axis.screw_lead_mm is None:
        print(f"  needs the screw lead: {CRITERION_SYMBOLS['v_2pi']} (its window is one lead; give --screw-lead-mm "
              f"or the profile's machine.axes.{axis.name}.screw_lead_mm)")

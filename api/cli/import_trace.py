"""``mebm import FILE.csv --profile PROFILE.toml --out DATASET``: a controller's scope
trace (CSV) into a mebm dataset run, for ``mebm analyze`` and ``mebm gap``.

The profile (TOML) holds the machine's axes as dataset.json does (``[machine]``), where
each value is in the file and in which unit (``[csv]``, ``[columns]``: see
acquisition.trace_import and docs/controllers.md) and the run's fields (``[run]``:
kind, axes, feed, temperature, ...); options on the command line override ``[run]``.

A round trip is analysed at once and its result printed. Two things a user importing a
trace may not know are optional: an axis' ``screw_lead_mm`` (only v_2π's window; the
rest is computed and the result says what needs it), and its ``travel_mm`` (the useful
travel; by default what both strokes cover outside their reversal transients, so a
trace recorded without overtravel is analysed, and the travel used is reported and
kept in the dataset). ``--useful-travel-mm START END`` sets it instead.
"""

from __future__ import annotations

import argparse
import re
import tomllib
from pathlib import Path

import numpy as np
from dataclasses import replace

from acquisition.trace_import import TraceImportError, parse_profile, read_trace
from core.criteria import CRITERION_NAMES, CRITERION_SYMBOLS, analyze_round_trip
from core.criteria.roundtrip import COVERED
from core.dataset import Run
from core.errors import DatasetError, InputError
from storage.dataset import append_runs, dataset_lock, next_run_name, parse_machine, parse_run_spec, read_dataset


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="a controller's scope trace (CSV) into a mebm dataset run",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("file", help="the trace file (CSV, as the controller's trace tool exports it)")
    p.add_argument("--profile", required=True, help="trace-import profile (TOML, mebm-trace-profile/1)")
    p.add_argument("--out", required=True, help="dataset folder; created, or the run is added to it")
    p.add_argument("--run-name", help="file name of the run in the dataset (default: from the trace's name)")
    p.add_argument("--feed-mm-min", type=float, help="programmed feed (overrides [run].feed_mm_min)")
    p.add_argument("--temperature-c", type=float,
                   help="ambient temperature (overrides [run].temperature_c and the mean of a temperature column)")
    p.add_argument("--utility-day", type=float, help="days in service since the first measurement")
    p.add_argument("--split", choices=("train", "test"), help="for `mebm gap`: a train or a test run")
    p.add_argument("--useful-travel-mm", type=float, nargs=2, metavar=("START", "END"),
                   help="the round trip's useful travel in table mm (overrides the axis' travel_mm; default: "
                        "travel_mm, else what both strokes cover outside the reversal transients)")
    p.set_defaults(func=run)


def load_trace_profile(path: Path) -> dict:
    """The trace profile's TOML as a table; a :class:`TraceImportError` naming the file when
    it cannot be read or is not TOML."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise TraceImportError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise TraceImportError(f"{path}: not valid TOML ({exc})") from exc


def run(a: argparse.Namespace) -> int:
    src = str(a.profile)
    doc = load_trace_profile(Path(a.profile))
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
    if "temperature_c" not in run_doc and "temperature_c" in cols:
        run_doc["temperature_c"] = float(np.mean(cols["temperature_c"]))
    for key in ("feed_mm_min", "temperature_c"):
        if key not in run_doc:
            flag = "--" + key.replace("_", "-")
            raise TraceImportError(f"{src}: run.{key} is needed (or {flag} on the command line"
                                   + (", or a temperature_c column" if key == "temperature_c" else "") + ")")
    result, not_analysed = None, None
    if run_doc["kind"] == "round_trip" and len(axes) == 1:
        axis = machine.axes[axes[0]]
        if a.useful_travel_mm is not None:
            axis = replace(axis, travel_mm=tuple(a.useful_travel_mm))
        elif axes[0] in measure_travel and (Path(a.out) / "dataset.json").is_file():
            known = read_dataset(a.out, load_runs=False).machine.axes.get(axes[0])
            if known is not None:  # the dataset's axis keeps its travel: every run on one grid
                axis = replace(axis, travel_mm=known.travel_mm)
                measure_travel = measure_travel - {axes[0]}
        try:
            result = analyze_round_trip(cols["time_s"], cols[f"{axes[0]}_motor_rev"], cols[f"{axes[0]}_table_mm"],
                                        axis, useful_travel_mm=COVERED if axes[0] in measure_travel else None)
        except InputError as exc:
            if axes[0] in measure_travel:  # the travel would come from this analysis: nothing to write
                raise TraceImportError(f"{a.file}: the useful travel cannot be taken from the trace ({exc}); "
                                       f"give travel_mm in the profile or --useful-travel-mm") from exc
            not_analysed = str(exc)
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
        append_runs(out, machine, [Run(spec, cols)])
    t = cols["time_s"]
    print(f"imported {a.file} -> {out / name}: {t.size} samples over {t[-1]:.2f} s "
          f"({t.size / t[-1] if t[-1] > 0 else float('nan'):.0f} Hz), {spec.kind} of axis/axes {', '.join(spec.axes)}")
    for ax_name in spec.axes:
        m, tb = cols[f"{ax_name}_motor_rev"], cols[f"{ax_name}_table_mm"]
        print(f"  {ax_name}: motor {m.min():.4f}..{m.max():.4f} rev, table {tb.min():.4f}..{tb.max():.4f} mm")
    if result is not None:
        _print_result(result, machine.axes[axes[0]], measured=axes[0] in measure_travel)
    elif not_analysed is not None:
        print(f"  imported, but not analysed: {not_analysed}")
    print(f"next: mebm analyze {out}" + ("" if spec.kind == "round_trip" else f"   or   mebm gap diagnose {out}"))
    return 0


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


def _print_result(res, axis, *, measured: bool) -> None:
    lo, hi = res.useful_travel_mm
    how = ("what both strokes cover outside the reversal transients" if measured else "the axis' travel_mm")
    print(f"  useful travel {lo:g}..{hi:g} mm ({hi - lo:g} mm): {how}")
    print(f"  mean backlash b̄ {res.backlash_mean_um:.2f} ± {res.backlash_mean_uncertainty_um:.2f} µm (k = 2)")
    pos = res.strokes["positive"]
    for key in CRITERION_NAMES:
        value = getattr(pos, f"{key}_um")
        shown = f"{value:.2f} µm" if value is not None else "not computed"
        print(f"  {CRITERION_SYMBOLS[key]} ({CRITERION_NAMES[key]}, positive stroke): {shown}")
    if axis.screw_lead_mm is None:
        print(f"  needs the screw lead: {CRITERION_SYMBOLS['v_2pi']} (its window is one lead; add screw_lead_mm "
              "to the profile's axis and import again)")

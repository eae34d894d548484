"""``mebm import FILE.csv --profile PROFILE.toml --out DATASET``: a controller's scope
trace (CSV) into a mebm dataset run, for ``mebm analyze`` and ``mebm gap``.

The profile (TOML) holds the machine's axes as dataset.json does (``[machine]``), where
each value is in the file and in which unit (``[csv]``, ``[columns]``: see
acquisition.trace_import and docs/controllers.md) and the run's fields (``[run]``:
kind, axes, feed, temperature, ...); options on the command line override ``[run]``.
"""

from __future__ import annotations

import argparse
import re
import tomllib
from pathlib import Path

import numpy as np

from acquisition.trace_import import TraceImportError, parse_profile, read_trace
from core.dataset import Run
from core.errors import DatasetError
from storage.dataset import append_runs, dataset_lock, next_run_name, parse_machine, parse_run_spec


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
    p.set_defaults(func=run)


def _load_profile(path: Path) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise TraceImportError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise TraceImportError(f"{path}: not valid TOML ({exc})") from exc


def run(a: argparse.Namespace) -> int:
    src = str(a.profile)
    doc = _load_profile(Path(a.profile))
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
    print(f"next: mebm analyze {out}" + ("" if spec.kind == "round_trip" else f"   or   mebm gap diagnose {out}"))
    return 0

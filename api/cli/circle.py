"""``mebm circle measure|import|analyze``: circular tests (ISO 230-4), the direct
measurement of the contouring error.

- ``measure``: run a circle in both directions on LinuxCNC (``--url linuxcnc://...``) or on
  the simulated two-axis machine (``--url sim:``) and record it with the CNC's own scales;
- ``import``: an exported circular test (a ballbar's angle and radial deviation, or a trace
  tool's positions) through a circle-import profile;
- ``analyze``: ISO 230-4's figures and the reversal spikes of a test file or of a dataset
  folder's ``circles/``; given the axis' backlash (``--backlash-um``, ``--backlash-u-um``,
  ``--gain-per-s``) or a dataset folder with a round trip of the axis, the spikes against
  Eq. 8; with a task (``--task``), the decision.

A measured or imported test is written with ``--out``: a ``.json`` file, or a dataset folder
where it goes to ``circles/<name>.json`` (core/circle/io.py's layout); nothing stored is
overwritten.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import tomllib
from pathlib import Path

from acquisition.files import KIB, MIB, FileRefused, read_regular
from api.cli.output import print_json
from core.errors import InputError

MAX_PROFILE_BYTES = 256 * KIB
MAX_TEST_BYTES = 256 * MIB
CIRCLES_DIR = "circles"


class CircleFileError(InputError):
    """A circular test file or folder cannot be read or written; the message says which and why."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("circle", help="circular tests (ISO 230-4): measure, import, analyze",
                       description=__doc__.split("\n\n")[0])
    cs = p.add_subparsers(dest="circle_command", metavar="ACTION")
    cs.required = True

    def test_options(q: argparse.ArgumentParser, *, required: bool) -> None:
        q.add_argument("--radius-mm", type=float, required=required, help="the circle's nominal radius (mm)")
        q.add_argument("--feed-mm-min", type=float, required=required, help="the programmed feed (mm/min)")
        q.add_argument("--plane", default=None if not required else "xy",
                       help="the two axes, the first at 0° (xy, yz, zx, ...; default xy)")
        q.add_argument("--directions", default=None,
                       help="ccw, cw or ccw,cw (default: both)")
        q.add_argument("--temperature-c", type=float, help="ambient temperature (°C; default: not recorded)")
        q.add_argument("--utility-day", type=float, help="days in service since the first measurement")
        q.add_argument("--out", required=True, help="a .json file, or a dataset folder (the test goes to its "
                       "circles/NAME.json)")
        q.add_argument("--name", help="the test's name in the folder (default: from the radius and feed)")
        q.add_argument("--json", action="store_true", help="print JSON (units in the keys)")

    m = cs.add_parser("measure", help="run a circle in both directions and record it with the CNC's own scales")
    m.add_argument("--url", required=True,
                   help="linuxcnc://HOST:PORT?sampler=N (its six-pin sampler of both axes) or sim:[?backlash_um=120"
                        "&gain_per_s=30&resolution_um=1&noise_um=0&seed=0] (the simulated two-axis machine)")
    test_options(m, required=True)
    m.add_argument("--centre-mm", type=float, nargs=2, metavar=("FIRST", "SECOND"), default=(0.0, 0.0),
                   help="the circle's centre in the program's work coordinates (G54), default 0 0")
    m.add_argument("--resolution-um", type=float,
                   help="the linear scales' resolution (µm): the radial reading's quantisation (LinuxCNC)")
    m.add_argument("--accuracy-um", type=float, default=0.0,
                   help="the scales' accuracy over the circle as a standard uncertainty (µm), default 0")
    m.set_defaults(func=measure)

    i = cs.add_parser("import", help="an exported circular test (CSV: a ballbar's or a trace tool's)")
    i.add_argument("file", help="the exported test (CSV)")
    i.add_argument("--profile", required=True, help="circle-import profile (TOML, mebm-circle-profile/1)")
    test_options(i, required=False)
    i.add_argument("--centre-mm", type=float, nargs=2, metavar=("FIRST", "SECOND"),
                   help="positions layout: the circle's centre in the file's coordinates")
    i.set_defaults(func=import_)

    a = cs.add_parser("analyze", help="ISO 230-4 figures and spikes of a test; against Eq. 8 and a task")
    a.add_argument("path", help="a circular test (.json) or a dataset folder (its circles/*.json)")
    a.add_argument("--axis", action="append", default=None,
                   help="the axis to compare with Eq. 8 and to decide on (repeatable; default: both of the plane)")
    a.add_argument("--backlash-um", type=float, help="the axis' mean backlash b̄ (µm), e.g. from mebm analyze")
    a.add_argument("--backlash-u-um", type=float, help="its expanded uncertainty U(b̄) (µm, k = 2)")
    a.add_argument("--gain-per-s", type=float, help="the axis' position-loop gain K (1/s)")
    a.add_argument("--task", action="append", default=[], metavar="circle:radius_mm=R,feed_mm_min=F,tolerance_um=T",
                   help="a circle task of the axis, as mebm measure takes it (repeatable): the test is judged "
                        "against the tasks at its own radius and feed")
    a.add_argument("--rule", choices=("simple", "guarded"), default="guarded", help="decision rule (default guarded)")
    a.add_argument("--warning-fraction", type=float, default=0.9,
                   help="WARNING from this fraction of the tolerance (default 0.9)")
    a.add_argument("--json", action="store_true", help="print JSON (units in the keys)")
    a.set_defaults(func=analyze)


# -- files ----------------------------------------------------------------------------------------
def write_test(test, out: str, name: str | None) -> Path:
    """``test`` as JSON at ``out`` (a .json file) or in ``out/circles/NAME.json``; never overwrites."""
    from core.circle import to_json

    target = Path(out)
    if target.suffix.lower() == ".json":
        target.parent.mkdir(parents=True, exist_ok=True)
        if name:
            raise CircleFileError(f"--name names a test in a dataset folder; --out {out} is a file")
        candidates = [target]
    else:
        folder = target / CIRCLES_DIR
        folder.mkdir(parents=True, exist_ok=True)
        if name:
            if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
                raise CircleFileError(f"--name (={name!r}) must be letters, digits, '_', '.' or '-'")
            candidates = [folder / (name if name.endswith(".json") else name + ".json")]
        else:
            stem = f"circle_R{test.radius_mm:g}_F{test.feed_mm_min:g}".replace(".", "p")
            candidates = [folder / f"{stem}_{k:02d}.json" for k in range(1000)]
    text = json.dumps(to_json(test), separators=(",", ":"))
    for path in candidates:
        try:
            with open(path, "x", encoding="utf-8") as f:
                f.write(text + "\n")
            return path
        except FileExistsError:
            continue
        except OSError as exc:
            raise CircleFileError(f"cannot write {path}: {exc.strerror or exc}") from exc
    raise CircleFileError(f"{candidates[-1]} exists: nothing stored is overwritten; give another --out or --name")


def read_test(path: Path):
    from core.circle import from_json

    try:
        raw = read_regular(path, MAX_TEST_BYTES, "circular test")
    except FileRefused as exc:
        raise CircleFileError(str(exc)) from exc
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CircleFileError(f"{path}: not a circular test's JSON ({exc})") from exc
    try:
        return from_json(doc)
    except InputError as exc:
        raise CircleFileError(f"{path}: {exc}") from None


def _directions(text: str | None):
    return None if text is None else tuple(d.strip() for d in text.split(",") if d.strip())


# -- measure / import -------------------------------------------------------------------------------
def measure(a: argparse.Namespace) -> int:
    from acquisition.circle import DIRECTIONS, CircleProgram, check_directions, measure_circle

    program = CircleProgram(a.radius_mm, a.feed_mm_min, plane=a.plane, centre_mm=tuple(a.centre_mm))
    dirs = check_directions(_directions(a.directions) or DIRECTIONS)
    test = measure_circle(a.url, program, dirs, resolution_um=a.resolution_um, accuracy_um=a.accuracy_um,
                          temperature_c=a.temperature_c, utility_day=a.utility_day)
    path = write_test(test, a.out, a.name)
    return _report_new(test, path, a, f"measured {'/'.join(dirs)} on {a.url}")


def load_profile(path: Path) -> dict:
    from acquisition.circle_import import CircleImportError

    try:
        return tomllib.loads(read_regular(path, MAX_PROFILE_BYTES, "circle-import profile").decode("utf-8"))
    except FileRefused as exc:
        raise CircleImportError(str(exc)) from exc
    except UnicodeDecodeError as exc:
        raise CircleImportError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise CircleImportError(f"{path}: not valid TOML ({exc})") from exc


def import_(a: argparse.Namespace) -> int:
    from acquisition.circle_import import parse_profile, read_circle

    profile = parse_profile(load_profile(Path(a.profile)), str(a.profile))
    test = read_circle(a.file, profile, radius_mm=a.radius_mm, feed_mm_min=a.feed_mm_min, plane=a.plane,
                       directions=_directions(a.directions), centre_mm=a.centre_mm, temperature_c=a.temperature_c,
                       utility_day=a.utility_day)
    path = write_test(test, a.out, a.name)
    return _report_new(test, path, a, f"imported {a.file} ({profile.layout} layout)")


def _report_new(test, path: Path, a: argparse.Namespace, what: str) -> int:
    from core.circle import analyze as analyze_test

    figures = analyze_test(test)
    if a.json:
        print_json({"file": str(path), "source": test.source, "figures": figures.to_dict()})
        return 0
    n = ", ".join(f"{p.direction} {p.angle_deg.size}" for p in test.passes)
    print(f"{what} -> {path}: R {test.radius_mm:g} mm at {test.feed_mm_min:g} mm/min in the plane "
          f"{''.join(test.plane)} ({n} samples; {test.instrument.kind}, resolution "
          f"{test.instrument.resolution_um:g} µm)")
    _print_figures(figures)
    print(f"next: mebm circle analyze {path} --backlash-um B --backlash-u-um U --gain-per-s K   (the spikes against "
          "Eq. 8 at the axis' b̄)")
    return 0


# -- analyze -----------------------------------------------------------------------------------------
def _tests_at(path: Path) -> list[tuple[Path, object]]:
    if path.is_dir():
        files = sorted((path / CIRCLES_DIR).glob("*.json"))
        if not files:
            raise CircleFileError(f"{path} has no circular test ({CIRCLES_DIR}/*.json): mebm circle measure or "
                                  f"import with --out {path} writes one")
        return [(f, read_test(f)) for f in files]
    if not path.exists():
        raise CircleFileError(f"{path}: no such file or folder")
    return [(path, read_test(path))]


def _dataset_backlash(folder: Path, axis: str):
    """The newest round trip of ``axis`` in the dataset folder: (b̄, U(b̄), K, run file) or the reason there is none."""
    from core.criteria import analyze_round_trip
    from core.criteria.uncertainty import inputs_of_spec
    from storage.dataset import read_dataset

    if not (folder / "dataset.json").is_file():
        return None, (f"{folder} is no dataset folder (no dataset.json): give --backlash-um, --backlash-u-um, "
                      "--gain-per-s")
    ds = read_dataset(folder)
    spec = ds.machine.axes.get(axis)
    runs = [r for r in ds.runs if r.spec.kind == "round_trip" and axis in r.spec.axes]
    if spec is None or not runs:
        return None, (f"the dataset {folder} has no round trip of axis {axis}: give --backlash-um, --backlash-u-um, "
                      "--gain-per-s")
    if spec.position_gain_per_s is None:
        return None, (f"the dataset's axis {axis} has no position_gain_per_s (K): give --gain-per-s, or the axis' "
                      "position_gain_per_s in dataset.json")
    run = max(runs, key=lambda r: (r.spec.utility_day if r.spec.utility_day is not None else -math.inf, r.spec.file))
    res = analyze_round_trip(run.time_s, run.motor_rev(axis), run.table_mm(axis), spec,
                             uncertainty=inputs_of_spec(run.spec))
    return (res.backlash_mean_um, res.backlash_mean_uncertainty_um, spec.position_gain_per_s, run.spec.file), None


def analyze(a: argparse.Namespace) -> int:
    from core.circle import analyze as analyze_test
    from api.cli.measure import parse_task
    from core.circle import compare_with_backlash, decide_circle

    path = Path(a.path)
    given = [a.backlash_um, a.backlash_u_um, a.gain_per_s]
    if any(v is not None for v in given) and not all(v is not None for v in given):
        raise InputError("the spikes against Eq. 8 need all three of --backlash-um, --backlash-u-um and --gain-per-s "
                         "(e.g. --backlash-um 120.2 --backlash-u-um 0.5 --gain-per-s 30, from mebm analyze and the "
                         "drive's K)")
    out = []
    for file, test in _tests_at(path):
        figures = analyze_test(test)
        axes = [x.strip().lower() for x in a.axis] if a.axis else list(test.plane)
        bad = [x for x in axes if x not in test.plane]
        if bad:
            raise InputError(f"--axis {bad[0]}: the test's plane is {''.join(test.plane)}; give one of its axes")
        agreements, notes, decisions = [], [], []
        for axis in axes:
            if a.backlash_um is not None:
                b, u, k, origin = a.backlash_um, a.backlash_u_um, a.gain_per_s, "given"
            elif path.is_dir():
                found, why = _dataset_backlash(path, axis)
                if found is None:
                    notes.append(f"axis {axis}: not compared with Eq. 8: {why}")
                    continue
                b, u, k, run = found
                origin = f"round trip {run}"
            else:
                notes.append(f"axis {axis}: not compared with Eq. 8 (give --backlash-um, --backlash-u-um, "
                             "--gain-per-s, or analyze the dataset folder that holds the axis' round trip)")
                continue
            ag = compare_with_backlash(figures, axis=axis, backlash_um=b, backlash_uncertainty_um=u, gain_per_s=k)
            agreements.append((ag, origin))
            if a.task:
                tasks = [parse_task(text, n, k) for n, text in enumerate(a.task)]
                d = decide_circle(figures, tasks, axis=axis, warning_fraction=a.warning_fraction, rule=a.rule)
                if d is None:
                    notes.append(f"axis {axis}: no --task at the test's radius {test.radius_mm:g} mm and feed "
                                 f"{test.feed_mm_min:g} mm/min (within 2 %): none judged")
                else:
                    decisions.append(d)
        if a.task and not agreements and not decisions:
            notes.append("the decision needs the axis' K: give --gain-per-s with --backlash-um and --backlash-u-um")
        out.append((file, test, figures, agreements, decisions, notes))
    if a.json:
        docs = [{"file": str(f), "source": t.source, "figures": fig.to_dict(),
                 "agreement": [{**ag.to_dict(), "backlash_from": origin} for ag, origin in ags],
                 "decision": [d.to_dict() for d in ds], "notes": notes}
                for f, t, fig, ags, ds, notes in out]
        print_json(docs if path.is_dir() else docs[0])
        return 0
    for f, t, fig, ags, ds, notes in out:
        print(f"{f}: R {t.radius_mm:g} mm at {t.feed_mm_min:g} mm/min in the plane {''.join(t.plane)}, "
              f"{'/'.join(t.directions)} ({t.source or 'source not recorded'})")
        _print_figures(fig)
        for ag, origin in ags:
            print(f"  Eq. 8, axis {ag.axis} (b̄ {origin}): spikes {ag.measured_um:.2f} ± "
                  f"{ag.measured_uncertainty_um:.2f} "
                  f"µm, predicted {ag.predicted_um:.2f} ± {ag.predicted_uncertainty_um:.2f} µm at b̄ "
                  f"{ag.backlash_um:.2f} ± {ag.backlash_uncertainty_um:.2f} µm, K {ag.gain_per_s:g}/s: E_n "
                  f"{ag.normalised_error:+.2f}, {ag.verdict.upper()}: {ag.meaning}")
            if ag.loop is not None and ag.loop.verdict != "agree":
                print(f"  loop, axis {ag.axis}: {ag.loop.sentence()}")
        for d in ds:
            print(f"  decision: {d.message()}")
        for n in notes:
            print(f"  {n}")
    print("U: expanded uncertainty, k = 2; E_n = (measured - predicted) / √(U_m² + U_p²), |E_n| <= 1 agrees")
    return 0


def _print_figures(f) -> None:
    u = f.circular_deviation_uncertainty_um
    print(f"  circular deviation G {f.circular_deviation_um:.2f} ± {u:.2f} µm (least squares), "
          f"{f.circular_deviation_mz_um:.2f} µm (minimum zone)")
    if f.hysteresis_um is not None:
        print(f"  circular hysteresis H {f.hysteresis_um:.2f} ± {f.hysteresis_uncertainty_um:.2f} µm")
    print(f"  radial deviation F max {f.radial_deviation_max_um:+.2f}, F min {f.radial_deviation_min_um:+.2f} ± "
          f"{f.radial_deviation_uncertainty_um:.2f} µm; mean radius {f.mean_radius_deviation_um:+.2f} µm, centre "
          f"offset ({f.centre_offset_um[0]:+.2f}, {f.centre_offset_um[1]:+.2f}) ± "
          f"{f.centre_offset_uncertainty_um:.2f} µm")
    for s in f.spikes:
        print(f"  spike {s.direction} at {s.quadrant_deg:>3g}° (axis {s.axis} reverses): {s.height_um:.2f} ± "
              f"{s.height_uncertainty_um:.2f} µm, {s.width_deg:.1f}° wide")

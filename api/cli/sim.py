"""``mebm sim round-trip|circle|line``: simulate a program and write it as a dataset run.

Each command appends one run to a dataset folder (created if absent), readable by
``mebm analyze``. Effects are added with ``--effect NAME:key=value,...`` (repeatable;
``--effect x.NAME:...`` applies to axis x only). A round trip is commanded over the
useful travel extended by ``--overtravel-mm`` at both ends (default 5 mm), so the
reversal transients fall outside the useful travel written to dataset.json.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from api.cli.output import print_json
from core.dataset import MachineSpec
from core.errors import DatasetError, InputError
from core.sim import AxisModel, Effects, Encoders, circle, line, parse_effect, round_trip, simulate
from core.sim.effects import effect_params
from storage.dataset import append_runs, next_run_name, read_dataset

DEFAULT_OVERTRAVEL_MM = 5.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="simulate a feed drive (the digital twin) and write a dataset run")
    ssub = p.add_subparsers(dest="sim_command", metavar="PROGRAM")
    ssub.required = True

    rt = ssub.add_parser("round-trip", help="one axis out and back over its travel (backlash and lead measurement)")
    rt.add_argument("--axis", default="y", help="axis name (default y)")
    rt.add_argument("--travel-mm", type=float, help="useful travel from --start-mm (default 600 mm)")
    rt.add_argument("--start-mm", type=float, help="start of the useful travel (default 0)")
    rt.add_argument("--end-mm", type=float, help="end of the useful travel (instead of --travel-mm)")
    rt.add_argument("--overtravel-mm", type=float, default=DEFAULT_OVERTRAVEL_MM,
                    help="commanded travel beyond each end of the useful travel (default 5 mm)")
    rt.add_argument("--feed-mm-min", type=float, required=True, help="programmed feed (mm/min)")
    rt.add_argument("--acceleration-mm-s2", type=float, default=500.0, help="ramp acceleration; inf = no ramp")
    rt.add_argument("--dwell-s", type=float, default=1.0, help="dwell at both ends (s)")
    _common(rt)
    rt.set_defaults(func=_round_trip)

    c = ssub.add_parser("circle", help="a circle of two axes (TBE at the quadrant points)")
    c.add_argument("--radius-mm", type=float, required=True)
    c.add_argument("--feed-mm-min", type=float, required=True, help="programmed feed (mm/min)")
    c.add_argument("--direction", choices=("cw", "ccw"), default="ccw")
    c.add_argument("--axes", default="x,y", help="the two axes, first one is the angle origin (default x,y)")
    c.add_argument("--centre-mm", type=float, nargs=2, default=(0.0, 0.0), metavar=("A", "B"))
    c.add_argument("--start-angle-deg", type=float, default=-90.0, help="start of the recorded arc")
    c.add_argument("--sweep-deg", type=float, default=360.0, help="length of the recorded arc")
    c.add_argument("--lead-in-deg", type=float, help="arc run before the recorded one (default: 1 s of feed)")
    c.add_argument("--lead-out-deg", type=float, help="arc run after the recorded one (default: as lead-in)")
    c.add_argument("--acceleration-mm-s2", type=float, help="start-up ramp (default: feed from the start)")
    _common(c)
    c.set_defaults(func=_circle)

    ln = ssub.add_parser("line", help="a straight line of two axes (the paper's Eq. 7 start)")
    ln.add_argument("--angle-deg", type=float, required=True, help="angle to the first (reversely engaged) axis")
    ln.add_argument("--length-mm", type=float, required=True)
    ln.add_argument("--feed-mm-min", type=float, required=True, help="programmed feed (mm/min)")
    ln.add_argument("--axes", default="x,y", help="the two axes (default x,y)")
    ln.add_argument("--start-mm", type=float, nargs=2, default=(0.0, 0.0), metavar=("A", "B"))
    ln.add_argument("--settle-s", type=float, default=1.0, help="recorded time after the end of the line")
    _common(ln)
    ln.set_defaults(func=_line)


def _common(q: argparse.ArgumentParser) -> None:
    q.add_argument("--out", required=True, help="dataset folder to create or append the run to")
    q.add_argument("--machine-id", default="sim", help="machine id of a new dataset (default sim)")
    q.add_argument("--transmission-mm-per-rev", type=float, default=6.857, help="k_a (default 6.857)")
    q.add_argument("--screw-lead-mm", type=float, default=16.0, help="ball-screw lead (default 16)")
    q.add_argument("--gain-per-s", type=float, default=10.0, help="position gain K = k_a k_p (default 10)")
    q.add_argument("--backlash-um", type=float, default=0.0, help="backlash width b (default 0)")
    q.add_argument("--initial-side", choices=("auto", "positive", "negative"), default="auto",
                   help="flank the nut pushed last (default: the program's natural start)")
    q.add_argument("--effect", action="append", default=[], metavar="[AXIS.]NAME:key=value,...",
                   help="add a real-machine effect (repeatable), e.g. friction:coulomb_n=300,static_n=380")
    q.add_argument("--motor-counts-per-rev", type=float, default=0.0, help="motor encoder counts/rev (0 = ideal)")
    q.add_argument("--table-resolution-um", type=float, default=0.0, help="linear scale resolution (0 = ideal)")
    q.add_argument("--motor-noise-um", type=float, default=0.0, help="motor encoder noise as table travel, 1 sigma")
    q.add_argument("--table-noise-um", type=float, default=0.0, help="linear scale noise, 1 sigma")
    q.add_argument("--temperature-c", type=float, default=20.0, help="machine temperature (default 20)")
    q.add_argument("--seed", type=int, default=0, help="seed of the noise generator (default 0)")
    q.add_argument("--rate-hz", type=float, default=1000.0, help="sampling rate of the run (default 1000)")
    q.add_argument("--split", choices=("train", "test"), help="split label of the run")
    q.add_argument("--utility-day", type=float, help="days in service at the run")
    q.add_argument("--json", action="store_true", help="print a JSON summary")


def _axis_names(text: str) -> tuple[str, str]:
    names = tuple(a.strip().lower() for a in text.split(",") if a.strip())
    if len(names) != 2 or names[0] == names[1]:
        raise InputError(f"--axes (={text!r}) must name two different axes, e.g. x,y")
    return names


def _effects_per_axis(specs: list[str], axes: tuple[str, ...]) -> dict[str, Effects]:
    out = {a: Effects() for a in axes}
    for spec in specs:
        head, colon, rest = spec.partition(":")
        target = axes
        if "." in head:
            axis, _, head = head.partition(".")
            axis = axis.strip().lower()
            if axis not in axes:
                raise InputError(f"--effect {spec!r}: axis {axis!r} is not in this program's axes {list(axes)}")
            target = (axis,)
        category, effect = parse_effect(head + colon + rest)
        for a in target:
            out[a] = out[a].with_effect(category, effect)
    return out


def _models(a: argparse.Namespace, axes: tuple[str, ...]) -> dict[str, AxisModel]:
    encoders = Encoders(
        motor_counts_per_rev=a.motor_counts_per_rev,
        table_resolution_um=a.table_resolution_um,
        motor_noise_um=a.motor_noise_um,
        table_noise_um=a.table_noise_um,
    )
    effects = _effects_per_axis(a.effect, axes)
    return {
        name: AxisModel(
            name=name,
            transmission_mm_per_rev=a.transmission_mm_per_rev,
            screw_lead_mm=a.screw_lead_mm,
            position_gain_per_s=a.gain_per_s,
            backlash_um=a.backlash_um,
            initial_side=a.initial_side,
            effects=effects[name],
            encoders=encoders,
        )
        for name in axes
    }


def _write(a: argparse.Namespace, models, program, travels: dict[str, tuple[float, float]], stem: str) -> int:
    out = Path(a.out)
    existing = {}
    if (out / "dataset.json").is_file():
        existing = dict(read_dataset(out, load_runs=False).machine.axes)
    specs = {}
    for name, model in models.items():
        spec = model.to_axis_spec(travels[name])
        old = existing.get(name)
        if old is not None:  # the machine's travel is kept; k_a, lead and K must agree
            spec = model.to_axis_spec(old.travel_mm)
            if spec != old:
                raise DatasetError(
                    f"axis {name!r} of the simulated machine (k_a {spec.transmission_mm_per_rev}, lead "
                    f"{spec.screw_lead_mm}, K {spec.position_gain_per_s}) differs from the dataset's (k_a "
                    f"{old.transmission_mm_per_rev}, lead {old.screw_lead_mm}, K {old.position_gain_per_s})",
                    source=str(out / "dataset.json"),
                )
        specs[name] = spec
    trace = simulate(
        models,
        program,
        temperature_c=a.temperature_c,
        rate_hz=a.rate_hz,
        rng=np.random.default_rng(a.seed),
    )
    file = next_run_name(out, stem)
    effects = {n: {c: effect_params(getattr(m.effects, c)) for c in m.effects.active} for n, m in models.items()}
    extra = {"backlash_um": a.backlash_um}
    if any(effects.values()):
        extra["effects"] = effects
    run = trace.to_run(file, split=a.split, utility_day=a.utility_day, extra=extra)
    append_runs(out, MachineSpec(id=a.machine_id, axes=specs), [run])
    summary = {
        "dataset": str(out),
        "file": file,
        "kind": program.kind,
        "axes": list(program.axes),
        "samples": len(run),
        "duration_s": float(trace.time_s[-1] - trace.time_s[0]),
        "step_s": dict(trace.step_s),
        "effects": effects,
    }
    if a.json:
        print_json(summary)
    else:
        active = "; ".join(f"{n}: {', '.join(e) or 'nominal'}" for n, e in effects.items())
        print(f"wrote {file} ({summary['samples']} samples, {summary['duration_s']:.2f} s; {active}) to {out}")
    return 0


def _round_trip(a: argparse.Namespace) -> int:
    start = 0.0 if a.start_mm is None else a.start_mm
    if a.end_mm is not None and a.travel_mm is not None:
        raise InputError("give --travel-mm or --end-mm, not both")
    end = a.end_mm if a.end_mm is not None else start + (600.0 if a.travel_mm is None else a.travel_mm)
    if not (math.isfinite(a.overtravel_mm) and a.overtravel_mm >= 0):
        raise InputError(f"--overtravel-mm (={a.overtravel_mm}) must be >= 0")
    if end == start:
        raise InputError(f"the useful travel is empty (start {start} mm, end {end} mm)")
    sign = 1.0 if end > start else -1.0
    axis = a.axis.strip().lower()
    program = round_trip(
        start - sign * a.overtravel_mm,
        end + sign * a.overtravel_mm,
        a.feed_mm_min,
        acceleration_mm_s2=a.acceleration_mm_s2,
        dwell_s=a.dwell_s,
        axis=axis,
    )
    models = _models(a, (axis,))
    return _write(a, models, program, {axis: (min(start, end), max(start, end))}, f"rt_{axis}")


def _range_travel(values: np.ndarray) -> tuple[float, float]:
    lo, hi = float(np.min(values)), float(np.max(values))
    return (lo - DEFAULT_OVERTRAVEL_MM, hi + DEFAULT_OVERTRAVEL_MM)


def _circle(a: argparse.Namespace) -> int:
    axes = _axis_names(a.axes)
    program = circle(
        a.radius_mm,
        tuple(a.centre_mm),
        a.feed_mm_min,
        a.direction,
        a.start_angle_deg,
        a.sweep_deg,
        axes=axes,
        lead_in_deg=a.lead_in_deg,
        lead_out_deg=a.lead_out_deg,
        acceleration_mm_s2=a.acceleration_mm_s2,
    )
    travels = {n: (c - a.radius_mm - DEFAULT_OVERTRAVEL_MM, c + a.radius_mm + DEFAULT_OVERTRAVEL_MM)
               for n, c in zip(axes, a.centre_mm)}  # fmt: skip
    return _write(a, _models(a, axes), program, travels, "circle")


def _line(a: argparse.Namespace) -> int:
    axes = _axis_names(a.axes)
    program = line(a.angle_deg, a.length_mm, a.feed_mm_min, tuple(a.start_mm), axes=axes, settle_s=a.settle_s)
    t = np.linspace(0.0, program.duration_s, 11)
    pos = program.command_mm(t)
    return _write(a, _models(a, axes), program, {n: _range_travel(pos[n]) for n in axes}, "line")


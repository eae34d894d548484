"""Benchmark datasets from the independent plant: round trips and circles of a 2-axis machine.

The case structure mirrors ``core.gap_benchmark.make_case``: per axis ``rt_train`` + ``rt_test``
round trips, then ``circles_train`` + ``circles_test`` circles; test runs lie outside the
train conditions (8-12 or 28-32 degC against 17-24 degC, other feeds and/or accelerations,
other radii, strokes anywhere on the travel). Beyond it, so that the diagnosis meets what a real machine records:

- circles are recorded with a feed-in arc and a lead-out of random length (0-180 deg, a
  quarter of them exactly 0: starting at rest on the data arc / stopping at its end),
  written as ``lead_in_deg``/``lead_out_deg`` in half of the datasets, absent in the rest;
- one third of the datasets have no ``split`` field (their test runs still sit at the
  extreme conditions, so a held-out split by temperature or feed makes sense);
- every run has ``<a>_command_mm`` (the interpolated set-points), ``<a>_motor_rev``,
  ``<a>_table_mm`` and a ``time_s`` that starts at an arbitrary controller-clock value.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from core.errors import InputError

from .drive import IPO_DT_S, simulate_axis
from .effects import (
    EFFECTS,
    LABELS,
    TRAVEL_MM,
    _u,
    backlash_lut,
    draw_effect,
    draw_nominal,
    drive_params,
    nut_error_lut,
    skew_s,
)
from .program import Program, circle_program, round_trip_program

AXES = ("x", "y")
TABLE_QUANT_MM = 0.05e-6 * 1e3  # 0.05 um
MOTOR_COUNTS_PER_REV = 2**20


@dataclass(frozen=True)
class PlantSize:
    """How big a dataset is: round trips per axis (train, test), circles (train, test),
    sample rates and the round trips' target duration."""

    rt_train_per_axis: int = 3
    rt_test_per_axis: int = 1
    circles_train: int = 4
    circles_test: int = 2
    rt_rate_hz: float = 1000.0
    circle_rate_hz: float = 500.0
    rt_duration_s: float = 30.0


SMALL_PLANT = PlantSize(2, 1, 2, 1, 250.0, 200.0, 14.0)


@dataclass(frozen=True)
class PlantCase:
    labels: tuple[str, ...]  # () for none; 1 or 2 effect names
    truth: dict
    dataset: Dataset = field(repr=False)


@dataclass(frozen=True)
class Layout:
    """Per-dataset choices of what is written: split fields, lead-in/out fields."""

    has_split: bool
    writes_lead: bool
    jerk_time_s: float


def draw_layout(rng: np.random.Generator) -> Layout:
    return Layout(has_split=bool(rng.random() >= 1.0 / 3.0), writes_lead=bool(rng.random() < 0.5),
                  jerk_time_s=_u(rng, 0.008, 0.03))  # fmt: skip


def _check_labels(labels: tuple[str, ...]) -> tuple[str, ...]:
    labels = tuple(labels)
    if labels == ("none",):
        return ()
    bad = [x for x in labels if x not in EFFECTS]
    if bad or len(labels) > 2 or len(set(labels)) != len(labels):
        raise InputError(f"labels (={labels!r}) must be (), ('none',) or 1-2 distinct names of {EFFECTS}")
    return labels


def record_program(prog: Program, axes: tuple[str, ...], temp_c: float, rate_hz: float, nominal: dict, effects: dict,
            skew: dict | None, rng: np.random.Generator, noise: bool = True) -> dict[str, np.ndarray]:  # fmt: skip
    """Simulate the program on each axis and sample both encoders and the command.

    ``noise=False`` leaves out encoder noise and quantisation (for checks of the physics).
    """
    dur = prog.duration_s
    t = np.arange(int(np.floor(dur * rate_hz)) + 1) / rate_hz
    delay = skew_s(skew, t, rng)
    cols: dict[str, np.ndarray] = {}
    for a in axes:
        nom, eff = nominal[a], effects[a]
        cmd = prog.command_mm[a]
        # the nut starts on a random flank: the axis came to its start point from either side
        side = 1 if rng.random() < 0.5 else -1
        traj = simulate_axis(drive_params(nom, eff), cmd, dur + 0.05, nut_error_lut(nom, eff, temp_c),
                             backlash_lut(nom, eff, temp_c), side)  # fmt: skip
        k_a = nom["transmission_mm_per_rev"]
        u = traj.motor_at(t)
        x = traj.table_at(np.clip(t + delay, 0.0, dur))
        cols[f"{a}_command_mm"] = np.interp(t, np.arange(cmd.shape[0]) * IPO_DT_S, cmd)
        if not noise:
            cols[f"{a}_motor_rev"] = u / k_a + nom["motor_zero_rev"]
            cols[f"{a}_table_mm"] = x
            continue
        u = u + nom["motor_noise_um"] * 1e-3 * rng.standard_normal(t.shape)
        x = x + nom["table_noise_um"] * 1e-3 * rng.standard_normal(t.shape)
        rev = u / k_a + nom["motor_zero_rev"]
        cols[f"{a}_motor_rev"] = np.round(rev * MOTOR_COUNTS_PER_REV) / MOTOR_COUNTS_PER_REV
        cols[f"{a}_table_mm"] = np.round(x / TABLE_QUANT_MM) * TABLE_QUANT_MM
    clock0 = round(_u(rng, 1.0, 3600.0), 3)
    cols["time_s"] = clock0 + t
    return cols


def make_plant_case(labels: tuple[str, ...], rng: np.random.Generator, size: PlantSize = PlantSize()) -> PlantCase:
    """A dataset of the independent plant carrying ``labels`` (() or ('none',) for none; 1-2 effects)."""
    labels = _check_labels(labels)
    layout = draw_layout(rng)
    nominal = {a: draw_nominal(rng) for a in AXES}
    effects: dict[str, dict] = {a: {} for a in AXES}
    skew = None
    for label in labels:
        if label == "sampling_skew":
            skew = draw_effect(label, rng, nominal["x"])  # one acquisition delay for both axes
            continue
        for a in AXES:
            effects[a][label] = draw_effect(label, rng, nominal[a])
    truth: dict = {"labels": list(labels), "layout": asdict(layout)}
    for a in AXES:
        truth[a] = {"nominal": nominal[a], **effects[a], "drive": asdict(drive_params(nominal[a], effects[a]))}
        if skew is not None:
            truth[a]["sampling_skew"] = skew
    name = "+".join(labels) or "none"
    machine = MachineSpec(id=f"plant-{name}", axes={
        a: AxisSpec(a, nominal[a]["transmission_mm_per_rev"], nominal[a]["screw_lead_mm"],
                    nominal[a]["position_gain_per_s"], TRAVEL_MM) for a in AXES})  # fmt: skip
    day = float(rng.integers(0, 1000))

    def split(test: bool) -> str | None:
        return ("test" if test else "train") if layout.has_split else None

    runs: list[Run] = []
    k = 0
    for a in AXES:
        n_tr, n_te = size.rt_train_per_axis, size.rt_test_per_axis
        temps_train = rng.permutation(np.linspace(17.0, 24.0, n_tr) + rng.uniform(-0.5, 0.5, n_tr))
        feeds_train = np.geomspace(600.0, 1600.0, n_tr) if n_tr > 1 else np.array([1000.0])
        for i in range(n_tr + n_te):
            test = i >= n_tr
            if test:
                temp = _u(rng, 8, 12) if rng.random() < 0.5 else _u(rng, 28, 32)
                other = ("feed", "acc", "both")[int(rng.integers(3))]
                feed = _u(rng, 700, 1500)
                if other in ("feed", "both"):
                    feed = _u(rng, 2200, 3000) if rng.random() < 0.5 else _u(rng, 300, 450)
                acc = _u(rng, 1300, 2000) if other in ("acc", "both") else _u(rng, 300, 1000)
            else:
                feed, temp, acc = float(feeds_train[i]), float(temps_train[i]), _u(rng, 300, 1000)
            lo, hi = 40.0, 760.0
            length = float(np.clip(feed / 60.0 * (size.rt_duration_s - 3.0) / 2.0, 30.0, hi - lo))
            start = _u(rng, lo, hi - length) if test else lo + (hi - lo - length) * (i / max(n_tr - 1, 1))
            prog = round_trip_program(a, start, start + length, feed, acc, 1.0, layout.jerk_time_s)
            cols = record_program(prog, (a,), temp, size.rt_rate_hz, nominal, effects, skew, rng)
            spec = RunSpec(file=f"rt_{a}_{k:02d}.csv", kind="round_trip", axes=(a,), feed_mm_min=feed,
                           temperature_c=temp, utility_day=day, acceleration_mm_s2=acc, split=split(test),
                           extra={"stroke_mm": [start, start + length], "dwell_s": 1.0})  # fmt: skip
            runs.append(Run(spec, cols))
            k += 1
    for i in range(size.circles_train + size.circles_test):
        test = i >= size.circles_train
        if test:
            radius = _u(rng, 100, 150) if rng.random() < 0.5 else _u(rng, 15, 25)
            feed = _u(rng, 2000, 3000)
            temp = _u(rng, 8, 12) if rng.random() < 0.5 else _u(rng, 28, 32)
            acc = _u(rng, 800, 2000)
        else:
            radius, feed, temp, acc = _u(rng, 30, 80), _u(rng, 500, 1500), _u(rng, 17, 24), _u(rng, 400, 1000)
        centre = (_u(rng, 200, 600), _u(rng, 200, 600))
        direction = "ccw" if i % 2 == 0 else "cw"
        start_deg = float(np.round(_u(rng, -180.0, 180.0)))
        lead_in, lead_out = (0.0 if rng.random() < 0.25 else _u(rng, 0.0, 180.0) for _ in range(2))
        prog, _ = circle_program(AXES, radius, centre, feed, acc, direction, start_deg, 360.0, lead_in, lead_out,
                                 layout.jerk_time_s)  # fmt: skip
        cols = record_program(prog, AXES, temp, size.circle_rate_hz, nominal, effects, skew, rng)
        extra = {"lead_in_deg": lead_in, "lead_out_deg": lead_out} if layout.writes_lead else {}
        spec = RunSpec(file=f"circle_{i:02d}.csv", kind="circle", axes=AXES, feed_mm_min=feed, temperature_c=temp,
                       utility_day=day, acceleration_mm_s2=acc, split=split(test), radius_mm=radius,
                       centre_mm=centre, direction=direction, start_angle_deg=start_deg, sweep_deg=360.0,
                       extra=extra)  # fmt: skip
        truth.setdefault("circles", []).append({"file": spec.file, "lead_in_deg": lead_in, "lead_out_deg": lead_out})
        runs.append(Run(spec, cols))
    return PlantCase(labels, truth, Dataset(machine, tuple(runs)))


__all__ = ["LABELS", "PlantCase", "PlantSize", "SMALL_PLANT", "make_plant_case"]

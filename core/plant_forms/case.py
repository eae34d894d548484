"""Benchmark cases of the second plant: a drawn two-axis machine, its programs and runs.

A case holds round trips per axis (out and back over 70-90 % of the travel, dwells of
0.3-1 s, feeds set so the trip fills 55-85 % of the run duration, at most 20 m/min)
and x-y circles (radius 20-150 mm, data arc 360° after a lead-in arc of 30-90° and
before a lead-out of 20-60°, feed 1-6 m/min; the radius shrinks (to 10 mm at least), then
the feed rises, when the circle would outlast the run duration), both axes' motor and table encoders latched at the sample rate. The
dataset's largest acceleration a_max is 300-1000 mm/s²; a run's path acceleration is
(0.5-1) a_max, a circle's feed keeps v²/R ≤ a_max; jerk filter 8-40 ms. Sample rates are the size's
rates times 0.8-1.2, drawn per dataset. Ambient temperature per run is the dataset's
17-25 °C ± 2 K, with a per-sample drift of ±0.5 K/h. Two thirds of the datasets mark
``split``; the rest leave it to the diagnosis.

Random streams: one generator per concern (machine and programs, noise, split, one per
effect label), all seeded from the caller's generator, so that the same seed with an
effect on or off gives the same nominal machine, programs and noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec, validate_columns, validate_run_spec
from core.errors import InputError
from core.plant_forms import drive
from core.plant_forms.forms import axis_params, draw_axis, draw_effect
from core.plant_forms.programs import path_profile

LABELS = ("none", "thermal", "backlash_profile", "cyclic_error", "friction", "compliance", "servo_dynamics",
          "sampling_skew")
AXES = ("x", "y")
SUB_STEP_S = 25e-6  # integration step at most; an integer fraction of the sample period


@dataclass(frozen=True)
class FormsSize:
    """How many runs a case holds, at which nominal rates (Hz) and round-trip length (s)."""

    rt_train_per_axis: int = 3
    rt_test_per_axis: int = 1
    circles_train: int = 4
    circles_test: int = 2
    rt_rate_hz: float = 1000.0
    circle_rate_hz: float = 500.0
    rt_duration_s: float = 30.0


@dataclass(frozen=True)
class FormsCase:
    """The effect labels, every drawn parameter (JSON-serialisable) and the dataset."""

    labels: tuple[str, ...]
    truth: dict
    dataset: Dataset


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _check(labels: tuple[str, ...], size: FormsSize) -> tuple[str, ...]:
    for key in ("rt_train_per_axis", "rt_test_per_axis", "circles_train", "circles_test"):
        if getattr(size, key) < 0:
            raise InputError(f"{key} (={getattr(size, key)}) must be >= 0")
    for key in ("rt_rate_hz", "circle_rate_hz", "rt_duration_s"):
        if not getattr(size, key) > 0:
            raise InputError(f"{key} (={getattr(size, key)}) must be > 0")
    labels = tuple(labels)
    if labels in ((), ("none",)):
        return ()
    for lab in labels:
        if lab not in LABELS or lab == "none":
            raise InputError(f"label (={lab!r}) must be one of {LABELS[1:]} (or the labels () / ('none',))")
    if not 1 <= len(labels) <= 2 or len(set(labels)) != len(labels):
        raise InputError(f"labels (={labels!r}) must be 1 or 2 distinct effect labels")
    return labels


def _round_trip_program(rng, ax: dict, size: FormsSize, max_accel_mm_s2: float) -> dict:
    length = ax["travel_mm"][1] - ax["travel_mm"][0]
    stroke = length * _u(rng, 0.7, 0.9)
    start = ax["travel_mm"][0] + _u(rng, 0.0, length - stroke)
    dwells = [_u(rng, 0.3, 1.0) for _ in range(3)]
    window_s = _u(rng, 0.008, 0.04)
    accel = _u(rng, 0.5, 1.0) * max_accel_mm_s2
    moving_s = max(size.rt_duration_s - sum(dwells) - 2 * window_s, 0.2 * size.rt_duration_s)
    feed_mm_s = min(2 * stroke / (_u(rng, 0.55, 0.85) * moving_s), 20000.0 / 60)
    outward = 1.0 if rng.random() < 0.5 else -1.0
    if outward < 0:
        start += stroke
    return {"start_mm": start, "stroke_mm": stroke, "direction": outward, "dwells_s": dwells,
            "jerk_window_s": window_s, "acceleration_mm_s2": accel, "feed_mm_min": feed_mm_s * 60}


def _circle_program(rng, axes: dict, size: FormsSize, max_accel_mm_s2: float) -> dict:
    centre = [0.5 * (axes[a]["travel_mm"][0] + axes[a]["travel_mm"][1]) for a in AXES]
    r_max = min(150.0, 0.3 * min(axes[a]["travel_mm"][1] - axes[a]["travel_mm"][0] for a in AXES))
    radius = _u(rng, 20.0, r_max)
    lead_in, lead_out = _u(rng, 30.0, 90.0), _u(rng, 20.0, 60.0)
    feed_mm_s = _u(rng, 1000.0, 6000.0) / 60
    dwells = [_u(rng, 0.3, 1.0) for _ in range(2)]
    budget_s = max(0.85 * size.rt_duration_s - sum(dwells), 0.5)
    arc_rad = np.radians(lead_in + 360.0 + lead_out)
    radius = max(min(radius, feed_mm_s * budget_s / arc_rad), 10.0)  # the circle fits the run duration
    if arc_rad * radius / feed_mm_s > budget_s:
        feed_mm_s = arc_rad * radius / budget_s
    # The centripetal acceleration stays within the dataset's largest acceleration.
    feed_mm_s = min(feed_mm_s, np.sqrt(max_accel_mm_s2 * radius))
    accel = _u(rng, 0.5, 1.0) * max_accel_mm_s2
    return {"centre_mm": centre, "radius_mm": radius, "lead_in_deg": lead_in, "lead_out_deg": lead_out,
            "start_angle_deg": float(rng.choice([-90.0, 0.0, 90.0, 180.0])),
            "direction": "ccw" if rng.random() < 0.5 else "cw", "dwells_s": dwells,
            "jerk_window_s": _u(rng, 0.008, 0.04), "acceleration_mm_s2": accel,
            "feed_mm_min": feed_mm_s * 60}


def _rt_command(prog: dict, dt_s: float) -> dict:
    v, a = prog["feed_mm_min"] / 60, prog["acceleration_mm_s2"]
    w, L = prog["dwells_s"], prog["direction"] * prog["stroke_mm"]
    s = path_profile([(w[0], L, v, a), (w[1], -L, v, a), (w[2], 0.0, v, a)], prog["jerk_window_s"], dt_s)
    return {"x": prog["start_mm"] + s}


def _circle_command(prog: dict, dt_s: float) -> dict:
    v, a, w = prog["feed_mm_min"] / 60, prog["acceleration_mm_s2"], prog["dwells_s"]
    r = prog["radius_mm"]
    sgn = 1.0 if prog["direction"] == "ccw" else -1.0
    path = np.radians(prog["lead_in_deg"] + 360.0 + prog["lead_out_deg"]) * r
    s = path_profile([(w[0], path, v, a), (w[1], 0.0, v, a)], prog["jerk_window_s"], dt_s)
    phi = np.radians(prog["start_angle_deg"] - sgn * prog["lead_in_deg"]) + sgn * s / r
    cx, cy = prog["centre_mm"]
    return {"x": cx + r * np.cos(phi), "y": cy + r * np.sin(phi)}


def _sub_step_s(rate_hz: float) -> float:
    period_s = 1.0 / rate_hz
    return period_s / int(np.ceil(period_s / SUB_STEP_S))


def _commands(kind: str, axes: tuple, prog: dict, rate_hz: float) -> tuple[float, dict]:
    """The run's sample rate and its set-points per axis on the sub-step grid (mm)."""
    if kind == "round_trip":
        return rate_hz, {axes[0]: _rt_command(prog, _sub_step_s(rate_hz))["x"]}
    return rate_hz, _circle_command(prog, _sub_step_s(rate_hz))


def _size_torque_limit(effect: dict, machine: dict, commands: list) -> None:
    """Set each axis's force limit between the steady force at the fastest feed and the
    nominal drive's largest peak force over the runs, so it cuts the hardest accelerations only."""
    for a, q in effect["axes"].items():
        ax = machine[a]
        peaks, speeds = [], []
        for rate, cmds in commands:
            if a in cmds:
                dt_s = _sub_step_s(rate)
                peaks.append(drive.simulate_axis(cmds[a] * 1e-3, dt_s, axis_params(ax, {}, a), 1.0)[3])
                speeds.append(np.abs(np.diff(cmds[a])).max() / dt_s)
        steady_n = ax["coulomb_n"] + ax["viscous_n_s_per_m"] * max(speeds, default=0.0) * 1e-3
        q["steady_force_n"] = float(steady_n)
        q["nominal_peak_force_n"] = float(np.max(peaks)) if peaks else 2 * steady_n
        q["f_max_n"] = steady_n + q["fraction"] * max(q["nominal_peak_force_n"] - steady_n, 0.0)


def _latch(fine_mm: np.ndarray, dt_s: float, t_s: np.ndarray) -> np.ndarray:
    return np.interp(t_s, np.arange(fine_mm.shape[0]) * dt_s, fine_mm)


def _simulate_run(cmds: dict, rate_hz: float, machine: dict, params: dict, noise_rng, skew_s: float,
                  max_skew_s: float, sides: dict, motor_zero_rev: dict) -> dict:
    period_s = 1.0 / rate_hz
    dt_s = _sub_step_s(rate_hz)
    n_sub = int(round(period_s / dt_s))
    cols: dict = {}
    n_fine = min(c.shape[0] for c in cmds.values())
    # The sample count leaves room for the largest latch delay, so it does not depend on the skew.
    n = int((n_fine - 1) * dt_s / period_s - max_skew_s / period_s) - 1
    t_s = np.arange(n) * period_s
    cols["time_s"] = t_s
    for a, cmd_fine_mm in cmds.items():
        ax = machine[a]
        x_m, x_scale, _, _ = drive.simulate_axis(cmd_fine_mm * 1e-3, dt_s, params[a], sides[a])
        cols[f"{a}_command_mm"] = cmd_fine_mm[::n_sub][:n]
        motor_mm = x_m[::n_sub][:n] * 1e3 + noise_rng.normal(0.0, ax["motor_noise_um"] * 1e-3, n)
        counts = ax["motor_counts_per_rev"]
        k_a = ax["transmission_mm_per_rev"]
        cols[f"{a}_motor_rev"] = np.round(motor_mm / k_a * counts) / counts + motor_zero_rev[a]
        table_mm = _latch(x_scale * 1e3, dt_s, t_s + skew_s) + noise_rng.normal(0.0, ax["scale_noise_um"] * 1e-3, n)
        q_mm = ax["scale_quantum_um"] * 1e-3
        cols[f"{a}_table_mm"] = np.round(table_mm / q_mm) * q_mm
    return cols


def make_forms_case(labels: tuple[str, ...], rng: np.random.Generator, size: FormsSize = FormsSize()) -> FormsCase:
    """A two-axis machine with the effects ``labels`` (() or ('none',) for none), its runs and truth."""
    labels = _check(labels, size)
    seeds = rng.integers(0, 2**63 - 1, size=3 + len(LABELS))
    nom_rng, noise_rng, split_rng = (np.random.default_rng(int(s)) for s in seeds[:3])

    max_accel = _u(nom_rng, 300.0, 1000.0)
    machine = {a: draw_axis(nom_rng, max_accel) for a in AXES}
    rt_rate = size.rt_rate_hz * _u(nom_rng, 0.8, 1.2)
    circle_rate = size.circle_rate_hz * _u(nom_rng, 0.8, 1.2)
    ambient_c = _u(nom_rng, 17.0, 25.0)
    day = round(_u(nom_rng, 0.0, 3000.0))
    n_rt = size.rt_train_per_axis + size.rt_test_per_axis
    n_circ = size.circles_train + size.circles_test
    rt_progs = {a: [_round_trip_program(nom_rng, machine[a], size, max_accel) for _ in range(n_rt)] for a in AXES}
    circ_progs = [_circle_program(nom_rng, machine, size, max_accel) for _ in range(n_circ)]
    runs_meta = []
    for a in AXES:
        for i, prog in enumerate(rt_progs[a]):
            runs_meta.append(("round_trip", f"rt_{a}_{i:02d}.csv", (a,), prog, i >= size.rt_train_per_axis))
    for i, prog in enumerate(circ_progs):
        runs_meta.append(("circle", f"circle_{i:02d}.csv", AXES, prog, i >= size.circles_train))
    run_env = [{"temperature_c": ambient_c + _u(nom_rng, -2.0, 2.0), "drift_k_per_h": _u(nom_rng, -0.5, 0.5),
                "sides": {a: float(nom_rng.choice([-1.0, 1.0])) for a in AXES},
                "motor_zero_rev": {a: float(nom_rng.integers(-5000, 5000)) for a in AXES}} for _ in runs_meta]

    all_rt = [p for a in AXES for p in rt_progs[a]]
    ctx = {"duration_s": size.rt_duration_s, "rt_period_s": 1.0 / rt_rate,
           "mean_rt_feed_mm_s": float(np.mean([p["feed_mm_min"] / 60 for p in all_rt])) if all_rt else 50.0}
    effects = {lab: draw_effect(lab, np.random.default_rng(int(seeds[3 + LABELS.index(lab)])), machine, ctx)
               for lab in labels}
    commands = [_commands(kind, axes, prog, rt_rate if kind == "round_trip" else circle_rate)
                for kind, _, axes, prog, _ in runs_meta]
    if effects.get("servo_dynamics", {}).get("form") == "torque_limit":
        _size_torque_limit(effects["servo_dynamics"], machine, commands)
    params = {a: axis_params(machine[a], effects, a) for a in AXES}
    skew_s = effects["sampling_skew"]["delay_s"] if "sampling_skew" in effects else 0.0

    mark_split = bool(split_rng.random() < 2 / 3)
    axis_specs = {a: AxisSpec(name=a, transmission_mm_per_rev=machine[a]["transmission_mm_per_rev"],
                              screw_lead_mm=machine[a]["screw_lead_mm"],
                              position_gain_per_s=machine[a]["position_gain_per_s"],
                              travel_mm=tuple(machine[a]["travel_mm"])) for a in AXES}
    spec_machine = MachineSpec(id=f"plant-forms-{int(seeds[0]) % 100000:05d}", axes=axis_specs)
    runs = []
    for (kind, file, axes, prog, is_test), env, (rate, cmds) in zip(runs_meta, run_env, commands):
        extra = {}
        if kind == "circle":
            extra = {"lead_in_deg": float(prog["lead_in_deg"]), "lead_out_deg": float(prog["lead_out_deg"])}
        cols = _simulate_run(cmds, rate, machine, params, noise_rng, skew_s, 3.0 / rt_rate,
                             env["sides"], env["motor_zero_rev"])
        cols["temperature_c"] = env["temperature_c"] + env["drift_k_per_h"] * cols["time_s"] / 3600.0
        common = dict(file=file, kind=kind, axes=tuple(axes), feed_mm_min=float(prog["feed_mm_min"]),
                      temperature_c=float(env["temperature_c"]), utility_day=float(day),
                      acceleration_mm_s2=float(prog["acceleration_mm_s2"]),
                      split=("test" if is_test else "train") if mark_split else None, extra=extra)
        if kind == "circle":
            spec = RunSpec(**common, radius_mm=float(prog["radius_mm"]),
                           centre_mm=tuple(float(c) for c in prog["centre_mm"]), direction=prog["direction"],
                           start_angle_deg=float(prog["start_angle_deg"]), sweep_deg=360.0)
        else:
            spec = RunSpec(**common)
        validate_run_spec(spec, spec_machine, source="plant_forms")
        validate_columns(spec, cols)
        runs.append(Run(spec=spec, columns=cols))

    truth = {"labels": list(labels) if labels else ["none"], "effects": effects,
             "machine": machine, "rt_rate_hz": rt_rate, "circle_rate_hz": circle_rate,
             "ambient_c": ambient_c, "max_accel_mm_s2": max_accel, "utility_day": day, "split_marked": mark_split,
             "round_trips": {a: rt_progs[a] for a in AXES}, "circles": circ_progs,
             "runs": [{"file": m[1], **{k: v for k, v in e.items()}} for m, e in zip(runs_meta, run_env)]}
    dataset = Dataset(machine=spec_machine, runs=tuple(runs), extra={"generator": "core.plant_forms"})
    return FormsCase(labels=labels if labels else ("none",), truth=truth, dataset=dataset)

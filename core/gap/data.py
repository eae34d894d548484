"""Runs of a dataset prepared for the gap diagnosis, and the train/test split.

A round trip becomes :class:`RoundTrip` (nut travel u = k_a x_m aligned to table
coordinates, table x, decimated fit indices); a circle or line becomes
:class:`Contour`. A contour's program is the **recorded command** when the run has
``<a>_command_mm`` columns (resampled linearly, as a CNC interpolator feeds its
position loop; a run recorded in motion, its command and its encoders moving at the first
sample, gets a pre-roll along the same path, so the loop is in steady state when the
recording starts; a command that steps to its feed while the encoders stand still starts
the model from rest), and is rebuilt from the run's
fields otherwise (``Contour.rebuilt``; the report says so). Only the samples on the
data arc (circle) or segment (line) are scored (``Contour.score``): a feed-in before
it and a lead-out after it drive the simulation but are not compared.
:func:`choose_split` uses the runs' ``split`` or, when none is given, holds out whole
runs at the most extreme conditions.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from core.dataset import AxisSpec, Dataset, Run
from core.errors import InputError
from core.sim import circle as circle_program
from core.sim import line as line_program
from core.sim.programs import Program

REFERENCE_C = 20.0  # °C: the temperature a lead and a backlash are stated at

MAX_FIT_SAMPLES = 8000  # per run, for the least-squares fits (the models run on all samples)


class GapError(InputError):
    """A dataset the gap diagnosis cannot work on (no test runs, a single run, unknown axis...)."""


@dataclass(frozen=True)
class RoundTrip:
    file: str
    axis: str
    split: str
    t_s: np.ndarray
    u_mm: np.ndarray  # k_a x_m, shifted so that it is close to table coordinates
    x_mm: np.ndarray  # table
    temperature_c: float
    feed_mm_min: float
    acceleration_mm_s2: float | None
    side0: int  # +1 if the first motion is positive
    fit_idx: np.ndarray
    command_mm: np.ndarray | None = None
    start: int = 0  # first sample compared: the table state before the first motion is unknown
    # where the table rested in the backlash at the first sample, from the encoders (mm):
    # the nut's lead on the table, +: the nut against the flank that drives a + move (see
    # :func:`rest_lead_mm`); None: not measurable, the nut assumed on the driving flank
    rest_lead_mm: float | None = None
    # the run's utility day (days in service), and the backlash its axis' wear adds to the
    # nominal backlash at this run against the reference day (µm; set by the nominal fit
    # of a history whose train runs span several utility days, else 0)
    utility_day: float | None = None
    wear_um: float = 0.0
    # a train run the fits use (False: a long history's train run left out of the fits by
    # :func:`thin_train`; still read for the noise at rest, the where and the observations)
    fitted: bool = True
    # False: no thermometer read the run's temperature_c, a stand-in
    # (:attr:`core.dataset.RunSpec.temperature_measured`)
    temperature_measured: bool = True
    # what depends on the record alone, computed once per run (the measured envelope split,
    # :func:`core.gap.roundtrip.residual_env_um`; the sample step, :attr:`dt_s`); a fresh one
    # for every copy
    memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def dt_s(self) -> float:
        """The median sample step (s), kept in ``memo``: every model evaluation asks for it
        (a kernel's sub-steps, each envelope window) and the run's times do not change."""
        dt = self.memo.get("dt_s")
        if dt is None:
            dt = self.memo["dt_s"] = float(np.median(np.diff(self.t_s)))
        return dt

    def start_table_mm(self, half_gap_mm: float) -> float:
        """The table at the first sample for a model whose nut-table contact opens
        ``half_gap_mm`` each side: the measured rest place, clipped to the model's gap,
        else the nut on the flank that drives the first motion. For a rigid play only the
        time of the first engagement depends on it (and it is not scored); a table with
        mass behind a compliant chain meets the nut at speed after crossing the gap, which
        sets off ringing and can start stick-slip where a start on the flank slides (a
        Karnopp chain is bistable in its start place)."""
        lead = self.side0 * half_gap_mm if self.rest_lead_mm is None else self.rest_lead_mm
        return float(self.u_mm[0] - min(max(lead, -half_gap_mm), half_gap_mm))


@dataclass(frozen=True)
class Contour:
    file: str
    kind: str  # circle | line
    axes: tuple[str, str]
    split: str
    t_s: np.ndarray  # program time of each sample
    table_mm: dict = field(repr=False)  # axis -> table positions
    program: Program = field(repr=False)
    temperature_c: float = 20.0
    feed_mm_min: float = 0.0
    acceleration_mm_s2: float | None = None
    fit_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    rate_hz: float = 500.0
    meta: dict = field(default_factory=dict)
    score: np.ndarray | None = field(default=None, repr=False)  # bool per sample: on the data arc/segment
    rebuilt: bool = False  # True: no command columns, the program was rebuilt from the run's fields
    temperature_measured: bool = True  # as RoundTrip's
    command_mm: dict | None = field(default=None, repr=False)  # axis -> recorded command

    @property
    def scored(self) -> np.ndarray:
        """Indices of the scored samples (all samples when no data arc is known)."""
        if self.score is None:
            return np.arange(self.t_s.size)
        return np.flatnonzero(self.score)

    def deviation_um(self, pos: dict) -> np.ndarray:
        """Contour error of positions ``pos`` (axis -> mm): radial deviation for a circle,
        perpendicular deviation for a line (µm)."""
        a, b = self.axes
        if self.kind == "circle":
            cx, cy = self.meta["centre_mm"]
            return (np.hypot(pos[a] - cx, pos[b] - cy) - self.meta["radius_mm"]) * 1e3
        th = math.radians(self.meta["angle_deg"])
        x0, y0 = self.meta["start_mm"]
        return (-(pos[a] - x0) * math.sin(th) + (pos[b] - y0) * math.cos(th)) * 1e3

    def angle_deg(self) -> np.ndarray:
        """Angle of each scored sample about the centre (circle) or distance along (line)."""
        a, b = self.axes
        k = self.scored
        xa, xb = self.table_mm[a][k], self.table_mm[b][k]
        if self.kind == "circle":
            cx, cy = self.meta["centre_mm"]
            return np.degrees(np.arctan2(xb - cy, xa - cx)) % 360.0
        th = math.radians(self.meta["angle_deg"])
        x0, y0 = self.meta["start_mm"]
        return (xa - x0) * math.cos(th) + (xb - y0) * math.sin(th)


def _fit_idx(n: int) -> np.ndarray:
    step = max(1, int(math.ceil(n / MAX_FIT_SAMPLES)))
    return np.arange(0, n, step)


def _first_direction(u: np.ndarray) -> int:
    span = float(np.ptp(u))
    d = u - u[0]
    moved = np.flatnonzero(np.abs(d) > 0.05 * span)
    return 1 if moved.size == 0 or d[moved[0]] > 0 else -1


REST_MOVE_MM = 2e-3  # the motor at rest: within 2 µm of its first sample
REST_SAMPLES = 10


def _lead_and_half_mm(d: np.ndarray, v: np.ndarray, n0: int) -> tuple[float, float] | None:
    """From ``d = x - u`` (table minus nut travel) and a velocity ``v`` of the same run:
    the nut's lead on the table over the first ``n0`` samples, ``c - mean(d[:n0])``, and
    the apparent half backlash, ``c`` and the half taken from the medians of ``d`` over
    the samples moving each way at over 0.3 of the top speed. None when the run does not
    move both ways (20 samples each at least)."""
    vmax = float(np.max(np.abs(v))) if v.size else 0.0
    pos, neg = d[v > 0.3 * vmax], d[v < -0.3 * vmax]
    if vmax <= 0 or pos.size < 20 or neg.size < 20:
        return None
    c = 0.5 * (float(np.median(neg)) + float(np.median(pos)))
    return c - float(np.mean(d[:n0])), 0.5 * (float(np.median(neg)) - float(np.median(pos)))


def rest_lead_mm(t_s: np.ndarray, u_mm: np.ndarray, x_mm: np.ndarray) -> float | None:
    """The nut's lead on the table at the first sample, measured on the encoders, in mm.

    ``d = x - u`` is ``c - h`` while the nut drives in + and ``c + h`` in - (``h`` the
    apparent half backlash, Coulomb stretch included), so the lead is ``c - d0``
    (:func:`_lead_and_half_mm`, moving each way by the motor's speed), ``d0`` the mean over
    the first samples at rest (at most ``REST_SAMPLES``, the motor within ``REST_MOVE_MM``
    of its start; a run that starts in motion: its first sample). None when the run does
    not move both ways. The principle of the contours' measured start
    (:func:`_measured_side`), in mm instead of a fraction of the apparent backlash: a
    chain model's contact gap is narrower than the apparent backlash by the Coulomb
    stretch, and a table at rest sits in that gap."""
    w = max(1, int(round(0.01 / max(float(np.median(np.diff(t_s))), 1e-9))))
    u_smooth = np.convolve(np.pad(u_mm, (w // 2, w - 1 - w // 2), mode="edge"), np.ones(w) / w, mode="valid")
    moved = np.flatnonzero(np.abs(u_mm - u_mm[0]) > REST_MOVE_MM)
    n0 = max(1, min(REST_SAMPLES, int(moved[0]) if moved.size else u_mm.size))
    found = _lead_and_half_mm(x_mm - u_mm, np.gradient(u_smooth, t_s), n0)
    return None if found is None else found[0]


def prepare_round_trip(run: Run, axis_spec, split: str) -> RoundTrip:
    a = run.spec.axes[0]
    m = np.asarray(run.motor_rev(a), float)
    x = np.asarray(run.table_mm(a), float)
    u = m * axis_spec.transmission_mm_per_rev
    if float(np.ptp(u)) < 1.0:
        raise GapError(f"round trip {run.spec.file!r}: the motor of axis {a!r} moves {np.ptp(u):.3f} mm (< 1 mm)")
    u = u + float(np.median(x - u))
    cmd = run.command_mm(a)
    # compare from the first engagement on: before it, the table's place in the backlash
    # depends on the unrecorded history
    moved_u = np.abs(u - u[0]) > 0.5
    moved_x = np.abs(x - x[0]) > 0.005
    k = np.flatnonzero(moved_u & (np.maximum.accumulate(moved_x)))
    start = int(k[0]) if k.size else 0
    idx = _fit_idx(u.size - start) + start
    t = np.asarray(run.time_s, float)
    return RoundTrip(
        file=run.spec.file, axis=a, split=split, t_s=t, u_mm=u, x_mm=x,
        temperature_c=float(run.spec.temperature_c), feed_mm_min=float(run.spec.feed_mm_min),
        temperature_measured=run.spec.temperature_measured,
        acceleration_mm_s2=run.spec.acceleration_mm_s2, side0=_first_direction(u), fit_idx=idx,
        command_mm=None if cmd is None else np.asarray(cmd, float), start=start,
        rest_lead_mm=rest_lead_mm(t, u, x),
        utility_day=None if run.spec.utility_day is None else float(run.spec.utility_day),
    )


def _program_of(run: Run) -> Program:
    s = run.spec
    if s.kind == "circle":
        return circle_program(
            s.radius_mm, tuple(s.centre_mm or (0.0, 0.0)), s.feed_mm_min, s.direction or "ccw",
            -90.0 if s.start_angle_deg is None else s.start_angle_deg,
            360.0 if s.sweep_deg is None else s.sweep_deg,
            axes=tuple(s.axes), acceleration_mm_s2=s.acceleration_mm_s2,
        )  # fmt: skip
    if s.angle_deg is None or s.length_mm is None:
        raise GapError(f"line run {s.file!r} needs angle_deg and length_mm")
    return line_program(s.angle_deg, s.length_mm, s.feed_mm_min, tuple(s.start_mm or (0.0, 0.0)), axes=tuple(s.axes))


def _align_time(run: Run, prog: Program) -> np.ndarray:
    """Program time of each sample: the recorded time, shifted so that the recorded
    commands match the program's (a controller's clock has its own zero)."""
    t = np.asarray(run.time_s, float)
    cols = [run.command_mm(a) for a in run.spec.axes]
    if any(c is None for c in cols):
        return t
    # shift search: coarse grid over one tenth of the run, then parabolic refinement
    sel = _fit_idx(t.size)[:: max(1, t.size // 400)]
    rec = np.stack([np.asarray(c, float)[sel] for c in cols])

    def cost(d):
        return float(np.sum((prog.positions(t[sel] + d) - rec) ** 2))

    if cost(0.0) < 1e-10 * sel.size:
        return t
    span = 0.1 * (t[-1] - t[0]) + 2.0
    grid = np.linspace(-span, span, 401)
    costs = np.array([cost(d) for d in grid])
    k = int(np.argmin(costs))
    d = grid[k]
    if 0 < k < grid.size - 1:
        c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
        den = c0 - 2 * c1 + c2
        if den > 0:
            d += 0.5 * (c0 - c2) / den * (grid[1] - grid[0])
    return t + d


PRE_ROLL_TIME_CONSTANTS = 12.0  # a run that starts in motion: e^-12 of the loop's start-up transient remains
MAX_PRE_ROLL_S = 3.0
# The start read off the encoders: over the first samples, no longer than one time constant
# of the fastest loop (an axis starting from rest has covered 1 - (1 - e^-KT) / KT of the
# command's way, e^-1 = 0.37 at KT = 1; one in steady motion all of it), until the command has
# moved START_NOISES times the deviation noise gives a difference of two samples (the
# fraction then carries a noise of 1/20: the midpoint stands 10 of it from steady motion).
START_WINDOW_TIME_CONSTANTS = 1.0
START_NOISES = 20.0
IN_MOTION_FRACTION = 0.5  # the midpoint between a start from rest (about 0) and steady motion (1)


def encoder_noise_mm(x: np.ndarray) -> float:
    """White-noise level of one encoder's record (mm): the MAD of its third differences /
    (0.6745 sqrt 20). A feed's motion is smooth on that scale (a circle's third difference
    is v^3 dt^3 / r^2), and the median passes the few samples of a start or a reversal."""
    if x.size < 5:
        return 0.0
    d = np.diff(np.asarray(x, float), 3)
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(20.0))


def start_speed_fraction(t_s: np.ndarray, cmd_mm: np.ndarray, enc_mm: np.ndarray,
                         gain_per_s: float) -> tuple[float, float]:
    """How far the encoders moved with the command at the start: the encoders' way since
    the first sample projected on the command's, as a fraction of the command's, and the
    window it is read over (s). ``cmd_mm`` and ``enc_mm`` are (axes, samples).

    In steady motion the loop lags the command by a constant amount, so the encoders cover
    the command's way (fraction about 1); an axis standing still when the command steps to
    its feed covers v (T - (1 - e^-KT) / K) of v T (about K T / 2, 0.37 at T = 1/K). The
    window is the first sample interval, grown until the command's way stands
    ``START_NOISES`` times above the noise of a difference of two encoder samples (the
    noise read on the record itself, :func:`encoder_noise_mm`) and no longer than
    ``START_WINDOW_TIME_CONSTANTS`` / ``gain_per_s`` (at least one interval)."""
    t = np.asarray(t_s, float)
    cmd = np.atleast_2d(np.asarray(cmd_mm, float))
    enc = np.atleast_2d(np.asarray(enc_mm, float))
    sigma = max(encoder_noise_mm(e) for e in enc)
    dc = cmd[:, 1:] - cmd[:, :1]
    way = np.sqrt(np.sum(dc * dc, axis=0))
    last = max(1, int(np.searchsorted(t, t[0] + START_WINDOW_TIME_CONSTANTS / max(gain_per_s, 1e-3), "right")) - 1)
    last = min(last, t.size - 1)
    enough = np.flatnonzero(way[:last] >= START_NOISES * math.sqrt(2.0) * sigma)
    n = int(enough[0]) + 1 if enough.size else last
    de = enc[:, n] - enc[:, 0]
    w2 = float(np.sum(dc[:, n - 1] ** 2))
    if w2 <= 0.0:
        return 0.0, float(t[n] - t[0])
    return float(np.dot(de, dc[:, n - 1]) / w2), float(t[n] - t[0])


def _first_sides(cmd: np.ndarray) -> tuple[str, ...]:
    """Each axis pushed in the direction it first moves (its natural engagement)."""
    out = []
    for c in cmd:
        d = c - c[0]
        tol = max(1e-6, 1e-4 * float(np.ptp(c)))
        k = np.flatnonzero(np.abs(d) > tol)
        out.append("positive" if k.size == 0 or d[k[0]] > 0 else "negative")
    return tuple(out)


def _recorded_program(run: Run, gains_per_s: tuple[float, ...],
                      ka_mm: tuple[float, ...] | None = None) -> tuple[Program, np.ndarray]:
    """The recorded command as a program, and the program time of each sample.

    When the command moves at the first sample and the encoders move with it (a recording
    begun in motion, :func:`start_speed_fraction`), a pre-roll of PRE_ROLL_TIME_CONSTANTS
    loop time constants is prepended: along the circle at the same angular speed for a
    circle, along the same straight line otherwise. When the encoders stand still the
    command stepped to its feed from rest, and the program starts from rest at the first
    sample. The program's ``meta["start"]`` says which, and on what."""
    s = run.spec
    t = np.asarray(run.time_s, float)
    cmd = np.stack([np.asarray(run.command_mm(a), float) for a in s.axes])
    # the command moves at the first sample: the first interval's speed is a good part of
    # the feed (a start from rest on an acceleration ramp covers a small fraction of it)
    n0 = 1
    v0 = (cmd[:, n0] - cmd[:, 0]) / (t[n0] - t[0])
    feed = s.feed_mm_min / 60.0
    stepped = float(np.hypot(*v0) if v0.size == 2 else abs(v0[0])) > 0.3 * feed
    # ... and a recording begun in motion only if the encoders move with it from the first
    # sample on; standing still, the axes start from rest on a step of the commanded speed
    # (the simulation starts them so, without a pre-roll). The motor encoders when their
    # transmission is known (the nut's backlash does not hide the loop's own motion).
    if ka_mm is not None:
        enc = np.stack([ka_mm[i] * np.asarray(run.motor_rev(a), float) for i, a in enumerate(s.axes)])
    else:
        enc = np.stack([np.asarray(run.table_mm(a), float) for a in s.axes])
    fraction, window_s = start_speed_fraction(t, cmd, enc, max(gains_per_s)) if stepped else (0.0, 0.0)
    moving = stepped and fraction > IN_MOTION_FRACTION
    start = {"command_moves": stepped, "in_motion": moving, "encoder_fraction": fraction, "window_s": window_s}
    pre = min(MAX_PRE_ROLL_S, PRE_ROLL_TIME_CONSTANTS / max(min(gains_per_s), 1e-3)) if moving else 0.0
    tt = t - t[0]
    if s.kind == "circle" and moving:
        cx, cy = s.centre_mm or (0.0, 0.0)
        th = np.unwrap(np.arctan2(cmd[1, : n0 + 1] - cy, cmd[0, : n0 + 1] - cx))
        r0 = float(np.hypot(cmd[0, 0] - cx, cmd[1, 0] - cy))
        w0 = (th[-1] - th[0]) / (t[n0] - t[0])

        def before(tau):  # tau < 0: time before the first sample
            a = th[0] + w0 * tau
            return np.stack([cx + r0 * np.cos(a), cy + r0 * np.sin(a)])
    else:

        def before(tau):
            return cmd[:, :1] + v0[:, None] * tau[None, :]

    def path(tp, _cmd=cmd, _tt=tt, _pre=pre):
        tau = np.atleast_1d(np.asarray(tp, float)) - _pre
        out = np.stack([np.interp(tau, _tt, c) for c in _cmd])
        early = tau < 0
        if early.any():
            out[:, early] = before(tau[early])
        return out

    sides = _first_sides(path(np.array([0.0, 0.05, 0.5])) if moving else cmd)
    one_way: dict[str, tuple[int, float]] = {}
    if not moving and ka_mm is not None:
        sides = tuple(_measured_side(run, a, ka_mm[i], sides[i]) for i, a in enumerate(s.axes))
        for i, a in enumerate(s.axes):
            w = _one_way_travel_mm(run, a, ka_mm[i]) if isinstance(sides[i], str) else None
            if w is not None:
                one_way[a] = w
    prog = Program(
        kind=s.kind, axes=tuple(s.axes), feed_mm_min=float(s.feed_mm_min), duration_s=float(tt[-1] + pre),
        record_from_s=pre, record_to_s=float(tt[-1] + pre), initial_sides=sides, path=path,
        meta={"acceleration_mm_s2": s.acceleration_mm_s2, "start": start, "rest_one_way_mm": one_way},
    )  # fmt: skip
    return prog, tt + pre


def _measured_side(run: Run, axis: str, ka_mm: float, natural: str):
    """Where the table rests in the backlash at the first sample of a run that starts at
    rest, from the encoders: d = table - k_a motor is c - b/2 while the nut pushes in +,
    c + b/2 in -, so (c - d0) / (b/2) is the place (+1: against the + flank). The
    natural engagement when the run never moves steadily both ways or b is below 2 µm (a
    run that moves one way has its place read against that way: :func:`_one_way_travel_mm`)."""
    t = np.asarray(run.time_s, float)
    x = np.asarray(run.table_mm(axis), float)
    d = x - ka_mm * np.asarray(run.motor_rev(axis), float)
    cmd = np.asarray(run.command_mm(axis), float)
    n0 = max(1, min(10, int(np.argmax(np.abs(cmd - cmd[0]) > 1e-4)) or 1))  # samples still at rest
    found = _lead_and_half_mm(d, np.gradient(cmd, t), n0)
    if found is None or found[1] < 1e-3:
        return natural
    return float(np.clip(found[0] / found[1], -1.0, 1.0))


def _one_way_travel_mm(run: Run, axis: str, ka_mm: float) -> tuple[int, float] | None:
    """Where the table rests in the backlash at the first sample of a run that starts at
    rest and moves one way only (a line), from the encoders: the direction ``s`` (+1, -1)
    and ``delta = d_move - d0`` (mm), d = table - k_a motor over the first samples at rest
    (``d0``) and its median while the command moves that way at over 0.3 of its top speed
    (``d_move``, the nut on the flank that drives it). The nut's lead on the table is
    then ``s h + delta`` for a contact gap of half ``h``: the full backlash (2 h) when the
    nut starts on the far flank, 0 on the driving one. Without the other direction the
    half gap is not measured, so the place is left to the model's own gap
    (:func:`core.gap.contour.start_side`). None when the run moves both ways or neither
    (20 samples at least)."""
    t = np.asarray(run.time_s, float)
    d = np.asarray(run.table_mm(axis), float) - ka_mm * np.asarray(run.motor_rev(axis), float)
    cmd = np.asarray(run.command_mm(axis), float)
    v = np.gradient(cmd, t)
    vmax = float(np.max(np.abs(v))) if v.size else 0.0
    if vmax <= 0:
        return None
    pos, neg = v > 0.3 * vmax, v < -0.3 * vmax
    if (pos.sum() >= 20) == (neg.sum() >= 20):
        return None
    sgn, way = (1, pos) if pos.sum() >= 20 else (-1, neg)
    n0 = max(1, min(10, int(np.argmax(np.abs(cmd - cmd[0]) > 1e-4)) or 1))  # samples still at rest
    return sgn, float(np.median(d[way])) - float(np.mean(d[:n0]))


def _data_arc_mask(run: Run, cmd: np.ndarray) -> tuple[np.ndarray, dict]:
    """Samples whose command lies on the data arc (circle) or segment (line)."""
    s = run.spec
    if s.kind == "circle":
        cx, cy = s.centre_mm or (0.0, 0.0)
        d = 1.0 if (s.direction or "ccw") == "ccw" else -1.0
        th = np.degrees(np.unwrap(np.arctan2(cmd[1] - cy, cmd[0] - cx)))
        progress = d * (th - th[0])  # degrees travelled along the circle from the first sample
        start = -90.0 if s.start_angle_deg is None else float(s.start_angle_deg)
        sweep = 360.0 if s.sweep_deg is None else float(s.sweep_deg)
        lead_in = s.extra.get("lead_in_deg")
        how = "given (lead_in_deg)"
        if lead_in is None:
            lead_in = (d * (start - th[0])) % 360.0
            if lead_in > 359.0:  # at rest on the start angle, a hair before it
                lead_in = 0.0
            how = "from the recorded command's angle"
            if lead_in + sweep > float(progress.max()) + 1.0:
                lead_in = max(0.0, float(progress.max()) - sweep)
                how = "from the recorded command's angle (recording shorter than lead-in + sweep: aligned to its end)"
        lead_in = float(lead_in)
        mask = (progress >= lead_in - 1e-6) & (progress <= lead_in + sweep + 1e-6)
        return mask, {"lead_in_deg": lead_in, "sweep_deg": sweep, "how": how,
                      "lead_out_deg": float(progress.max()) - lead_in - sweep}  # fmt: skip
    th = math.radians(s.angle_deg)
    x0, y0 = s.start_mm or (0.0, 0.0)
    along = (cmd[0] - x0) * math.cos(th) + (cmd[1] - y0) * math.sin(th)
    across = -(cmd[0] - x0) * math.sin(th) + (cmd[1] - y0) * math.cos(th)
    tol = 1e-3
    mask = (along >= -tol) & (along <= s.length_mm + tol) & (np.abs(across) <= tol)
    return mask, {"how": "samples whose command lies on the segment"}


def prepare_contour(run: Run, split: str, axes: Mapping[str, AxisSpec] | None = None) -> Contour:
    s = run.spec
    has_cmd = all(run.command_mm(a) is not None for a in s.axes)
    meta = {"radius_mm": s.radius_mm, "centre_mm": tuple(s.centre_mm or (0.0, 0.0)),
            "angle_deg": s.angle_deg, "start_mm": tuple(s.start_mm or (0.0, 0.0))}  # fmt: skip
    score = None
    cmd_cols = None
    if has_cmd:
        gains = tuple(axes[a].position_gain_per_s for a in s.axes) if axes else (10.0,)
        kas = tuple(axes[a].transmission_mm_per_rev for a in s.axes) if axes else None
        prog, t = _recorded_program(run, gains, kas)
        cmd_cols = {a: np.asarray(run.command_mm(a), float) for a in s.axes}
        if s.kind == "line" and (s.angle_deg is None or s.length_mm is None):
            raise GapError(f"line run {s.file!r} needs angle_deg and length_mm")
        score, arc = _data_arc_mask(run, np.stack([cmd_cols[a] for a in s.axes]))
        if score.sum() < 10:
            raise GapError(f"{s.kind} run {s.file!r}: fewer than 10 samples of its command lie on the data "
                           f"{'arc' if s.kind == 'circle' else 'segment'} its fields name ({arc['how']})")  # fmt: skip
        meta["data_arc"] = arc
        meta["start"] = prog.meta["start"]
    else:
        prog = _program_of(run)
        t = _align_time(run, prog)
    dt = float(np.median(np.diff(t)))
    return Contour(
        file=s.file, kind=s.kind, axes=tuple(s.axes), split=split, t_s=t,
        table_mm={a: np.asarray(run.table_mm(a), float) for a in s.axes}, program=prog,
        temperature_c=float(s.temperature_c), feed_mm_min=float(s.feed_mm_min),
        acceleration_mm_s2=s.acceleration_mm_s2, fit_idx=_fit_idx_on(score, t.size),
        rate_hz=min(1000.0, 1.0 / dt), meta=meta, score=score, rebuilt=not has_cmd, command_mm=cmd_cols,
        temperature_measured=run.spec.temperature_measured,
    )  # fmt: skip


def _fit_idx_on(score: np.ndarray | None, n: int) -> np.ndarray:
    if score is None:
        return _fit_idx(n)
    k = np.flatnonzero(score)
    return k[_fit_idx(k.size)]


@dataclass(frozen=True)
class Split:
    train: tuple[str, ...]
    test: tuple[str, ...]
    how: str  # "given" or a sentence saying which runs were held out and why


def choose_split(dataset: Dataset) -> Split:
    """The runs' ``split`` when any run has one; else hold out whole runs at the most
    extreme condition (temperature, then feed) per kind, never random samples. Only
    measured temperatures count: a run without one is held out by its feed, if at all."""
    runs = dataset.runs
    if len(runs) < 2:
        raise GapError(f"the dataset has {len(runs)} run(s); a diagnosis needs at least 2 (one to fit, one to test)")
    if any(r.spec.split is not None for r in runs):
        train = tuple(r.spec.file for r in runs if r.spec.split != "test")
        test = tuple(r.spec.file for r in runs if r.spec.split == "test")
        if not test:
            raise GapError("no run has split 'test': mark the runs the diagnosis must predict, or drop 'split'")
        if not train:
            raise GapError("every run has split 'test': at least one run must be 'train'")
        return Split(train, test, "given by the runs' split fields")
    test: list[str] = []
    reasons = []
    groups: dict[tuple, list[Run]] = {}
    for r in runs:
        groups.setdefault((r.spec.kind, r.spec.axes if r.spec.kind == "round_trip" else ()), []).append(r)
    for (kind, _), rs in groups.items():
        if len(rs) < 2:
            continue
        temps = np.array([r.spec.temperature_c if r.spec.temperature_measured else np.nan for r in rs])
        feeds = np.array([r.spec.feed_mm_min for r in rs])
        if np.sum(np.isfinite(temps)) >= 2 and np.nanmax(temps) - np.nanmin(temps) > 0.5:
            dev = np.nan_to_num(np.abs(temps - np.nanmedian(temps)), nan=-1.0)  # unmeasured: never the extreme
            what = "temperature"
            vals = temps
        else:
            dev = np.abs(np.log(feeds) - np.median(np.log(feeds)))
            what = "feed"
            vals = feeds
        n_out = max(1, len(rs) // 4)
        if what == "temperature":  # of the measured runs only
            n_out = min(n_out, int(np.sum(np.isfinite(temps))))
        order = np.argsort(-dev, kind="stable")[:n_out]
        for i in order:
            test.append(rs[i].spec.file)
        unit = "°C" if what == "temperature" else " mm/min"
        reasons.append(
            f"{kind} {', '.join(rs[i].spec.file for i in order)} (most extreme {what}: "
            f"{', '.join(f'{vals[i]:g}{unit}' for i in order)})"
        )
    if not test:
        raise GapError("cannot hold out a run: every kind of run has a single run (need two of a kind)")
    train = tuple(r.spec.file for r in runs if r.spec.file not in test)
    return Split(train, tuple(test), "held out by the diagnosis: " + "; ".join(reasons))


# The train round trips of an axis that the fits use, at most: a longer history's are
# thinned evenly over the measurement order, its first and newest kept. Every evaluation
# of a chain form simulates each train record through the chain's sub-steps, so without a
# bound the diagnosis' time grows with the history (the demo axis' 16 stored 1000 mm
# round trips would take minutes); six round trips pin down a family's few parameters per axis,
# and every held-out run is still scored.
MAX_FITTED_ROUND_TRIPS = 6


def thin_train(rts: Sequence[RoundTrip], max_per_axis: int = MAX_FITTED_ROUND_TRIPS) -> tuple[list[RoundTrip], str]:
    """``rts`` with the train round trips beyond ``max_per_axis`` per axis marked
    ``fitted=False`` (evenly over their order in the dataset, the first and the last
    kept), and a sentence saying which were left out of the fits ("" when none)."""
    out = list(rts)
    said = []
    for a in dict.fromkeys(r.axis for r in rts):
        idx = [i for i, r in enumerate(rts) if r.axis == a and r.split == "train"]
        if len(idx) <= max_per_axis:
            continue
        keep = {idx[int(round(k))] for k in np.linspace(0, len(idx) - 1, max_per_axis)}
        left = [i for i in idx if i not in keep]
        for i in left:
            out[i] = replace(out[i], fitted=False)
        said.append(f"{max_per_axis} of axis {a}'s {len(idx)} train round trips, evenly over their order "
                    f"(left out of the fits: {', '.join(rts[i].file for i in left)})")
    return out, ("the fits use " + "; ".join(said) if said else "")


def prepare_runs(dataset: Dataset, split: Split | None = None) -> tuple[list[RoundTrip], list[Contour]]:
    """Every run of ``dataset`` prepared as the diagnosis fits and scores it: its round
    trips and its contours, in the dataset's order, each marked ``"train"`` or ``"test"``
    by ``split`` (default: :func:`choose_split`). A run whose temperature was not measured
    (:attr:`core.dataset.RunSpec.temperature_measured`) is taken at the mean of the measured runs' (the
    reference 20 °C where none was): judged by the others' temperatures, not by the
    stand-in stored in its place, which would read as a temperature step to the
    thermal family and the simulated contours."""
    split = choose_split(dataset) if split is None else split
    axes = dataset.machine.axes
    rts: list[RoundTrip] = []
    cts: list[Contour] = []
    for run in dataset.runs:
        sp = "test" if run.spec.file in split.test else "train"
        if run.spec.kind == "round_trip":
            rts.append(prepare_round_trip(run, axes[run.spec.axes[0]], sp))
        else:
            cts.append(prepare_contour(run, sp, axes))
    measured = [r.temperature_c for r in (*rts, *cts) if r.temperature_measured]
    if len(measured) < len(rts) + len(cts):
        fill = float(np.mean(measured)) if measured else REFERENCE_C
        rts = [r if r.temperature_measured else replace(r, temperature_c=fill) for r in rts]
        cts = [c if c.temperature_measured else replace(c, temperature_c=fill) for c in cts]
    return rts, cts

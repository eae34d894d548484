"""Simulate NC programs on modelled axes: :func:`simulate` -> :class:`SimTrace`.

The model per axis (seed paper Figs. 11-12): position loop closed on the linear
encoder, motor velocity (as nominal table travel) = K (command - table); the nut at
u = k_a x_m drives the table through backlash b (Eq. 5): with a rigid massless table,
the table stays within [u - b/2, u + b/2], pushed at the bounds. Each axis runs its
own loop (no coupling between axes), so axes are simulated one by one.

Internal step, and why
----------------------
The command is evaluated on a uniform grid and taken as linear in between (as a CNC
interpolator does); the grid step is ``step_s`` (default 1/(4 rate_hz), at most
0.25 ms). The chord error of that linearisation is R (v/R)^2 step^2 / 8, below
0.001 µm on every circle of the paper's range.

* Nominal chain (no compliance, friction or servo dynamics; thermal, backlash
  profile, cyclic error, skew and encoders allowed): the paper's model is piecewise
  first order, so each step is integrated in closed form with its events (flank
  contact, reversal) located analytically and samples evaluated on their segment;
  there is no step-size error for the nominal model (Eqs. 7-8 are met to the
  accuracy of the formulas themselves).
* Servo dynamics and/or compliance/friction: a fixed sub-step h = step / m with m
  chosen so that h <= 0.05 / omega_n (omega_n = sqrt((chain + bristle stiffness) /
  mass), 126 steps per natural period: phase error of symplectic Euler
  (omega h)^2/24 < 1e-4, far inside its stability limit omega h < 2),
  (servo lag exact per step, dead times interpolated, the loop's table taken at
  mid-step: second order, no bound from the servo; dead time interpolated
  between steps), and h <= 0.1 ms. Stiff parts (viscous friction, LuGre bristles,
  velocity lag) are implicit or exact per step, so they do not limit h.
  The default 200 N/µm, 500 kg chain needs h <= 79 µs and runs at 62.5 µs (0.25 ms
  / 4); the stiffest documented chain (1000 N/µm, 100 kg, LuGre 500 N/µm) at 12.5 µs.
  A test cross-checks this loop against the exact one (zero servo lag): circle TBEs
  agree to 0.3 %.

Samples are taken at ``rate_hz`` over the program's record window; motor and table
encoders are latched together unless ``sampling_skew`` delays the table one. Noise
and quantisation (:class:`~core.sim.effects.Encoders`) apply to the samples only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from core.dataset import Run, RunSpec
from core.errors import InputError, require_finite, require_positive
from core.sim import kernels
from core.sim.axis import AxisModel
from core.sim.effects import Compliance
from core.sim.programs import Program

MAX_GRID_STEP_S = 2.5e-4
MAX_SAMPLES = 20_000_000  # per axis and array: a guard against a mistyped rate or step
MAX_DYNAMIC_STEP_S = 1e-4
STEPS_PER_RADIAN = 20.0  # h <= 0.05 / omega_n
DEFAULT_CHAIN = Compliance()  # used for friction when compliance is off


@dataclass(frozen=True)
class Chain:
    """The kinematic chain of one axis at one temperature, as the kernels take it."""

    fixed_mm: float
    lead_scale: float
    periods_mm: np.ndarray
    amplitudes_mm: np.ndarray
    phases_rad: np.ndarray
    profile_mm: np.ndarray
    half_width_mm: np.ndarray

    @classmethod
    def of(cls, axis: AxisModel, temperature_c: float) -> Chain:
        fx = axis.effects
        th = fx.thermal
        lam = th.lead_scale(temperature_c) if th else 1.0
        shift_um = th.backlash_shift_um(temperature_c) if th else 0.0
        if fx.backlash_profile is not None:
            pos = np.array(fx.backlash_profile.positions_mm, dtype=float)
            wid = np.array(fx.backlash_profile.widths_um, dtype=float)
        else:
            pos = np.zeros(1)
            wid = np.array([axis.backlash_um], dtype=float)
        ce = fx.cyclic_error if fx.cyclic_error is not None and fx.cyclic_error.on == "nut" else None
        per = np.array(ce.periods_mm if ce else (), dtype=float)
        amp = np.array(ce.amplitudes_um if ce else (), dtype=float) * 1e-3
        pha = np.deg2rad(np.array(ce.phases_deg if ce else (), dtype=float))
        return cls(
            fixed_mm=th.fixed_end_mm if th else 0.0,
            lead_scale=lam,
            periods_mm=per,
            amplitudes_mm=amp,
            phases_rad=pha,
            profile_mm=pos,
            half_width_mm=np.maximum(wid + shift_um, 0.0) * 0.5e-3,
        )

    def nut_mm(self, u_mm):
        """Nut position (table coordinates) at nominal motor travel u_mm."""
        u = np.asarray(u_mm, dtype=float)
        n = self.fixed_mm + (u - self.fixed_mm) * self.lead_scale
        for p, a, f in zip(self.periods_mm, self.amplitudes_mm, self.phases_rad):
            n = n + a * np.sin(2 * np.pi * u / p + f)
        return n

    def half_width_at(self, nut_mm):
        return np.interp(nut_mm, self.profile_mm, self.half_width_mm)

    def motor_for_nut(self, nut_mm: float) -> float:
        """Inverse of :meth:`nut_mm` near the nominal (Newton; s' > 0 in the valid range)."""
        u = self.fixed_mm + (nut_mm - self.fixed_mm) / self.lead_scale
        for _ in range(50):
            n, g = kernels._nut(u, self.fixed_mm, self.lead_scale, self.periods_mm, self.amplitudes_mm, self.phases_rad)
            du = (n - nut_mm) / g
            u -= du
            if abs(du) < 1e-13:
                break
        return u


@dataclass(frozen=True)
class SimTrace:
    """Result of :func:`simulate`: samples as recorded plus the true internal states.

    ``motor_rev`` and ``table_mm`` are what the encoders deliver (skew, noise,
    quantisation applied); ``table_true_mm`` is the true table position at
    ``time_s``, ``nut_mm`` the nut position (table coordinates) and
    ``motor_true_rev`` the true motor position. motor_rev is nominal travel / k_a, so
    k_a * motor_rev is in table coordinates at the reference temperature.
    """

    time_s: np.ndarray
    axes: tuple[str, ...]
    command_mm: Mapping[str, np.ndarray]
    motor_rev: Mapping[str, np.ndarray]
    table_mm: Mapping[str, np.ndarray]
    motor_true_rev: Mapping[str, np.ndarray]
    nut_mm: Mapping[str, np.ndarray]
    table_true_mm: Mapping[str, np.ndarray]
    program: Program = field(repr=False)
    models: Mapping[str, AxisModel] = field(repr=False)
    temperature_c: float = 20.0
    step_s: Mapping[str, float] = field(default_factory=dict)

    def columns(self) -> dict[str, np.ndarray]:
        """The dataset columns: time_s, <a>_command_mm, <a>_motor_rev, <a>_table_mm."""
        cols = {"time_s": self.time_s}
        for a in self.axes:
            cols[f"{a}_command_mm"] = self.command_mm[a]
            cols[f"{a}_motor_rev"] = self.motor_rev[a]
            cols[f"{a}_table_mm"] = self.table_mm[a]
        return cols

    def to_run(self, file: str, split: str | None = None, utility_day: float | None = None, extra=None) -> Run:
        """This trace as a dataset :class:`~core.dataset.Run` (spec + columns)."""
        p = self.program
        m = p.meta
        kw: dict = {}
        rest = dict(extra or {})
        if p.kind == "circle":
            kw = {k: m[k] for k in ("radius_mm", "centre_mm", "direction", "start_angle_deg", "sweep_deg")}
        elif p.kind == "line":
            kw = {k: m[k] for k in ("angle_deg", "length_mm", "start_mm")}
        elif p.kind == "round_trip":
            rest.setdefault("commanded_mm", [m["start_mm"][0], m["end_mm"]])
            rest.setdefault("dwell_s", m["dwell_s"])
        rest.setdefault("simulated", True)
        spec = RunSpec(
            file=file,
            kind=p.kind,
            axes=p.axes,
            feed_mm_min=p.feed_mm_min,
            temperature_c=self.temperature_c,
            utility_day=utility_day,
            acceleration_mm_s2=m.get("acceleration_mm_s2"),
            split=split,
            extra=rest,
            **kw,
        )
        return Run(spec=spec, columns=self.columns())


def _dynamic_step_s(axis: AxisModel, steps_per_radian: float = STEPS_PER_RADIAN) -> float:
    fx = axis.effects
    h = math.inf  # a rigid chain with servo dynamics only: the command grid's step
    if fx.compliance is not None or fx.friction is not None:
        h = MAX_DYNAMIC_STEP_S
        ch = fx.compliance or DEFAULT_CHAIN
        k_si = ch.stiffness_n_per_um * 1e6
        if fx.friction is not None and fx.friction.model == "lugre":
            k_si += fx.friction.bristle_stiffness_n_per_um * 1e6
        h = min(h, 1.0 / (steps_per_radian * math.sqrt(k_si / ch.table_mass_kg)))
    # Servo dynamics set no bound of their own: the lag is solved exactly per step, the
    # delays are interpolated between steps and the loop sees the table at mid-step, so
    # the result converges at second order (a 0.3 ms lag with 0.2 ms dead time on a 50 mm
    # circle at 2500 mm/min: within 0.001 µm at 0.25 ms steps and 0.007 µm at 0.5 ms of
    # 25 µs steps; zero servo dynamics match the exact nominal integrator).
    return h


def is_rigid(axis: AxisModel) -> bool:
    """True if the axis runs on the exact nominal-chain integrator."""
    fx = axis.effects
    return fx.compliance is None and fx.friction is None and fx.servo_dynamics is None


def _initial_side(side) -> float:
    """+1 / -1 for "positive" / "negative"; a number in [-1, 1] is the table's place in
    the backlash (the nut at table + side b/2: a measured start inside the gap)."""
    if side == "positive":
        return 1.0
    if side == "negative":
        return -1.0
    f = float(side)
    if not (math.isfinite(f) and -1.0 <= f <= 1.0):
        raise InputError(f"initial side (={side!r}) must be 'positive', 'negative' or a number in [-1, 1]")
    return f


def _simulate_axis(axis, chain, cmd, t0, h, ts, ts_tab, frac, steps_per_radian):
    n0 = float(cmd[0])  # the table rests on the command; the nut at table + frac b/2
    nut = n0
    for _ in range(20):
        nut = n0 + frac * float(chain.half_width_at(nut))
    u0 = chain.motor_for_nut(nut)
    x0 = nut - frac * float(chain.half_width_at(nut))
    side = 1 if frac >= 0.999 else (-1 if frac <= -0.999 else 0)  # engaged, or resting in the gap
    out_u = np.empty(ts.size)
    out_x = np.empty(ts.size)
    out_xt = np.empty(ts_tab.size)
    k = float(axis.position_gain_per_s)
    args = (chain.fixed_mm, chain.lead_scale, chain.periods_mm, chain.amplitudes_mm, chain.phases_rad,
            chain.profile_mm, chain.half_width_mm)  # fmt: skip
    if is_rigid(axis):
        kernels.run_rigid(t0, h, cmd, k, u0, x0, side, *args, ts, ts_tab, out_u, out_x, out_xt)
        return out_u, out_x, out_xt, h
    fx = axis.effects
    sub = _dynamic_step_s(axis, steps_per_radian)
    nsub = 1 if math.isinf(sub) else max(1, math.ceil(h / sub - 1e-9))
    sd = fx.servo_dynamics
    lag = sd.velocity_lag_s if sd else 0.0
    dead = sd.dead_time_s if sd else 0.0
    ff = sd.feedforward if sd else 0.0
    fb = sd.feedback_delay_s if sd else 0.0
    ki = sd.integral_per_s if sd else 0.0
    a_max = sd.accel_limit_mm_s2 if sd else 0.0
    compliant = fx.compliance is not None or fx.friction is not None
    ch = fx.compliance or DEFAULT_CHAIN
    k_si = ch.stiffness_n_per_um * 1e6
    c_contact = 2 * ch.damping_ratio * math.sqrt(k_si * ch.table_mass_kg) / 1000.0
    fr = fx.friction
    # Without the friction effect the guides hold the table with Coulomb friction.
    model, vs, sig0, sig1, visc, band, fdir = kernels.FRICTION_STRIBECK, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0
    fc = fs = ch.guide_friction_n
    if fr is not None:
        model = kernels.FRICTION_LUGRE if fr.model == "lugre" else kernels.FRICTION_STRIBECK
        fc, fs, vs, visc = fr.coulomb_n, fr.static_n, fr.stribeck_velocity_mm_s, fr.viscous_n_s_per_mm
        band, fdir = fr.stick_band_mm_s, fr.direction_asymmetry
        sig0 = fr.bristle_stiffness_n_per_um * 1000.0
        sig1 = 2 * fr.bristle_damping_ratio * math.sqrt(fr.bristle_stiffness_n_per_um * 1e6 * ch.table_mass_kg) / 1000.0
    visc += ch.guide_damping_n_s_per_mm
    kernels.run_dynamic(
        t0, h, nsub, cmd, k, u0, x0, side, *args,
        lag, dead, compliant, ch.stiffness_n_per_um * 1000.0, ch.table_mass_kg, c_contact, visc,
        model, fc, fs, vs, sig0, sig1, ts, ts_tab, out_u, out_x, out_xt, ff, fb, band, ki, a_max, fdir,
    )  # fmt: skip
    return out_u, out_x, out_xt, h / nsub


def _quantise(values: np.ndarray, step: float) -> np.ndarray:
    return values if step <= 0 else np.round(values / step) * step


def simulate(
    axes: Mapping[str, AxisModel],
    program: Program,
    *,
    temperature_c: float = 20.0,
    rate_hz: float = 1000.0,
    step_s: float | None = None,
    rng: np.random.Generator | None = None,
    steps_per_radian: float = STEPS_PER_RADIAN,
) -> SimTrace:
    """Run ``program`` on ``axes`` (a model for each of ``program.axes``).

    temperature_c is the machine temperature (used by the thermal effect); rate_hz
    the sampling rate of the recorded trace; step_s the command grid step (see the
    module docstring; default min(0.25 ms, 1/(4 rate_hz))). rng draws the encoder
    noise (default: a Generator seeded with 0, so runs are reproducible);
    steps_per_radian the integration steps per radian of a compliant chain's natural
    frequency (with LuGre friction, of the chain and bristles together), at most
    MAX_DYNAMIC_STEP_S apart (default STEPS_PER_RADIAN, the twin's; the gap diagnosis
    takes fewer, see core.gap.contour.SIM_STEPS_PER_RADIAN).
    """
    temp = require_finite("temperature_c", temperature_c)
    rate = require_positive("rate_hz", rate_hz)
    spr = require_positive("steps_per_radian", steps_per_radian)
    h = min(MAX_GRID_STEP_S, 0.25 / rate) if step_s is None else require_positive("step_s", step_s)
    missing = [a for a in program.axes if a not in axes]
    if missing:
        raise InputError(f"no AxisModel for program axis/axes {missing} (have {sorted(axes)})")
    if rng is None:
        rng = np.random.default_rng(0)
    t0 = 0.0
    n_grid = max(2, math.ceil(program.duration_s / h - 1e-9) + 1)
    n_out = int(math.floor((program.record_to_s - program.record_from_s) * rate + 1e-9)) + 1
    if n_out > MAX_SAMPLES or n_grid > MAX_SAMPLES:
        raise InputError(
            f"the run would need {n_out} samples at rate_hz (={rate}) and {n_grid} command steps at "
            f"step_s (={h}); the limit is {MAX_SAMPLES}: lower rate_hz or raise step_s"
        )
    grid = t0 + h * np.arange(n_grid)
    commands = program.positions(grid)
    ts = program.record_from_s + np.arange(n_out) / rate
    cmd_out = program.command_mm(ts)
    res = {k: {} for k in ("command", "motor", "table", "motor_true", "nut", "table_true", "step")}
    for i, name in enumerate(program.axes):
        axis = axes[name]
        chain = Chain.of(axis, temp)
        side_name = program.initial_sides[i] if axis.initial_side == "auto" else axis.initial_side
        side = _initial_side(side_name)
        skew = axis.effects.sampling_skew.table_delay_s if axis.effects.sampling_skew else 0.0
        ts_tab = ts + skew
        u, x, xt, h_used = _simulate_axis(axis, chain, np.ascontiguousarray(commands[i]), t0, h, ts, ts_tab, side,
                                          spr)
        enc = axis.encoders
        ka = axis.transmission_mm_per_rev
        motor = u / ka
        if enc.motor_noise_um > 0:
            motor = motor + rng.normal(0.0, enc.motor_noise_um * 1e-3 / ka, motor.size)
        if enc.motor_counts_per_rev > 0:
            motor = _quantise(motor, 1.0 / enc.motor_counts_per_rev)
        table = xt
        if axis.effects.cyclic_error is not None:
            table = table + axis.effects.cyclic_error.scale_error_mm(xt)
        if axis.effects.thermal is not None and axis.effects.thermal.warmup_um_per_m != 0.0:
            table = table + axis.effects.thermal.warmup_error_mm(ts, xt)
        if enc.table_noise_um > 0:
            table = table + rng.normal(0.0, enc.table_noise_um * 1e-3, table.size)
        table = _quantise(table, enc.table_resolution_um * 1e-3)
        res["command"][name] = cmd_out[name]
        res["motor"][name] = motor
        res["table"][name] = table
        res["motor_true"][name] = u / ka
        res["nut"][name] = chain.nut_mm(u)
        res["table_true"][name] = x
        res["step"][name] = h_used
    return SimTrace(
        time_s=ts,
        axes=program.axes,
        command_mm=res["command"],
        motor_rev=res["motor"],
        table_mm=res["table"],
        motor_true_rev=res["motor_true"],
        nut_mm=res["nut"],
        table_true_mm=res["table_true"],
        program=program,
        models={a: axes[a] for a in program.axes},
        temperature_c=temp,
        step_s=res["step"],
    )

"""One feed-drive axis as a continuous-time state model, integrated at a fixed internal step.

Units inside: positions mm, velocities mm/s, forces N, masses N*s^2/mm (kg / 1000), so
that ``F = m * a`` holds with ``a`` in mm/s^2; stiffness N/mm, damping N*s/mm.

State model (one axis; axes are independent)
--------------------------------------------
Command ``c(t)``: the CNC interpolator's output on a 1 ms IPO grid, interpolated linearly
between IPO points (as a drive does between set-points); ``c'(t)`` is the slope of the
current IPO segment (the feed-forward a controller derives from the set-point difference).

Position loop (closed on the table encoder)::

    v_ref = K_eff * (c(t) - x(t - T_fb)) + k_ff * c'(t)

``x(t - T_fb)`` is the table position delayed by the feedback dead time ``T_fb``, read from
the stored trajectory by linear interpolation (a fractional delay, no rounding to steps).

Velocity loop: ideal (``u' = v_ref``) or second order::

    u' = w,   w'' = wn^2 (v_ref - w) - 2 zeta wn w'

``u`` is the motor position expressed as nominal table travel (k_a * motor revolutions).
The nut sits at ``n = u + e(u)``, ``e`` the transmission error (thermal growth, gear-period
error; a look-up table on a fine grid of ``u``).

Chain, rigid mode (massless table): a dead-zone contact with a stiff spring and a guide
damper, ``c_g x' = k_c dz(n - x)`` with ``dz(d) = d - b/2`` for ``d > b/2``, ``d + b/2`` for
``d < -b/2`` and 0 between, i.e. ``x' = dz(n - x) / tau_c`` with ``tau_c = 1 us``. That is
far too stiff for an explicit step, so it is taken by a backward-Euler step, which is
solvable in closed form for the piecewise-linear dead zone. The backlash width
``b(x)`` is a look-up table on the table position.

Chain, mass mode (friction and compliance): table mass ``m`` on a spring-damper contact
``F = max(0, k_c (d - b/2) + c_c (w - x'))`` for ``d > b/2`` (mirrored for ``d < -b/2``,
zero in the gap), a guide viscous damper ``c_g`` (an oil film), a rolling-guide friction
``F_g tanh(x' / 0.5 mm/s)`` and a chain friction force ``F_f``::

    m x'' = F - c_g x' - F_g tanh(x' / v_s) - F_f

Friction ``F_f``: none; Karnopp (inside the zero-velocity band ``|x'| < dv``: stuck while
the applied force ``|F - c_g x'| <= F_s``, the velocity then relaxing to zero with
``tau_st``; breaking away with the Coulomb force ``F_c``; outside the band ``F_c sgn(x')``);
or Dahl (``F_f = sigma0 z``, ``dz/dx = 1 - sigma0 z sgn(dx) / F_c``, rate independent).

Integration scheme
------------------
Classical fixed-step RK4 for the motor states (and the table states in mass mode) at a
step ``h`` that divides the IPO cycle (:func:`internal_step_s`): ``omega h <= 0.2`` for the
fastest rate of the model (RK4's local error is then ~ (omega h)^5 / 120 < 3e-6 of the
motion per step), at most 0.25 ms. So: 0.25 ms for the rigid chain with an ideal or an
80 Hz velocity loop (rates K <= 56 1/s, wn <= 503 rad/s), 0.1-0.25 ms for a compliant
chain (omega = sqrt(k/m) <= 820 rad/s), down to ~0.07 ms for a stiff Dahl pre-sliding
spring (sqrt(sigma0/m) up to ~2900 rad/s), and at most 0.1 ms under Karnopp friction,
whose zero-velocity band must be crossed within one step but stay well below the feeds.
Two parts are taken out of RK4 and stepped exactly instead:
the rigid contact (backward Euler, see above; its lag ``v tau_c`` is below 0.1 um) and the
Dahl state (the closed-form solution of the rate-independent Dahl equation over the
step's table displacement, with ``z`` held within the RK4 stages: a Lie splitting). In
rigid mode without a feedback delay the RK4 stages see the table position extrapolated
linearly from the last two steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

IPO_DT_S = 1e-3
MAX_STEP_S = 2.5e-4
KARNOPP_STEP_S = 1e-4
GUIDE_SMOOTH_MM_S = 0.5
CONTACT_TAU_S = 1e-6

# indices into the parameter vector handed to the kernel
P_K, P_FF, P_VL, P_WN, P_ZETA, P_TD, P_MODE, P_M, P_KC, P_CC, P_CG, P_FK, P_FC, P_FS, P_DV, P_TST, P_SIG, P_TAUC, P_FG, P_VS = range(20)
N_P = 20

FRICTION_KINDS = {"none": 0, "karnopp": 1, "dahl": 2}


@dataclass(frozen=True)
class DriveParams:
    """Dynamic parameters of one axis. Defaults are the nominal machine (ideal velocity
    loop, rigid chain, no friction): only ``gain_per_s`` is needed then."""

    gain_per_s: float
    ff_fraction: float = 0.0
    vloop_bandwidth_hz: float = 0.0  # 0 means an ideal velocity loop
    vloop_damping: float = 0.7
    feedback_delay_s: float = 0.0
    table_mass_kg: float = 0.0  # 0 means the rigid chain (massless table, stiff contact)
    chain_stiffness_n_per_um: float = 0.0
    chain_damping_ratio: float = 0.1
    guide_damping_time_s: float = 2.0  # m / c_g: how slowly a free table coasts down (oil film)
    guide_friction_n: float = 0.0  # rolling-guide friction, a Coulomb force smoothed over 0.5 mm/s
    friction: str = "none"
    coulomb_n: float = 0.0
    static_n: float = 0.0
    presliding_um: float = 2.0  # Dahl: F_c / sigma0

    @property
    def mass_mode(self) -> bool:
        return self.table_mass_kg > 0.0


def internal_step_s(p: DriveParams) -> float:
    """The RK4 step: the largest divisor of the 1 ms IPO cycle with ``omega h <= 0.2`` for the
    fastest rate ``omega`` of the model, at most 0.25 ms, and at most 0.1 ms under Karnopp
    friction (whose zero-velocity band is tied to the step)."""
    rates = [p.gain_per_s]
    if p.vloop_bandwidth_hz > 0:
        rates.append(2 * np.pi * p.vloop_bandwidth_hz)
    cap = MAX_STEP_S
    if p.mass_mode:
        m = p.table_mass_kg / 1000.0
        kc = p.chain_stiffness_n_per_um * 1000.0
        rates.append(np.sqrt(kc / m))
        rates.append(2.0 * p.chain_damping_ratio * np.sqrt(kc / m))
        rates.append(p.guide_friction_n / (GUIDE_SMOOTH_MM_S * m))
        if p.friction == "dahl":
            rates.append(np.sqrt(p.coulomb_n / (p.presliding_um * 1e-3) / m))
        if p.friction == "karnopp":
            cap = KARNOPP_STEP_S
    h = min(cap, 0.2 / max(rates))
    return IPO_DT_S / np.ceil(IPO_DT_S / h - 1e-9)


def param_vector(p: DriveParams, h_s: float) -> np.ndarray:
    v = np.zeros(N_P)
    v[P_K] = p.gain_per_s
    v[P_FF] = p.ff_fraction
    v[P_VL] = 1.0 if p.vloop_bandwidth_hz > 0 else 0.0
    v[P_WN] = 2 * np.pi * p.vloop_bandwidth_hz
    v[P_ZETA] = p.vloop_damping
    v[P_TD] = p.feedback_delay_s
    v[P_TAUC] = CONTACT_TAU_S
    if p.mass_mode:
        m = p.table_mass_kg / 1000.0
        kc = p.chain_stiffness_n_per_um * 1000.0
        v[P_MODE] = 1.0
        v[P_M] = m
        v[P_KC] = kc
        v[P_CC] = 2.0 * p.chain_damping_ratio * np.sqrt(kc * m)
        v[P_CG] = m / p.guide_damping_time_s
        v[P_FK] = FRICTION_KINDS[p.friction]
        v[P_FC] = p.coulomb_n
        v[P_FS] = max(p.static_n, p.coulomb_n)
        v[P_TST] = 2.0 * h_s
        v[P_FG] = p.guide_friction_n
        v[P_VS] = GUIDE_SMOOTH_MM_S
        if p.friction == "dahl":
            v[P_SIG] = p.coulomb_n / (p.presliding_um * 1e-3)
        # the band must catch a zero crossing within one step: near zero speed the table's
        # acceleration is at most about F_s / m; wider would stop a merely slow table
        v[P_DV] = max(0.1, 1.5 * v[P_FS] / m * h_s)
    return v


@njit(cache=True, fastmath=True, inline="always")
def _lut(v, x0, dx, arr):
    s = (v - x0) / dx
    n = arr.shape[0]
    if s <= 0.0:
        return arr[0]
    i = int(s)
    if i >= n - 1:
        return arr[n - 1]
    f = s - i
    return arr[i] + f * (arr[i + 1] - arr[i])


@njit(cache=True, fastmath=True, inline="always")
def _cmd(t, ipo_dt, cmd):
    s = t / ipo_dt
    n = cmd.shape[0]
    if s <= 0.0:
        return cmd[0], 0.0
    i = int(s)
    if i >= n - 1:
        return cmd[n - 1], 0.0
    d = cmd[i + 1] - cmd[i]
    return cmd[i] + (s - i) * d, d / ipo_dt


@njit(cache=True, fastmath=True, inline="always")
def _past(t, h, hist, n_filled):
    s = t / h
    if s <= 0.0:
        return hist[0]
    i = int(s)
    if i >= n_filled - 1:
        return hist[n_filled - 1]
    return hist[i] + (s - i) * (hist[i + 1] - hist[i])


@njit(cache=True, fastmath=True, inline="always")
def _deriv(t, y, xfb, use_state_fb, z, p, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, dy):
    c, cd = _cmd(t, ipo_dt, cmd)
    fb = y[3] if use_state_fb else xfb
    vref = p[P_K] * (c - fb) + p[P_FF] * cd
    if p[P_VL] > 0.0:
        wn = p[P_WN]
        dy[0] = y[1]
        dy[1] = y[2]
        dy[2] = wn * wn * (vref - y[1]) - 2.0 * p[P_ZETA] * wn * y[2]
        w = y[1]
    else:
        dy[0] = vref
        dy[1] = 0.0
        dy[2] = 0.0
        w = vref
    if p[P_MODE] > 0.0:
        nut = y[0] + _lut(y[0], e_x0, e_dx, e_arr)
        bh = 0.5 * _lut(y[3], b_x0, b_dx, b_arr)
        d = nut - y[3]
        rel = w - y[4]
        f = 0.0
        if d > bh:
            f = max(0.0, p[P_KC] * (d - bh) + p[P_CC] * rel)
        elif d < -bh:
            f = min(0.0, p[P_KC] * (d + bh) + p[P_CC] * rel)
        v = y[4]
        fapp = f - p[P_CG] * v - p[P_FG] * np.tanh(v / p[P_VS])
        m = p[P_M]
        fk = p[P_FK]
        if fk == 1.0:
            if abs(v) < p[P_DV]:
                if abs(fapp) <= p[P_FS]:
                    acc = -v / p[P_TST]
                else:
                    acc = (fapp - p[P_FC] * np.sign(fapp)) / m
            else:
                acc = (fapp - p[P_FC] * np.sign(v)) / m
        elif fk == 2.0:
            acc = (fapp - p[P_SIG] * z) / m
        else:
            acc = fapp / m
        dy[3] = v
        dy[4] = acc
    else:
        dy[3] = 0.0
        dy[4] = 0.0


@njit(cache=True, fastmath=True, inline="always")
def integrate(p, h, n_steps, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, u0, x0):
    """RK4 over ``n_steps`` of ``h`` from rest; returns (u, x) at every step (n_steps + 1)."""
    u_h = np.empty(n_steps + 1)
    x_h = np.empty(n_steps + 1)
    y = np.zeros(5)
    y[0] = u0
    y[3] = x0
    u_h[0] = u0
    x_h[0] = x0
    k1 = np.zeros(5)
    k2 = np.zeros(5)
    k3 = np.zeros(5)
    k4 = np.zeros(5)
    yt = np.zeros(5)
    z = 0.0
    x_prev = x0
    td = p[P_TD]
    rigid = p[P_MODE] == 0.0
    use_state = (not rigid) and td <= 0.0
    g = h / p[P_TAUC]
    for k in range(n_steps):
        t = k * h
        if td > 0.0:
            fa = _past(t - td, h, x_h, k + 1)
            fb = _past(t + 0.5 * h - td, h, x_h, k + 1)
            fc = _past(t + h - td, h, x_h, k + 1)
        elif rigid:
            dx = y[3] - x_prev
            fa = y[3]
            fb = y[3] + 0.5 * dx
            fc = y[3] + dx
        else:
            fa = fb = fc = 0.0
        _deriv(t, y, fa, use_state, z, p, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, k1)
        for i in range(5):
            yt[i] = y[i] + 0.5 * h * k1[i]
        _deriv(t + 0.5 * h, yt, fb, use_state, z, p, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, k2)
        for i in range(5):
            yt[i] = y[i] + 0.5 * h * k2[i]
        _deriv(t + 0.5 * h, yt, fb, use_state, z, p, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, k3)
        for i in range(5):
            yt[i] = y[i] + h * k3[i]
        _deriv(t + h, yt, fc, use_state, z, p, ipo_dt, cmd, e_x0, e_dx, e_arr, b_x0, b_dx, b_arr, k4)
        x_old = y[3]
        for i in range(5):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if rigid:
            # backward Euler of x' = dz(n - x) / tau_c, closed form per contact side
            nut = y[0] + _lut(y[0], e_x0, e_dx, e_arr)
            bh = 0.5 * _lut(x_old, b_x0, b_dx, b_arr)
            if nut - bh > x_old:
                y[3] = (x_old + g * (nut - bh)) / (1.0 + g)
            elif nut + bh < x_old:
                y[3] = (x_old + g * (nut + bh)) / (1.0 + g)
            x_prev = x_old
        elif p[P_FK] == 2.0:
            # exact Dahl update over the step's displacement (rate independent)
            ddx = y[3] - x_old
            if ddx != 0.0:
                zs = np.sign(ddx) * p[P_FC] / p[P_SIG]
                z = zs + (z - zs) * np.exp(-p[P_SIG] * abs(ddx) / p[P_FC])
        u_h[k + 1] = y[0]
        x_h[k + 1] = y[3]
    return u_h, x_h


@dataclass(frozen=True)
class Trajectory:
    """Motor travel ``u_mm`` and table position ``x_mm`` at every internal step ``h_s``."""

    h_s: float
    u_mm: np.ndarray
    x_mm: np.ndarray

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        grid = np.arange(self.u_mm.shape[0]) * self.h_s
        return np.interp(t_s, grid, self.u_mm), np.interp(t_s, grid, self.x_mm)

    def table_at(self, t_s: np.ndarray) -> np.ndarray:
        grid = np.arange(self.x_mm.shape[0]) * self.h_s
        return np.interp(t_s, grid, self.x_mm)

    def motor_at(self, t_s: np.ndarray) -> np.ndarray:
        grid = np.arange(self.u_mm.shape[0]) * self.h_s
        return np.interp(t_s, grid, self.u_mm)


@dataclass(frozen=True)
class Lut:
    """A function on a uniform grid: value at ``x0_mm + i * dx_mm`` is ``values[i]``."""

    x0_mm: float
    dx_mm: float
    values: np.ndarray


def constant_lut(value: float) -> Lut:
    return Lut(0.0, 1.0, np.array([value, value], dtype=float))


def simulate_axis(p: DriveParams, command_mm: np.ndarray, duration_s: float, nut_error_mm: Lut,
                  backlash_mm: Lut, first_side: int) -> Trajectory:
    """Integrate one axis from rest for ``duration_s``, driven by ``command_mm`` (IPO grid).

    The table starts on the command, the nut against its ``first_side`` flank (+1: the nut
    ahead of the table in +direction, so a +move drives at once; -1: a +move first crosses
    the gap).
    """
    h = internal_step_s(p)
    n = int(np.ceil(duration_s / h)) + 1
    x0 = float(command_mm[0])
    b0 = float(np.interp(x0, lut_grid(backlash_mm), backlash_mm.values))
    # the nut position n = u + e(u) sits at x0 + side * b/2; solve for u by two fixed-point steps
    target = x0 + first_side * 0.5 * b0
    u0 = target
    for _ in range(3):
        u0 = target - float(np.interp(u0, lut_grid(nut_error_mm), nut_error_mm.values))
    u_h, x_h = integrate(param_vector(p, h), h, n, IPO_DT_S, np.ascontiguousarray(command_mm, dtype=float),
                         nut_error_mm.x0_mm, nut_error_mm.dx_mm, nut_error_mm.values,
                         backlash_mm.x0_mm, backlash_mm.dx_mm, backlash_mm.values, u0, x0)  # fmt: skip
    return Trajectory(h, u_h, x_h)


def lut_grid(lut: Lut) -> np.ndarray:
    return lut.x0_mm + lut.dx_mm * np.arange(lut.values.shape[0])

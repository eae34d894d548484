"""Time-stepping loops of one axis (numba). Called by :mod:`core.sim.engine`, and
:func:`play_inertia` by the gap diagnosis' chain forms (through :mod:`core.gap.play`),
which share :func:`flank_force` with the simulator.

Positions in mm, velocities in mm/s, forces in N, masses in kg (so an acceleration
in mm/s^2 is 1000 F/m), stiffness in N/mm, damping in N s/mm.

The nut position in table coordinates is n = s(u), u the motor position as nominal
travel (k_a x_m): s(u) = F + lam (u - F) + sum A_i sin(2 pi u / P_i + phi_i) (thermal
lead scale about the fixed end F, cyclic error). The backlash half width hb(n) is a
piecewise-linear table (one node = constant). The command arrives on a uniform grid
(step hc) and is linear between grid points, as from a CNC interpolator.

Both loops record the motor and the true table at times ``ts`` and the table again at
``ts_tab`` (sampling skew): run_rigid evaluates its closed-form segments there,
run_dynamic interpolates linearly between its (small) steps.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi
FRICTION_NONE, FRICTION_STRIBECK, FRICTION_LUGRE = 0, 1, 2


@njit(cache=True, nogil=True)
def _nut(u, fixed, lam, per, amp, pha):
    n = fixed + (u - fixed) * lam
    g = lam
    for i in range(per.size):
        k = TWO_PI / per[i]
        arg = k * u + pha[i]
        n += amp[i] * math.sin(arg)
        g += amp[i] * k * math.cos(arg)
    return n, g


@njit(cache=True)
def _half(n, pos, hw):
    """Half backlash width at nut position n and its slope dhb/dn."""
    m = pos.size
    if m == 1 or n <= pos[0]:
        return hw[0], 0.0
    if n >= pos[m - 1]:
        return hw[m - 1], 0.0
    lo, hi = 0, m - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pos[mid] <= n:
            lo = mid
        else:
            hi = mid
    slope = (hw[hi] - hw[lo]) / (pos[hi] - pos[lo])
    return hw[lo] + slope * (n - pos[lo]), slope


@njit(cache=True)
def flank_force(delta, hb, k, c, dv):
    """Push of the nut on the table through a compliant flank contact (never a pull).

    ``delta`` = nut - table, ``hb`` the half backlash, ``k`` the contact stiffness, ``c``
    its damping and ``dv`` = nut velocity - table velocity: zero inside the play, the
    spring-damper force on the flank reached, clipped so that the flank only pushes.
    Units are the caller's (N/mm and N s/mm here, per unit mass in core.gap.play).
    """
    if delta > hb:
        f = k * (delta - hb) + c * dv
        return 0.0 if f < 0.0 else f  # a NaN stays NaN: bad input must show, not vanish
    if delta < -hb:
        f = k * (delta + hb) + c * dv
        return 0.0 if f > 0.0 else f
    return 0.0


# The gap diagnosis' chain forms (core.gap.stages): here, beside flank_force, because
# numba's on-disk cache is keyed by the file of the function it compiles, so a kernel
# that calls a function of another file could be left compiled against its old copy.
@njit(cache=True, nogil=True)
def play_inertia(u, nut_v, t, half_width, w2, c_contact, c_guide, mu, nsub, x0, mu_static=0.0, v_band=0.0):
    """The table as a mass behind the nut (Compliance): per unit mass,
    x'' = w2 (n - x -+ b/2) + c_contact (n' - x')  in contact with a flank (pushing only),
          - c_guide x' - mu sign(x')                 (guide damping and Coulomb friction),
    sticking while |force| <= max(mu, mu_static) (Karnopp: a static friction above the
    Coulomb one makes the table stick until the chain's stretch breaks it away, then
    slip); with ``v_band`` > 0 (mm/s) a table slower than it counts as at rest (Karnopp's
    zero-velocity band: a slowing table is caught without its velocity crossing zero,
    which makes stick-slip set in at higher drive speeds). Semi-implicit Euler with ``nsub`` steps per sample,
    the nut linear between samples; nut_v (mm/s) is the nut velocity per sample (given
    separately so that it can be smoothed harder than the position). w2 in 1/s^2, c in 1/s, mu in mm/s^2, positions mm."""
    n = u.size
    out = np.empty(n)
    x = x0
    v = 0.0
    mus = max(mu, mu_static)
    out[0] = x
    for i in range(1, n):
        h = (t[i] - t[i - 1]) / nsub
        du = (u[i] - u[i - 1]) / nsub
        nv = 0.5 * (nut_v[i - 1] + nut_v[i])
        hb = half_width[i]
        for s in range(nsub):
            nut = u[i - 1] + du * s  # state at the start of the sub-step (symplectic Euler)
            f = flank_force(nut - x, hb, w2, c_contact, nv - v)
            vf = v + h * f
            if v == 0.0 or abs(v) <= v_band:
                if abs(f) <= mus:
                    vn = 0.0
                else:
                    vn = (vf - math.copysign(h * mu, f)) / (1.0 + h * c_guide)
            else:
                vn = vf - math.copysign(h * mu, v)
                if vn * v <= 0.0:
                    vn = 0.0
                else:
                    vn = vn / (1.0 + h * c_guide)
            v = vn
            x += h * v
        out[i] = x
    return out


@njit(cache=True)
def _first_root(a, b, d, limit, sgn):
    """Smallest tau in [0, limit] where a tau^2 + b tau reaches the flank at d, else inf.

    sgn is the side of the flank (+1 above, -1 below). At the flank already (|d| tiny)
    the contact is immediate if the motion goes towards it, else when it comes back.
    """
    if sgn * d <= 1e-13:
        if sgn * b > 0.0 or (b == 0.0 and sgn * a > 0.0):
            return 0.0
        if a != 0.0:
            r = -b / a
            if 0.0 < r <= limit:
                return r
        return np.inf
    best = np.inf
    if abs(a) < 1e-300:
        if b != 0.0:
            r = d / b
            if 0.0 <= r <= limit:
                best = r
        return best
    disc = b * b + 4.0 * a * d
    if disc < 0.0:
        return best
    sq = math.sqrt(disc)
    q = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
    if q != 0.0:
        for r in (q / a, -d / q):
            if 0.0 <= r <= limit and r < best:
                best = r
    return best


@njit(cache=True)
def _record(ta, tb, ua, ub, xa, xb, ts, ts_tab, j, jt, out_u, out_x, out_xt):
    span = tb - ta
    while j < ts.size and ts[j] <= tb:
        f = (ts[j] - ta) / span
        if f < 0.0:
            f = 0.0
        out_u[j] = ua + f * (ub - ua)
        out_x[j] = xa + f * (xb - xa)
        j += 1
    while jt < ts_tab.size and ts_tab[jt] <= tb:
        f = (ts_tab[jt] - ta) / span
        if f < 0.0:
            f = 0.0
        out_xt[jt] = xa + f * (xb - xa)
        jt += 1
    return j, jt


@njit(cache=True)
def _rec_segment(engaged, t_seg, dt, u, x, cc, cd, q, kp, gy, gain, e, ts, ts_tab, j, jt, out_u, out_x, out_xt):
    """Record the samples inside one analytic segment of run_rigid, exactly."""
    t_end = t_seg + dt
    while j < ts.size and ts[j] <= t_end:
        s = max(ts[j] - t_seg, 0.0)
        if engaged:
            y = cc + cd * s - q + (x - cc + q) * math.exp(-kp * s)
            out_x[j] = y
            out_u[j] = u + (y - x) / gy
        else:
            out_x[j] = x
            out_u[j] = u + gain * (e * s + 0.5 * cd * s * s)
        j += 1
    while jt < ts_tab.size and ts_tab[jt] <= t_end:
        s = max(ts_tab[jt] - t_seg, 0.0)
        if engaged:
            out_xt[jt] = cc + cd * s - q + (x - cc + q) * math.exp(-kp * s)
        else:
            out_xt[jt] = x
        jt += 1
    return j, jt


@njit(cache=True, nogil=True)
def run_rigid(t0, h, cmd, gain, u0, x0, side0, fixed, lam, per, amp, pha, pos, hw, ts, ts_tab, out_u, out_x, out_xt):
    """Rigid massless table, ideal inner loops: the paper's model, integrated exactly.

    Piecewise: engaged on one flank the table obeys dy/dt = K g (c - y), solved in
    closed form for the linear command of the step; in the backlash gap the table
    rests and u is a quadratic in time. Flank contacts (gap end) and error zero
    crossings (reversal: the nut leaves the flank) are located analytically inside
    the step, and samples are evaluated on the analytic segment they fall in. Exact
    for the nominal model with a piecewise-linear command; with cyclic error, thermal
    lead or a backlash profile, s(u) and hb(n) are linearised over each segment
    (error ~ s'' du^2 per step, below 1e-6 µm at the default step).
    """
    u = u0
    x = x0
    side = side0
    j = 0
    jt = 0
    while jt < ts_tab.size and ts_tab[jt] < t0:
        out_xt[jt] = x0
        jt += 1
    nstep = cmd.size - 1
    for i in range(nstep):
        ta = t0 + i * h
        c0 = cmd[i]
        cd = (cmd[i + 1] - c0) / h
        tau = 0.0
        rem = h
        it = 0
        while rem > 1e-15 * h and it < 8:
            it += 1
            cc = c0 + cd * tau
            e = cc - x
            n, g = _nut(u, fixed, lam, per, amp, pha)
            hb, dhb = _half(n, pos, hw)
            # engaged: the error pushes against the flank, or is nil (to rounding, as the gap
            # branch takes it) with the command moving that way; an exact e == 0 test let a
            # zero-width play flip between the flank and the gap 8 times at one instant and
            # end the step through the cut-short path (table resting while the nut moved)
            if side != 0 and (side * e > 0.0 or (abs(e) < 1e-13 and side * cd >= 0.0)):
                gy = g * (1.0 - side * dhb)
                if gy < 1e-6:
                    gy = 1e-6
                kp = gain * gy
                q = cd / kp
                dt = rem
                leave = False
                if side * q < 0.0 and side * e > 0.0:
                    tz = math.log((e - q) / (-q)) / kp  # error reaches zero: reversal
                    if tz < rem:
                        dt = tz
                        leave = True
                j, jt = _rec_segment(True, ta + tau, dt, u, x, cc, cd, q, kp, gy, gain, e,
                                     ts, ts_tab, j, jt, out_u, out_x, out_xt)
                c1 = cc + cd * dt
                y1 = c1 - q + (x - cc + q) * math.exp(-kp * dt)
                u = u + (y1 - x) / gy
                n1, g1 = _nut(u, fixed, lam, per, amp, pha)
                hb1, dhb1 = _half(n1, pos, hw)
                x = n1 - side * hb1
                tau += dt
                rem -= dt
                if leave:
                    side = 0
            else:
                side = 0
                if abs(e) < 1e-13:
                    e = 0.0
                aq = gain * g * cd * 0.5
                bq = gain * g * e
                tp = _first_root(aq, bq, x + hb - n, rem, 1.0)
                tm = _first_root(aq, bq, x - hb - n, rem, -1.0)
                dt = min(tp, tm, rem)
                j, jt = _rec_segment(False, ta + tau, dt, u, x, cc, cd, 0.0, 1.0, 1.0, gain, e,
                                     ts, ts_tab, j, jt, out_u, out_x, out_xt)
                u = u + gain * (e * dt + 0.5 * cd * dt * dt)
                tau += dt
                rem -= dt
                if tp <= tm and tp < np.inf:
                    side = 1
                elif tm < np.inf:
                    side = -1
                if side != 0:
                    n1, g1 = _nut(u, fixed, lam, per, amp, pha)
                    hb1, dhb1 = _half(n1, pos, hw)
                    x = n1 - side * hb1
        if rem > 1e-15 * h:  # event cascade cut short (not seen in tests): finish explicitly
            e = c0 + cd * tau - x
            j, jt = _rec_segment(False, ta + tau, rem, u, x, c0 + cd * tau, cd, 0.0, 1.0, 1.0, gain, e,
                                 ts, ts_tab, j, jt, out_u, out_x, out_xt)
            u += gain * (e * rem + 0.5 * cd * rem * rem)
            n1, g1 = _nut(u, fixed, lam, per, amp, pha)
            hb1, dhb1 = _half(n1, pos, hw)
            x = min(max(x, n1 - hb1), n1 + hb1)
    while j < ts.size:
        out_u[j] = u
        out_x[j] = x
        j += 1
    while jt < ts_tab.size:
        out_xt[jt] = x
        jt += 1
    return u, x, side


@njit(cache=True, nogil=True)
def run_dynamic(
    t0, hc, nsub, cmd, gain, u0, x0, side0, fixed, lam, per, amp, pha, pos, hw,
    lag_s, dead_s, compliant, k_n_mm, mass_kg, c_contact, c_visc,
    fr_model, fc, fs, vs, sig0, sig1,
    ts, ts_tab, out_u, out_x, out_xt, kff=0.0, fb_s=0.0, v_band=0.0, ki=0.0, a_max=0.0, fr_dir=0.0,
):  # fmt: skip
    """Servo dynamics and/or a compliant chain with friction, fixed step hc / nsub.

    Motor: v_cmd = (K e + kff c')(t - dead_s) with e = c - x(t - fb_s), first-order lag
    solved exactly per step for a constant input; u integrates the motor velocity
    exactly over the step. Both delays are interpolated linearly between sub-steps, so
    the result is continuous in them. ``ki`` > 0 (1/s): a PI position loop, K (e + ki
    ∫e dt). ``a_max`` > 0 (mm/s^2): the motor's acceleration is held within ±a_max
    (the velocity integrated as a ramp over a limited step) and the position integral
    is frozen while the limit holds and the error pushes further (anti-windup).
    Rigid chain: the table is the play operator of the nut. Compliant chain:
    semi-implicit (symplectic) Euler on the table mass with a unilateral spring-damper
    contact at each flank; viscous terms implicit; Coulomb/static friction as a
    velocity-level complementarity (the table sticks when the friction impulse can
    stop it, which needs no small-velocity window); LuGre bristle state implicit.
    ``v_band`` > 0 (mm/s, Stribeck model only): Karnopp's zero-velocity band as well, a
    table slower than it counts as at rest (sticks while the chain force is within the
    static friction, else breaks away against the Stribeck friction at its speed), as the
    round-trip chain form has it (:func:`core.gap.play.play_inertia`); 0 leaves the
    velocity-level switch alone. ``fr_dir`` (-1..1): friction that differs by direction,
    the friction levels (Coulomb, static, Stribeck curve) times 1 + fr_dir for motion in +
    and 1 - fr_dir in - (at rest, the direction the chain force pushes).
    """
    h = hc / nsub
    u = u0
    w = 0.0
    x = x0
    v = 0.0
    z = 0.0
    side = side0
    acc = 1000.0 / mass_kg
    damp_imp = 1.0 + h * acc * c_visc
    lag_f = math.exp(-h / lag_s) if lag_s > 0.0 else 0.0
    nd = dead_s / h
    nd0 = int(nd)
    frac = nd - nd0
    nbuf = nd0 + 2
    buf = np.zeros(nbuf)
    bi = 0
    nf = fb_s / h
    nf0 = int(nf)
    ffrac = nf - nf0
    nfbuf = nf0 + 2
    xbuf = np.full(nfbuf, x0)
    xi = 0
    xprev = x0
    integ = 0.0  # the position error's integral (mm s), PI loop only
    lim = 0.0  # the sign of the acceleration limit that held in the last step (0: none)
    j = 0
    jt = 0
    nstep = cmd.size - 1
    for i in range(nstep):
        c0 = cmd[i]
        dc = (cmd[i + 1] - c0) / nsub
        for s in range(nsub):
            ta = t0 + i * hc + s * h
            cc = c0 + dc * (s + 0.5)  # mid-step command: second-order accurate loop
            # the table at mid-step (linear extrapolation), to match the mid-step command:
            # without it the loop sees the table h/2 late, a first-order error of v h / 2
            xm = 1.5 * x - 0.5 * xprev
            xprev = x
            if fb_s > 0.0:
                xbuf[xi] = xm
                xd = xbuf[(xi - nf0) % nfbuf] * (1.0 - ffrac) + xbuf[(xi - nf0 - 1) % nfbuf] * ffrac
                xi = (xi + 1) % nfbuf
                err = cc - xd
            else:
                err = cc - xm
            if ki > 0.0:
                if lim == 0.0 or err * lim < 0.0:
                    integ += err * h
                e = gain * (err + ki * integ) + kff * dc / h
            else:
                e = gain * err + kff * dc / h
            if dead_s > 0.0:
                buf[bi] = e
                ia = (bi - nd0) % nbuf
                ib = (bi - nd0 - 1) % nbuf
                e_del = buf[ia] * (1.0 - frac) + buf[ib] * frac
                bi = (bi + 1) % nbuf
            else:
                e_del = e
            vc = e_del
            ua = u
            xa = x
            # chain state at the start of the step (symplectic Euler: the force at
            # (u_i, x_i) sets v_{i+1}, then x_{i+1} = x_i + h v_{i+1}; mixing u_{i+1}
            # with x_i would offset the static deflection by v h)
            n, g = _nut(u, fixed, lam, per, amp, pha)
            hb, dhb = _half(n, pos, hw)
            nv = g * w
            if a_max > 0.0:
                w1 = vc + (w - vc) * lag_f if lag_s > 0.0 else vc
                dw = a_max * h
                if w1 > w + dw:
                    w1 = w + dw
                    lim = 1.0
                elif w1 < w - dw:
                    w1 = w - dw
                    lim = -1.0
                else:
                    lim = 0.0
                if lim != 0.0:
                    u += 0.5 * (w + w1) * h
                elif lag_s > 0.0:
                    u += vc * h + (w - vc) * lag_s * (1.0 - lag_f)
                else:
                    u += vc * h
                w = w1
            elif lag_s > 0.0:
                u += vc * h + (w - vc) * lag_s * (1.0 - lag_f)
                w = vc + (w - vc) * lag_f
            else:
                u += vc * h
                w = vc
            if not compliant:
                n, g = _nut(u, fixed, lam, per, amp, pha)
                hb, dhb = _half(n, pos, hw)
                if x < n - hb:
                    x = n - hb
                elif x > n + hb:
                    x = n + hb
            else:
                f = flank_force(n - x, hb, k_n_mm, c_contact, nv - v)
                vf = v + h * acc * f
                if fr_model == FRICTION_STRIBECK:
                    if v == 0.0 or abs(v) <= v_band:
                        sd = 1.0 + fr_dir * math.copysign(1.0, f)
                        if abs(f) <= fs * sd:
                            vn = 0.0
                        else:
                            r = v / vs
                            ff = sd * (fc + (fs - fc) * math.exp(-r * r))
                            vn = (vf - math.copysign(h * acc * ff, f)) / damp_imp
                    else:
                        r = v / vs
                        ff = (1.0 + fr_dir * math.copysign(1.0, v)) * (fc + (fs - fc) * math.exp(-r * r))
                        vn = vf - math.copysign(h * acc * ff, v)
                        if vn * v <= 0.0:
                            vn = 0.0  # friction stops the table within the step
                        else:
                            vn = vn / damp_imp
                elif fr_model == FRICTION_LUGRE:
                    r = v / vs
                    gz = (1.0 + fr_dir * math.copysign(1.0, v)) * (fc + (fs - fc) * math.exp(-r * r)) / sig0
                    if gz < 1e-12:
                        gz = 1e-12
                    zn = (z + h * v) / (1.0 + h * abs(v) / gz)
                    ff = sig0 * zn + sig1 * (zn - z) / h
                    z = zn
                    vn = (v + h * acc * (f - ff)) / damp_imp
                else:
                    vn = vf / damp_imp
                v = vn
                x = x + h * v
            j, jt = _record(ta, ta + h, ua, u, xa, x, ts, ts_tab, j, jt, out_u, out_x, out_xt)
    while j < ts.size:
        out_u[j] = u
        out_x[j] = x
        j += 1
    while jt < ts_tab.size:
        out_xt[jt] = x
        jt += 1
    return u, x, side

"""The table given the motor: the play operator of Eq. 5 and its friction variant (numba).

With ideal inner loops and a rigid chain the table is a function of the motor
history only: x_t = clip(x_{t-1}, u_t - b_t/2, u_t + b_t/2), u = k_a x_m (Eq. 5).
``play_friction`` adds lost motion L(v) (the chain stretches by F(v)/k before the
table moves) and a break-away threshold L_s (stick until the stretch exceeds it).
Positions in mm.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core.sim.kernels import play_inertia  # noqa: F401  (the chain forms' kernel, beside the simulator's)


@njit(cache=True, nogil=True)
def play(u, half_width, x0):
    """Play operator: u (n,) nut position, half_width (n,) b/2 per sample, x0 start."""
    n = u.size
    out = np.empty(n)
    x = x0
    for i in range(n):
        lo = u[i] - half_width[i]
        hi = u[i] + half_width[i]
        if x < lo:
            x = lo
        elif x > hi:
            x = hi
        out[i] = x
    return out


@njit(cache=True, nogil=True)
def play_friction(u, half_width, lost_mm, breakaway_mm, x0, lost_minus_mm=None, breakaway_minus_mm=-1.0):
    """Play with friction lost motion: moving in direction s the table sits at
    u - s (b/2 + L_i); at rest it sticks until |u - x| exceeds b/2 + breakaway_mm.
    Friction that differs by direction: ``lost_minus_mm`` and ``breakaway_minus_mm``
    (>= 0) are the lost motion and break-away moving in -, ``lost_mm`` and
    ``breakaway_mm`` then those moving in + (None and -1: the same both ways)."""
    n = u.size
    out = np.empty(n)
    lost_m = lost_mm if lost_minus_mm is None else lost_minus_mm
    brk_m = breakaway_mm if breakaway_minus_mm < 0.0 else breakaway_minus_mm
    x = x0
    s = 0
    for i in range(n):
        hb = half_width[i]
        lo = u[i] - hb - lost_mm[i]
        hi = u[i] + hb + lost_m[i]
        if s == 0:
            if u[i] - x > hb + breakaway_mm:
                s = 1
                x = max(x, lo)
            elif x - u[i] > hb + brk_m:
                s = -1
                x = min(x, hi)
        elif s == 1:
            if lo >= x:
                x = lo
            else:
                s = 0
        else:
            if hi <= x:
                x = hi
            else:
                s = 0
        out[i] = x
    return out


@njit(cache=True, nogil=True)
def _dahl_force(x, xr, fr, s, lp):
    """Dahl's friction (per unit Coulomb force) at table position ``x``, moving in
    direction ``s`` from ``xr`` where it was ``fr``: s - (s - fr) exp(-s (x - xr) / lp)."""
    return s - (s - fr) * math.exp(-s * (x - xr) / lp)


@njit(cache=True, nogil=True)
def _penetration(u, x, hb):
    """How far the nut presses into a flank (mm, signed: + pushes the table +), 0 in the gap."""
    d = u - x
    if d > hb:
        return d - hb
    if d < -hb:
        return d + hb
    return 0.0


@njit(cache=True, nogil=True)
def play_dahl(u, half_width, coulomb_mm, presliding_mm, x0):
    """Play with Dahl pre-sliding friction on a stiff chain, quasi-static (a massless
    table): the chain's stretch ``coulomb_mm`` f (f the friction over its Coulomb level,
    |f| < 1) balances the friction, which builds with the table's travel as Dahl's law
    df/dx = (1 - f sgn(dx)) / presliding_mm has it. Where the nut leaves a flank the chain
    unloads and the table springs back until its friction is zero (presliding_mm
    ln(1 + |f|): 0.69 presliding_mm after steady sliding); on the other flank it moves
    while the friction builds, and once sliding it lags the nut by b/2 + coulomb_mm.
    Each sample's place is solved exactly (Dahl's law integrated in closed form, the
    balance by Newton's method kept inside a bracket: the balance is monotone in the
    table's travel), so the sampling rate does not matter. Positions in mm; the table
    starts at ``x0`` with the friction the chain holds there."""
    n = u.size
    out = np.empty(n)
    x = x0
    lc = max(coulomb_mm, 1e-12)
    lp = max(presliding_mm, 1e-9)
    f = min(1.0, max(-1.0, _penetration(u[0], x, half_width[0]) / lc))
    for i in range(n):
        hb = half_width[i]
        g0 = _penetration(u[i], x, hb) - lc * f
        if g0 != 0.0:
            s = 1.0 if g0 > 0.0 else -1.0
            # s g(d) falls from s g0 > 0 as the table travels d in direction s; it is <= 0
            # by d = |g0| (the nut's press taken up) + lp ln(1 + |f|) (the spring-back to f = 0)
            lo, hi = 0.0, abs(g0) + lp * math.log(2.0 + abs(f))
            d = min(abs(g0), hi)
            for _ in range(60):
                xm = x + s * d
                e = math.exp(-d / lp)
                g = s * (_penetration(u[i], xm, hb) - lc * (s - (s - f) * e))
                if g > 0.0:
                    lo = d
                else:
                    hi = d
                if hi - lo < 1e-13 or abs(g) < 1e-14:
                    break
                # slope of s g in d: the press (1 in contact) and the friction's build-up
                dm = u[i] - xm
                contact = 1.0 if (dm > hb or dm < -hb) else 0.0
                slope = -contact - lc * (1.0 - s * f) * e / lp
                dn = d - g / slope if slope < 0.0 else -1.0
                d = dn if lo < dn < hi else 0.5 * (lo + hi)
            f = _dahl_force(x + s * d, x, f, s, lp)
            x = x + s * d
        out[i] = x
    return out

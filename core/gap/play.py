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

from core.sim.kernels import flank_force


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
def play_friction(u, half_width, lost_mm, breakaway_mm, x0):
    """Play with friction lost motion: moving in direction s the table sits at
    u - s (b/2 + L_i); at rest it sticks until |u - x| exceeds b/2 + breakaway_mm."""
    n = u.size
    out = np.empty(n)
    x = x0
    s = 0
    for i in range(n):
        hb = half_width[i]
        lo = u[i] - hb - lost_mm[i]
        hi = u[i] + hb + lost_mm[i]
        if s == 0:
            if u[i] - x > hb + breakaway_mm:
                s = 1
                x = max(x, lo)
            elif x - u[i] > hb + breakaway_mm:
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


# Not cached: it calls core.sim.kernels.flank_force, and numba's on-disk cache is keyed
# by this file only, so an edit there would leave a stale compiled copy here (compiling
# costs about 0.5 s once per process).
@njit(nogil=True)
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

"""One feed-drive axis in continuous time, integrated by semi-implicit Euler (numba).

Three lumped masses in linear-equivalent SI units (m, m/s, N, kg), all referred to
table travel through k_a:

    motor  m_m x_m'' = F_drive - F_coupling - c_m x_m'
    screw  m_s x_s'' = F_coupling - F_nut
    table  m_t x_t'' = F_nut - F_friction

    F_coupling = k_c (x_m - x_s) + c_c (x_m' - x_s')
    F_nut      = spring(d) + c_n d'   while engaged, 0 inside the gap
    d          = (x_s + e_screw(x_s, t)) - x_t -+ b(x_t)/2   (the nut's deflection past the gap)

Control (full closed loop): the position loop is proportional on the linear scale's
reading, v_ref = K (x_cmd - x_scale); the velocity loop is PI on the motor velocity,
F = K_pv (e_v + z / T_iv), z' = e_v, with anti-windup while the drive is limited.

Friction on the table is integrated implicitly (a time-stepping stick/slip law): the
table stays at rest while the nut force is below the static level, and a kinetic
friction step never reverses the velocity within one sub-step. The effect forms
(core.plant_forms.forms) switch on through the form codes in the parameter vector.
"""

from __future__ import annotations

import numba
import numpy as np

# Parameter vector layout (SI units).
(P_MM, P_MS, P_MT, P_KC, P_CC, P_KN, P_CN, P_B0, P_K, P_KPV, P_TIV, P_FC, P_CV, P_CM,
 P_X0, P_L,
 P_BL_FORM, P_BL_DB, P_BL_XC, P_BL_W,
 P_CY_FORM, P_CY_A1, P_CY_A2, P_CY_P, P_CY_PH1, P_CY_PH2,
 P_TH_FORM, P_TH_G, P_TH_TAU, P_TH_ALPHA, P_TH_DT,
 P_FR_FORM, P_FR_DF, P_FR_TAU, P_FR_VS, P_FR_XZ, P_FR_W,
 P_CO_FORM, P_CO_K1, P_CO_K3,
 P_SV_FORM, P_SV_FMAX, P_SV_TAU,
 N_PARAMS) = range(44)

BL_NONE, BL_WORN_MIDDLE, BL_BUMP, BL_TAPER = 0, 1, 2, 3
CY_NONE, CY_SCALE, CY_SCREW = 0, 1, 2
TH_NONE, TH_SCREW_GROWTH, TH_SCALE_DRIFT = 0, 1, 2
FR_NONE, FR_DWELL, FR_STRIBECK, FR_LUBE_ZONE = 0, 1, 2, 3
CO_NONE, CO_HARDENING = 0, 1
SV_NONE, SV_TORQUE_LIMIT, SV_LOWPASS = 0, 1, 2
V_STICK_M_S = 1e-6  # below this speed the table sticks when friction can hold it


@numba.njit(cache=True)
def _backlash_m(p, x_t):
    """Backlash width b(x) at table position x_t (m)."""
    b = p[P_B0]
    form = int(p[P_BL_FORM])
    if form == BL_WORN_MIDDLE:
        u = (x_t - p[P_BL_XC]) / (0.5 * p[P_L])
        b += p[P_BL_DB] * max(0.0, 1.0 - u * u)
    elif form == BL_BUMP:
        u = (x_t - p[P_BL_XC]) / p[P_BL_W]
        b += p[P_BL_DB] * np.exp(-u * u)
    elif form == BL_TAPER:
        b += p[P_BL_DB] * (x_t - p[P_X0]) / p[P_L]
    return max(b, 0.0)


@numba.njit(cache=True)
def _scale_error_m(p, x_t, t):
    """What the linear scale adds to the true table position (m)."""
    e = 0.0
    if int(p[P_CY_FORM]) == CY_SCALE:
        ph = 2.0 * np.pi * x_t / p[P_CY_P]
        e += p[P_CY_A1] * np.sin(ph + p[P_CY_PH1]) + p[P_CY_A2] * np.sin(2.0 * ph + p[P_CY_PH2])
    if int(p[P_TH_FORM]) == TH_SCALE_DRIFT:
        e += p[P_TH_ALPHA] * p[P_TH_DT] * (1.0 - np.exp(-t / p[P_TH_TAU])) * (x_t - p[P_X0])
    return e


@numba.njit(cache=True)
def simulate_axis(cmd_m, dt_s, p, side):
    """Integrate one axis driven by the command ``cmd_m`` (m, one value per sub-step).

    ``side`` (+1 or -1) is the flank of the nut in contact at rest at the start.
    Returns (motor position, scale reading, true table position), each per sub-step (m),
    and the largest drive force |F_drive| (N).
    """
    n = cmd_m.shape[0]
    out_m = np.empty(n)
    out_scale = np.empty(n)
    out_t = np.empty(n)
    m_m, m_s, m_t = p[P_MM], p[P_MS], p[P_MT]
    k_c, c_c, k_n, c_n = p[P_KC], p[P_CC], p[P_KN], p[P_CN]
    gain, k_pv, t_iv = p[P_K], p[P_KPV], p[P_TIV]
    f_c0, c_v, c_m = p[P_FC], p[P_CV], p[P_CM]
    th_form, fr_form, co_form, sv_form = int(p[P_TH_FORM]), int(p[P_FR_FORM]), int(p[P_CO_FORM]), int(p[P_SV_FORM])
    cy_screw = int(p[P_CY_FORM]) == CY_SCREW

    # Start at rest on the command, the nut resting on flank `side`, preloaded by friction.
    x_t = cmd_m[0]
    b_start = _backlash_m(p, x_t)
    x_s = x_t + side * 0.5 * b_start
    x_m = x_s
    v_m = 0.0
    v_s = 0.0
    v_t = 0.0
    z_v = 0.0        # velocity-loop integral (m)
    v_lp1 = 0.0      # velocity set-point filter stages (m/s)
    v_lp2 = 0.0
    theta_k = 0.0    # screw temperature rise (K)
    t_rest = 0.0     # time the table has been at rest (s)
    d_prev = 0.0
    f_peak = 0.0
    for i in range(n):
        t = i * dt_s
        x_scale = x_t + _scale_error_m(p, x_t, t)
        out_m[i] = x_m
        out_scale[i] = x_scale
        out_t[i] = x_t

        # Controller: P position on the scale, PI velocity on the motor.
        v_ref = gain * (cmd_m[i] - x_scale)
        if sv_form == SV_LOWPASS:  # two first-order stages on the velocity set-point
            a_lp = dt_s / (p[P_SV_TAU] + dt_s)
            v_lp1 += a_lp * (v_ref - v_lp1)
            v_lp2 += a_lp * (v_lp1 - v_lp2)
            v_ref = v_lp2
        e_v = v_ref - v_m
        f_drive = k_pv * (e_v + z_v / t_iv)
        limited = False
        if sv_form == SV_TORQUE_LIMIT:
            f_max = p[P_SV_FMAX]
            if f_drive > f_max:
                f_drive = f_max
                limited = True
            elif f_drive < -f_max:
                f_drive = -f_max
                limited = True
        if not limited or e_v * f_drive < 0.0:
            z_v += dt_s * e_v
        f_peak = max(f_peak, abs(f_drive))

        # Chain forces.
        f_coupling = k_c * (x_m - x_s) + c_c * (v_m - v_s)
        x_nut = x_s
        if cy_screw:
            x_nut += p[P_CY_A1] * np.sin(2.0 * np.pi * x_s / p[P_CY_P] + p[P_CY_PH1]) \
                + p[P_CY_A2] * np.sin(4.0 * np.pi * x_s / p[P_CY_P] + p[P_CY_PH2])
        if th_form == TH_SCREW_GROWTH:
            x_nut += p[P_TH_ALPHA] * theta_k * (x_s - p[P_X0])
        half_b = 0.5 * _backlash_m(p, x_t)
        gap = x_nut - x_t
        if gap > half_b:
            d = gap - half_b
        elif gap < -half_b:
            d = gap + half_b
        else:
            d = 0.0
        if d != 0.0:
            if co_form == CO_HARDENING:
                ad = abs(d)
                f_spring = np.sign(d) * (p[P_CO_K1] * ad + p[P_CO_K3] * ad * ad * ad)
            else:
                f_spring = k_n * d
            f_nut = f_spring + c_n * (d - d_prev) / dt_s
            if f_nut * d < 0.0:  # a contact pushes, never pulls
                f_nut = 0.0
        else:
            f_nut = 0.0
        d_prev = d

        # Friction levels of the guides.
        f_kin = f_c0
        f_static = f_c0
        if fr_form == FR_DWELL:
            f_static = f_c0 + p[P_FR_DF] * (1.0 - np.exp(-t_rest / p[P_FR_TAU]))
        elif fr_form == FR_STRIBECK:
            u = v_t / p[P_FR_VS]
            f_kin = f_c0 + p[P_FR_DF] * np.exp(-u * u)
            f_static = f_c0 + p[P_FR_DF]
        elif fr_form == FR_LUBE_ZONE:
            u = (x_t - p[P_FR_XZ]) / p[P_FR_W]
            f_kin = f_c0 + p[P_FR_DF] * np.exp(-u * u)
            f_static = f_kin

        # Semi-implicit Euler: velocities first, positions with the new velocities.
        v_m += dt_s * (f_drive - f_coupling - c_m * v_m) / m_m
        v_s += dt_s * (f_coupling - f_nut) / m_s
        if v_t == 0.0:
            if abs(f_nut) <= f_static:
                v_new = 0.0
            else:
                sgn = 1.0 if f_nut > 0.0 else -1.0
                v_new = dt_s * (f_nut - sgn * f_kin) / (m_t + dt_s * c_v)
        else:
            sgn = 1.0 if v_t > 0.0 else -1.0
            v_new = (m_t * v_t + dt_s * (f_nut - sgn * f_kin)) / (m_t + dt_s * c_v)
            # Stops on a velocity reversal, or sticks once creeping below V_STICK with the
            # nut force inside the static level (an asymptotic approach would never stop).
            if v_new * sgn <= 0.0 or (abs(v_new) < V_STICK_M_S and abs(f_nut) <= f_static):
                v_new = 0.0
        v_t = v_new
        if v_t == 0.0:
            t_rest += dt_s
        else:
            t_rest = 0.0
        x_m += dt_s * v_m
        x_s += dt_s * v_s
        x_t += dt_s * v_t
        if th_form == TH_SCREW_GROWTH:
            theta_k += dt_s * (p[P_TH_G] * abs(v_s) - theta_k) / p[P_TH_TAU]
    return out_m, out_scale, out_t, f_peak


def empty_params() -> np.ndarray:
    """A parameter vector with every effect form off."""
    return np.zeros(N_PARAMS)

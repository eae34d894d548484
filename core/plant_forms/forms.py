"""The nominal machine and the effect forms of the second plant, as drawn parameters.

Every quantity is drawn per dataset from the ranges below, through the
``numpy.random.Generator`` handed in. Parameters are kept in human units (mm, µm, N,
N/µm, kg, s) in the truth dictionary and converted to SI for the integrator
(core.plant_forms.drive).

Nominal machine (every dataset, each axis drawn on its own)
-----------------------------------------------------------
- screw lead P_h 5-20 mm (0.5 mm steps), gear ratio 1, 1.5 or 2: k_a = P_h / gear
- position gain K 15-60 1/s, useful travel 300-1000 mm
- table mass m_t 100-400 kg; motor inertia as an equivalent mass m_m = (0.5-2) m_t
  (J_m = m_m (k_a / 2π)²); screw m_s = (0.15-0.3) m_t
- nut and bearing stiffness k_n 150-400 N/µm, damping ratio 0.03-0.08; coupling
  k_c = (3-6) k_n, damping ratio 0.05
- backlash b 5-150 µm (constant along the travel)
- velocity loop PI, bandwidth ω_v = 2π (60-120) Hz: K_pv = (m_m + m_s + m_t) ω_v,
  T_iv = (3-6) / ω_v
- guide friction Coulomb F_c = max(40-200 N, (1.2-2) m_t a_max) (static = kinetic), a_max the
  dataset's largest path or centripetal acceleration; viscous 300-2000 N s/m
- encoders: linear scale quantum 0.05-1 µm, motor encoder 2^13-2^20 counts/rev,
  white noise 0.05-0.3 µm on each (table-equivalent)

Effect forms (one form per label per dataset, the same form on both axes)
-------------------------------------------------------------------------
thermal
  ``screw_growth``: the screw warms by nut friction times speed, with a first-order
  time constant, and grows from its fixed bearing at the travel start:
  τ θ' = G |v_s| - θ,  e_screw = α θ (x_s - x_0),  α = 11.5e-6 1/K,
  τ = (0.3-1.2) × run duration, G set so that θ_ss = 2-5 K at the dataset's mean
  round-trip feed.
  ``scale_drift``: the table side warms during the run and the scale's mounting grows:
  e_scale = α_s ΔT (1 - exp(-t/τ)) (x_t - x_0),  α_s = 8-12e-6 1/K, ΔT = 1.5-4 K,
  τ = (0.3-1) × run duration.
backlash_profile (b(x) = b_0 + Δb · shape, x the table position, Δb = 15-50 µm)
  ``worn_middle``: shape = max(0, 1 - ((x - x_c) / (L/2))²), x_c = centre of travel ± 10 %
  ``bump``: shape = exp(-((x - x_c) / w)²), x_c = (0.25-0.75) L, w = (0.05-0.15) L
  ``taper``: shape = (x - x_0) / L, Δb of either sign (b stays ≥ 2 µm)
cyclic_error
  ``scale_interpolation``: e_scale = A_1 sin(2π x/p + φ_1) + A_2 sin(4π x/p + φ_2),
  p = 20-40 µm (the scale's signal period), A_1 = 1.5-4 µm, A_2 = (0.2-0.5) A_1
  ``screw_once_per_rev``: e_screw = A_1 sin(2π x_s/P_h + φ_1) + A_2 sin(4π x_s/P_h + φ_2),
  A_1 = 3-10 µm, A_2 = (0.1-0.4) A_1
friction (on the table's guides)
  ``dwell_breakaway``: static level F_s = F_c + ΔF (1 - exp(-t_rest/τ_d)), t_rest the
  time at rest, ΔF = k_n × (3-10 µm) (the extra nut deflection it
  causes), τ_d = 0.2-2 s; kinetic level F_c
  ``stribeck``: F_k(v) = F_c + ΔF exp(-(v/v_s)²), ΔF as above, v_s = 1-15 mm/s
  ``lubrication_zone``: a poorly lubricated stretch: F_c(x) = F_c + ΔF exp(-((x-x_z)/w)²),
  ΔF as above, x_z = (0.2-0.8) L, w = (0.05-0.15) L
compliance
  ``hardening_nut``: a preloaded nut whose stiffness grows with load:
  F = k_1 d + k_3 d³, k_1 = (0.1-0.3) k_n, k_3 = (k_n - k_1) / (3 d_ref²) (the tangent
  stiffness reaches k_n at d_ref = 8-20 µm)
  ``soft_coupling``: a soft motor coupling, k_c = 30-80 N/µm, damping ratio 0.02-0.05
servo_dynamics
  ``torque_limit``: |F_drive| ≤ F_max = F_st + f (F_pk - F_st), f = 0.6-0.85, F_st the
  steady force at the axis's fastest feed (F_c + c_v v_max), F_pk the largest peak force
  of the nominal drive over the dataset's runs (anti-windup while limited): the drive
  saturates in the hardest accelerations, never at constant feed
  ``velocity_lowpass``: a two-pole low-pass on the velocity set-point (the position loop's
  output), v_ref <- v_ref / (1 + τ_f s)², τ_f = 0.5-2 ms: an extra lag a 2τ_f / K while
  accelerating and a second-order overshoot after a change of acceleration
sampling_skew
  ``latch_delay``: the table encoder is latched δ after the motor encoder (δ of either
  sign, |δ| = 0.2-3 round-trip sample periods, the same for both axes, every run):
  table_mm(t_i) = x_scale(t_i + δ), interpolated in the continuous trajectory.
"""

from __future__ import annotations

import numpy as np

from core.plant_forms import drive as d

FORMS = {
    "thermal": ("screw_growth", "scale_drift"),
    "backlash_profile": ("worn_middle", "bump", "taper"),
    "cyclic_error": ("scale_interpolation", "screw_once_per_rev"),
    "friction": ("dwell_breakaway", "stribeck", "lubrication_zone"),
    "compliance": ("hardening_nut", "soft_coupling"),
    "servo_dynamics": ("torque_limit", "velocity_lowpass"),
    "sampling_skew": ("latch_delay",),
}


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def draw_axis(rng: np.random.Generator, max_accel_mm_s2: float) -> dict:
    """The nominal parameters of one axis, in human units.

    Guide friction exceeds the table's largest inertial force (``max_accel_mm_s2``), so
    the nominal table rests on the driving flank of the nut except at reversals.
    """
    lead_mm = round(_u(rng, 5.0, 20.0) * 2) / 2
    gear = float(rng.choice([1.0, 1.0, 1.5, 2.0]))
    table_kg = _u(rng, 100.0, 400.0)
    k_n = _u(rng, 150.0, 400.0)
    omega_v = 2 * np.pi * _u(rng, 60.0, 120.0)
    return {
        "screw_lead_mm": lead_mm,
        "gear_ratio": gear,
        "transmission_mm_per_rev": lead_mm / gear,
        "position_gain_per_s": _u(rng, 15.0, 60.0),
        "travel_mm": [0.0, round(_u(rng, 300.0, 1000.0))],
        "table_kg": table_kg,
        "motor_equiv_kg": _u(rng, 0.5, 2.0) * table_kg,
        "screw_equiv_kg": _u(rng, 0.15, 0.3) * table_kg,
        "nut_stiffness_n_per_um": k_n,
        "nut_damping_ratio": _u(rng, 0.03, 0.08),
        "coupling_stiffness_n_per_um": _u(rng, 3.0, 6.0) * k_n,
        "coupling_damping_ratio": 0.05,
        "backlash_um": _u(rng, 5.0, 150.0),
        "velocity_bandwidth_rad_s": omega_v,
        "velocity_integral_s": _u(rng, 3.0, 6.0) / omega_v,
        "coulomb_n": max(_u(rng, 40.0, 200.0), _u(rng, 1.2, 2.0) * table_kg * max_accel_mm_s2 * 1e-3),
        "viscous_n_s_per_m": _u(rng, 300.0, 2000.0),
        "scale_quantum_um": _u(rng, 0.05, 1.0),
        "motor_counts_per_rev": int(2 ** int(rng.integers(13, 21))),
        "scale_noise_um": _u(rng, 0.05, 0.3),
        "motor_noise_um": _u(rng, 0.05, 0.3),
    }


def draw_effect(label: str, rng: np.random.Generator, axes: dict, ctx: dict) -> dict:
    """One form of ``label`` with its parameters per axis (human units).

    ``ctx`` holds dataset quantities the sizes refer to: ``duration_s`` (round trip),
    ``mean_rt_feed_mm_s``, ``rt_period_s``.
    """
    form = str(rng.choice(FORMS[label]))
    if label == "sampling_skew":
        delay_s = float(rng.choice([-1.0, 1.0])) * _u(rng, 0.2, 3.0) * ctx["rt_period_s"]
        return {"form": form, "delay_s": delay_s, "delay_periods": delay_s / ctx["rt_period_s"]}
    per_axis = {}
    for name, ax in axes.items():
        length = ax["travel_mm"][1] - ax["travel_mm"][0]
        q: dict = {}
        # A friction form's added force, sized by the nut deflection it causes (3-10 µm).
        df_n = _u(rng, 3.0, 10.0) * ax["nut_stiffness_n_per_um"]
        if form == "screw_growth":
            theta_ss = _u(rng, 2.0, 5.0)
            q = {"alpha_per_k": 11.5e-6, "tau_s": _u(rng, 0.3, 1.2) * ctx["duration_s"],
                 "theta_ss_k": theta_ss, "gain_k_per_mm_s": theta_ss / ctx["mean_rt_feed_mm_s"]}
        elif form == "scale_drift":
            q = {"alpha_per_k": _u(rng, 8e-6, 12e-6), "delta_t_k": _u(rng, 1.5, 4.0),
                 "tau_s": _u(rng, 0.3, 1.0) * ctx["duration_s"]}
        elif form in ("worn_middle", "bump", "taper"):
            q = {"delta_b_um": _u(rng, 15.0, 50.0)}
            if form == "worn_middle":
                q["centre_mm"] = ax["travel_mm"][0] + length * _u(rng, 0.4, 0.6)
            elif form == "bump":
                q["centre_mm"] = ax["travel_mm"][0] + length * _u(rng, 0.25, 0.75)
                q["width_mm"] = length * _u(rng, 0.05, 0.15)
            else:
                if rng.random() < 0.5:
                    q["delta_b_um"] = -min(q["delta_b_um"], ax["backlash_um"] - 2.0)
        elif form == "scale_interpolation":
            a1 = _u(rng, 1.5, 4.0)
            q = {"period_um": _u(rng, 20.0, 40.0), "a1_um": a1, "a2_um": _u(rng, 0.2, 0.5) * a1,
                 "phase1_rad": _u(rng, 0, 2 * np.pi), "phase2_rad": _u(rng, 0, 2 * np.pi)}
        elif form == "screw_once_per_rev":
            a1 = _u(rng, 3.0, 10.0)
            q = {"period_mm": ax["screw_lead_mm"], "a1_um": a1, "a2_um": _u(rng, 0.1, 0.4) * a1,
                 "phase1_rad": _u(rng, 0, 2 * np.pi), "phase2_rad": _u(rng, 0, 2 * np.pi)}
        elif form == "dwell_breakaway":
            q = {"delta_f_n": df_n, "tau_s": _u(rng, 0.2, 2.0)}
        elif form == "stribeck":
            q = {"delta_f_n": df_n, "stribeck_mm_s": _u(rng, 1.0, 15.0)}
        elif form == "lubrication_zone":
            q = {"delta_f_n": df_n,
                 "centre_mm": ax["travel_mm"][0] + length * _u(rng, 0.2, 0.8),
                 "width_mm": length * _u(rng, 0.05, 0.15)}
        elif form == "hardening_nut":
            k1 = _u(rng, 0.1, 0.3) * ax["nut_stiffness_n_per_um"]
            d_ref = _u(rng, 8.0, 20.0)
            q = {"k1_n_per_um": k1, "d_ref_um": d_ref,
                 "k3_n_per_um3": (ax["nut_stiffness_n_per_um"] - k1) / (3 * d_ref ** 2)}
        elif form == "soft_coupling":
            q = {"coupling_stiffness_n_per_um": _u(rng, 30.0, 80.0), "coupling_damping_ratio": _u(rng, 0.02, 0.05)}
        elif form == "torque_limit":
            # f_max_n is set once the nominal runs' peak drive forces are known (case.py).
            q = {"fraction": _u(rng, 0.6, 0.85)}
        elif form == "velocity_lowpass":
            q = {"tau_s": _u(rng, 0.5e-3, 2e-3)}
        per_axis[name] = q
    return {"form": form, "axes": per_axis}


def axis_params(ax: dict, effects: dict, axis: str) -> np.ndarray:
    """The integrator's SI parameter vector of ``axis`` with the drawn ``effects`` on."""
    p = d.empty_params()
    m_m, m_s, m_t = ax["motor_equiv_kg"], ax["screw_equiv_kg"], ax["table_kg"]
    k_n = ax["nut_stiffness_n_per_um"] * 1e6
    k_c = ax["coupling_stiffness_n_per_um"] * 1e6
    zeta_c = ax["coupling_damping_ratio"]
    p[d.P_MM], p[d.P_MS], p[d.P_MT] = m_m, m_s, m_t
    p[d.P_KN] = k_n
    p[d.P_CN] = 2 * ax["nut_damping_ratio"] * np.sqrt(k_n * m_t)
    p[d.P_B0] = ax["backlash_um"] * 1e-6
    p[d.P_K] = ax["position_gain_per_s"]
    omega_v = ax["velocity_bandwidth_rad_s"]
    p[d.P_KPV] = (m_m + m_s + m_t) * omega_v
    p[d.P_TIV] = ax["velocity_integral_s"]
    p[d.P_FC] = ax["coulomb_n"]
    p[d.P_CV] = ax["viscous_n_s_per_m"]
    p[d.P_CM] = 50.0
    p[d.P_X0] = ax["travel_mm"][0] * 1e-3
    p[d.P_L] = (ax["travel_mm"][1] - ax["travel_mm"][0]) * 1e-3
    for label, eff in effects.items():
        if label == "sampling_skew":
            continue
        form, q = eff["form"], eff["axes"][axis]
        if label == "thermal":
            p[d.P_TH_ALPHA] = q["alpha_per_k"]
            p[d.P_TH_TAU] = q["tau_s"]
            if form == "screw_growth":
                p[d.P_TH_FORM] = d.TH_SCREW_GROWTH
                p[d.P_TH_G] = q["gain_k_per_mm_s"] * 1e3
            else:
                p[d.P_TH_FORM] = d.TH_SCALE_DRIFT
                p[d.P_TH_DT] = q["delta_t_k"]
        elif label == "backlash_profile":
            p[d.P_BL_FORM] = {"worn_middle": d.BL_WORN_MIDDLE, "bump": d.BL_BUMP, "taper": d.BL_TAPER}[form]
            p[d.P_BL_DB] = q["delta_b_um"] * 1e-6
            p[d.P_BL_XC] = q.get("centre_mm", 0.0) * 1e-3
            p[d.P_BL_W] = q.get("width_mm", 1.0) * 1e-3
        elif label == "cyclic_error":
            p[d.P_CY_A1], p[d.P_CY_A2] = q["a1_um"] * 1e-6, q["a2_um"] * 1e-6
            p[d.P_CY_PH1], p[d.P_CY_PH2] = q["phase1_rad"], q["phase2_rad"]
            if form == "scale_interpolation":
                p[d.P_CY_FORM], p[d.P_CY_P] = d.CY_SCALE, q["period_um"] * 1e-6
            else:
                p[d.P_CY_FORM], p[d.P_CY_P] = d.CY_SCREW, q["period_mm"] * 1e-3
        elif label == "friction":
            p[d.P_FR_DF] = q["delta_f_n"]
            if form == "dwell_breakaway":
                p[d.P_FR_FORM], p[d.P_FR_TAU] = d.FR_DWELL, q["tau_s"]
            elif form == "stribeck":
                p[d.P_FR_FORM], p[d.P_FR_VS] = d.FR_STRIBECK, q["stribeck_mm_s"] * 1e-3
            else:
                p[d.P_FR_FORM] = d.FR_LUBE_ZONE
                p[d.P_FR_XZ], p[d.P_FR_W] = q["centre_mm"] * 1e-3, q["width_mm"] * 1e-3
        elif label == "compliance":
            if form == "hardening_nut":
                p[d.P_CO_FORM] = d.CO_HARDENING
                p[d.P_CO_K1] = q["k1_n_per_um"] * 1e6
                p[d.P_CO_K3] = q["k3_n_per_um3"] * 1e18  # N/µm³ -> N/m³
            else:
                k_c = q["coupling_stiffness_n_per_um"] * 1e6
                zeta_c = q["coupling_damping_ratio"]
        elif label == "servo_dynamics":
            if form == "torque_limit":
                p[d.P_SV_FORM], p[d.P_SV_FMAX] = d.SV_TORQUE_LIMIT, q["f_max_n"]
            else:
                p[d.P_SV_FORM], p[d.P_SV_TAU] = d.SV_LOWPASS, q["tau_s"]
    p[d.P_KC] = k_c
    m_red = m_m * m_s / (m_m + m_s)
    p[d.P_CC] = 2 * zeta_c * np.sqrt(k_c * m_red)
    return p

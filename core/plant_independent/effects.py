"""The machine of the independent plant: its nominal draw and each effect's form and draw.

Nominal machine (what the diagnosis assumes), per axis: position loop on the table
encoder ``u' = K (c - x)``; ``u = k_a * motor_rev`` (plus an arbitrary encoder zero); the
nut drives the table through a backlash of width ``b`` (a stiff dead-zone contact, see
:mod:`.drive`); ideal velocity loop; rigid chain. Draws: lead in {10, 16, 20} mm,
``k_a = lead * U(0.35, 0.9)``, ``K = U(8, 40) 1/s``, ``b = U(15, 150) um``, white encoder noise
``U(0.05, 0.5) um`` on each encoder, quantisation 0.05 um (table) and 2^20 counts/rev
(motor), a CNC jerk filter of ``U(8, 30) ms``.

Effect forms (each other than a simple twin's); temperatures ``dT = T - 20 degC``:

``servo_dynamics``
    ``v_ref = K_eff (c - x(t - T_fb)) + k_ff c'`` and a second-order velocity loop
    ``w'' = wn^2 (v_ref - w) - 2 zeta wn w'``: ``k_ff = U(0.3, 1.0)``,
    ``K_eff = K * U(0.7, 1.4)``, ``wn = 2 pi U(30, 80) Hz``, ``zeta = U(0.5, 0.9)``,
    ``T_fb = U(0.5, 3) ms`` (dead time in the feedback path). The dataset keeps the
    configured ``K``.
``friction`` (form drawn per case, each axis its own parameters)
    (a) Karnopp stick-slip on a compliant chain: table ``m = U(300, 1500) kg``, chain
    ``k = U(50, 300) N/um`` with structural damping ``zeta_c = U(0.05, 0.15)``, Coulomb
    ``F_c = U(800, 2500) N``, static ``F_s = F_c * U(2, 4)``, zero-velocity band ``dv``
    (:mod:`.drive`). (b) Dahl pre-sliding friction ``dF/dx = sigma0 (1 - F sgn(dx) / F_c)``
    with the same chain, ``F_c = U(800, 2500) N`` and pre-sliding distance
    ``F_c / sigma0 = U(1, 5) um``. Signatures at these ranges: Coulomb lost motion
    ``2 F_c / k`` = 5-100 um on top of ``b``; Karnopp break-away overshoot ``(F_s - F_c) / k``
    = 3-150 um; below the critical speed ``(F_s - F_c) / sqrt(k m)`` (3-27 mm/s) a Karnopp
    stroke stick-slips throughout; circle spikes after the quadrant reversals of 15-65 um
    peak (R 60 mm, 1000 mm/min).
``compliance``
    Two-mass chain: the motor/screw side held by the velocity loop, the table mass
    ``m = U(300, 1500) kg`` behind a nut-table spring ``k = U(60, 200) N/um`` with
    structural damping ``zeta_c = U(0.05, 0.2)`` (raised to ``K / omega`` if needed, so the
    position loop stays stable with ``K / (2 zeta_c omega) <= 0.5``), rolling-guide and
    seal friction ``F_g = mu m g``, ``mu = U(0.02, 0.05)`` (smoothed over 0.5 mm/s), and an
    oil-film damper ``c_g = m / 2 s`` (both also under ``friction``, where ``F_g = 0``).
    The gap grows with the drive force ``m a``: 2-30 um of chain deflection at
    0.3-2 m/s^2, and a table decelerating faster than ``mu g`` overruns the nut across the
    backlash. (With ``mu`` below ~0.01 a table floating in a wide gap rattles between the
    flanks at constant feed: real tables do not, so the guide friction is drawn above it.)
``thermal``
    Screw growth about a bearing point that moves with temperature, and a backlash that
    changes with it: ``e(u) = alpha dT (u - p_b - gamma dT)``, ``alpha = U(5, 15) ppm/K``,
    ``p_b = U(100, 400) mm`` (not a travel end), ``gamma = +-U(2, 10) mm/K``;
    ``b(T) = b (1 + kappa dT)``, ``kappa = +-U(0.5, 2) %/K``.
``backlash_profile``
    ``b(x) = b (1 + sum_i a_i s_i(x))`` with 2-4 wear bumps, ``a_i = U(0.2, 0.6)``, centres
    ``U(60, 740) mm``, each a Gaussian (``sigma = U(25, 100) mm``) or a raised cosine
    (half-width ``U(40, 150) mm``).
``cyclic_error``
    ``e(u) = A sin(2 pi u / P_g + phi) [+ A_l sin(2 pi u / lead + phi_l)]`` with a gear
    period ``P_g = k_a * U(1.3, 3.7)``, ``A = U(2, 6) um``, and with probability 1/2 a lead
    component ``A_l = U(0.5, 1.5) um``.
``sampling_skew``
    The table encoder is latched ``tau(t)`` after the motor encoder (earlier when
    negative), one acquisition delay shared by the axes:
    ``tau(t) = tau0 (1 + delta (2 t / T_run - 1)) + jitter``, ``|tau0| = U(1, 5) ms``,
    ``delta = U(-0.5, 0.5)`` (the drift over each run), with probability 1/2 a white
    jitter of ``U(5, 15) %`` of ``|tau0|``.
"""

from __future__ import annotations

import numpy as np

from .drive import DriveParams, Lut

LABELS: tuple[str, ...] = ("none", "thermal", "backlash_profile", "cyclic_error", "friction", "compliance",
                           "servo_dynamics", "sampling_skew")  # fmt: skip
EFFECTS = LABELS[1:]
T_REF_C = 20.0
TRAVEL_MM = (0.0, 800.0)
GRID_MM = (-60.0, 860.0)  # look-up tables cover the travel and any overshoot


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _pm(rng: np.random.Generator, lo: float, hi: float) -> float:
    return (1.0 if rng.random() < 0.5 else -1.0) * _u(rng, lo, hi)


def draw_nominal(rng: np.random.Generator) -> dict:
    lead = float(rng.choice([10.0, 16.0, 20.0]))
    return {
        "screw_lead_mm": lead,
        "transmission_mm_per_rev": lead * _u(rng, 0.35, 0.9),
        "position_gain_per_s": _u(rng, 8.0, 40.0),
        "backlash_um": _u(rng, 15.0, 150.0),
        "table_noise_um": _u(rng, 0.05, 0.5),
        "motor_noise_um": _u(rng, 0.05, 0.5),
        "motor_zero_rev": _u(rng, -500.0, 500.0),
    }


def draw_effect(label: str, rng: np.random.Generator, nominal: dict) -> dict:
    """The drawn parameters of ``label`` for one axis (see the module docstring)."""
    k_a = nominal["transmission_mm_per_rev"]
    if label == "servo_dynamics":
        return {"ff_fraction": _u(rng, 0.3, 1.0), "gain_ratio": _u(rng, 0.7, 1.4),
                "vloop_bandwidth_hz": _u(rng, 30.0, 80.0), "vloop_damping": _u(rng, 0.5, 0.9),
                "feedback_delay_s": _u(rng, 0.5e-3, 3e-3)}  # fmt: skip
    if label == "friction":
        kind = "karnopp" if rng.random() < 0.5 else "dahl"
        fc = _u(rng, 800.0, 2500.0)
        out = {"form": kind, "table_mass_kg": _u(rng, 300.0, 1500.0), "chain_stiffness_n_per_um": _u(rng, 50.0, 300.0),
               "chain_damping_ratio": _u(rng, 0.05, 0.15), "coulomb_n": fc}  # fmt: skip
        if kind == "karnopp":
            out["static_n"] = fc * _u(rng, 2.0, 4.0)
        else:
            out["presliding_um"] = _u(rng, 1.0, 5.0)
        return out
    if label == "compliance":
        m = _u(rng, 300.0, 1500.0)
        return {"table_mass_kg": m, "chain_stiffness_n_per_um": _u(rng, 60.0, 200.0),
                "chain_damping_ratio": _u(rng, 0.05, 0.2), "guide_friction_n": _u(rng, 0.02, 0.05) * m * 9.81}  # fmt: skip
    if label == "thermal":
        return {"lead_growth_ppm_per_k": _u(rng, 5.0, 15.0), "bearing_mm": _u(rng, 100.0, 400.0),
                "bearing_shift_mm_per_k": _pm(rng, 2.0, 10.0), "backlash_pct_per_k": _pm(rng, 0.5, 2.0)}  # fmt: skip
    if label == "backlash_profile":
        bumps = []
        for _ in range(int(rng.integers(2, 5))):
            shape = "gauss" if rng.random() < 0.5 else "cosine"
            width = _u(rng, 25.0, 100.0) if shape == "gauss" else _u(rng, 40.0, 150.0)
            bumps.append({"shape": shape, "centre_mm": _u(rng, 60.0, 740.0), "width_mm": width,
                          "amplitude": _u(rng, 0.2, 0.6)})  # fmt: skip
        return {"bumps": bumps}
    if label == "cyclic_error":
        out = {"period_mm": k_a * _u(rng, 1.3, 3.7), "amplitude_um": _u(rng, 2.0, 6.0),
               "phase_rad": _u(rng, 0.0, 2 * np.pi), "lead_amplitude_um": 0.0, "lead_phase_rad": 0.0}  # fmt: skip
        if rng.random() < 0.5:
            out["lead_amplitude_um"] = _u(rng, 0.5, 1.5)
            out["lead_phase_rad"] = _u(rng, 0.0, 2 * np.pi)
        return out
    if label == "sampling_skew":
        tau = _pm(rng, 1e-3, 5e-3)
        jitter = _u(rng, 0.05, 0.15) if rng.random() < 0.5 else 0.0
        return {"table_delay_s": tau, "drift_fraction": _u(rng, -0.5, 0.5), "jitter_fraction": jitter}
    raise ValueError(f"label (={label!r}) must be one of {EFFECTS}")


def drive_params(nominal: dict, effects: dict) -> DriveParams:
    """The axis's dynamics from its nominal draw and the effects it carries."""
    kw: dict = {"gain_per_s": nominal["position_gain_per_s"]}
    if "servo_dynamics" in effects:
        s = effects["servo_dynamics"]
        kw.update(gain_per_s=nominal["position_gain_per_s"] * s["gain_ratio"], ff_fraction=s["ff_fraction"],
                  vloop_bandwidth_hz=s["vloop_bandwidth_hz"], vloop_damping=s["vloop_damping"],
                  feedback_delay_s=s["feedback_delay_s"])  # fmt: skip
    chain = effects.get("compliance") or effects.get("friction")
    if chain is not None:
        m = chain["table_mass_kg"]
        k = chain["chain_stiffness_n_per_um"]
        if "compliance" in effects:  # the compliance draw names the chain when both act
            k, m = effects["compliance"]["chain_stiffness_n_per_um"], effects["compliance"]["table_mass_kg"]
        omega = np.sqrt(k * 1e6 / m)
        zeta = max(chain["chain_damping_ratio"], kw["gain_per_s"] / omega)
        kw.update(table_mass_kg=m, chain_stiffness_n_per_um=k, chain_damping_ratio=zeta)
        if "compliance" in effects:
            kw["guide_friction_n"] = effects["compliance"]["guide_friction_n"]
        if "friction" in effects:
            f = effects["friction"]
            kw.update(friction=f["form"], coulomb_n=f["coulomb_n"], static_n=f.get("static_n", 0.0),
                      presliding_um=f.get("presliding_um", 2.0))  # fmt: skip
    return DriveParams(**kw)


def _grid(step_mm: float) -> np.ndarray:
    return np.arange(GRID_MM[0], GRID_MM[1] + step_mm, step_mm)


def nut_error_lut(nominal: dict, effects: dict, temperature_c: float) -> Lut:
    """``e(u)`` in mm on a grid of the motor travel ``u``: thermal growth and cyclic error."""
    th, cy = effects.get("thermal"), effects.get("cyclic_error")
    if th is None and cy is None:
        return Lut(GRID_MM[0], GRID_MM[1] - GRID_MM[0], np.zeros(2))
    step = 0.005 if cy is not None else 1.0
    u = _grid(step)
    e = np.zeros_like(u)
    if th is not None:
        dt = temperature_c - T_REF_C
        centre = th["bearing_mm"] + th["bearing_shift_mm_per_k"] * dt
        e += th["lead_growth_ppm_per_k"] * 1e-6 * dt * (u - centre)
    if cy is not None:
        e += cy["amplitude_um"] * 1e-3 * np.sin(2 * np.pi * u / cy["period_mm"] + cy["phase_rad"])
        e += cy["lead_amplitude_um"] * 1e-3 * np.sin(2 * np.pi * u / nominal["screw_lead_mm"] + cy["lead_phase_rad"])
    return Lut(GRID_MM[0], step, e)


def backlash_lut(nominal: dict, effects: dict, temperature_c: float) -> Lut:
    """``b(x)`` in mm on a grid of the table position ``x``: wear bumps and thermal change."""
    b0 = nominal["backlash_um"] * 1e-3
    scale = 1.0
    th = effects.get("thermal")
    if th is not None:
        scale = max(0.3, 1.0 + th["backlash_pct_per_k"] * 1e-2 * (temperature_c - T_REF_C))
    bp = effects.get("backlash_profile")
    if bp is None:
        return Lut(GRID_MM[0], GRID_MM[1] - GRID_MM[0], np.full(2, b0 * scale))
    x = _grid(0.5)
    rel = np.ones_like(x)
    for bump in bp["bumps"]:
        d = (x - bump["centre_mm"]) / bump["width_mm"]
        if bump["shape"] == "gauss":
            rel += bump["amplitude"] * np.exp(-0.5 * d**2)
        else:
            rel += bump["amplitude"] * np.where(np.abs(d) < 1.0, 0.5 * (1.0 + np.cos(np.pi * d)), 0.0)
    return Lut(GRID_MM[0], 0.5, b0 * scale * rel)


def skew_s(skew: dict | None, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The table encoder's latch delay at each sample time ``t_s`` (from the run's start)."""
    if skew is None:
        return np.zeros_like(t_s)
    tau = skew["table_delay_s"]
    ramp = 2.0 * t_s / max(float(t_s[-1]), 1e-9) - 1.0
    out = tau * (1.0 + skew["drift_fraction"] * ramp)
    if skew["jitter_fraction"] > 0:
        out = out + abs(tau) * skew["jitter_fraction"] * rng.standard_normal(t_s.shape)
    return out

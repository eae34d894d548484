"""Real-machine effects the simulator adds to the paper's nominal model, one dataclass each.

Every effect is off unless given; each takes physical parameters with the unit in
the name, validated on construction; any combination may be switched on at once.
The category names (the :class:`Effects` field names) are the effect categories of
the dataset spec, so the gap diagnosis and the simulator speak of the same things.

"Realistic range" in each docstring is the range the stability test covers: within
it, no combination of effects blows up or settles into a limit cycle. Values outside
it but physically valid (e.g. a 5000 kg table) are accepted and simulated, untested.

:func:`parse_effect` turns the CLI spelling ``"friction:coulomb_n=300,static_n=400"``
into ``("friction", Friction(coulomb_n=300.0, static_n=400.0))``.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, fields, replace

import numpy as np

from core.errors import InputError

FRICTION_MODELS = ("stribeck", "lugre")


def _finite(owner: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{owner}.{name} (={value!r}) must be a finite number")
    return float(value)


def _nonneg(owner: str, name: str, value: float) -> float:
    v = _finite(owner, name, value)
    if v < 0:
        raise InputError(f"{owner}.{name} (={value!r}) must be >= 0")
    return v


def _positive(owner: str, name: str, value: float) -> float:
    v = _finite(owner, name, value)
    if not v > 0:
        raise InputError(f"{owner}.{name} (={value!r}) must be > 0")
    return v


def _floats(owner: str, name: str, values) -> tuple[float, ...]:
    try:
        items = tuple(values)
    except TypeError:
        items = (values,)
    return tuple(_finite(owner, name, v) for v in items)


@dataclass(frozen=True)
class Friction:
    """Friction of the table on its guides (and of the nut), acting on the table mass.

    The table is driven through a compliant chain: the stiffness and mass come from
    :class:`Compliance` when that effect is on, else from its defaults (200 N/µm,
    500 kg, damping ratio 0.2).

    model:
      ``"stribeck"``: static/Coulomb/Stribeck/viscous curve
      F(v) = coulomb_n + (static_n - coulomb_n) exp(-(v/stribeck_velocity_mm_s)^2)
      + viscous_n_s_per_mm v, with a stick-slip switch: at rest the table sticks while
      the chain force is within static_n (Karnopp's model, solved as a velocity-level
      complementarity each step, so sticking needs no small-velocity window).
      ``stick_band_mm_s`` > 0 adds Karnopp's zero-velocity band to it: a table slower
      than that counts as at rest (the round-trip chain form's law, which the gap
      diagnosis carries to contours); 0, the default, leaves the switch as it is.
      ``"lugre"``: the LuGre bristle model with the same steady-state curve, adding
      pre-sliding (elastic micro-motion, bristle_stiffness_n_per_um) and frictional lag.

    direction_asymmetry (-1..1, either model): friction that differs by direction, the
    friction levels (Coulomb, static and the Stribeck curve, not the viscous part) times
    1 + direction_asymmetry while the table moves (or the chain pushes it) in + and
    1 - direction_asymmetry in -; coulomb_n is the mean of the two directions' levels.
    A wiper or a seal that drags one way, a table on an incline, a guide preloaded on
    one side.

    Realistic ranges: coulomb_n 100..3000 N and at least 2 % of the table weight (less
    lets a heavy table bounce across the backlash in a limit cycle, see Compliance);
    static_n coulomb_n..1.3 coulomb_n; stribeck_velocity_mm_s 0.1..20;
    viscous_n_s_per_mm 0..10; bristle_stiffness_n_per_um 20..500;
    bristle_damping_ratio 0.1..1; direction_asymmetry -0.3..0.3.
    With the stick-slip model and static_n > coulomb_n, a proportional loop closed on
    the table "hunts" by at most 2 (static_n - coulomb_n) / stiffness around a target,
    slowly (the nut must cross the backlash at the creep speed K e): a real effect of
    full-closed loops, bounded by that amount.
    """

    coulomb_n: float = 0.0
    static_n: float | None = None  # None: equal to coulomb_n
    stribeck_velocity_mm_s: float = 1.0
    viscous_n_s_per_mm: float = 0.0
    model: str = "stribeck"
    bristle_stiffness_n_per_um: float = 100.0
    bristle_damping_ratio: float = 0.5
    stick_band_mm_s: float = 0.0
    direction_asymmetry: float = 0.0

    def __post_init__(self) -> None:
        o = "friction"
        a = _finite(o, "direction_asymmetry", self.direction_asymmetry)
        if not -1.0 < a < 1.0:
            raise InputError(f"friction.direction_asymmetry (={self.direction_asymmetry}) must be within (-1, 1): "
                             "the levels are times 1 + a one way and 1 - a the other")  # fmt: skip
        object.__setattr__(self, "direction_asymmetry", a)
        object.__setattr__(self, "stick_band_mm_s", _nonneg(o, "stick_band_mm_s", self.stick_band_mm_s))
        object.__setattr__(self, "coulomb_n", _nonneg(o, "coulomb_n", self.coulomb_n))
        static = self.coulomb_n if self.static_n is None else _nonneg(o, "static_n", self.static_n)
        if static < self.coulomb_n:
            raise InputError(f"friction.static_n (={static}) must be >= coulomb_n (={self.coulomb_n})")
        object.__setattr__(self, "static_n", static)
        object.__setattr__(
            self, "stribeck_velocity_mm_s", _positive(o, "stribeck_velocity_mm_s", self.stribeck_velocity_mm_s)
        )
        object.__setattr__(self, "viscous_n_s_per_mm", _nonneg(o, "viscous_n_s_per_mm", self.viscous_n_s_per_mm))
        if self.model not in FRICTION_MODELS:
            raise InputError(f"friction.model (={self.model!r}) must be one of {FRICTION_MODELS}")
        if self.model != "stribeck" and self.stick_band_mm_s > 0:
            raise InputError(f"friction.stick_band_mm_s (={self.stick_band_mm_s}) is for the 'stribeck' model only "
                             f"(LuGre's bristles stick without a band)")  # fmt: skip
        object.__setattr__(
            self,
            "bristle_stiffness_n_per_um",
            _positive(o, "bristle_stiffness_n_per_um", self.bristle_stiffness_n_per_um),
        )
        object.__setattr__(
            self, "bristle_damping_ratio", _nonneg(o, "bristle_damping_ratio", self.bristle_damping_ratio)
        )


@dataclass(frozen=True)
class Compliance:
    """Finite axial stiffness of the chain (screw, nut, bearings) and the table mass.

    The nut drives the table through a spring (stiffness_n_per_um) with viscous
    damping (damping_ratio of critical, in contact only) once the backlash is closed.
    guide_damping_n_s_per_mm is viscous damping of the guides, always acting on the
    table. When the friction effect is off, the guides still hold the table with
    Coulomb friction guide_friction_n (None: max(100 N, 2 % of the table weight)); a
    frictionless table would float across the backlash when braking and, with the
    loop closed on it, bounce between the flanks for ever. When friction is on, its
    parameters replace guide_friction_n.

    Realistic ranges: stiffness_n_per_um 100..1000; table_mass_kg 100..1500;
    damping_ratio 0.2..0.5; guide_damping_n_s_per_mm 0..10; guide_friction_n at least
    max(100 N, 2 % of the table weight). Below that damping or friction, or with the
    resonance sqrt(k/m) near K / damping_ratio, a full-closed loop limit-cycles or goes
    unstable on a real machine too, and so it does here.
    """

    stiffness_n_per_um: float = 200.0
    table_mass_kg: float = 500.0
    damping_ratio: float = 0.2
    guide_damping_n_s_per_mm: float = 1.0
    guide_friction_n: float | None = None

    def __post_init__(self) -> None:
        o = "compliance"
        object.__setattr__(self, "stiffness_n_per_um", _positive(o, "stiffness_n_per_um", self.stiffness_n_per_um))
        object.__setattr__(self, "table_mass_kg", _positive(o, "table_mass_kg", self.table_mass_kg))
        object.__setattr__(self, "damping_ratio", _nonneg(o, "damping_ratio", self.damping_ratio))
        object.__setattr__(
            self, "guide_damping_n_s_per_mm", _nonneg(o, "guide_damping_n_s_per_mm", self.guide_damping_n_s_per_mm)
        )
        gf = self.guide_friction_n
        gf = max(100.0, 0.02 * 9.81 * self.table_mass_kg) if gf is None else _nonneg(o, "guide_friction_n", gf)
        object.__setattr__(self, "guide_friction_n", gf)


@dataclass(frozen=True)
class Thermal:
    """Temperature-dependent lead (screw expansion as the table sees it) and backlash.

    At temperature T the nut travels, per nominal millimetre, 1 + (lead_error_um_per_m
    + lead_growth_ppm_per_k (T - reference_c)) 1e-6 millimetres, measured from the fixed
    bearing end at fixed_end_mm (table coordinates); i.e. the ISO mean travel deviation
    e_p is lead_error_um_per_m at the reference and grows by lead_growth_ppm_per_k per
    kelvin. The backlash width changes by backlash_um_per_k per kelvin.

    Realistic ranges: lead_error_um_per_m -100..100; lead_growth_ppm_per_k -15..15 (a
    free steel screw: 11.5; preloaded or cooled screws much less; the seed paper's
    machine about 1.3); backlash_um_per_k -5..5 (the paper's machine about 3);
    temperature 0..40 °C.

    A warm-up during the run: the table side warms and the linear scale's mounting grows,
    so the scale reads warmup_um_per_m (1 - exp(-t / warmup_tau_s)) 1e-6 (x -
    fixed_end_mm) beyond the table at position x, t the program time (s). An error of the
    reading alone (the loop and the chain follow the true table). Realistic ranges:
    warmup_um_per_m -60..60 (10 ppm/K over 1-5 K); warmup_tau_s 5..3600.
    """

    lead_error_um_per_m: float = 0.0
    lead_growth_ppm_per_k: float = 0.0
    backlash_um_per_k: float = 0.0
    fixed_end_mm: float = 0.0
    reference_c: float = 20.0
    warmup_um_per_m: float = 0.0
    warmup_tau_s: float = 60.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _finite("thermal", f.name, getattr(self, f.name)))
        object.__setattr__(self, "warmup_tau_s", _positive("thermal", "warmup_tau_s", self.warmup_tau_s))

    def warmup_error_mm(self, t_s, x_mm) -> np.ndarray:
        """The scale's reading beyond the table at program time ``t_s`` (s) and table
        position ``x_mm`` (mm), in mm."""
        t = np.maximum(np.asarray(t_s, dtype=float), 0.0)
        growth = self.warmup_um_per_m * 1e-6 * -np.expm1(-t / self.warmup_tau_s)
        return growth * (np.asarray(x_mm, dtype=float) - self.fixed_end_mm)

    def lead_scale(self, temperature_c: float) -> float:
        """Nut travel per nominal travel at ``temperature_c`` (1 = nominal)."""
        dt = temperature_c - self.reference_c
        return 1.0 + (self.lead_error_um_per_m + self.lead_growth_ppm_per_k * dt) * 1e-6

    def backlash_shift_um(self, temperature_c: float) -> float:
        return self.backlash_um_per_k * (temperature_c - self.reference_c)


@dataclass(frozen=True)
class BacklashProfile:
    """Backlash width as a function of position: widths_um at positions_mm, interpolated.

    Replaces the axis' constant backlash_um (the thermal shift still adds). Positions
    are table coordinates (mm, strictly increasing); outside them the end widths hold.
    Realistic range: widths 0..500 µm, varying by up to ~50 % along the travel.
    """

    positions_mm: tuple[float, ...] = (0.0,)
    widths_um: tuple[float, ...] = (0.0,)

    def __post_init__(self) -> None:
        o = "backlash_profile"
        pos = _floats(o, "positions_mm", self.positions_mm)
        wid = _floats(o, "widths_um", self.widths_um)
        if len(pos) == 0 or len(pos) != len(wid):
            raise InputError(
                f"backlash_profile: positions_mm ({len(pos)} values) and widths_um ({len(wid)} values) "
                "must be non-empty and of equal length"
            )
        if any(b <= a for a, b in zip(pos, pos[1:])):
            raise InputError(f"backlash_profile.positions_mm (={list(pos)}) must be strictly increasing")
        if any(w < 0 for w in wid):
            raise InputError(f"backlash_profile.widths_um (={list(wid)}) must all be >= 0")
        object.__setattr__(self, "positions_mm", pos)
        object.__setattr__(self, "widths_um", wid)


@dataclass(frozen=True)
class CyclicError:
    """Periodic transmission error: the nut leads the nominal travel u by

    sum_i amplitudes_um[i] sin(2 pi u / periods_mm[i] + phases_deg[i]).

    Usual periods: the screw lead (16 mm), the motor revolution (k_a = 6.857 mm), the
    gear stages (k_a times their ratios to the motor). Realistic ranges: period
    0.5..50 mm, amplitude 0..10 µm.
    ``CyclicError.of((16, 2.0, 0), (6.857, 1.0, 90))`` builds one from triples.

    ``on="scale"``: the linear scale's interpolation error instead, an error of the
    reading alone: the recorded table is x + sum_i a_i sin(2 pi x / p_i + phi_i) at the
    true table position x, while the loop and the nut follow the true one (the encoders'
    rule, :class:`Encoders`). Its periods are the scale's signal period (20-40 µm on
    incremental scales) and its harmonics, amplitudes 0.5..5 µm; a reading's error has
    no slope limit (the nut's does).
    """

    periods_mm: tuple[float, ...] = ()
    amplitudes_um: tuple[float, ...] = ()
    phases_deg: tuple[float, ...] | None = None  # None: all zero
    on: str = "nut"  # "nut": a transmission error; "scale": the linear scale's reading

    def __post_init__(self) -> None:
        o = "cyclic_error"
        per = _floats(o, "periods_mm", self.periods_mm)
        amp = _floats(o, "amplitudes_um", self.amplitudes_um)
        pha = (0.0,) * len(per) if self.phases_deg is None else _floats(o, "phases_deg", self.phases_deg)
        if not (len(per) == len(amp) == len(pha)):
            raise InputError(
                f"cyclic_error: periods_mm ({len(per)}), amplitudes_um ({len(amp)}) and phases_deg "
                f"({len(pha)}) need one value per component"
            )
        if any(p <= 0 for p in per):
            raise InputError(f"cyclic_error.periods_mm (={list(per)}) must all be > 0")
        if self.on not in ("nut", "scale"):
            raise InputError(f"cyclic_error.on (={self.on!r}) must be 'nut' or 'scale'")
        slope = sum(abs(a) * 1e-3 * 2 * math.pi / p for a, p in zip(amp, per))
        if self.on == "nut" and slope >= 0.5:
            raise InputError(
                f"cyclic_error: amplitudes_um (={list(amp)}) are too large for periods_mm (={list(per)}): "
                f"the nut would nearly stop or run backwards (slope {slope:.2f}, must be < 0.5)"
            )
        object.__setattr__(self, "periods_mm", per)
        object.__setattr__(self, "amplitudes_um", amp)
        object.__setattr__(self, "phases_deg", pha)

    @classmethod
    def of(cls, *components: tuple[float, float, float], on: str = "nut") -> CyclicError:
        """From (period_mm, amplitude_um, phase_deg) triples."""
        if not components:
            return cls(on=on)
        per, amp, pha = zip(*components)
        return cls(periods_mm=per, amplitudes_um=amp, phases_deg=pha, on=on)

    def scale_error_mm(self, x_mm: np.ndarray) -> np.ndarray:
        """The reading's error (mm) at true table positions ``x_mm`` (``on="scale"``; else 0)."""
        x = np.asarray(x_mm, dtype=float)
        out = np.zeros_like(x)
        if self.on == "scale":
            for p, a, f in zip(self.periods_mm, self.amplitudes_um, self.phases_deg):
                out = out + a * 1e-3 * np.sin(2 * np.pi * x / p + math.radians(f))
        return out


@dataclass(frozen=True)
class ServoDynamics:
    """Non-ideal loops: the motor velocity command K e(t - dead_time_s) + feedforward *
    command velocity(t - dead_time_s), with e = command - table measured
    feedback_delay_s late, followed through a first-order lag (velocity_lag_s). Set per
    axis; unequal axes tilt a circle into a 45° ellipse. An effective position gain
    other than the configured K is the axis model's ``position_gain_per_s``.

    Realistic ranges: velocity_lag_s 0..0.01 (velocity-loop bandwidth >= 16 Hz);
    dead_time_s and feedback_delay_s 0..0.003; feedforward 0..1 (modern CNCs run
    0.5-1). With K <= 30 1/s the product K (velocity_lag_s + dead times) stays below
    0.4 there, so the position loop keeps a well-damped response. Every parameter
    acts continuously (no value is rounded to zero).

    ``integral_per_s`` (K_i, 1/s): a PI position loop, v = K (e + K_i ∫e dt) + ...;
    with an ideal velocity loop its characteristic polynomial s² + K s + K K_i has the
    damping ratio 0.5 sqrt(K / K_i), so K_i <= K keeps it at 0.5 or more (0: a P loop).
    ``accel_limit_mm_s2`` (a_max): a drive that saturates, the motor's acceleration (as
    table travel) held within ±a_max, the position integral frozen while limited and
    pushing further (anti-windup); 0: no limit. A force limit F_max on a mass m is
    a_max = F_max / m less the friction and viscous force at that speed.
    """

    velocity_lag_s: float = 0.002
    dead_time_s: float = 0.0
    feedforward: float = 0.0
    feedback_delay_s: float = 0.0
    integral_per_s: float = 0.0
    accel_limit_mm_s2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("velocity_lag_s", "dead_time_s", "feedback_delay_s", "integral_per_s", "accel_limit_mm_s2"):
            object.__setattr__(self, name, _nonneg("servo_dynamics", name, getattr(self, name)))
        ff = _finite("servo_dynamics", "feedforward", self.feedforward)
        if not 0.0 <= ff <= 1.5:
            raise InputError(f"servo_dynamics: feedforward (={ff!r}) must be within 0..1.5")
        object.__setattr__(self, "feedforward", ff)


@dataclass(frozen=True)
class SamplingSkew:
    """The table (linear) encoder is latched table_delay_s after the motor encoder of the
    same row (negative: before). Realistic range: -0.005..0.005 s (one to a few
    controller cycles). It shows as an apparent backlash change of 2 v table_delay_s.
    """

    table_delay_s: float = 0.001

    def __post_init__(self) -> None:
        object.__setattr__(self, "table_delay_s", _finite("sampling_skew", "table_delay_s", self.table_delay_s))


@dataclass(frozen=True)
class Encoders:
    """Encoder resolution and white noise of the recorded signals (0 = ideal).

    motor_counts_per_rev: counts per motor revolution (typical 2**16..2**23);
    table_resolution_um: linear scale resolution (typical 0.001..1 µm);
    motor_noise_um, table_noise_um: white noise standard deviation, the motor one
    expressed as table travel (µm); typical 0..0.5 µm.
    These act on the recorded samples; the position loop sees the true table position.
    """

    motor_counts_per_rev: float = 0.0
    table_resolution_um: float = 0.0
    motor_noise_um: float = 0.0
    table_noise_um: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _nonneg("encoders", f.name, getattr(self, f.name)))


@dataclass(frozen=True)
class Effects:
    """The real-machine effects switched on for one axis; ``None`` = off (nominal)."""

    friction: Friction | None = None
    compliance: Compliance | None = None
    thermal: Thermal | None = None
    backlash_profile: BacklashProfile | None = None
    cyclic_error: CyclicError | None = None
    servo_dynamics: ServoDynamics | None = None
    sampling_skew: SamplingSkew | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if v is not None and not isinstance(v, EFFECT_TYPES[f.name]):
                raise InputError(f"effects.{f.name} must be a {EFFECT_TYPES[f.name].__name__} or None, got {v!r}")

    def with_effect(self, category: str, value) -> Effects:
        """A copy with ``category`` set to ``value`` (None switches it off)."""
        if category not in EFFECT_TYPES:
            raise InputError(f"unknown effect category {category!r}; valid: {', '.join(EFFECT_TYPES)}")
        return replace(self, **{category: value})

    @property
    def active(self) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self) if getattr(self, f.name) is not None)

    @property
    def is_nominal(self) -> bool:
        return not self.active


EFFECT_TYPES: dict[str, type] = {
    "friction": Friction,
    "compliance": Compliance,
    "thermal": Thermal,
    "backlash_profile": BacklashProfile,
    "cyclic_error": CyclicError,
    "servo_dynamics": ServoDynamics,
    "sampling_skew": SamplingSkew,
}
CATEGORIES = tuple(EFFECT_TYPES)


# The documented realistic ranges (see each class), as (low, high) per parameter; the
# stability test draws from them. Coupled limits: friction coulomb_n (and the guide
# friction) >= max(100 N, 2 % of the table weight); static_n <= 1.3 coulomb_n.
REALISTIC_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "friction": {
        "coulomb_n": (100.0, 3000.0),
        "stribeck_velocity_mm_s": (0.1, 20.0),
        "viscous_n_s_per_mm": (0.0, 10.0),
        "bristle_stiffness_n_per_um": (20.0, 500.0),
        "bristle_damping_ratio": (0.1, 1.0),
    },
    "compliance": {
        "stiffness_n_per_um": (100.0, 1000.0),
        "table_mass_kg": (100.0, 1500.0),
        "damping_ratio": (0.2, 0.5),
        "guide_damping_n_s_per_mm": (0.0, 10.0),
    },
    "thermal": {
        "lead_error_um_per_m": (-100.0, 100.0),
        "lead_growth_ppm_per_k": (-15.0, 15.0),
        "backlash_um_per_k": (-5.0, 5.0),
    },
    "backlash_profile": {"widths_um": (0.0, 500.0)},
    "cyclic_error": {"periods_mm": (0.5, 50.0), "amplitudes_um": (0.0, 10.0)},
    "servo_dynamics": {"velocity_lag_s": (0.0, 0.01), "dead_time_s": (0.0, 0.002)},
    "sampling_skew": {"table_delay_s": (-0.005, 0.005)},
}


def _convert(cls: type, name: str, text: str):
    hint = typing.get_type_hints(cls)[name]
    origin_args = typing.get_args(hint)
    if hint is str:
        return text.strip()
    if hint == tuple[float, ...] or tuple[float, ...] in origin_args:
        parts = [p for p in text.replace("/", ";").split(";") if p.strip()]
        try:
            return tuple(float(p) for p in parts)
        except ValueError:
            raise InputError(f"{name} (={text!r}) must be numbers separated by ';' or '/'") from None
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{name} (={text!r}) must be a number") from None


def parse_effect(text: str) -> tuple[str, object]:
    """Parse ``"category:key=value,key=value"`` into ``(category, effect dataclass)``.

    Keys are the dataclass field names; list values (positions_mm, periods_mm, ...) are
    separated by ``;`` or ``/``. A bare ``"category"`` uses the defaults. Unknown
    categories or keys raise :class:`InputError` listing the valid ones.
    """
    category, _, rest = text.strip().partition(":")
    category = category.strip()
    if category not in EFFECT_TYPES:
        raise InputError(f"unknown effect category {category!r} in {text!r}; valid: {', '.join(CATEGORIES)}")
    cls = EFFECT_TYPES[category]
    valid = [f.name for f in fields(cls)]
    kwargs = {}
    for item in (p for p in rest.split(",") if p.strip()):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq:
            raise InputError(f"effect {category!r}: {item!r} is not key=value")
        if key not in valid:
            raise InputError(f"effect {category!r} has no parameter {key!r}; valid: {', '.join(valid)}")
        kwargs[key] = _convert(cls, key, value)
    return category, cls(**kwargs)


def effect_params(effect) -> dict:
    """The fields of an effect dataclass as a plain dict (for JSON summaries)."""
    return {f.name: getattr(effect, f.name) for f in fields(effect)}


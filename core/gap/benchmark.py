"""Generated datasets whose effect is withheld, and the benchmark that scores the diagnosis.

:func:`make_case` draws a two-axis machine, one effect (or none) with random parameters
over realistic ranges, and simulates round trips and circles with ``core.sim``; test
runs lie outside the train conditions (other temperatures, feeds, accelerations,
radii and positions on the travel). Part of the data follows effect forms the
candidates do not fit: LuGre friction (the candidate is Coulomb+Stribeck lost motion),
an asymmetric non-Gaussian wear profile (the candidate is 5 linear knots), cyclic error
with an unknown gear period besides a lead/k_a one, servo dynamics with dead time and
lag together, compliance with guide damping and contact damping, thermal lead growth
about a fixed bearing end together with a backlash change.
:func:`run_benchmark` diagnoses each case without its label and scores it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from core.dataset import Dataset, MachineSpec
from core.sim import (
    AxisModel,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Encoders,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    circle,
    round_trip,
    simulate,
)

LABELS = ("none", "thermal", "backlash_profile", "cyclic_error", "friction", "compliance", "servo_dynamics",
          "sampling_skew")  # fmt: skip
TRAVEL_MM = (0.0, 800.0)


@dataclass(frozen=True)
class CaseSize:
    """How big a generated dataset is: round trips per axis (train, test), circles
    (train, test), sample rates and the round trips' target duration."""

    rt_train_per_axis: int = 3
    rt_test_per_axis: int = 1
    circles_train: int = 4
    circles_test: int = 2
    rt_rate_hz: float = 1000.0
    circle_rate_hz: float = 500.0
    rt_duration_s: float = 30.0
    circle_sweep_deg: float = 360.0


SMALL = CaseSize(2, 1, 2, 1, 250.0, 200.0, 14.0, 360.0)


@dataclass(frozen=True)
class Case:
    label: str
    axis: str  # a randomly named axis ("" for none); both axes carry the effect
    truth: dict
    dataset: Dataset = field(repr=False)


def _u(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def _sgn(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


def draw_effect(label: str, rng: np.random.Generator, axis_model: AxisModel) -> tuple[Effects, dict]:
    """One effect with random parameters in the realistic ranges of core.sim (the upper
    part of them where the effect would otherwise vanish in the noise)."""
    ka, lead = axis_model.transmission_mm_per_rev, axis_model.screw_lead_mm
    b = axis_model.backlash_um
    if label == "thermal":
        th = Thermal(lead_error_um_per_m=_u(rng, -30, 30), lead_growth_ppm_per_k=_sgn(rng) * _u(rng, 3, 12),
                     backlash_um_per_k=_sgn(rng) * _u(rng, 1.0, 4.0), fixed_end_mm=TRAVEL_MM[0])  # fmt: skip
        return Effects(thermal=th), {"thermal": th.__dict__}
    if label == "backlash_profile":
        pos = np.linspace(*TRAVEL_MM, 17)
        x = (pos - TRAVEL_MM[0]) / (TRAVEL_MM[1] - TRAVEL_MM[0])
        c = _u(rng, 0.25, 0.75)
        wl, wr = _u(rng, 0.08, 0.25), _u(rng, 0.15, 0.45)  # asymmetric wear bump, flat top
        bump = np.where(x < c, np.clip((x - c + 2 * wl) / wl, 0, 1), np.clip((c + 2 * wr - x) / wr, 0, 1))
        ramp = _sgn(rng) * _u(rng, 0.0, 0.2) * x
        widths = b * (1.0 + _u(rng, 0.3, 0.6) * bump + ramp)
        prof = BacklashProfile(tuple(pos), tuple(np.maximum(widths, 1.0)))
        return Effects(backlash_profile=prof), {"widths_um": [round(w, 1) for w in prof.widths_um]}
    if label == "cyclic_error":
        known = float(rng.choice([lead, ka, lead / 2]))
        gear = ka * _u(rng, 1.6, 3.4)  # a gear stage: not given in the dataset
        ce = CyclicError.of((known, _u(rng, 2.0, 6.0), _u(rng, 0, 360)), (gear, _u(rng, 1.5, 5.0), _u(rng, 0, 360)))
        return Effects(cyclic_error=ce), {"periods_mm": ce.periods_mm, "amplitudes_um": ce.amplitudes_um}
    if label == "friction":
        fc = _u(rng, 1500, 3000)
        fs = fc * _u(rng, 1.15, 1.3)
        model = "lugre" if rng.random() < 0.5 else "stribeck"
        fr = Friction(coulomb_n=fc, static_n=fs, stribeck_velocity_mm_s=_u(rng, 0.5, 10), viscous_n_s_per_mm=_u(rng, 5, 10),
                      model=model, bristle_stiffness_n_per_um=_u(rng, 50, 300))  # fmt: skip
        return Effects(friction=fr), {"coulomb_n": fc, "static_n": fs, "model": model}
    if label == "compliance":
        comp = Compliance(stiffness_n_per_um=_u(rng, 100, 180), table_mass_kg=_u(rng, 1000, 1500),
                          damping_ratio=_u(rng, 0.2, 0.5), guide_damping_n_s_per_mm=_u(rng, 2, 10))  # fmt: skip
        return Effects(compliance=comp), {"compliance": dict(comp.__dict__)}
    if label == "servo_dynamics":
        dead = _u(rng, 0.0008, 0.002)
        lag = _u(rng, 0.004, 0.01)
        sd = ServoDynamics(velocity_lag_s=lag, dead_time_s=dead)
        return Effects(servo_dynamics=sd), {"velocity_lag_s": lag, "dead_time_s": dead}
    if label == "sampling_skew":
        tau = _sgn(rng) * _u(rng, 0.001, 0.005)
        return Effects(sampling_skew=SamplingSkew(tau)), {"table_delay_s": tau}
    return Effects(), {}


def make_case(label: str, rng: np.random.Generator, size: CaseSize = CaseSize()) -> Case:
    """A dataset with ``label`` (one of LABELS) injected on one random axis."""
    if label not in LABELS:
        raise ValueError(f"label (={label!r}) must be one of {LABELS}")
    axes = {}
    for name in ("x", "y"):
        lead = float(rng.choice([10.0, 16.0, 20.0]))
        axes[name] = AxisModel(
            name=name, transmission_mm_per_rev=lead * _u(rng, 0.35, 0.9), screw_lead_mm=lead,
            position_gain_per_s=_u(rng, 8, 25), backlash_um=_u(rng, 15, 150),
            encoders=Encoders(table_noise_um=_u(rng, 0.1, 0.5), motor_noise_um=_u(rng, 0.1, 0.5)),
        )  # fmt: skip
    # A machine's effect acts on every axis (with its own parameters; a skew is one
    # acquisition delay): the "axis" of a case is the one with the larger effect draw.
    eff_axis = ""
    truth: dict = {}
    if label != "none":
        skew = None
        for name in ("x", "y"):
            fx, tr = draw_effect(label, rng, axes[name])
            if label == "sampling_skew":
                skew = skew or fx
                fx, tr = skew, {"table_delay_s": skew.sampling_skew.table_delay_s}
            truth[name] = tr
            am = axes[name]
            axes[name] = AxisModel(am.name, am.transmission_mm_per_rev, am.screw_lead_mm, am.position_gain_per_s,
                                   am.backlash_um, effects=fx, encoders=am.encoders)  # fmt: skip
        eff_axis = str(rng.choice(["x", "y"]))
    machine = MachineSpec(id=f"bench-{label}", axes={a: m.to_axis_spec(TRAVEL_MM) for a, m in axes.items()})
    runs = []
    k = 0
    for name in ("x", "y"):
        n_tr, n_te = size.rt_train_per_axis, size.rt_test_per_axis
        # train temperatures shuffled against the train feeds, so that a feed effect and a
        # temperature effect are not collinear in the train runs
        temps_train = rng.permutation(np.linspace(17.0, 24.0, n_tr) + rng.uniform(-0.5, 0.5, n_tr))
        for i in range(n_tr + n_te):
            test = i >= n_tr
            if test:
                # always another temperature; another feed and/or another acceleration
                # (at least one of them), as test runs on a real machine differ
                temp = _u(rng, 8, 12) if rng.random() < 0.5 else _u(rng, 28, 32)
                other = ("feed", "acc", "both")[int(rng.integers(3))]
                feed = _u(rng, 700, 1500)
                if other in ("feed", "both"):
                    feed = _u(rng, 2200, 3000) if rng.random() < 0.5 else _u(rng, 300, 450)
                acc = _u(rng, 1300, 2000) if other in ("acc", "both") else _u(rng, 300, 1000)
            else:
                feed = float(np.geomspace(600, 1600, n_tr)[i])
                temp = float(temps_train[i])
                acc = _u(rng, 300, 1000)
            v = feed / 60.0
            lo, hi = 40.0, 760.0  # the characterised travel: train strokes tile it, test strokes fall anywhere in it
            length = float(np.clip(v * (size.rt_duration_s - 3.0) / 2.0, 30.0, hi - lo))
            if test:
                start = _u(rng, lo, hi - length)
            else:
                start = lo + (hi - lo - length) * (i / max(n_tr - 1, 1))
            prog = round_trip(start, start + length, feed, acc, 1.0, axis=name)
            tr = simulate({name: axes[name]}, prog, temperature_c=temp, rate_hz=size.rt_rate_hz, rng=rng)
            runs.append(tr.to_run(f"rt_{name}_{k:02d}.csv", split="test" if test else "train"))
            k += 1
    for i in range(size.circles_train + size.circles_test):
        test = i >= size.circles_train
        if test:
            radius = _u(rng, 100, 150) if rng.random() < 0.5 else _u(rng, 15, 25)
            feed = _u(rng, 2000, 3000)
            temp = _u(rng, 8, 12) if rng.random() < 0.5 else _u(rng, 28, 32)
        else:
            radius = _u(rng, 30, 80)
            feed = _u(rng, 500, 1500)
            temp = _u(rng, 17, 24)
        centre = (_u(rng, 200, 600), _u(rng, 200, 600))
        prog = circle(radius, centre, feed, "ccw" if i % 2 == 0 else "cw", -90.0, size.circle_sweep_deg)
        tr = simulate(axes, prog, temperature_c=temp, rate_hz=size.circle_rate_hz, rng=rng)
        runs.append(tr.to_run(f"circle_{i:02d}.csv", split="test" if test else "train"))
    return Case(label, eff_axis, truth, Dataset(machine, tuple(runs)))


def labels_for(n_cases: int, rng: np.random.Generator) -> list[str]:
    """Balanced labels: each block of len(LABELS) cases holds every label once, shuffled."""
    out: list[str] = []
    while len(out) < n_cases:
        out += [LABELS[i] for i in rng.permutation(len(LABELS))]
    return out[:n_cases]


@dataclass(frozen=True)
class CaseResult:
    index: int
    label: str
    diagnosed: str
    gap_before_um: float
    gap_after_um: float
    noise_floor_um: float
    seconds: float
    axis: str

    @property
    def ratio(self) -> float:
        return self.gap_after_um / self.gap_before_um if self.gap_before_um > 0 else float("nan")


@dataclass(frozen=True)
class BenchmarkResult:
    cases: tuple[CaseResult, ...]
    seed: int

    @property
    def fraction_correct(self) -> float:
        return float(np.mean([c.label == c.diagnosed for c in self.cases])) if self.cases else float("nan")

    @property
    def false_effects_on_none(self) -> int:
        return sum(1 for c in self.cases if c.label == "none" and c.diagnosed != "none")

    @property
    def median_ratio_effect_cases(self) -> float:
        r = [c.ratio for c in self.cases if c.label != "none"]
        return float(np.median(r)) if r else float("nan")

    @property
    def median_seconds(self) -> float:
        return float(np.median([c.seconds for c in self.cases])) if self.cases else float("nan")

    def confusion(self) -> dict[str, dict[str, int]]:
        m = {t: {p: 0 for p in LABELS} for t in LABELS}
        for c in self.cases:
            m[c.label][c.diagnosed] += 1
        return m

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "n_cases": len(self.cases),
            "fraction_correct": self.fraction_correct,
            "none_diagnosed_as_effect": self.false_effects_on_none,
            "median_gap_ratio_effect_cases": self.median_ratio_effect_cases,
            "median_seconds_per_case": self.median_seconds,
            "confusion": self.confusion(),
            "cases": [c.__dict__ | {"ratio": c.ratio} for c in self.cases],
        }


def run_benchmark(n_cases: int, seed: int, size: CaseSize = CaseSize(),
                  progress: Callable[[CaseResult], None] | None = None) -> BenchmarkResult:
    """Generate ``n_cases`` datasets (balanced labels) and diagnose each without its label."""
    from core.gap.diagnose import GapSettings, diagnose

    rng = np.random.default_rng(seed)
    labels = labels_for(n_cases, rng)
    out = []
    for i, label in enumerate(labels):
        case = make_case(label, np.random.default_rng([seed, i]), size)
        t0 = time.perf_counter()
        rep = diagnose(case.dataset, GapSettings(keep_curves=False))
        dt = time.perf_counter() - t0
        res = CaseResult(i, label, rep.effect, rep.gap_before_um, rep.gap_after_um, rep.noise_floor_um, dt, case.axis)
        out.append(res)
        if progress is not None:
            progress(res)
    return BenchmarkResult(tuple(out), seed)

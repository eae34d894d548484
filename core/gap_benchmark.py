"""Generated datasets whose effect is withheld, and the benchmark that scores the diagnosis.

Three plants generate the cases: ``twin`` (:func:`make_case`, the project's own twin,
``core.sim``), ``independent`` (:mod:`core.plant_independent`, a feed-drive simulator
written separately, with its own integration scheme and its own forms of each
effect) and ``forms`` (:mod:`core.plant_forms`, written from the dataset format and a
list of forms alone, without reading the diagnosis or either plant: forms neither of
them has, held out for an evaluation of a decision that is no longer tuned). In both, a case draws a two-axis machine (K 8-40 1/s), no effect, one effect,
or (a quarter of the cases) two effects, with random parameters over realistic ranges,
and records round trips and circles; circles carry a feed-in arc and a lead-out of
random length (0-180°), and a third of the datasets have no ``split`` field. Test runs
lie outside the train conditions (other temperatures, feeds, accelerations, radii and
positions on the travel). In the twin, part of the data follows forms the candidates do
not fit exactly: LuGre friction, an asymmetric wear profile, a gear period beside a
lead/k_a one, servo dynamics with feed-forward, an effective gain other than the
configured K and a feedback delay. :func:`run_benchmark` diagnoses each case without
its label and scores it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from core.dataset import AxisSpec, Dataset, MachineSpec
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

from core.sim import CATEGORIES  # noqa: E402  (the one effect list)

LABELS = ("none", *CATEGORIES)
PLANTS = ("twin", "independent", "forms")
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
    label: str  # the first effect ("none" for none)
    axis: str  # a randomly named axis ("" for none); both axes carry the effect
    truth: dict
    dataset: Dataset = field(repr=False)
    labels: tuple[str, ...] = ()  # every effect injected (empty for none)


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
        dead = _u(rng, 0.0, 0.002)
        lag = _u(rng, 0.001, 0.01)
        ff = _u(rng, 0.3, 0.95) if rng.random() < 0.5 else 0.0
        fb = _u(rng, 0.0005, 0.003) if rng.random() < 0.5 else 0.0
        sd = ServoDynamics(velocity_lag_s=lag, dead_time_s=dead, feedforward=ff, feedback_delay_s=fb)
        return Effects(servo_dynamics=sd), {"velocity_lag_s": lag, "dead_time_s": dead, "feedforward": ff,
                                            "feedback_delay_s": fb}  # fmt: skip
    if label == "sampling_skew":
        tau = _sgn(rng) * _u(rng, 0.001, 0.005)
        return Effects(sampling_skew=SamplingSkew(tau)), {"table_delay_s": tau}
    return Effects(), {}


def make_case(label: str | tuple[str, ...], rng: np.random.Generator, size: CaseSize = CaseSize(),
              split_fields: bool = True) -> Case:
    """A dataset with ``label`` (one of LABELS, or a tuple of two effects) on both axes."""
    labels = tuple(x for x in ((label,) if isinstance(label, str) else tuple(label)) if x != "none")
    for x in labels:
        if x not in LABELS:
            raise ValueError(f"label (={x!r}) must be one of {LABELS}")
    label = labels[0] if labels else "none"
    axes = {}
    configured_k = {}
    for name in ("x", "y"):
        lead = float(rng.choice([10.0, 16.0, 20.0]))
        configured_k[name] = _u(rng, 8, 40)
        axes[name] = AxisModel(
            name=name, transmission_mm_per_rev=lead * _u(rng, 0.35, 0.9), screw_lead_mm=lead,
            position_gain_per_s=configured_k[name], backlash_um=_u(rng, 15, 150),
            encoders=Encoders(table_noise_um=_u(rng, 0.1, 0.5), motor_noise_um=_u(rng, 0.1, 0.5)),
        )  # fmt: skip
    # A machine's effect acts on every axis (with its own parameters; a skew is one
    # acquisition delay): the "axis" of a case is the one with the larger effect draw.
    eff_axis = ""
    truth: dict = {}
    skew = None
    for lab in labels:
        for name in ("x", "y"):
            fx, tr = draw_effect(lab, rng, axes[name])
            if lab == "sampling_skew":
                skew = skew or fx
                fx, tr = skew, {"table_delay_s": skew.sampling_skew.table_delay_s}
            am = axes[name]
            gain = am.position_gain_per_s
            if lab == "servo_dynamics" and rng.random() < 0.5:  # the drive's real gain differs from the configured one
                gain = configured_k[name] * _u(rng, 0.7, 1.4)
                tr = dict(tr, effective_gain_per_s=gain)
            truth.setdefault(name, {})[lab] = tr
            eff = am.effects
            for cat in fx.active:
                eff = eff.with_effect(cat, getattr(fx, cat))
            axes[name] = AxisModel(am.name, am.transmission_mm_per_rev, am.screw_lead_mm, gain,
                                   am.backlash_um, effects=eff, encoders=am.encoders)  # fmt: skip
    if labels:
        eff_axis = str(rng.choice(["x", "y"]))
    label_name = "+".join(labels) or "none"
    specs = {}
    for a, m in axes.items():
        sp = m.to_axis_spec(TRAVEL_MM)
        specs[a] = AxisSpec(a, sp.transmission_mm_per_rev, sp.screw_lead_mm, configured_k[a], sp.travel_mm)
    machine = MachineSpec(id=f"bench-{label_name}", axes=specs)
    split = (lambda test: "test" if test else "train") if split_fields else (lambda test: None)
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
            runs.append(tr.to_run(f"rt_{name}_{k:02d}.csv", split=split(test)))
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
        lead_in = 0.0 if rng.random() < 0.25 else _u(rng, 0, 180)  # 0: at rest on the data arc
        lead_out = _u(rng, 0, 180)
        prog = circle(radius, centre, feed, "ccw" if i % 2 == 0 else "cw", _u(rng, -180, 180), size.circle_sweep_deg,
                      lead_in_deg=lead_in, lead_out_deg=lead_out, acceleration_mm_s2=_u(rng, 300, 2000))  # fmt: skip
        prog = replace(prog, record_from_s=0.0, record_to_s=prog.duration_s)  # the whole program, feed-in included
        tr = simulate(axes, prog, temperature_c=temp, rate_hz=size.circle_rate_hz, rng=rng)
        extra = {"lead_in_deg": lead_in, "lead_out_deg": lead_out} if rng.random() < 0.5 else {}
        runs.append(tr.to_run(f"circle_{i:02d}.csv", split=split(test), extra=extra))
    return Case(label, eff_axis, truth, Dataset(machine, tuple(runs)), labels)


def labels_for(n_cases: int, rng: np.random.Generator, mixed_fraction: float = 0.25) -> list[tuple[str, ...]]:
    """Balanced labels: each block of len(LABELS) cases holds every label once, shuffled;
    ``mixed_fraction`` of all cases (taken from the effect cases) get a second effect."""
    out: list[str] = []
    while len(out) < n_cases:
        out += [LABELS[i] for i in rng.permutation(len(LABELS))]
    out = out[:n_cases]
    effect_idx = [i for i, x in enumerate(out) if x != "none"]
    n_mixed = min(len(effect_idx), int(round(mixed_fraction * n_cases)))
    mixed = set(rng.choice(effect_idx, n_mixed, replace=False).tolist()) if n_mixed else set()
    res: list[tuple[str, ...]] = []
    for i, x in enumerate(out):
        if x == "none":
            res.append(())
        elif i in mixed:
            others = [e for e in LABELS[1:] if e != x]
            res.append((x, str(rng.choice(others))))
        else:
            res.append((x,))
    return res


@dataclass(frozen=True)
class CaseResult:
    index: int
    label: str  # "none", an effect, or "a+b" for a mixed case
    diagnosed: str
    gap_before_um: float
    gap_after_um: float
    noise_floor_um: float
    seconds: float
    axis: str
    labels: tuple[str, ...] = ()
    diagnosed_effects: tuple[str, ...] = ()
    plant: str = "twin"
    split_given: bool = True
    # every candidate's test gap alone and every pair's (base+second), in µm, and the
    # decision's sentence: why a case was missed, without diagnosing it again
    candidate_gaps_um: Mapping[str, float] = field(default_factory=dict)
    pair_gaps_um: Mapping[str, float] = field(default_factory=dict)
    decision: str = ""
    close_alternatives: tuple[str, ...] = ()  # the report's candidates not told apart from the answer

    @property
    def ratio(self) -> float:
        return self.gap_after_um / self.gap_before_um if self.gap_before_um > 0 else float("nan")

    @property
    def correct(self) -> bool:
        """For a mixed case either effect counts."""
        return self.diagnosed == "none" if not self.labels else self.diagnosed in self.labels

    @property
    def second_found(self) -> bool | None:
        """Mixed cases: whether the diagnosis named both effects (None otherwise)."""
        if len(self.labels) < 2:
            return None
        return set(self.labels) <= set(self.diagnosed_effects)


@dataclass(frozen=True)
class BenchmarkResult:
    cases: tuple[CaseResult, ...]
    seed: int
    plant: str = "twin"

    @property
    def fraction_correct(self) -> float:
        return float(np.mean([c.correct for c in self.cases])) if self.cases else float("nan")

    @property
    def false_effects_on_none(self) -> int:
        return sum(1 for c in self.cases if not c.labels and c.diagnosed != "none")

    @property
    def none_within_2x_noise(self) -> tuple[int, int]:
        none = [c for c in self.cases if not c.labels]
        return sum(1 for c in none if c.gap_before_um <= 2 * c.noise_floor_um), len(none)

    @property
    def second_effect_recall(self) -> tuple[int, int]:
        mixed = [c for c in self.cases if len(c.labels) > 1]
        return sum(1 for c in mixed if c.second_found), len(mixed)

    @property
    def close_alternative_cases(self) -> tuple[int, int, int]:
        """Answers that came with candidates not told apart from them (the report's
        ``close_alternatives``), how many of them were wrong, and of those how many had an
        injected effect among the alternatives."""
        close = [c for c in self.cases if c.close_alternatives]
        wrong = [c for c in close if not c.correct]
        return len(close), len(wrong), sum(1 for c in wrong if set(c.labels) & set(c.close_alternatives))

    def hidden_effect_cases(self, noise_factor: float = 2.0) -> tuple[CaseResult, ...]:
        """Effect cases whose nominal test gap is within ``noise_factor`` times the noise
        floor: the effect drawn did not show in the test runs, so "none" is what the data
        say. They stay in :attr:`fraction_correct`; this is reported beside it."""
        return tuple(c for c in self.cases if c.labels and c.gap_before_um <= noise_factor * c.noise_floor_um)

    def fraction_correct_visible(self, noise_factor: float = 2.0) -> float:
        """:attr:`fraction_correct` without :meth:`hidden_effect_cases`."""
        hidden = {c.index for c in self.hidden_effect_cases(noise_factor)}
        rest = [c.correct for c in self.cases if c.index not in hidden]
        return float(np.mean(rest)) if rest else float("nan")

    @property
    def errors(self) -> tuple[CaseResult, ...]:
        """Cases whose diagnosis raised (``axis`` holds the error)."""
        return tuple(c for c in self.cases if c.diagnosed == "error")

    @property
    def median_ratio_effect_cases(self) -> float:
        r = [c.ratio if c.diagnosed != "error" else 1.0 for c in self.cases if c.labels]
        return float(np.median(r)) if r else float("nan")

    @property
    def median_seconds(self) -> float:
        return float(np.median([c.seconds for c in self.cases])) if self.cases else float("nan")

    def confusion(self) -> dict[str, dict[str, int]]:
        """Rows: the first injected effect (either counts for a mixed case: the row of the
        one diagnosed, if any); columns: the diagnosed one."""
        m = {t: {p: 0 for p in LABELS} for t in LABELS}
        for c in self.cases:
            row = c.diagnosed if c.labels and c.diagnosed in c.labels else (c.labels[0] if c.labels else "none")
            if c.diagnosed in m[row]:  # an "error" case is in no column (errors are counted apart)
                m[row][c.diagnosed] += 1
        return m

    def to_dict(self) -> dict:
        hit, n_none = self.none_within_2x_noise
        rec, n_mixed = self.second_effect_recall
        return {
            "seed": self.seed,
            "plant": self.plant,
            "n_cases": len(self.cases),
            "fraction_correct": self.fraction_correct,
            "none_diagnosed_as_effect": self.false_effects_on_none,
            "none_gap_within_2x_noise": [hit, n_none],
            "second_effect_recall": [rec, n_mixed],
            "effect_cases_within_2x_noise": len(self.hidden_effect_cases()),
            "close_alternative_cases": list(self.close_alternative_cases),
            "diagnoses_that_raised": len(self.errors),
            "fraction_correct_without_them": self.fraction_correct_visible(),
            "median_gap_ratio_effect_cases": self.median_ratio_effect_cases,
            "median_seconds_per_case": self.median_seconds,
            "confusion": self.confusion(),
            "cases": [c.__dict__ | {"ratio": c.ratio, "correct": c.correct} for c in self.cases],
        }


def make_plant_case(plant: str, labels: tuple[str, ...], rng: np.random.Generator, size: CaseSize,
                    split_fields: bool) -> tuple[Dataset, bool]:
    """A dataset of ``plant`` with ``labels``; returns (dataset, whether it has split fields)."""
    ds, split_given, _ = _plant_case(plant, labels, rng, size, split_fields)
    return ds, split_given


def _plant_case(plant: str, labels: tuple[str, ...], rng: np.random.Generator, size: CaseSize,
                split_fields: bool) -> tuple[Dataset, bool, dict]:
    if plant == "twin":
        case = make_case(labels or "none", rng, size, split_fields=split_fields)
        return case.dataset, split_fields, case.truth
    if plant == "independent":
        from core.plant_independent import PlantSize, make_plant_case as make_independent

        psize = PlantSize(size.rt_train_per_axis, size.rt_test_per_axis, size.circles_train, size.circles_test,
                          size.rt_rate_hz, size.circle_rate_hz, size.rt_duration_s)  # fmt: skip
        case = make_independent(labels, rng, psize)
        return case.dataset, any(r.spec.split is not None for r in case.dataset.runs), case.truth
    if plant == "forms":
        from core.plant_forms import FormsSize, make_forms_case

        fsize = FormsSize(size.rt_train_per_axis, size.rt_test_per_axis, size.circles_train, size.circles_test,
                          size.rt_rate_hz, size.circle_rate_hz, size.rt_duration_s)  # fmt: skip
        case = make_forms_case(labels, rng, fsize)
        return case.dataset, any(r.spec.split is not None for r in case.dataset.runs), case.truth
    raise ValueError(f"plant (={plant!r}) must be one of {PLANTS}")


def _draw(n_cases: int, seed: int) -> list[tuple[tuple[str, ...], bool]]:
    """Per case of a benchmark of ``n_cases`` drawn from ``seed``: its labels and whether its
    dataset has split fields (a third have none)."""
    rng = np.random.default_rng(seed)
    labels = labels_for(n_cases, rng)
    no_split = set(rng.choice(n_cases, n_cases // 3, replace=False).tolist())
    return [(labs, i not in no_split) for i, labs in enumerate(labels)]


def benchmark_case(plant: str, n_cases: int, seed: int, index: int,
                   size: CaseSize = CaseSize()) -> tuple[tuple[str, ...], Dataset, dict]:
    """Case ``index`` (0-based) of ``run_benchmark(n_cases, seed, size, plant=plant)``, the
    same data: its labels, its dataset and the plant's truth (every drawn parameter), to
    look at a case apart (``mebm gap benchmark --write-datasets``)."""
    if not 0 <= index < n_cases:
        raise ValueError(f"index (={index}) must be in 0..{n_cases - 1}")
    labs, with_split = _draw(n_cases, seed)[index]
    ds, _, truth = _plant_case(plant, labs, np.random.default_rng([seed, index]), size, with_split)
    return labs, ds, truth


def diagnose_case(args) -> CaseResult:
    """One benchmark case, generated and diagnosed (a worker process' job when ``jobs`` > 1):
    ``args`` is (index, labels, seed, size, plant, with_split, keep_dataset). A diagnosis
    that raises is a result, scored wrong, not a stopped benchmark."""
    from core.gap.diagnose import GapSettings, diagnose

    i, labs, seed, size, plant, with_split, keep_dataset = args
    ds, split_given, truth = _plant_case(plant, labs, np.random.default_rng([seed, i]), size, with_split)
    if keep_dataset is not None:
        keep_dataset(i, labs, ds, truth)
    t0 = time.perf_counter()
    try:
        rep = diagnose(ds, GapSettings(keep_curves=False))
    except Exception as exc:  # noqa: BLE001 - a case that breaks the diagnosis is a result, scored wrong
        return CaseResult(i, "+".join(labs) or "none", "error", float("nan"), float("nan"), float("nan"),
                          time.perf_counter() - t0, f"{type(exc).__name__}: {exc}", labs, (), plant, split_given)  # fmt: skip
    dt = time.perf_counter() - t0
    return CaseResult(i, "+".join(labs) or "none", rep.effect, rep.gap_before_um, rep.gap_after_um,
                      rep.noise_floor_um, dt, "", labs, tuple(rep.effects), plant, split_given,
                      {c.effect: c.gap_after_um for c in rep.candidates}, {c.effect: c.gap_after_um for c in rep.pairs},
                      rep.decision, tuple(e for e, _ in rep.close_alternatives))  # fmt: skip


def run_benchmark(n_cases: int, seed: int, size: CaseSize = CaseSize(),
                  progress: Callable[[CaseResult], None] | None = None, plant: str = "twin",
                  jobs: int = 1, only: Collection[int] | None = None,
                  keep_dataset: Callable[[int, tuple[str, ...], Dataset, dict], None] | None = None) -> BenchmarkResult:
    """Generate ``n_cases`` datasets of ``plant`` (balanced labels, a quarter mixed, a third
    without split fields) and diagnose each without its label, in ``jobs`` processes.
    Each case's data depend only on (seed, index), so the result does not depend on jobs.
    ``only``: diagnose just these cases (0-based indexes) of the same draw, with the same
    data as in the whole run (to look again at a case of an evaluation). ``keep_dataset``:
    called with each case's index, labels, dataset and the plant's truth before its
    diagnosis, in the process that generated it (picklable when ``jobs`` > 1), to store
    the dataset without generating it twice."""
    if plant not in PLANTS:
        raise ValueError(f"plant (={plant!r}) must be one of {PLANTS}")
    if jobs < 1:
        raise ValueError(f"jobs (={jobs}) must be >= 1")
    if only is not None and not all(0 <= i < n_cases for i in only):
        raise ValueError(f"only (={sorted(only)}) must hold case indexes in 0..{n_cases - 1}")
    work = [(i, labs, seed, size, plant, with_split, keep_dataset) for i, (labs, with_split) in enumerate(_draw(n_cases, seed))
            if only is None or i in only]  # fmt: skip
    out = []
    if jobs == 1:
        for w in work:
            res = diagnose_case(w)
            out.append(res)
            if progress is not None:
                progress(res)
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for res in pool.map(diagnose_case, work):
                out.append(res)
                if progress is not None:
                    progress(res)
    return BenchmarkResult(tuple(out), seed, plant)

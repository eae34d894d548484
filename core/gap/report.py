"""The result of a gap diagnosis: :class:`GapReport` (JSON ``mebm-gap/1`` and a text report)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

FORMAT = "mebm-gap/1"


_FLOOR_FROM = {"rest": "where the encoders stand still", "motion": "in motion: no encoder stood still",
               "rest and motion": "at rest, in motion where an encoder never stood still"}


def _num(x, nd: int = 4):
    if x is None:
        return None
    if isinstance(x, (list, tuple)):
        return [_num(v, nd) for v in x]
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


@dataclass(frozen=True)
class Where:
    """Where the nominal model's test gap lies."""

    kind: str
    phase: str | None
    axis: str | None
    angle_deg: tuple[float, ...] | None
    position_mm: float | None
    summary: str
    details: Mapping = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "phase": self.phase,
            "axis": self.axis,
            "angle_deg": None if self.angle_deg is None else _num(list(self.angle_deg), 1),
            "position_mm": _num(self.position_mm, 2),
            "summary": self.summary,
            "details": dict(self.details),
        }


@dataclass(frozen=True)
class Candidate:
    """One effect added to the nominal model, fitted on the train runs, scored on the test runs."""

    effect: str
    gap_after_um: float
    params: Mapping[str, float]
    n_params: int
    score: float
    identifiable: bool = True
    notes: str = ""
    axes: tuple[str, ...] = ()
    intervals: Mapping = field(default_factory=dict)  # param -> [lo, hi] (95 %) or "not identifiable"
    values: Mapping = field(default_factory=dict, compare=False, repr=False)  # every fitted number, identifiable or not
    fitted: bool = True  # False: its fit failed (worse than the nominal model from other starts too)
    converged: bool = True  # every fit of it ended at convergence, not at an evaluation cap

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "gap_after_um": _num(self.gap_after_um, 3),
            "params": {k: _num(v, 5) if not isinstance(v, str) else v for k, v in self.params.items()},
            "n_params": self.n_params,
            "score_um": _num(self.score, 3),
            "identifiable": self.identifiable,
            "fitted": self.fitted,
            "converged": self.converged,
            "axes": list(self.axes),
            "notes": self.notes,
            "intervals": {k: (_num(v, 5) if not isinstance(v, str) else v) for k, v in self.intervals.items()},
        }


@dataclass(frozen=True)
class GapReport:
    """Diagnosis of the gap between the nominal model and a machine's test runs."""

    machine_id: str
    effect: str
    where: Where
    gap_before_um: float
    gap_after_um: float
    noise_floor_um: float
    train: tuple[str, ...]
    test: tuple[str, ...]
    split_how: str
    candidates: tuple[Candidate, ...]
    nominal_backlash_um: Mapping[str, float]
    quantity: Mapping[str, str]
    gap_before_by_kind_um: Mapping[str, float]
    n_test_samples: int
    decision: str
    thresholds: Mapping[str, float]
    curves: Mapping = field(default_factory=dict, compare=False, repr=False)
    effects: tuple[str, ...] = ()  # dominant first, then a second effect when one remains
    second_effect: str = ""  # the sentence on a second effect
    program_source: str = "recorded command columns"
    pairs: tuple[Candidate, ...] = ()  # the dominant effect with each other candidate on top
    observations: tuple[str, ...] = ()  # what the data show beside the decision (a rattling table)
    # eligible hypotheses the test runs do not tell apart from the answer: (effects joined by "+",
    # gap_after_um), best first (core.gap.select)
    close_alternatives: tuple[tuple[str, float], ...] = ()
    selection: Mapping = field(default_factory=dict)  # the decision's reasons as data (selection_dict)
    # the wear of a stored history in the nominal model: per axis (rate µm per utility day,
    # the reference utility day its backlash is given at)
    nominal_wear: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    # where the noise floor's white level was read: "rest" (every test run's encoders stood
    # still somewhere), "motion" (none did: from the residuals' third differences), or both
    noise_floor_from: str = "motion"
    # the train runs the fits used where a long history's train round trips were thinned
    # (core.gap.data.thin_train); None: every train run
    fitted: tuple[str, ...] | None = None

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "effect": self.effect,
            "effects": list(self.effects),
            "second_effect": self.second_effect,
            "program_source": self.program_source,
            "where": self.where.to_dict(),
            "gap_before_um": _num(self.gap_before_um, 3),
            "gap_after_um": _num(self.gap_after_um, 3),
            "split": {"train": list(self.train), "test": list(self.test), "how": self.split_how,
                      **({"fitted": list(self.fitted)} if self.fitted is not None else {})},
            "candidates": [c.to_dict() for c in self.candidates],
            "noise_floor_um": _num(self.noise_floor_um, 3),
            "noise_floor_from": self.noise_floor_from,
            "quantity": dict(self.quantity),
            "gap_before_by_kind_um": {k: _num(v, 3) for k, v in self.gap_before_by_kind_um.items()},
            "nominal_backlash_um": {k: _num(v, 2) for k, v in self.nominal_backlash_um.items()},
            "nominal_wear": {k: {"wear_um_per_day": _num(r, 4), "reference_utility_day": _num(d, 2)}
                             for k, (r, d) in self.nominal_wear.items()},
            "n_test_samples": self.n_test_samples,
            "decision": self.decision,
            "thresholds": dict(self.thresholds),
            "machine_id": self.machine_id,
            "pairs": [c.to_dict() for c in self.pairs],
            "observations": list(self.observations),
            "close_alternatives": [{"effect": e, "gap_after_um": _num(g, 3)} for e, g in self.close_alternatives],
            "selection": dict(self.selection),
        }

    def text(self) -> str:
        """The human report: a few sentences, then the candidate table."""
        gb, ga = self.gap_before_um, self.gap_after_um
        n_tr, n_te = len(self.train), len(self.test)
        b = ", ".join(f"{a} {v:.1f} µm" + (f" at utility day {self.nominal_wear[a][1]:g}, growing "
                                           f"{self.nominal_wear[a][0]:.3g} µm per utility day"
                                           if a in self.nominal_wear else "")
                      for a, v in self.nominal_backlash_um.items())  # fmt: skip
        kind = "a backlash per axis, with its wear," if self.nominal_wear else "a constant backlash per axis"
        lines = [f"Gap diagnosis of machine {self.machine_id or '(unnamed)'}: {n_tr} train run(s), {n_te} test run(s)."]
        lines.append(
            f"The nominal model (K from the axis, {kind} fitted on the train runs: {b}) "
            f"misses the test runs by {gb:.2f} µm RMS; the measurement noise floor is {self.noise_floor_um:.2f} µm"
            f" (read {_FLOOR_FROM[self.noise_floor_from]})."
        )
        if self.effect == "none":
            lines.append(f"Diagnosis: none. {self.decision}")
        else:
            # the named effect's own figure; a second effect's is its own line
            own = next((c.gap_after_um for c in self.candidates if c.effect == self.effect), ga)
            lines.append(
                f"Diagnosis: {self.effect}. Adding it, fitted on the train runs only, brings the test gap to "
                f"{own:.2f} µm ({(own / gb - 1) * 100:+.0f} %). {self.decision}"
            )
        if self.second_effect:
            lines.append(self.second_effect)
        if self.close_alternatives:
            alts = ", ".join(f"{e} ({g:.2f} µm)" for e, g in self.close_alternatives)
            cut = self.thresholds.get("min_reduction", 0.25) * 100
            named = "+".join(self.effects) or self.effect
            lines.append(f"Not told apart: {alts} also cut the test gap by {cut:.0f} % or more, and neither "
                         f"{named} ({ga:.2f} µm) nor they cut the other's gap by another {cut:.0f} %; test runs at "
                         "other conditions (feed, acceleration, temperature) may separate them.")  # fmt: skip
        lines.append(f"Where: {self.where.summary}")
        lines += [f"Observed: {o}" for o in self.observations]
        lines.append(f"Contour programs: {self.program_source}.")
        q = "; ".join(f"{k}: {v}" for k, v in self.quantity.items())
        lines.append(f"Compared quantity: {q}. Gaps are RMS over all {self.n_test_samples} test samples.")
        lines.append(f"Split: {self.split_how}.")
        lines.append("")
        rows = [("effect", "gap after (µm)", "change", "params", "score", "fitted parameters")]
        for c in self.candidates:
            ps = ", ".join(f"{k}={v:.4g}" if not isinstance(v, str) else f"{k}={v}" for k, v in c.params.items())
            change = f"{(c.gap_after_um / gb - 1) * 100:+.0f} %" if gb > 0 else "-"
            rows.append((c.effect, f"{c.gap_after_um:.3f}", change, str(c.n_params), f"{c.score:.3f}",
                         (ps or "-") + (f"  [{c.notes}]" if c.notes else "")))  # fmt: skip
        if self.pairs:
            rows.append(("", "", "", "", "", ""))
            for c in self.pairs:
                change = f"{(c.gap_after_um / gb - 1) * 100:+.0f} %" if gb > 0 else "-"
                rows.append((c.effect, f"{c.gap_after_um:.3f}", change, str(c.n_params), f"{c.score:.3f}",
                             "(second effect on top)" + (f"  [{c.notes}]" if c.notes else "")))  # fmt: skip
        widths = [max(len(r[i]) for r in rows) for i in range(5)]
        for r in rows:
            lines.append("  ".join(r[i].ljust(widths[i]) for i in range(5)) + "  " + r[5])
        return "\n".join(lines)


def _pct(after_um: float, before_um: float) -> str:
    return f"{(1 - after_um / before_um) * 100:.0f} %"


def explain(dec, single_gap_um: Mapping[str, float], second_effect: bool, on_top: bool) -> tuple[str, str]:
    """The decision's sentence and the second effect's, from a :class:`core.gap.select.Decision`.
    ``single_gap_um``: each single family's held-out gap; ``second_effect``: pairs were
    searched; ``on_top``: pairs were fitted on top of the named family."""
    gb, r = dec.gap_before_um, dec.rule
    m = f"{r.min_reduction * 100:.0f} %"
    pointed = sorted({e for o in dec.unsupported for e in o.supports})
    unsupported = ""
    if pointed:
        kinds = ", ".join(o.kind.replace("_", "-") for o in dec.unsupported)
        fam = "; ".join(f"{e} {_pct(single_gap_um[e], gb)}" for e in pointed if e in single_gap_um)
        unsupported = (f" The observations ({kinds}) point at {' or '.join(pointed)}, whose fit does not explain "
                       f"the gap as well (its cut of the test gap: {fam}).")  # fmt: skip
    if dec.kind == "within_noise":
        return (f"The test gap {gb:.2f} µm is within {r.noise_factor:g}x the noise floor ({dec.noise_floor_um:.2f} µm)."
                ), ""  # fmt: skip
    if dec.kind == "no_cut":
        best = "" if dec.best is None else f" (best: {dec.best.effects[0]}, {dec.best.gap_after_um:.2f} µm)"
        pair = ", and no pair of candidates does" if second_effect else ""
        return (f"No candidate cuts the test gap by {m} or more{best}{pair}: the gap is not one of the modelled "
                f"effects.{unsupported}"), ""  # fmt: skip
    c = dec.chosen
    name = dec.effect
    if dec.kind == "weak":
        text = (f"{name} cuts the test gap by {_pct(c.gap_after_um, gb)} only (under {m}): the likeliest of the "
                "modelled effects, but most of the gap stays unexplained.")  # fmt: skip
        return text + unsupported, ("No second effect found (no other candidate on top cuts the remaining gap by "
                                    f"{m})." if second_effect else "")  # fmt: skip
    alone = single_gap_um.get(name, gb)
    if len(dec.effects) > 1:
        second = dec.effects[1]
        if alone <= (1 - r.min_reduction) * gb:
            text = f"{name} cuts the test gap by {_pct(alone, gb)}, and {second} on top by another {_pct(c.gap_after_um, alone)}."
        else:
            text = (f"Neither {name} nor {second} alone cuts the test gap by {m}, but together they cut it by "
                    f"{_pct(c.gap_after_um, gb)}.")  # fmt: skip
        second_text = (f"A second effect remains: {second} (together the test gap falls to {c.gap_after_um:.2f} µm; "
                       f"{name} alone leaves {alone:.2f} µm).")  # fmt: skip
    else:
        text = f"{name} cuts the test gap by {_pct(c.gap_after_um, gb)}."
        if not second_effect:
            second_text = ""
        elif c.gap_after_um <= r.noise_factor * dec.noise_floor_um:
            second_text = "No second effect found: the remaining gap is at the noise floor."
        elif on_top:
            second_text = f"No second effect found (no other candidate on top cuts the remaining gap by {m})."
        else:
            second_text = "No second effect found (no other candidate took anything on its own)."
    if dec.by_evidence:
        b = dec.best
        kinds = ", ".join(o.kind.replace("_", "-") for o in dec.supporting)
        text += (f" The held-out runs do not tell it apart from {'+'.join(b.effects)} ({b.gap_after_um:.2f} µm, the "
                 f"better score); the observations ({kinds}) support {name}.")  # fmt: skip
    elif dec.best is not None and c is not dec.best:
        b = dec.best
        text += (f" The held-out runs do not tell it apart from {'+'.join(b.effects)} ({b.gap_after_um:.2f} µm, the "
                 "better score), whose fit stopped at its evaluation cap, not at convergence.")  # fmt: skip
    text += _passed_over(dec)
    if not c.identified:
        text += (" Its parameters are not identifiable from the train runs, and no eligible hypothesis has "
                 "identifiable ones: the data support the fit more than the physics it names.")  # fmt: skip
    if not c.converged:
        text += (" Its fit stopped at its evaluation cap, not at convergence: its figures may move in their last "
                 "digits with the computer's numerics.")  # fmt: skip
    return text + unsupported, second_text


def _passed_over(dec) -> str:
    """The sentences on eligible hypotheses the decision passed over: those whose parameters
    are not identifiable, and the larger forms that contain the answer's."""
    out = ""
    name = "+".join(dec.effects)
    if dec.not_identified:
        hs = ", ".join(f"{'+'.join(h.effects)} ({h.gap_after_um:.2f} µm)" for h in dec.not_identified)
        out += (f" {hs} cut the test gap further, but the train runs do not pin their parameters down (not "
                f"identifiable): a fit, not a physics, so {name}, whose parameters are identifiable, is named.")
    if dec.contained:
        hs = ", ".join(f"{'+'.join(h.effects)} ({h.gap_after_um:.2f} µm)" for h in dec.contained)
        out += (f" {hs} contain{'s' if len(dec.contained) == 1 else ''} {name}'s form; the held-out runs do not tell "
                f"them apart or the larger form's own parameters are not identifiable, so the simpler {name} is "
                "named.")  # fmt: skip
    return out


def selection_dict(dec) -> dict:
    """The decision's reasons as JSON: its kind, the hypothesis named and the best by score,
    the ties, whether evidence broke a tie, and the observations for and outside the answer."""
    def hyp(h):
        return None if h is None else {"effects": list(h.effects), "gap_after_um": _num(h.gap_after_um, 3)}

    return {
        "kind": dec.kind,
        # the named hypothesis' families dominant first, as the report's ``effects``
        "chosen": None if dec.chosen is None else hyp(dec.chosen) | {"effects": list(dec.effects)},
        "best_by_score": hyp(dec.best),
        "ties": [hyp(h) for h in dec.ties],
        "by_evidence": dec.by_evidence,
        "not_identified": [hyp(h) for h in dec.not_identified],
        "contained": [hyp(h) for h in dec.contained],
        "converged": None if dec.chosen is None else dec.chosen.converged,
        "supporting": [{"kind": o.kind, "supports": sorted(o.supports)} for o in dec.supporting],
        "unsupported": [{"kind": o.kind, "supports": sorted(o.supports)} for o in dec.unsupported],
        "rule": {"penalty_per_param": dec.rule.penalty_per_param, "min_reduction": dec.rule.min_reduction,
                 "noise_factor": dec.rule.noise_factor, "min_first_reduction": dec.rule.min_first_reduction},
    }

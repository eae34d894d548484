"""The decision of the gap diagnosis: which hypothesis of the results table is named.

The results table holds the hypotheses the search fitted on the train runs and scored on
the held-out runs (:mod:`core.gap.diagnose`): every single family, and pairs (a family on
top of another). The decision is one rule:

1. **The noise gate.** A gap before within ``noise_factor`` times the noise floor is
   noise: ``none``.
2. **Eligible hypotheses.** A single family is eligible when it cuts the gap before by
   ``min_reduction``; a pair when it cuts the gap before by ``min_reduction`` and its
   second effect cuts its base's gap by ``min_reduction`` too (each effect is needed),
   its base's gap lying above the noise gate.
3. **The best by score.** Held-out gap times (1 + ``penalty_per_param`` x parameters).
4. **Told apart, symmetrically.** Two hypotheses are told apart when the better cuts the
   worse one's gap by ``min_reduction``, whichever of them is named. The eligible
   hypotheses not told apart from the best are its ties.
5. **Evidence breaks ties only.** Among the best and its ties, each observation
   (:mod:`core.gap.evidence`) adds one to the hypotheses that hold a family it
   supports; the highest weight is named, the score deciding between equal weights. An
   observation never names a hypothesis the held-out runs tell apart as worse, and never
   one that does not cut the gap; an observation that points at a family outside the
   answer is reported as such.
6. **Nothing eligible**: ``none``; with ``min_first_reduction`` set (off by default),
   the best single family is still named when it cuts the gap by that weaker fraction,
   and the report says that most of the gap stays unexplained.

:func:`select` returns a :class:`Decision`, reasons as data; :mod:`core.gap.report`
turns it into sentences.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from core.gap.evidence import Observation


class Hypothesis(Protocol):
    """A row of the results table, as the decision reads it."""

    effects: tuple[str, ...]
    gap_after_um: float

    def score(self, penalty: float) -> float: ...


@dataclass(frozen=True)
class Rule:
    """The decision's parameters."""

    penalty_per_param: float = 0.01
    min_reduction: float = 0.25
    noise_factor: float = 2.0
    min_first_reduction: float | None = None


@dataclass(frozen=True)
class Decision:
    """What was named and why.

    ``kind``: ``within_noise`` (the gap before is noise), ``no_cut`` (no hypothesis is
    eligible), ``named`` or ``weak`` (the best single family under ``min_first_reduction``).
    ``chosen``: the hypothesis named (None for ``none``); ``best``: the best eligible by
    score (the chosen one unless evidence broke a tie), or the best single family where
    nothing is eligible; ``ties``: eligible hypotheses not told apart from the best
    (the chosen one excluded); ``by_evidence``: evidence chose a tie over the best score;
    ``supporting`` / ``unsupported``: the observations that support the answer, and those
    that point at families outside it."""

    kind: str
    chosen: Hypothesis | None
    best: Hypothesis | None
    ties: tuple[Hypothesis, ...]
    by_evidence: bool
    supporting: tuple[Observation, ...]
    unsupported: tuple[Observation, ...]
    gap_before_um: float
    noise_floor_um: float
    rule: Rule

    @property
    def effect(self) -> str:
        return "none" if self.chosen is None else self.chosen.effects[0]


def cuts(better_um: float, worse_um: float, min_reduction: float) -> bool:
    """Whether a gap of ``better_um`` cuts one of ``worse_um`` by ``min_reduction``."""
    return better_um <= (1.0 - min_reduction) * worse_um


def told_apart(a: Hypothesis, b: Hypothesis, min_reduction: float) -> bool:
    """Whether the held-out runs tell ``a`` and ``b`` apart: the better cuts the worse one's
    gap by ``min_reduction``, whichever is given first."""
    lo, hi = sorted((a.gap_after_um, b.gap_after_um))
    return cuts(lo, hi, min_reduction)


def ranked(rows: Sequence[Hypothesis], penalty: float) -> list[Hypothesis]:
    return sorted(rows, key=lambda h: h.score(penalty))


def eligible_singles(singles: Sequence[Hypothesis], gap_before: float, rule: Rule) -> list[Hypothesis]:
    """The single families that cut the gap before by ``min_reduction``, best first."""
    return ranked([h for h in singles if cuts(h.gap_after_um, gap_before, rule.min_reduction)], rule.penalty_per_param)


def ties_of(best: Hypothesis, rows: Sequence[Hypothesis], rule: Rule) -> list[Hypothesis]:
    """The rows other than ``best`` that the held-out runs do not tell apart from it, best first."""
    return ranked([h for h in rows if h is not best and not told_apart(best, h, rule.min_reduction)],
                  rule.penalty_per_param)  # fmt: skip


def eligible_pairs(pairs: Sequence[Hypothesis], singles: Sequence[Hypothesis], gap_before: float,
                   gate_um: float, rule: Rule) -> list[Hypothesis]:
    """The pairs that cut the gap before by ``min_reduction`` and whose second effect cuts
    its base's gap by ``min_reduction`` (the base: the single of the pair's first effect,
    above the noise gate), best first; of two pairs of the same families, the better."""
    base = {h.effects[0]: h for h in singles}
    ok = [p for p in pairs if p.effects[0] in base and base[p.effects[0]].gap_after_um > gate_um
          and cuts(p.gap_after_um, gap_before, rule.min_reduction)
          and cuts(p.gap_after_um, base[p.effects[0]].gap_after_um, rule.min_reduction)]  # fmt: skip
    out, seen = [], set()
    for p in ranked(ok, rule.penalty_per_param):
        if frozenset(p.effects) not in seen:
            seen.add(frozenset(p.effects))
            out.append(p)
    return out


def select(singles: Sequence[Hypothesis], pairs: Sequence[Hypothesis], gap_before: float, noise_floor: float,
           observations: Sequence[Observation], rule: Rule) -> Decision:
    """The decision on the results table (``singles``: every single family; ``pairs``: the
    pairs fitted), the gap before, the noise floor and the observations."""
    gate = rule.noise_factor * noise_floor
    obs = tuple(observations)

    def decision(kind, chosen=None, best=None, ties=(), by_evidence=False):
        held = () if chosen is None else chosen.effects
        supporting = tuple(o for o in obs if o.weight(held))
        unsupported = tuple(o for o in obs if not o.weight(held))
        return Decision(kind, chosen, best, tuple(ties), by_evidence, supporting, unsupported, gap_before,
                        noise_floor, rule)  # fmt: skip

    if gap_before <= gate:
        return decision("within_noise")
    rows = eligible_singles(singles, gap_before, rule) + eligible_pairs(pairs, singles, gap_before, gate, rule)
    if not rows:
        top = ranked(singles, rule.penalty_per_param)[:1]
        if top and rule.min_first_reduction is not None and cuts(top[0].gap_after_um, gap_before,
                                                                 rule.min_first_reduction):
            return decision("weak", top[0], top[0])
        return decision("no_cut", None, top[0] if top else None)
    best = ranked(rows, rule.penalty_per_param)[0]
    close = ties_of(best, rows, rule)
    # evidence weighs among the best and its ties only; the score decides between equal weights
    pool = [best] + close
    weight = {id(h): sum(o.weight(h.effects) for o in obs) for h in pool}
    chosen = max(pool, key=lambda h: (weight[id(h)], -h.score(rule.penalty_per_param)))
    return decision("named", chosen, best, [h for h in pool if h is not chosen], chosen is not best)

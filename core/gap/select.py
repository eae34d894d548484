"""The decision of the gap diagnosis: which hypothesis of the results table is named.

The results table holds the hypotheses the search fitted on the train runs and scored on
the held-out runs (:mod:`core.gap.diagnose`): every single family, and pairs (a family on
top of another). The decision is one rule:

1. **The noise gate.** A gap before within ``noise_factor`` times the noise floor is
   noise: ``none``.
2. **Eligible hypotheses.** A single family is eligible when it cuts the gap before by
   ``min_reduction``; a pair when it cuts the gap before by ``min_reduction`` and the gap
   each of its families leaves alone by ``min_reduction`` too (each effect is needed,
   whichever of the two the pair was fitted on), each of those gaps lying above the
   noise gate. A pair is named dominant first: its families in the order of what each
   explains alone (the smaller single gap first), not in the order it was fitted.
3. **The best by score.** Held-out gap times (1 + ``penalty_per_param`` x parameters).
4. **Told apart, symmetrically.** Two hypotheses are told apart when the better cuts the
   worse one's gap by ``min_reduction``, whichever of them is named. The eligible
   hypotheses not told apart from the best are its ties.
5. **Identifiable first.** A hypothesis whose parameters the train runs cannot pin down
   (one of its families has no identifiable parameter on any axis it took, or its
   family says so) is not named over an eligible one whose parameters are: the data support
   its fit, not its physics. It is named only where no eligible hypothesis is
   identifiable, and the report says so.
6. **Parsimony.** Where one hypothesis' forms contain another's (a family's form that
   reduces to another family's, ``Stage.contains``; a pair contains its own base), the
   larger is named only when the held-out runs tell it apart from the smaller and its
   own parameters are identifiable; among hypotheses not told apart, one that contains
   another of them is never named.
7. **Evidence breaks ties only.** Among the best and its ties, each observation
   (:mod:`core.gap.evidence`) adds one to the hypotheses that hold a family it
   supports; the highest weight is named; between equal weights a fit that ended at
   convergence goes before one stopped at its evaluation cap (whose figure may move
   with the computer's numerics), and then the score decides. An observation never
   names a hypothesis the held-out runs tell apart as worse, and never one that does
   not cut the gap; an observation that points at a family outside the answer is
   reported as such.
8. **Nothing eligible**: ``none``; with ``min_first_reduction`` set (off by default),
   the best single family is still named when it cuts the gap by that weaker fraction,
   and the report says that most of the gap stays unexplained.

A row whose fit failed (it makes the held-out gap worse than the nominal model even from
other starts: :mod:`core.gap.diagnose`) is "not fitted" and never eligible.

:func:`select` returns a :class:`Decision`, reasons as data; :mod:`core.gap.report`
turns it into sentences.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from core.gap.evidence import Observation


class Hypothesis(Protocol):
    """A row of the results table, as the decision reads it.

    ``unidentified``: its families whose parameters the train runs do not pin down, and
    ``identified`` (none is; rule 5); ``contains``: the families whose forms its own forms
    contain (rule 6); ``converged``: every fit of it ended at convergence, not at an
    evaluation cap; ``fitted``: its fit did not fail."""

    effects: tuple[str, ...]
    gap_after_um: float
    unidentified: frozenset[str]
    identified: bool
    contains: frozenset[str]
    converged: bool
    fitted: bool

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
    that point at families outside it; ``not_identified``: eligible hypotheses with a
    better score passed over because their parameters are not identifiable (rule 5);
    ``contained``: eligible hypotheses passed over for a simpler one they contain, which
    the held-out runs do not tell apart from them or whose own parameters are (rule 6);
    ``effects``: the chosen hypothesis' families, dominant first (rule 2)."""

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
    not_identified: tuple[Hypothesis, ...] = ()
    contained: tuple[Hypothesis, ...] = ()
    effects: tuple[str, ...] = ()

    @property
    def effect(self) -> str:
        return self.effects[0] if self.effects else "none"


def cuts(better_um: float, worse_um: float, min_reduction: float) -> bool:
    """Whether a gap of ``better_um`` cuts one of ``worse_um`` by ``min_reduction``."""
    return better_um <= (1.0 - min_reduction) * worse_um


def told_apart(a: Hypothesis, b: Hypothesis, min_reduction: float) -> bool:
    """Whether the held-out runs tell ``a`` and ``b`` apart: the better cuts the worse one's
    gap by ``min_reduction``, whichever is given first."""
    lo, hi = sorted((a.gap_after_um, b.gap_after_um))
    return cuts(lo, hi, min_reduction)


def extra_identified(small: Hypothesis, large: Hypothesis) -> bool:
    """Whether the families ``large`` adds over ``small`` have identifiable parameters."""
    return not (set(large.effects) - set(small.effects)) & set(large.unidentified)


def nests(small: Hypothesis, large: Hypothesis) -> bool:
    """Whether ``large``'s forms contain ``small``'s: every family of ``small`` is one of
    ``large``'s or one its forms contain, and the two are not the same families."""
    mine, theirs = set(small.effects), set(large.effects)
    return mine != theirs and mine <= theirs | set(large.contains)


def ranked(rows: Sequence[Hypothesis], penalty: float) -> list[Hypothesis]:
    return sorted(rows, key=lambda h: h.score(penalty))


def eligible_singles(singles: Sequence[Hypothesis], gap_before: float, rule: Rule) -> list[Hypothesis]:
    """The single families that cut the gap before by ``min_reduction``, best first."""
    return ranked([h for h in singles if cuts(h.gap_after_um, gap_before, rule.min_reduction)], rule.penalty_per_param)


def ties_of(best: Hypothesis, rows: Sequence[Hypothesis], rule: Rule) -> list[Hypothesis]:
    """The rows other than ``best`` that the held-out runs do not tell apart from it, best first."""
    return ranked([h for h in rows if h is not best and not told_apart(best, h, rule.min_reduction)],
                  rule.penalty_per_param)  # fmt: skip


def dominant_first(h: Hypothesis, singles: Sequence[Hypothesis]) -> tuple[str, ...]:
    """``h``'s families in the order of what each explains alone: the smaller held-out gap
    of its single row first (a family without one last); between equal gaps, as fitted."""
    alone = {s.effects[0]: s.gap_after_um for s in singles}
    return tuple(sorted(h.effects, key=lambda e: alone.get(e, math.inf)))


def eligible_pairs(pairs: Sequence[Hypothesis], singles: Sequence[Hypothesis], gap_before: float,
                   gate_um: float, rule: Rule) -> list[Hypothesis]:
    """The pairs that cut the gap before by ``min_reduction`` and the gap each of their
    families leaves alone (its single row, above the noise gate) by ``min_reduction``:
    each effect is needed, whichever the pair was fitted on. Best first; of two pairs of
    the same families, the better."""
    alone = {h.effects[0]: h.gap_after_um for h in singles}

    def needed(p: Hypothesis) -> bool:  # a family without a single row explains nothing alone
        return all(alone.get(e, math.inf) > gate_um and cuts(p.gap_after_um, alone.get(e, math.inf), rule.min_reduction)
                   for e in p.effects)  # fmt: skip

    ok = [p for p in pairs if cuts(p.gap_after_um, gap_before, rule.min_reduction) and needed(p)]
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

    def decision(kind, chosen=None, best=None, ties=(), by_evidence=False, not_identified=(), contained=()):
        held = () if chosen is None else chosen.effects
        supporting = tuple(o for o in obs if o.weight(held))
        unsupported = tuple(o for o in obs if not o.weight(held))
        return Decision(kind, chosen, best, tuple(ties), by_evidence, supporting, unsupported, gap_before,
                        noise_floor, rule, tuple(not_identified), tuple(contained),
                        () if chosen is None else dominant_first(chosen, singles))  # fmt: skip

    if gap_before <= gate:
        return decision("within_noise")
    fitted = [h for h in singles if h.fitted]
    # a pair is weighed against each of its families' single rows, fitted or not (a family
    # that fails alone may be half of a pair: core.gap.diagnose.pair_jobs)
    eligible = eligible_singles(fitted, gap_before, rule) + eligible_pairs(
        [p for p in pairs if p.fitted], singles, gap_before, gate, rule)
    if not eligible:
        top = ranked(fitted, rule.penalty_per_param)[:1]
        if top and rule.min_first_reduction is not None and cuts(top[0].gap_after_um, gap_before,
                                                                 rule.min_first_reduction):
            return decision("weak", top[0], top[0])
        return decision("no_cut", None, top[0] if top else None)
    pen = rule.penalty_per_param
    # identifiable first (rule 5): the unidentified are named only where nothing identified is eligible
    known = [h for h in eligible if h.identified]
    rows = known or eligible
    best = ranked(rows, pen)[0]
    passed = [h for h in ranked(eligible, pen) if not h.identified and h.score(pen) < best.score(pen)] if known else []
    # parsimony (rule 6): a larger hypothesis over a smaller one it contains only where the
    # held-out runs tell them apart and its own parameters are identifiable
    contained: list[Hypothesis] = []
    for _ in rows:  # each step goes to a strictly smaller hypothesis
        smaller = [h for h in ranked(rows, pen) if nests(h, best)
                   and (not told_apart(best, h, rule.min_reduction) or not extra_identified(h, best))]  # fmt: skip
        if not smaller:
            break
        contained.append(best)
        best = smaller[0]
    pool = [best] + ties_of(best, rows, rule)
    # among hypotheses not told apart, one that contains another of them is never named
    simple = [h for h in pool if not any(o is not h and nests(o, h) for o in pool)] or pool
    contained += [h for h in pool if all(h is not x for x in simple) and all(h is not x for x in contained)]
    pool = simple
    # evidence weighs among the best and its ties only; between equal weights a converged
    # fit goes first, then the score
    weight = {id(h): sum(o.weight(h.effects) for o in obs) for h in pool}
    chosen = max(pool, key=lambda h: (weight[id(h)], h.converged, -h.score(pen)))
    return decision("named", chosen, best, [h for h in pool if h is not chosen], weight[id(chosen)] > weight[id(best)],
                    passed, contained)  # fmt: skip

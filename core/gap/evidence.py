"""Observations of the chain, as evidence for the decision (:mod:`core.gap.select`).

An observation is something the data show whatever the fits say: a table that breaks
away at rest, a table that rattles against the nut (:mod:`core.gap.where`). Each family
of the registry declares the observations its physics produces
(:attr:`core.gap.families.Family.shown_by`); an observation *supports* the families
that declare it. Evidence weighs only among hypotheses the held-out runs do not tell
apart: it never names a family whose held-out gap is clearly worse than another's, nor
one that does not cut the gap.

The kinds:

* ``breakaway``: while the command stands still the table stays put, then jumps
  (:func:`core.gap.where.breakaways`): static friction above the Coulomb level giving
  way to a chain the position loop winds up.
* ``stick_slip``: the table rattles against the nut in both stroke directions on every
  round trip that rattles: a friction below its critical speed sticks and slips out and
  back alike.
* ``hunting``: the table rattles in one stroke direction only on some round trip: a
  self-excited cycle that a stroke falls into or not, depending on how it began.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from core.gap.where import breakaway_sentence, rattle_sentence, stick_slips

KINDS = ("breakaway", "stick_slip", "hunting")


@dataclass(frozen=True)
class Observation:
    """One observation: its kind, the sentence that says what was seen, and the families
    whose physics produces it."""

    kind: str
    seen: str
    supports: frozenset[str]

    def weight(self, effects: Sequence[str]) -> int:
        """+1 for a hypothesis that holds a family this observation supports, else 0."""
        return int(any(e in self.supports for e in effects))


def observe(broke: Sequence[Mapping], found: Sequence[Mapping], shown_by: Mapping[str, Sequence[str]]) -> tuple[Observation, ...]:
    """The observations of break-away findings ``broke`` and rattle findings ``found``
    (:func:`core.gap.where.breakaways`, :func:`core.gap.where.rattles`); ``shown_by``: per
    family, the kinds its physics produces."""

    def supports(kind: str) -> frozenset[str]:
        return frozenset(e for e, kinds in shown_by.items() if kind in kinds)

    out = []
    if found:
        kind = "stick_slip" if stick_slips(found) else "hunting"
        out.append(Observation(kind, rattle_sentence(found), supports(kind)))
    if broke:
        out.append(Observation("breakaway", breakaway_sentence(broke), supports("breakaway")))
    return tuple(out)

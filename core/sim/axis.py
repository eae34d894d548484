"""One simulated feed-drive axis: the paper's nominal parameters plus its effects."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from core.dataset import AxisSpec
from core.errors import InputError, require_positive
from core.sim.effects import Effects, Encoders

INITIAL_SIDES = ("auto", "positive", "negative")


@dataclass(frozen=True)
class AxisModel:
    """A full-closed-loop axis (Figs. 11-12 of the seed paper).

    transmission_mm_per_rev is k_a (nominal table travel per motor revolution),
    position_gain_per_s the open-loop position gain K = k_a k_p, backlash_um the width
    b between nut and table (Eq. 5). initial_side says which flank the nut last
    pushed: ``"positive"`` (the table sits at nut - b/2, directly engaged for a
    positive move), ``"negative"`` (at nut + b/2) or ``"auto"`` (the program's
    natural start: directly engaged for round trips and circles, the paper's reverse
    engagement of X for lines).
    """

    name: str = "y"
    transmission_mm_per_rev: float = 6.857
    screw_lead_mm: float = 16.0
    position_gain_per_s: float = 10.0
    backlash_um: float = 0.0
    initial_side: str = "auto"
    effects: Effects = field(default_factory=Effects)
    encoders: Encoders = field(default_factory=Encoders)

    def __post_init__(self) -> None:
        require_positive(f"axis {self.name!r}: transmission_mm_per_rev", self.transmission_mm_per_rev)
        require_positive(f"axis {self.name!r}: screw_lead_mm", self.screw_lead_mm)
        require_positive(f"axis {self.name!r}: position_gain_per_s", self.position_gain_per_s)
        b = float(self.backlash_um)
        if not (math.isfinite(b) and b >= 0):
            raise InputError(f"axis {self.name!r}: backlash_um (={self.backlash_um!r}) must be a finite number >= 0")
        if self.initial_side not in INITIAL_SIDES:
            raise InputError(
                f"axis {self.name!r}: initial_side (={self.initial_side!r}) must be one of {INITIAL_SIDES}"
            )
        if not isinstance(self.effects, Effects):
            raise InputError(f"axis {self.name!r}: effects must be an Effects, got {type(self.effects).__name__}")
        if not isinstance(self.encoders, Encoders):
            raise InputError(f"axis {self.name!r}: encoders must be an Encoders, got {type(self.encoders).__name__}")

    @classmethod
    def from_axis_spec(
        cls,
        spec: AxisSpec,
        backlash_um: float = 0.0,
        *,
        initial_side: str = "auto",
        effects: Effects | None = None,
        encoders: Encoders | None = None,
    ) -> AxisModel:
        """The axis of a dataset's machine description, with a backlash and effects."""
        return cls(
            name=spec.name,
            transmission_mm_per_rev=spec.transmission_mm_per_rev,
            screw_lead_mm=spec.screw_lead_mm,
            position_gain_per_s=spec.position_gain_per_s,
            backlash_um=backlash_um,
            initial_side=initial_side,
            effects=effects if effects is not None else Effects(),
            encoders=encoders if encoders is not None else Encoders(),
        )

    def to_axis_spec(self, travel_mm: tuple[float, float]) -> AxisSpec:
        """The dataset description of this axis with useful travel ``travel_mm``."""
        return AxisSpec(
            name=self.name,
            transmission_mm_per_rev=float(self.transmission_mm_per_rev),
            screw_lead_mm=float(self.screw_lead_mm),
            position_gain_per_s=float(self.position_gain_per_s),
            travel_mm=(float(travel_mm[0]), float(travel_mm[1])),
        )

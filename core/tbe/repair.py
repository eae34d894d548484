"""The backlash a repair must restore the chain below, and why that figure.

A chain restored just below the largest permissible backlash would cross the WARNING
threshold again after a little wear, so the target is the warning level in backlash:
the binding task's backlash limit times the axis' warning fraction. Every place that
tells a maintenance engineer what to do (the alert, the work order, the status, the
dashboard, MTConnect, OPC UA, the CLI) takes its figure and sentence from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from core.errors import InputError


@dataclass(frozen=True)
class RepairTarget:
    """Restore the mean backlash below ``restore_below_um`` (µm)."""

    restore_below_um: float
    backlash_limit_um: float
    warning_fraction: float

    @property
    def explanation(self) -> str:
        """One sentence: why the target is this figure and not the backlash limit."""
        return (f"below the warning level, {self.warning_fraction * 100:g} % of the largest permissible "
                f"backlash {self.backlash_limit_um:.1f} µm, so that the repaired axis does not warn again at once")

    def sentence(self) -> str:
        """The instruction with its reason, as the alert and the work order give it."""
        return f"restore the backlash below {self.restore_below_um:.1f} µm ({self.explanation})"


def stored_repair_target(restore_below_um: float | None, backlash_limit_um: float | None) -> RepairTarget | None:
    """The target a stored work order names (its two figures; the warning fraction is
    their ratio), so its explanation reads as when the order was opened."""
    if restore_below_um is None or backlash_limit_um is None or not backlash_limit_um > 0:
        return None
    return RepairTarget(restore_below_um=float(restore_below_um), backlash_limit_um=float(backlash_limit_um),
                        warning_fraction=float(restore_below_um) / float(backlash_limit_um))


def repair_target(backlash_limit_um: float | None, warning_fraction: float) -> RepairTarget | None:
    """The repair target for an axis whose binding backlash limit is ``backlash_limit_um``
    (µm; None or inf: no task limits the backlash, so there is no target)."""
    if backlash_limit_um is None or not math.isfinite(backlash_limit_um):
        return None
    if backlash_limit_um < 0:
        raise InputError(f"backlash_limit_um (={backlash_limit_um}) must be >= 0")
    if not 0.0 < warning_fraction <= 1.0:
        raise InputError(f"warning_fraction (={warning_fraction}) must be in (0, 1]")
    return RepairTarget(restore_below_um=float(backlash_limit_um) * float(warning_fraction),
                        backlash_limit_um=float(backlash_limit_um), warning_fraction=float(warning_fraction))

"""The instrument options of the commands that build uncertainty budgets (``mebm analyze``,
``mebm measure``, ``mebm export-comp``): the linear scale's accuracy and the thermometer."""

from __future__ import annotations

import argparse

from core.criteria.uncertainty import (
    DEFAULT_SCALE_ACCURACY_UM,
    DEFAULT_SCALE_ACCURACY_UM_PER_M,
    DEFAULT_THERMOMETER_CLASS,
    STEEL_EXPANSION_PER_K,
    THERMOMETER_CLASSES,
    Instruments,
)

OPTIONS = ("scale_accuracy_um", "scale_accuracy_um_per_m", "thermometer_class", "thermal_expansion_per_k")


def add_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("instruments of the uncertainty budget (default: what a run states, else the defaults)")
    g.add_argument("--scale-accuracy-um", type=float, default=None, metavar="UM",
                   help=f"the linear scale's short-range accuracy, ± µm (default {DEFAULT_SCALE_ACCURACY_UM:g})")
    g.add_argument("--scale-accuracy-um-per-m", type=float, default=None, metavar="UM",
                   help="the linear scale's accuracy class, ± µm per metre "
                        f"(default {DEFAULT_SCALE_ACCURACY_UM_PER_M:g})")
    g.add_argument("--thermometer-class", choices=tuple(THERMOMETER_CLASSES), default=None,
                   help=f"IEC 60751 class of the Pt100 thermometer (default {DEFAULT_THERMOMETER_CLASS})")
    g.add_argument("--thermal-expansion-per-k", type=float, default=None, metavar="BETA",
                   help=f"the axis' thermal expansion coefficient, 1/K (default {STEEL_EXPANSION_PER_K:g}, steel)")


def instruments_of(a: argparse.Namespace) -> Instruments | None:
    """The instruments the options give (the defaults for those not given); None without any."""
    given = {k: getattr(a, k) for k in OPTIONS if getattr(a, k, None) is not None}
    return Instruments(**given) if given else None

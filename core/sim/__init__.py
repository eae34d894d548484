"""The feed-drive digital twin: the seed paper's nominal axis model plus real-machine effects.

``simulate(axes, program)`` runs an NC program (:func:`round_trip`, :func:`circle`,
:func:`line`) on :class:`AxisModel` s; each axis carries :class:`Effects` (friction,
compliance, thermal, backlash_profile, cyclic_error, servo_dynamics, sampling_skew,
all off by default) and :class:`Encoders`. The result :class:`SimTrace` converts to
a dataset run (``to_run``). See :mod:`core.sim.engine` for the model and the
integration step.
"""

from core.sim.axis import AxisModel
from core.sim.effects import (
    CATEGORIES,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Encoders,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    parse_effect,
)
from core.sim.engine import SimTrace, simulate
from core.sim.programs import Program, circle, line, round_trip

__all__ = [
    "CATEGORIES",
    "AxisModel",
    "BacklashProfile",
    "Compliance",
    "CyclicError",
    "Effects",
    "Encoders",
    "Friction",
    "Program",
    "SamplingSkew",
    "ServoDynamics",
    "SimTrace",
    "Thermal",
    "circle",
    "line",
    "parse_effect",
    "round_trip",
    "simulate",
]

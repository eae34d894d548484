"""An independent feed-drive plant: benchmark datasets whose model forms the diagnosis does not share.

Written from scratch: it imports neither ``core.sim`` nor the rest of
``core.gap``, integrates its own continuous-time state model with its own fixed-step
scheme (:mod:`.drive`), and carries each effect in a form other than the twin's
(:mod:`.effects` documents every equation and range). :func:`make_plant_case` builds a
two-axis dataset with the case structure of ``core.gap_benchmark`` (:mod:`.case`).

Modules: :mod:`.program` (the CNC interpolator: IPO set-points, jerk filter, circles with
feed-in and lead-out), :mod:`.drive` (the axis model and its integrator, numba),
:mod:`.effects` (nominal machine and effect draws), :mod:`.case` (datasets).
"""

from .case import SMALL_PLANT, PlantCase, PlantSize, make_plant_case
from .effects import LABELS

__all__ = ["LABELS", "SMALL_PLANT", "PlantCase", "PlantSize", "make_plant_case"]

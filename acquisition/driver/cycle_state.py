"""Everything one acquisition cycle knows, in one object made fresh for each cycle.

A driver is configuration plus a link; what a round trip learns on the way (whether the
link ever came up, the last fault recovered from, the wire's read position, the samples
assembled so far) lives here, so nothing of one cycle can leak into the next one run on
the same driver.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from acquisition.driver.trace_assembler import TraceAssembler
from acquisition.types import RoundTripProgram
from core.dataset import AxisSpec


@dataclass
class AcquisitionCycle:
    """One round trip under way. ``wire`` is the wire's own per-cycle state (the Modbus ring
    cursor, the CANopen SYNC reorder buffer), set by the driver's ``_start``."""

    program: RoundTripProgram
    axis: AxisSpec
    t_wall0: float  # monotonic time the cycle began
    ever_connected: bool = False  # the link came up in this cycle (failures before are not retried)
    link_trouble: str | None = None  # last transient fault recovered from
    started: bool = False  # the start command may have gone out: any failure now sends an abort
    temperature0_c: float = float("nan")
    assembler: TraceAssembler | None = None
    wire: Any = field(default=None)

"""CANopen active mode through standard CiA 402 objects, for a drive on a bench.

Like :class:`acquisition.canopen.driver.CanopenDriver` (mebm is the NMT master and the SYNC
producer; TPDO1 = 0x6064, 0x60E4 sub 1 latched on every SYNC), but the round trip is
commanded in Profile Position mode through the standard objects instead of mebm's
manufacturer objects 0x2000-0x2006, so any CiA 402 drive will do:

- device control: controlword 0x6040 = 0x06, 0x07, 0x0F (shutdown, switch on, enable
  operation), statusword 0x6041 checked after each; fault reset = bit 7;
- modes of operation 0x6060 = 1 (Profile Position);
- profile velocity 0x6081 and acceleration/deceleration 0x6083/0x6084 from the round
  trip's feed and acceleration, in increments/s and increments/s² (position factor 1:
  user units are encoder increments; mm of table travel -> increments through k_a and
  0x608F);
- each stroke: target position 0x607A, then controlword bit 4 (new set-point) until the
  statusword acknowledges it (bit 12), then bit 10 (target reached) ends the stroke.

Sequence: move to the start (not recorded), then the recorded round trip: dwell, out
to the reversal, dwell, back to the start, dwell. Dwells are counted in SYNCs (machine
time). Abort: quick stop (controlword 0x02). The table encoder's resolution has no
standard object: it comes from the configuration (``table_nm_per_count``), or 0x2005
when the drive has it.
"""

from __future__ import annotations

import math
import time

from acquisition.canopen import objects as co
from acquisition.canopen.driver import CanopenDriver, SyncOrder
from acquisition.errors import ControllerTimeoutError, ProtocolError
from acquisition.types import AxisState, Command, ControllerStatus, RoundTripProgram
from core.errors import InputError

# phases of the recorded round trip: (what is waited for, what follows)
_IDLE, _APPROACH, _DWELL0, _OUT, _DWELL1, _BACK, _DWELL2, _DONE = range(8)


class CanopenCia402Driver(CanopenDriver):
    """Active mode through CiA 402 Profile Position (see the module docstring)."""

    mode = "sync"

    def __init__(self, channel: str, node_id: int, *, table_nm_per_count: float | None = None, **kwargs):
        super().__init__(channel, node_id, **kwargs)
        if table_nm_per_count is not None and not (math.isfinite(table_nm_per_count) and table_nm_per_count > 0):
            raise InputError(f"table_nm_per_count (={table_nm_per_count}) must be > 0")
        self.table_nm_per_count = table_nm_per_count
        self._phase = _IDLE
        self._phase_until_k = 0
        self._targets: tuple[int, int] = (0, 0)

    def describe(self) -> str:
        return f"canopen://{self.interface}/{self.channel}?node={self.node_id}&mode=active-cia402"

    # -- start-up hooks ----------------------------------------------------------------------------
    def _check_objects(self, sdo) -> None:
        self._sdo("reading the statusword (0x6041)", lambda: sdo[co.STATUSWORD].raw)

    def _table_nm_per_count(self, sdo) -> float:
        if self.table_nm_per_count is not None:
            return float(self.table_nm_per_count)
        try:
            return float(self._sdo("reading the table resolution (0x2005)", lambda: sdo[co.TABLE_NM_PER_COUNT].raw))
        except ProtocolError as exc:
            raise ProtocolError(f"node {self.node_id} has no table encoder resolution (0x2005): give "
                                "table_nm_per_count in the configuration", code=exc.code) from exc

    # -- CiA 402 helpers (worker thread) -----------------------------------------------------------
    def _write(self, what: str, index: int, value: int) -> None:
        sdo = self._node.sdo
        self._sdo(what, lambda: setattr(sdo[index], "raw", int(value)))

    def _statusword(self) -> int:
        sdo = self._node.sdo
        return int(self._sdo("reading the statusword (0x6041)", lambda: sdo[co.STATUSWORD].raw))

    def _wait_status(self, what: str, mask: int, value: int, timeout_s: float) -> int:
        end = time.monotonic() + timeout_s
        while True:
            sw = self._statusword()
            if sw & co.SW_FAULT and not mask & co.SW_FAULT:
                raise ProtocolError(f"node {self.node_id} in FAULT while {what} (statusword 0x{sw:04X})")
            if sw & mask == value:
                return sw
            if time.monotonic() > end:
                raise ControllerTimeoutError(f"node {self.node_id}: {what} not seen within {timeout_s:g} s "
                                             f"(statusword 0x{sw:04X})")
            time.sleep(0.005)

    def _enable(self) -> None:
        for cw, what, mask, val in (
            (co.CW_SHUTDOWN, "READY TO SWITCH ON", 0x6F, 0x21),
            (co.CW_SWITCH_ON, "SWITCHED ON", 0x6F, 0x23),
            (co.CW_ENABLE_OPERATION, "OPERATION ENABLED", 0x6F, 0x27),
        ):
            self._write(f"the controlword 0x{cw:02X}", co.CONTROLWORD, cw)
            self._wait_status(what, mask, val, self.timeout_s)

    def _setpoint(self, target: int) -> None:
        self._write("the target position (0x607A)", co.TARGET_POSITION, target)
        self._write("the new set-point (controlword bit 4)", co.CONTROLWORD, co.CW_ENABLE_OPERATION | co.CW_NEW_SETPOINT)
        self._wait_status("the set-point acknowledge (statusword bit 12)", co.SW_SETPOINT_ACK, co.SW_SETPOINT_ACK,
                          self.timeout_s)
        self._write("the controlword 0x0F", co.CONTROLWORD, co.CW_ENABLE_OPERATION)

    def _counts(self, table_mm: float) -> int:
        return int(round(table_mm / self.cycle.axis.transmission_mm_per_rev * self.scale.counts_per_rev))

    # -- wire -------------------------------------------------------------------------------------
    def _status_blocking(self) -> ControllerStatus:
        sw = self._statusword()
        fault = self._emcy.code if self._emcy is not None else 0
        if sw & co.SW_FAULT:
            state = AxisState.FAULT
        elif self._phase == _IDLE:
            state = AxisState.IDLE
        elif self._phase == _DONE:
            state = AxisState.DONE
        elif not sw & co.SW_OPERATION_ENABLED:
            state = AxisState.ABORTED  # disabled under us (a quick stop or a power stage off)
        else:
            state = self._advance(sw)
        return ControllerStatus(state, fault, float("nan"), self.sync_rate_hz)

    def _advance(self, sw: int) -> AxisState:
        """Step the round trip on: dwell over (SYNCs counted), or the stroke's target reached."""
        with self._sync.lock:
            k = self._sync.k
        reached = bool(sw & co.SW_TARGET_REACHED)
        dwell_syncs = int(math.ceil(self.cycle.program.dwell_s * self.sync_rate_hz))
        if self._phase == _APPROACH and reached:
            # at the start: samples from the next SYNC on are the round trip's
            order: SyncOrder = self.cycle.wire
            order.first = order.next_k = k + 1
            self._phase = _DWELL0
            self._phase_until_k = k + 1 + dwell_syncs
        elif self._phase in (_DWELL0, _DWELL1) and k >= self._phase_until_k:
            self._phase += 1
            self._setpoint(self._targets[1] if self._phase == _OUT else self._targets[0])
        elif self._phase in (_OUT, _BACK) and reached:
            self._phase += 1
            self._phase_until_k = k + dwell_syncs
        elif self._phase == _DWELL2 and k >= self._phase_until_k:
            self._phase = _DONE
            return AxisState.DONE
        return AxisState.RUNNING

    def _command(self, cmd: Command) -> None:
        if cmd == Command.ABORT:
            self._phase = _IDLE
            self._write("the quick stop (controlword 0x02)", co.CONTROLWORD, 0x02)
        elif cmd == Command.ACKNOWLEDGE:
            self._phase = _IDLE
            self._write("the fault reset (controlword 0x00)", co.CONTROLWORD, 0x00)
            self._write("the fault reset (controlword 0x80)", co.CONTROLWORD, co.CW_FAULT_RESET)
            self._write("the controlword 0x00", co.CONTROLWORD, 0x00)

    def _start_blocking(self, program: RoundTripProgram) -> None:
        k_a = self.cycle.axis.transmission_mm_per_rev
        per_mm = self.scale.counts_per_rev / k_a
        velocity = int(round(program.speed_mm_s * per_mm))
        accel = int(round(program.acceleration_mm_s2 * per_mm))
        if velocity < 1 or accel < 1 or velocity > 0xFFFFFFFF or accel > 0xFFFFFFFF:
            raise InputError(f"feed (={program.feed_mm_min} mm/min) or acceleration (={program.acceleration_mm_s2} "
                             "mm/s²) does not fit 0x6081/0x6083 in increments")
        self._write("the mode of operation (0x6060 = 1)", co.MODES_OF_OPERATION, co.MODE_PROFILE_POSITION)
        self._write("the profile velocity (0x6081)", co.PROFILE_VELOCITY, velocity)
        self._write("the profile acceleration (0x6083)", co.PROFILE_ACCELERATION, accel)
        self._write("the profile deceleration (0x6084)", co.PROFILE_DECELERATION, accel)
        self._enable()
        self._targets = (self._counts(program.start_mm), self._counts(program.end_mm))
        # first to the start, not recorded (the round trip's samples begin once it is reached:
        # _advance); the start request must stay within one timeout, so the move is not waited for here
        self._emcy = None
        self._frames.clear()
        self.cycle.wire = SyncOrder(2**62, self.REORDER_HORIZON)
        self._setpoint(self._targets[0])
        self._phase = _APPROACH
        return None

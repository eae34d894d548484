"""Simulated CANopen drive: a canopen ``LocalNode`` whose positions come from a :class:`SimAxis`.

The drive is clocked by SYNC: every SYNC advances its machine time by the
communication cycle period (0x1006) and it answers with TPDO1 (0x6064 motor counts,
0x60E4 sub 1 table counts) latched at that instant, in OPERATIONAL state only.
Program, command, state, temperature and fault code are SDO objects
(docs/canopen-objects.md). Runs on python-can's ``virtual`` bus in-process, or on
``udp_multicast`` to be reachable from another process.

Reply timing, as a hardware drive: each TPDO goes on the wire ``reply_delay_s`` plus a
uniform jitter in ``[0, reply_jitter_s]`` after the SYNC's bus time; one that would
leave later than the synchronous window (0x1007) is discarded (CiA 301) and counted in
``late_discards``. On ``virtual`` the frame is stamped with that wire time (the drive is
hardware: its timing is not the host's thread scheduling, so frames may reach the
driver out of order); on other buses the drive waits until then and the receiver
stamps the frame.
"""

from __future__ import annotations

import collections
import struct
import threading
import time

import can
import canopen
import numpy as np
from canopen.sdo import SdoAbortedError

from acquisition.canopen import objects as co
from acquisition.scale import EncoderScale
from acquisition.sim.axis import SimAxis
from acquisition.sim.canopen import wear as sim_wear
from acquisition.sim.canopen.cia402 import Cia402Motion
from acquisition.sim.twin import Twin
from acquisition.types import AxisState, Command, RoundTripProgram
from core.errors import InputError

ABORT_DEVICE_STATE = 0x08000022  # data cannot be transferred because of the present device state
ABORT_VALUE_RANGE = 0x06090030


class SyncLossTimer:
    """CiA 402 0x6007-style reaction of the simulated drive: a running program stops when
    SYNC stops coming for ``loss_s``.

    Counted on the drive's own timer: each tick without a new SYNC adds the time since the
    previous tick, but at most two ticks' worth. A tick that comes late means the host
    stalled the simulated drive itself (a garbage collection, a starved process); a
    hardware drive runs on through its host's stalls, and SYNCs the stalled host did not
    send are not a loss that drive could have seen.
    """

    def __init__(self, loss_s: float, tick_s: float = 0.05):
        self.loss_s, self.tick_s = float(loss_s), float(tick_s)
        self._last_tick: float | None = None
        self._last_syncs = 0
        self.silent_s = 0.0

    def tick(self, now: float, syncs: int, running: bool) -> bool:
        """One tick at ``now`` (s), with ``syncs`` SYNCs received so far; True: SYNC is lost."""
        if syncs != self._last_syncs or not running or not syncs or self._last_tick is None:
            self.silent_s = 0.0
        else:
            self.silent_s += min(now - self._last_tick, 2 * self.tick_s)
        self._last_tick, self._last_syncs = now, syncs
        if self.silent_s > self.loss_s:
            self.silent_s = 0.0
            return True
        return False


class SimCanopenDrive:
    """A simulated CiA 402 drive on a CAN bus. Use as a context manager or start()/stop()."""

    def __init__(
        self,
        twin: Twin,
        *,
        node_id: int = 5,
        channel: str = "mebm-sim",
        interface: str = "virtual",
        servo_rate_hz: float = 1000.0,
        scale: EncoderScale | None = None,
        faults=(),
        bus_kwargs: dict | None = None,
        reply_delay_s: float = 0.0001,
        reply_jitter_s: float = 0.0002,
        rng: np.random.Generator | None = None,
    ):
        self.node_id = int(node_id)
        self.channel, self.interface = channel, interface
        self.bus_kwargs = dict(bus_kwargs or {})
        self.scale = scale or EncoderScale()
        self.machine_time_s = 0.0
        self.axis = SimAxis(twin, servo_rate_hz=servo_rate_hz, time_scale=1.0, scale=self.scale,
                            faults=faults, clock=lambda: self.machine_time_s)
        self.axis.on_fault = self._on_axis_fault
        self.od = co.object_dictionary(self.node_id, counts_per_rev=self.scale.counts_per_rev,
                                       table_nm_per_count=int(round(self.scale.table_nm_per_count)))
        sim_wear.add_objects(self.od)  # the simulator's wear and repair objects
        self.node = canopen.LocalNode(self.node_id, self.od)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.network: canopen.Network | None = None
        self._period_s = 1e-3
        self._silent_until = 0.0
        self.sync_loss_s = 0.5  # a running program is aborted when SYNC stops for this long
        self._watchdog: threading.Thread | None = None
        self._watchdog_stop = threading.Event()
        self._lost_left = 0
        self._fault_cycle: dict[str, int] = {}
        self.reply_delay_s = float(reply_delay_s)
        self.reply_jitter_s = float(reply_jitter_s)
        if self.reply_delay_s < 0 or self.reply_jitter_s < 0:
            raise InputError(f"reply_delay_s (={reply_delay_s}) and reply_jitter_s (={reply_jitter_s}) must be >= 0")
        self._rng = rng if rng is not None else np.random.default_rng()
        self._window_s = 0.0
        self._held: can.Message | None = None  # a frame held back to be sent after the next (reorder)
        self._dup_left = 0
        self._reorder_left = 0
        self.syncs = 0
        self.tpdos_sent = 0
        self.late_discards = 0
        self.answered: collections.deque = collections.deque(maxlen=100_000)  # SYNC counter bytes answered
        self._timers: list[threading.Timer] = []
        self._init_cia402(twin)

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> "SimCanopenDrive":
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.1
        kwargs = dict(self.bus_kwargs)
        if self.interface == "virtual":
            kwargs.setdefault("preserve_timestamps", True)
        self.network.connect(interface=self.interface, channel=self.channel, **kwargs)
        self.network.add_node(self.node)
        # route SDO requests through a wrapper so faults can make the drive silent or slow
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        self.network.subscribe(co.SYNC_COB_ID, self._on_sync)
        self.network.subscribe(co.rpdo1_cob_id(self.node_id), self._on_rpdo)
        self.network.send_message(0x700 + self.node_id, [0])  # boot-up
        self.node.nmt.state = "PRE-OPERATIONAL"
        self._watchdog_stop.clear()
        self._watchdog = threading.Thread(target=self._watch_sync, name="sim-drive-sync-watchdog", daemon=True)
        self._watchdog.start()
        return self

    def stop(self) -> None:
        self._watchdog_stop.set()
        if self._watchdog is not None:
            self._watchdog.join(1.0)
            self._watchdog = None
        if self.network is not None:
            try:
                self.node.nmt.stop_heartbeat()
                self.network.disconnect()
            finally:
                self.network = None

    def __enter__(self) -> "SimCanopenDrive":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- faults -----------------------------------------------------------------------------------
    def _due(self, kind: str):
        f = self.axis.fault(kind)
        if f is None or self.axis.state != AxisState.RUNNING:
            return None
        if self._fault_cycle.get(kind) == self.axis.cycles_started:
            return None  # already fired in this cycle
        if self.axis.progress() < f.at:
            return None
        self._fault_cycle[kind] = self.axis.cycles_started
        return f

    def _silent(self) -> bool:
        return time.monotonic() < self._silent_until

    def _go_silent(self, for_s: float) -> None:
        self._silent_until = time.monotonic() + min(for_s, 3600.0)
        self.node.nmt.stop_heartbeat()
        hb_raw = self.node.data_store.get(co.PRODUCER_HEARTBEAT, {}).get(0)
        hb = struct.unpack("<H", hb_raw)[0] if hb_raw else 0

        def wake():
            if self.network is not None and hb:
                self.node.nmt.start_heartbeat(hb)

        t = threading.Timer(min(for_s, 3600.0), wake)
        t.daemon = True
        t.start()
        self._timers.append(t)

    def recover(self) -> None:
        """End every injected fault now: speak again, drop delayed replies (tests: the fault
        clears on cue, not after a wall-clock window)."""
        self.axis.clear_faults()
        timers, self._timers = self._timers, []
        for t in timers:
            t.cancel()
        if self._silent_until:
            self._silent_until = 0.0
            hb_raw = self.node.data_store.get(co.PRODUCER_HEARTBEAT, {}).get(0)
            hb = struct.unpack("<H", hb_raw)[0] if hb_raw else 0
            if self.network is not None and hb:
                self.node.nmt.start_heartbeat(hb)

    def _on_axis_fault(self, code: int) -> None:
        if self.network is not None:
            self.node.emcy.send(code, register=0x01)

    # -- CAN callbacks (python-can notifier thread) ------------------------------------------------------
    def _watch_sync(self) -> None:
        """The drive's own SYNC-loss timer (:class:`SyncLossTimer`), ticking on its own thread."""
        timer = SyncLossTimer(self.sync_loss_s)
        while not self._watchdog_stop.wait(timer.tick_s):
            timer.loss_s = self.sync_loss_s
            if timer.tick(time.monotonic(), self.syncs, self.axis.state == AxisState.RUNNING):
                self.axis.abort()  # True only while running

    def _on_sdo_request(self, can_id, data, timestamp):
        if self._silent():
            return
        slow = self.axis.fault("slow")
        if slow is not None and self.axis.state == AxisState.RUNNING and self.axis.progress() >= slow.at:
            t = threading.Timer(float(slow.value("s")), self.node.sdo.on_request, (can_id, data, timestamp))
            t.daemon = True
            t.start()
            self._timers = [x for x in self._timers if x.is_alive()] + [t]
            return
        self.node.sdo.on_request(can_id, data, timestamp)

    def _on_sync(self, can_id, data, timestamp):
        if self._silent() or self.node.nmt.state != "OPERATIONAL":
            return
        self.syncs += 1
        self.machine_time_s += self._period_s
        self.axis.update()
        cia402_position = self._cia402_step()
        drop = self._due("drop")
        if drop is not None:
            self._go_silent(drop.for_s)
            return
        lost = self._due("lost")
        if lost is not None:
            self._lost_left = int(lost.value("n"))
        if self._lost_left > 0:
            self._lost_left -= 1
            return
        for kind in ("duplicate", "reorder"):
            f = self._due(kind)
            if f is not None:
                setattr(self, f"_{'dup' if kind == 'duplicate' else kind}_left", int(f.value("n")))
        motor_rev, table_mm = cia402_position or self.axis.position_at()
        m = int(self.scale.motor_counts(motor_rev))
        t = int(self.scale.table_counts(table_mm))
        t_sync = timestamp or time.time()
        delay_s = self.reply_delay_s + (self._rng.uniform(0.0, self.reply_jitter_s) if self.reply_jitter_s else 0.0)
        if self._window_s and delay_s > self._window_s:
            self.late_discards += 1  # CiA 301: a synchronous PDO is not sent outside the window
            return
        msg = can.Message(arbitration_id=co.tpdo1_cob_id(self.node_id), is_extended_id=False,
                          data=co.encode_tpdo1(m, t), timestamp=t_sync + delay_s)
        if self.interface != "virtual":
            wait_s = t_sync + delay_s - time.time()
            if wait_s > 0:
                time.sleep(wait_s)
            if self._window_s and time.time() - t_sync > self._window_s:
                self.late_discards += 1  # this host was too slow to make the window: a real loss
                return
        if data:
            self.answered.append(int(data[0]))
        if self._reorder_left > 0 and self._held is None:
            self._reorder_left -= 1
            self._held = msg  # goes out after the next one
            return
        self._send(msg)
        if self._held is not None:
            held, self._held = self._held, None
            self._send(held)
        if self._dup_left > 0:
            self._dup_left -= 1
            self._send(msg)

    def _send(self, msg: can.Message) -> None:
        self.network.bus.send(msg)
        self.tpdos_sent += 1

    def _on_read(self, index, subindex, od):
        ax = self.axis
        if self.cia402.engaged and index in (co.POSITION_ACTUAL, co.ADDITIONAL_POSITION):
            m_rev, t_mm = self.cia402.follower.position()
            return int(self.scale.motor_counts(m_rev) if index == co.POSITION_ACTUAL else self.scale.table_counts(t_mm))
        if index in (co.STATUSWORD, co.MODES_DISPLAY):
            return self.cia402.statusword() if index == co.STATUSWORD else self.cia402.mode
        wear = sim_wear.read(ax.twin, index)
        if wear is not None:
            return wear
        if index == co.POSITION_ACTUAL:
            return int(self.scale.motor_counts(ax.position_at()[0]))
        if index == co.ADDITIONAL_POSITION and subindex == 1:
            return int(self.scale.table_counts(ax.position_at()[1]))
        if index == co.AXIS_STATE:
            return int(ax.update())
        if index == co.TEMPERATURE:
            return int(round(ax.twin.temperature_c * 100))
        if index == co.FAULT_CODE:
            return int(ax.fault_code)
        return None

    def _program(self) -> RoundTripProgram:
        def raw(sub):
            return self.node.get_data(co.PROGRAM, sub)

        v = [self.od[co.PROGRAM][s].decode_raw(raw(s)) for s in range(1, 6)]
        return RoundTripProgram(start_mm=v[0] / 1000.0, end_mm=v[1] / 1000.0, feed_mm_min=v[2] / 1000.0,
                                acceleration_mm_s2=float(v[3]), dwell_s=v[4] / 1000.0)

    def _on_write(self, index, subindex, od, data):
        repaired = sim_wear.repair_write(self.axis.twin, index, data)  # the simulator's repair
        if repaired is False:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index in _CIA402_WRITABLE:
            self._cia402_write(index, od.decode_raw(bytes(data)))
        elif index == co.COMM_CYCLE_PERIOD:
            us = struct.unpack("<L", bytes(data))[0]
            if us == 0:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self._period_s = us * 1e-6
        elif index == co.SYNC_WINDOW:
            self._window_s = struct.unpack("<L", bytes(data))[0] * 1e-6
        elif index == co.PROGRAM and subindex == 5:  # the last word of the program: compute it now
            self.node.data_store.setdefault(index, {})[subindex] = bytes(data)  # stored after this callback
            try:
                self.axis.prepare(self._program())
            except InputError:
                pass  # refused when started
        elif index == co.COMMAND:
            cmd = struct.unpack("<H", bytes(data))[0]
            if cmd == Command.START:
                self.cia402.release()
                try:
                    program = self._program()
                except InputError:
                    raise SdoAbortedError(ABORT_VALUE_RANGE) from None
                try:
                    self.axis.start(program)
                except InputError:
                    raise SdoAbortedError(ABORT_DEVICE_STATE) from None
            elif cmd == Command.ABORT:
                self.axis.abort()
            elif cmd == Command.ACKNOWLEDGE:
                self.axis.acknowledge()

    # -- CiA 402 position control (acquisition/sim/canopen/cia402.py) ------------------------------------------
    def _init_cia402(self, twin: Twin) -> None:
        self.cia402 = Cia402Motion(twin, self.scale)
        self._cia402_lock = threading.Lock()

    def _hold(self) -> tuple[float, float]:
        return self.axis.position_at()

    def _cia402_write(self, index: int, value: int) -> None:
        with self._cia402_lock:
            self.cia402.write(index, value, self._hold())

    def _on_rpdo(self, can_id, data, timestamp) -> None:
        """RPDO1 (controlword, target position) from a CNC master, applied on the next SYNC."""
        if self._silent() or self.node.nmt.state != "OPERATIONAL" or len(data) < co.RPDO_STRUCT.size:
            return
        cw, target = co.decode_rpdo1(bytes(data))
        with self._cia402_lock:
            self.cia402.rpdo(cw, target, self._hold())

    def _cia402_step(self) -> tuple[float, float] | None:
        """Positions latched at this SYNC when CiA 402 moves the axis, else None."""
        with self._cia402_lock:
            if not self.cia402.engaged:
                return None
            return self.cia402.step(self._period_s)


_CIA402_WRITABLE = frozenset({co.CONTROLWORD, co.MODES_OF_OPERATION, co.TARGET_POSITION, co.PROFILE_VELOCITY,
                              co.PROFILE_ACCELERATION, co.PROFILE_DECELERATION, co.POSITION_WINDOW})

"""CANopen driver (canopen on python-can): SYNC-latched TPDO acquisition from a CiA 402 drive.

Only the wire lives here; the measurement loop is :class:`acquisition.driver.base.ControllerDriver`.
The driver produces SYNC at the measurement rate (its own thread); the drive answers
each SYNC with TPDO1 = (0x6064 motor, 0x60E4 sub 1 table), both latched at that SYNC,
within the synchronous window (0x1007, written at start-up). A TPDO is paired with its
SYNC on bus timestamps by :class:`acquisition.canopen.sync_matcher.SyncMatcher`; frames that
arrive out of order are put back in SYNC order; a SYNC without its TPDO is a lost
sample (a counter gap), never filled in. The bus is injected (``bus_factory``). Program, command and state go through SDO; heartbeat and EMCY
are watched; an EMCY during a cycle aborts it with the error code in the reason.
"""

from __future__ import annotations

import asyncio
import collections
import threading
import time
from collections.abc import Callable

import can
import canopen
import numpy as np
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from acquisition.canopen import objects as co
from acquisition.driver.base import BlockingLinkDriver, raise_device_fault
from acquisition.errors import (
    ControllerConnectionError,
    ControllerTimeoutError,
    DeviceFaultError,
    ProtocolError,
)
from acquisition.scale import EncoderScale
from acquisition.canopen.sync_matcher import SyncMatcher, sync_counter_byte
from acquisition.types import AxisState, Command, ControllerStatus, RoundTripProgram, SampleBlock
from core.errors import InputError, require_positive

try:  # python-can's base error; canopen re-raises bus errors as can.CanError
    from can import CanError
except ImportError:  # pragma: no cover
    CanError = OSError


class _SyncProducer(threading.Thread):
    """Sends SYNC (with its 1..240 counter byte) every ``period_s``; pairs the TPDOs that answer.

    Each SYNC is stamped with the wall-clock time it is handed to the bus and recorded in
    a :class:`SyncMatcher`; TPDOs are paired on their bus timestamps (the receive stamps a
    socketcan or udp_multicast bus gives them). The next SYNC never goes out sooner than
    0.9 period (and never within the window) after the previous one was sent: after a
    stall the producer does not burst to catch up, and a reply sent within the window of
    its SYNC has the rest of the period as margin before the next SYNC on a bus that
    stamps frames on arrival.
    """

    def __init__(self, bus, period_s: float, start_k: int, window_s: float):
        super().__init__(name="mebm-sync", daemon=True)
        self.bus, self.period_s, self.window_s = bus, period_s, window_s
        self.min_gap_s = max(window_s, 0.9 * period_s)
        self.k = start_k
        self.matcher = SyncMatcher(window_s, history=4096)
        self.lock = threading.Lock()
        self.stop_event = threading.Event()
        self.error: Exception | None = None

    def run(self) -> None:
        next_t = time.perf_counter()
        while not self.stop_event.is_set():
            now = time.perf_counter()
            if now < next_t:
                delay = next_t - now
                if delay > 0.002:
                    self.stop_event.wait(delay - 0.001)
                else:
                    time.sleep(0 if delay < 2e-4 else delay / 2)
                continue
            with self.lock:
                self.k += 1
                t_wall = time.time()
                self.matcher.sync(self.k, t_wall)
            try:
                self.bus.send(can.Message(arbitration_id=co.SYNC_COB_ID, is_extended_id=False,
                                          data=[sync_counter_byte(self.k)], timestamp=t_wall))
            except Exception as exc:  # noqa: BLE001 - reported by the driver's next drain
                self.error = exc
                return
            sent = time.perf_counter()
            next_t = max(next_t + self.period_s, sent + self.min_gap_s)
            if sent - next_t > 20 * self.period_s:  # fell far behind (host stalled): do not burst
                next_t = sent

    def echoed(self, counter: int, timestamp: float) -> None:
        """Our own SYNC came back from the bus (loopback): its bus time replaces the send time."""
        with self.lock:
            k = self.k - (self.k - counter) % 240  # the latest SYNC sent with that counter value
            if k >= 1:
                self.matcher.restamp(k, timestamp)

    def pair(self, timestamp: float, payload) -> tuple[int, object] | None:
        with self.lock:
            return self.matcher.frame(timestamp, payload)

    def stats(self) -> dict[str, int]:
        with self.lock:
            m = self.matcher
            return {"sent": self.k, "matched": m.matched, "late": m.late, "duplicates": m.duplicates}


class CanopenDriver(BlockingLinkDriver):
    protocol = "canopen"
    mode = "sync"
    connect_exchanges = 15  # SDO reads/writes of the start-up; the first unanswered one ends it
    #: SYNCs answered after a missing one before it is given up as lost (reordered frames wait)
    REORDER_HORIZON = 32

    def __init__(self, channel: str, node_id: int, *, interface: str = "virtual", sync_rate_hz: float = 250.0,
                 time_scale: float = 1.0, heartbeat_ms: int = 100, bus_kwargs: dict | None = None,
                 status_interval_s: float = 0.05, sync_window_s: float | None = None,
                 bus_factory: Callable[[], can.BusABC] | None = None, **kwargs):
        super().__init__(**kwargs)
        if not 1 <= int(node_id) <= 127:
            raise InputError(f"node (={node_id}) must be a CANopen node id 1..127")
        self.channel, self.node_id, self.interface = channel, int(node_id), interface
        self.sync_rate_hz = require_positive("sync_rate_hz", sync_rate_hz)
        # time_scale > 1 only for simulated drives: SYNC is sent faster than its machine period
        self.time_scale = require_positive("time_scale", time_scale)
        self.heartbeat_ms = int(heartbeat_ms)
        self.bus_kwargs = dict(bus_kwargs or {})
        # the bus is injected (canopen takes it as an argument): a factory, since every
        # reconnect needs a fresh one (closing the network shuts its bus down)
        self.bus_factory = bus_factory or self._open_bus
        self.status_interval_s = status_interval_s
        # synchronous window (CiA 301 0x1007, written to the drive): a TPDO is paired with the
        # latest SYNC before its bus timestamp only within this long after it. Default half the
        # SYNC period; it must be shorter than the period so windows never overlap.
        sync_period_s = 1.0 / (self.sync_rate_hz * self.time_scale)
        self.sync_window_s = sync_window_s if sync_window_s else 0.5 * sync_period_s
        if not 0 < self.sync_window_s < sync_period_s:
            raise InputError(f"sync_window_s (={self.sync_window_s:g}) must be > 0 and shorter than the SYNC "
                             f"period ({sync_period_s:g} s)")
        self.servo_rate_hz = self.sync_rate_hz
        self._network = None
        self._node = None
        self._sync: _SyncProducer | None = None
        self._k = 0
        self._frames: collections.deque = collections.deque()
        self._emcy = None
        self._last_hb = 0.0
        self.sync_stats: dict[str, int] = {}  # SYNCs sent, TPDOs paired, late and duplicate ones (last link)
        self.scale: EncoderScale | None = None

    def describe(self) -> str:
        return f"canopen://{self.interface}/{self.channel}?node={self.node_id}"

    # -- blocking helpers (run in a worker thread) -----------------------------------------------------
    def _sdo(self, what: str, fn):
        try:
            return fn()
        except SdoCommunicationError as exc:
            raise ControllerTimeoutError(
                f"no SDO answer from CANopen node {self.node_id} on {self.interface}/{self.channel} while {what}: "
                "check the node id and that the drive is powered and on the bus"
            ) from exc
        except SdoAbortedError as exc:
            raise ProtocolError(f"node {self.node_id} refused {what}: {exc}", code=exc.code) from exc
        except (CanError, OSError) as exc:
            raise ControllerConnectionError(f"CAN bus {self.interface}/{self.channel}: {exc}") from exc

    def _open_bus(self) -> can.BusABC:
        kwargs = dict(self.bus_kwargs)
        if self.interface == "virtual":
            # the SYNC's bus time is the stamp the SYNC thread recorded, as a real bus would
            # stamp it on the wire; TPDOs keep the stamp their sender put on the wire
            kwargs.setdefault("preserve_timestamps", True)
        if self.interface in ("virtual", "socketcan"):
            # our own SYNCs come back with their bus timestamps (udp_multicast loops them
            # back anyway); a bus that does not echo falls back on the time before sending
            kwargs.setdefault("receive_own_messages", True)
        return can.Bus(interface=self.interface, channel=self.channel, **kwargs)

    def _connect_blocking(self) -> None:
        try:
            net = canopen.Network(self.bus_factory())
            net.NOTIFIER_CYCLE = 0.1  # a short receive cycle so closing takes ~0.1 s, not 1 s
            net.connect()
        except (CanError, OSError, ValueError, ImportError) as exc:
            raise ControllerConnectionError(
                f"cannot open CAN interface {self.interface!r} channel {self.channel!r}: {exc}"
            ) from exc
        self._network = net
        node = canopen.RemoteNode(self.node_id, co.object_dictionary(self.node_id))
        net.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = max(0.6 * self.timeout_s, 0.05)
        node.sdo.MAX_RETRIES = 1  # one attempt: canopen counts the first try (0 would loop forever)
        self._node = node
        sdo = node.sdo
        dev = self._sdo("reading the device type", lambda: sdo[co.DEVICE_TYPE].raw)
        if dev & 0xFFFF != co.DEVICE_TYPE_CIA402 & 0xFFFF:
            raise ProtocolError(f"node {self.node_id} is not a CiA 402 drive (device type 0x{dev:08X})")
        self._check_objects(sdo)
        mapping = self._sdo("reading the TPDO1 mapping", lambda: tuple(sdo[co.TPDO1_MAP][s].raw for s in (0, 1, 2)))
        ttype = self._sdo("reading the TPDO1 transmission type", lambda: sdo[co.TPDO1_COMM][2].raw)
        if mapping != (2, *co.TPDO1_MAPPING) or ttype != 1:
            raise ProtocolError(
                f"TPDO1 of node {self.node_id} maps {[hex(m) for m in mapping[1:]]} (type {ttype}); mebm needs "
                "0x6064 and 0x60E4 sub 1 together, sent on every SYNC (docs/canopen-objects.md)"
            )
        inc = self._sdo("reading the encoder resolution", lambda: (sdo[co.ENCODER_RESOLUTION][1].raw,
                                                                   sdo[co.ENCODER_RESOLUTION][2].raw))
        nm = self._table_nm_per_count(sdo)
        self.scale = EncoderScale(counts_per_rev=inc[0] / max(inc[1], 1), table_nm_per_count=float(nm))
        period_us = int(round(1e6 / self.sync_rate_hz))
        self._sdo("setting the SYNC period (0x1006)", lambda: setattr(sdo[co.COMM_CYCLE_PERIOD], "raw", period_us))
        # the drive's own window, in wall-clock µs of the SYNC it actually receives
        window_us = max(1, int(self.sync_window_s * 1e6))
        self._sdo("setting the synchronous window (0x1007)", lambda: setattr(sdo[co.SYNC_WINDOW], "raw", window_us))
        self._sdo("setting the heartbeat (0x1017)", lambda: setattr(sdo[co.PRODUCER_HEARTBEAT], "raw", self.heartbeat_ms))
        self._last_hb = time.monotonic()
        node.nmt.add_heartbeat_callback(self._on_heartbeat)
        node.emcy.add_callback(self._on_emcy)
        net.subscribe(co.tpdo1_cob_id(self.node_id), self._on_tpdo)
        net.subscribe(co.SYNC_COB_ID, self._on_sync_echo)
        node.nmt.state = "OPERATIONAL"
        self._sync = _SyncProducer(net.bus, 1.0 / (self.sync_rate_hz * self.time_scale), self._k, self.sync_window_s)
        self._sync.start()

    def _check_objects(self, sdo) -> None:
        """The drive offers what this mode commands (here: mebm's objects 0x2000-0x2006)."""
        ver = self._sdo("reading the mebm objects version", lambda: sdo[co.OBJECTS_VERSION_IDX].raw)
        if ver != co.OBJECTS_VERSION:
            raise ProtocolError(f"node {self.node_id} has mebm objects version {ver}, mebm speaks {co.OBJECTS_VERSION}")

    def _table_nm_per_count(self, sdo) -> float:
        return float(self._sdo("reading the table resolution", lambda: sdo[co.TABLE_NM_PER_COUNT].raw))

    def _close_blocking(self) -> None:
        sync, self._sync = self._sync, None
        if sync is not None:
            sync.stop_event.set()
            sync.join(1.0)
            self._k = sync.k
            self.sync_stats = sync.stats()
        net, self._network = self._network, None
        if net is not None:
            try:
                if self._node is not None:
                    self._node.nmt.state = "PRE-OPERATIONAL"
            except Exception:  # noqa: BLE001 - closing must never fail
                pass
            try:
                net.disconnect()
            except Exception:  # noqa: BLE001
                pass
        self._node = None

    # -- callbacks (notifier thread) -------------------------------------------------------------------
    def _on_heartbeat(self, state) -> None:
        self._last_hb = time.monotonic()

    def _on_emcy(self, err) -> None:
        if self._emcy is None and err.code != 0:
            self._emcy = err

    def _on_sync_echo(self, can_id, data, timestamp) -> None:
        sync = self._sync
        if sync is not None and data and timestamp:
            sync.echoed(int(data[0]), timestamp)

    def _on_tpdo(self, can_id, data, timestamp) -> None:
        sync = self._sync
        if sync is None:
            return
        paired = sync.pair(timestamp or 0.0, bytes(data))
        if paired is not None:  # otherwise counted by the matcher; a lost sample by the gap it leaves
            m, t = co.decode_tpdo1(paired[1])
            self._frames.append((paired[0], m, t))

    # -- wire -----------------------------------------------------------------------------------------
    def _status_blocking(self) -> ControllerStatus:
        sdo = self._node.sdo
        state = self._sdo("reading the axis state", lambda: sdo[co.AXIS_STATE].raw)
        fault = self._sdo("reading the fault code", lambda: sdo[co.FAULT_CODE].raw)
        temp = self._sdo("reading the temperature", lambda: sdo[co.TEMPERATURE].raw)
        if state not in AxisState._value2member_map_:
            raise ProtocolError(f"node {self.node_id}: unknown axis state {state}")
        return ControllerStatus(AxisState(state), fault, temp / 100.0, self.sync_rate_hz)

    async def _read_status(self) -> ControllerStatus:
        self._check_link()
        return await asyncio.to_thread(self._status_blocking)

    def _command(self, cmd: Command) -> None:
        sdo = self._node.sdo
        self._sdo(f"the {cmd.name.lower()} command", lambda: setattr(sdo[co.COMMAND], "raw", int(cmd)))

    def _start_blocking(self, program: RoundTripProgram) -> int:
        sdo = self._node.sdo
        values = (round(program.start_mm * 1000), round(program.end_mm * 1000), round(program.feed_mm_min * 1000),
                  min(int(round(program.acceleration_mm_s2)), 65535), min(int(round(program.dwell_s * 1000)), 65535))
        for sub, v in enumerate(values, start=1):
            self._sdo("writing the round-trip program", lambda s=sub, v=v: setattr(sdo[co.PROGRAM][s], "raw", v))
        self._emcy = None
        # the first sample is the first SYNC after the start command went out: earlier ones
        # may already be answered from the running program; the drive answers the ones before
        # it takes effect from the axis at rest, where the program begins
        with self._sync.lock:
            first = self._sync.k + 1
        self._frames.clear()  # before the start: frames of SYNC >= first may arrive any moment
        self.cycle.wire = SyncOrder(first, self.REORDER_HORIZON)
        self._command(Command.START)
        return first

    async def _start(self, program: RoundTripProgram) -> int | None:
        self._check_link()
        return await asyncio.to_thread(self._start_blocking, program)

    async def _abort(self) -> None:
        await asyncio.to_thread(self._command, Command.ABORT)

    async def _acknowledge(self) -> None:
        self._emcy = None
        await asyncio.to_thread(self._command, Command.ACKNOWLEDGE)

    def _check_link(self) -> None:
        if self._node is None or self._sync is None:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        if self._sync.error is not None:
            raise ControllerConnectionError(f"cannot send SYNC on {self.interface}/{self.channel}: {self._sync.error}")
        silent = time.monotonic() - self._last_hb
        if self.heartbeat_ms and silent > 3 * self.heartbeat_ms / 1000.0 + 0.2:
            raise ControllerConnectionError(
                f"heartbeat of node {self.node_id} lost for {silent:.2f} s (drive off, cable or bus-off?)"
            )

    @property
    def frames_too_late(self) -> int:
        """TPDOs of the cycle under way (or the last one) paired after their SYNC was given up."""
        c = self._cycle or self.last_cycle
        return c.wire.frames_too_late if c is not None and isinstance(c.wire, SyncOrder) else 0

    async def _drain(self) -> SampleBlock:
        if self._emcy is not None:
            e = self._emcy
            raise DeviceFaultError(f"drive node {self.node_id} sent EMCY ({e.get_desc() or 'fault'})", code=e.code)
        self._check_link()
        order: SyncOrder = self.cycle.wire
        finished = False
        now = time.monotonic()
        if now - order.last_status >= self.status_interval_s:
            order.last_status = now
            status = await asyncio.to_thread(self._status_blocking)
            if status.state == AxisState.DONE:
                finished = True
            elif status.state != AxisState.RUNNING:
                if self._emcy is not None:
                    e = self._emcy
                    raise DeviceFaultError(f"drive node {self.node_id} sent EMCY ({e.get_desc() or 'fault'})", code=e.code)
                raise_device_fault(status, self.describe(), self.link_trouble)
        # frames are taken only after the status read, which may time out: a retry then finds
        # them still queued (nothing read is lost), and a DONE status covers every frame taken
        while self._frames:
            order.take(*self._frames.popleft())
        frames = order.release(finished)
        if not frames:
            return SampleBlock.empty(finished)
        arr = np.asarray(frames, dtype=np.int64)
        return SampleBlock(arr[:, 0], self.scale.motor_rev(arr[:, 1]), self.scale.table_mm(arr[:, 2]), finished=finished)


class SyncOrder:
    """One cycle's paired TPDOs put back in SYNC order (per cycle, in ``cycle.wire``).

    A missing SYNC holds back the later ones until ``horizon`` later SYNCs have been
    answered (its frame may be on its way, reordered); then it is given up as lost (a
    counter gap, counted by the trace assembler). At the end all go.
    """

    def __init__(self, first: int, horizon: int):
        self.first = first  # SYNC of the first sample: earlier ones answer SYNCs before the start
        self.next_k = first
        self.horizon = horizon
        self.buf: dict[int, tuple[int, int]] = {}  # paired frames not yet released, by SYNC
        self.frames_too_late = 0  # paired, but after their SYNC was given up as lost
        self.last_status = 0.0  # monotonic time of the last status read while draining

    def take(self, k: int, m: int, t: int) -> None:
        if k < self.first:
            return
        if k < self.next_k:
            self.frames_too_late += 1
        elif k not in self.buf:
            self.buf[k] = (m, t)

    def release(self, finished: bool) -> list[tuple[int, int, int]]:
        out = []
        buf = self.buf
        while buf:
            if self.next_k in buf:
                m, t = buf.pop(self.next_k)
                out.append((self.next_k, m, t))
                self.next_k += 1
                continue
            if not finished and max(buf) - self.next_k < self.horizon:
                break
            self.next_k = min(buf)  # the SYNCs before it are lost
        return out

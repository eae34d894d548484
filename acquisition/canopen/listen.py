"""CANopen listen-only: mebm beside a CNC master, sending no frame at all.

The CNC is the NMT master and the SYNC producer; its drive answers every SYNC with a
TPDO carrying 0x6064 (motor) and 0x60E4 sub 1 (table), latched at that SYNC. mebm
opens the bus, hears both, and pairs each TPDO with the latest SYNC within the
synchronous window on their bus timestamps (:class:`acquisition.canopen.sync_matcher.SyncMatcher`),
exactly as in the active mode, but the SYNCs are the master's. It sends no NMT, no
SYNC, no SDO, no heartbeat: the bus it opens is wrapped so that a send raises (a bug,
never a frame). The mapping comes from the configuration or the drive's EDS/DCF
(:mod:`acquisition.canopen.mapping`).

SYNCs are numbered from their CiA 301 counter byte when the master sends one (a SYNC
this host missed is then a counter gap, a lost sample), else from their spacing
(a gap of 2.5 periods is two SYNCs, one of them missed). A SYNC heard without its TPDO
is a lost sample too; nothing is interpolated.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace

import can
import numpy as np

from acquisition.canopen.mapping import ListenMapping
from acquisition.driver.base import BlockingLinkDriver
from acquisition.errors import (
    ControllerConnectionError,
    ControllerTimeoutError,
    DeviceFaultError,
    DriverMisuseError,
    LostSamplesError,
)
from acquisition.canopen.sync_matcher import SYNC_COUNTER_MAX, SyncMatcher
from acquisition.types import AcquiredTrace, AxisState, ControllerStatus, SampleBlock
from core.errors import InputError

try:
    from can import CanError
except ImportError:  # pragma: no cover
    CanError = OSError


class ListenOnlyBusError(DriverMisuseError):
    """Something tried to send on a bus opened listen-only (a bug in mebm: nothing was sent)."""


class ListenOnlyBus:
    """A python-can bus whose ``send`` refuses: everything else is passed through."""

    def __init__(self, bus: can.BusABC):
        self._bus = bus
        self.sends_refused = 0

    def send(self, msg, timeout=None):  # noqa: ARG002
        self.sends_refused += 1
        raise ListenOnlyBusError(f"listen-only: refused to send CAN frame 0x{msg.arbitration_id:03X}")

    def __getattr__(self, name):
        return getattr(self._bus, name)

    def __iter__(self):
        return iter(self._bus)


class SyncListener:
    """Numbers the master's SYNCs and pairs the drive's TPDOs with them (notifier thread).

    ``wall_period_s``: expected SYNC spacing on the host clock (None: learned from the
    first SYNCs); ``window_s``: synchronous window (None: half the spacing).
    """

    LEARN_SYNCS = 16

    def __init__(self, mapping: ListenMapping, *, wall_period_s: float | None = None, window_s: float | None = None,
                 emcy_cob_id: int | None = None):
        self.mapping = mapping
        self.emcy_cob_id = emcy_cob_id
        self.emcy: tuple[int, bytes] | None = None  # the first fault EMCY heard (error code, frame)
        self.wall_period_s = wall_period_s
        self.window_s = window_s
        self.lock = threading.Lock()
        self.k = 0
        self._last_counter: int | None = None
        self._last_t: float | None = None
        self._learn: list[float] = []
        self.matcher: SyncMatcher | None = None
        self.frames: deque = deque()  # (k, motor counts, table counts)
        self.syncs_heard = 0
        self.tpdos_heard = 0
        self.short_frames = 0
        self.syncs_missed = 0  # counter or spacing gaps: SYNCs this host did not hear
        self.first_sync_t: float | None = None
        self.first_tpdo_t: float | None = None

    def __call__(self, msg: can.Message) -> None:  # a can.Listener is any callable
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        cob = msg.arbitration_id
        t = msg.timestamp or time.time()
        with self.lock:
            if cob == self.mapping.sync_cob_id:
                self._sync(bytes(msg.data), t)
            elif cob == self.mapping.tpdo_cob_id:
                self._tpdo(bytes(msg.data), t)
            elif cob == self.emcy_cob_id and len(msg.data) >= 2 and self.emcy is None:
                code = int.from_bytes(bytes(msg.data[:2]), "little")
                if code:  # 0x0000: error reset / no error
                    self.emcy = (code, bytes(msg.data))

    def _sync(self, data: bytes, t: float) -> None:
        self.syncs_heard += 1
        if self.first_sync_t is None:
            self.first_sync_t = t
        step = 1
        if data and 1 <= data[0] <= SYNC_COUNTER_MAX:
            c = data[0]
            if self._last_counter is not None:
                step = (c - self._last_counter) % SYNC_COUNTER_MAX or SYNC_COUNTER_MAX
            self._last_counter = c
        elif self._last_t is not None and self.wall_period_s:
            step = max(1, int(round((t - self._last_t) / self.wall_period_s)))
        if self._last_t is not None and self.wall_period_s is None:
            self._learn.append(t - self._last_t)
            if len(self._learn) >= self.LEARN_SYNCS:
                self.wall_period_s = float(np.median(self._learn))
        if self._last_t is not None and t < self._last_t:
            t = self._last_t  # a host stamp out of order: keep the SYNCs ordered
        self._last_t = t
        if self.matcher is None:
            if self.wall_period_s is None and self.window_s is None:
                return  # still learning the spacing: these SYNCs are not used
            window = self.window_s or 0.5 * self.wall_period_s
            self.matcher = SyncMatcher(window, history=4096)
        self.syncs_missed += step - 1
        self.k += step
        self.matcher.sync(self.k, t)

    def _tpdo(self, data: bytes, t: float) -> None:
        self.tpdos_heard += 1
        if self.first_tpdo_t is None:
            self.first_tpdo_t = t
        if self.matcher is None:
            return
        if len(data) < self.mapping.min_length:
            self.short_frames += 1
            return
        paired = self.matcher.frame(t, data)
        if paired is not None:
            m, tc = self.mapping.decode(paired[1])
            self.frames.append((paired[0], m, tc))

    def stats(self) -> dict[str, int]:
        with self.lock:
            m = self.matcher
            return {"syncs_heard": self.syncs_heard, "syncs_missed": self.syncs_missed,
                    "tpdos_heard": self.tpdos_heard, "matched": m.matched if m else 0,
                    "late": m.late if m else 0, "duplicates": m.duplicates if m else 0,
                    "short_frames": self.short_frames}


class CanopenListenWire:
    """The bus side of listen-only: open, listen, hand over paired samples in SYNC order.

    ``sync_rate_hz``: the machine's SYNC rate (the time base of the samples); None takes
    the mapping's (a DCF's 0x1006), else the rate measured on the bus. ``time_scale`` as
    for the active driver (simulated drives only: SYNC runs that many times faster than
    its machine period).
    """

    REORDER_HORIZON = 32

    def __init__(self, channel: str, mapping: ListenMapping, *, interface: str = "socketcan",
                 sync_rate_hz: float | None = None, time_scale: float = 1.0, window_s: float | None = None,
                 bus_kwargs: dict | None = None, bus_factory: Callable[[], can.BusABC] | None = None,
                 emcy_cob_id: int | None = None):
        self.channel, self.interface, self.mapping = channel, interface, mapping
        self.emcy_cob_id = emcy_cob_id
        if sync_rate_hz is None and mapping.sync_period_s:
            sync_rate_hz = 1.0 / mapping.sync_period_s
        if sync_rate_hz is not None and not sync_rate_hz > 0:
            raise InputError(f"sync_rate_hz (={sync_rate_hz}) must be > 0")
        if not time_scale > 0:
            raise InputError(f"time_scale (={time_scale}) must be > 0")
        self.sync_rate_hz, self.time_scale = sync_rate_hz, time_scale
        self.window_s = window_s or mapping.window_s
        self.bus_kwargs = dict(bus_kwargs or {})
        self.bus_factory = bus_factory or self._open_bus
        self.bus: ListenOnlyBus | None = None
        self.notifier: can.Notifier | None = None
        self.listener: SyncListener | None = None
        self.last_stats: dict[str, int] = {}

    def describe(self) -> str:
        return f"canopen://{self.interface}/{self.channel}?mode=listen-only"

    def _open_bus(self) -> can.BusABC:
        kwargs = dict(self.bus_kwargs)
        if self.interface == "virtual":
            kwargs.setdefault("preserve_timestamps", True)
        return can.Bus(interface=self.interface, channel=self.channel, **kwargs)

    def open(self) -> None:
        self.close()
        wall = 1.0 / (self.sync_rate_hz * self.time_scale) if self.sync_rate_hz else None
        self.listener = SyncListener(self.mapping, wall_period_s=wall, window_s=self.window_s,
                                     emcy_cob_id=self.emcy_cob_id)
        try:
            self.bus = ListenOnlyBus(self.bus_factory())
            self.notifier = can.Notifier(self.bus._bus, [self.listener], timeout=0.1)
        except (CanError, OSError, ValueError, ImportError) as exc:
            self.close()
            raise ControllerConnectionError(
                f"cannot open CAN interface {self.interface!r} channel {self.channel!r}: {exc}") from exc

    def wait_for_traffic(self, timeout_s: float) -> None:
        """Until the master's SYNC and the drive's TPDO have both been heard (typed failures)."""
        end = time.monotonic() + timeout_s
        li = self.listener
        while time.monotonic() < end:
            if li.first_sync_t is not None and li.first_tpdo_t is not None and li.matcher is not None:
                if self.sync_rate_hz is None:
                    self.sync_rate_hz = 1.0 / (li.wall_period_s * self.time_scale)
                return
            time.sleep(0.01)
        m = self.mapping
        if li.first_sync_t is None:
            raise ControllerTimeoutError(
                f"listen-only on {self.interface}/{self.channel}: no SYNC (COB-ID 0x{m.sync_cob_id:03X}) heard in "
                f"{timeout_s:g} s: is the CNC master in OPERATIONAL and producing SYNC?")
        if li.first_tpdo_t is None:
            raise ControllerTimeoutError(
                f"listen-only on {self.interface}/{self.channel}: SYNC heard but no TPDO 0x{m.tpdo_cob_id:03X} in "
                f"{timeout_s:g} s: check the node id and the PDO mapping ({m.source})")
        raise ControllerTimeoutError(
            f"listen-only on {self.interface}/{self.channel}: too few SYNCs in {timeout_s:g} s to learn their "
            "period: give sync_rate_hz (or a DCF with 0x1006)")

    def close(self) -> None:
        if self.listener is not None:
            self.last_stats = self.listener.stats()
        notifier, self.notifier = self.notifier, None
        if notifier is not None:
            try:
                notifier.stop(0.5)
            except Exception:  # noqa: BLE001 - closing must never fail
                pass
        bus, self.bus = self.bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass

    def take(self) -> list[tuple[int, int, int]]:
        """Every paired (SYNC number, motor counts, table counts) since the last take."""
        li = self.listener
        out = []
        if li is None:
            return out
        while li.frames:
            out.append(li.frames.popleft())
        return out

    def samples(self, frames: list[tuple[int, int, int]], finished: bool = False) -> SampleBlock:
        if not frames:
            return SampleBlock.empty(finished)
        arr = np.asarray(frames, dtype=np.int64)
        cpr, nm = self.mapping.counts_per_rev, self.mapping.table_nm_per_count
        k = arr[:, 0]
        return SampleBlock(k, arr[:, 1] / cpr, arr[:, 2] * (nm * 1e-6), finished=finished,
                           time_s=k / float(self.sync_rate_hz))


class CanopenListenDriver(BlockingLinkDriver):
    """Listen-only CANopen: samples the master's SYNC-latched TPDOs; starts, stops and asks nothing.

    The round trip is the CNC's: it is cut from the stream passively. Status, start,
    abort and acknowledge do not exist here (they would need a frame on the bus).
    """

    protocol = "canopen"
    mode = "sync"  # SYNC-latched, numbered by SYNC: a gap is a lost sample
    supports_passive = True
    has_running_flag = False  # CiA 402 has no "program running" object: the positions tell
    REORDER_HORIZON = 32
    # opening the bus, then one timeout_s for the master's traffic: the link's budget leaves
    # the bus' opening a timeout_s of its own and one more, so on a busy host the traffic
    # wait still ends in its own typed error (no SYNC, no TPDO), never in the link's
    # generic "no answer"
    connect_exchanges = 3

    def __init__(self, channel: str, node_id: int, *, mapping: ListenMapping, interface: str = "socketcan",
                 sync_rate_hz: float | None = None, time_scale: float = 1.0, window_s: float | None = None,
                 bus_kwargs: dict | None = None, bus_factory: Callable[[], can.BusABC] | None = None, **kwargs):
        kwargs.setdefault("timeout_s", 5.0)  # the first SYNC and TPDO may take a while on a busy master
        if kwargs.setdefault("trigger", "passive") != "passive":
            raise InputError(f"trigger (={kwargs['trigger']!r}): listen-only is passive (mebm sends nothing, so it "
                             "cannot start a round trip); for an active mode use mode=active-cia402 or active-mebm")
        # a bus mebm does not drive loses a frame now and then (a TPDO the drive sent outside
        # the window, a datagram this host missed): by default up to 1 % of the round trip's
        # SYNCs may go without a sample, each counted, none filled in
        self.max_lost_fraction = 0.01 if kwargs.get("max_lost_samples") is None else 0.0
        kwargs.pop("max_lost_samples", None) if kwargs.get("max_lost_samples") is None else None
        super().__init__(**kwargs)
        if not 1 <= int(node_id) <= 127:
            raise InputError(f"node (={node_id}) must be a CANopen node id 1..127")
        self.node_id = int(node_id)
        self.wire = CanopenListenWire(channel, mapping, interface=interface, sync_rate_hz=sync_rate_hz,
                                      time_scale=time_scale, window_s=window_s, bus_kwargs=bus_kwargs,
                                      bus_factory=bus_factory, emcy_cob_id=0x80 + self.node_id)
        self._order = None
        self.sends_refused = 0

    def describe(self) -> str:
        w = self.wire
        return f"canopen://{w.interface}/{w.channel}?node={self.node_id}&mode=listen-only"

    @property
    def listen_stats(self) -> dict[str, int]:
        """SYNCs and TPDOs heard, paired, missed, late (of the link under way, else the last)."""
        li = self.wire.listener
        return li.stats() if li is not None and self.wire.bus is not None else dict(self.wire.last_stats)

    def _connect_blocking(self) -> None:
        self._order = None  # a new link numbers SYNCs afresh
        self.wire.open()
        self.wire.wait_for_traffic(self.timeout_s)
        self.servo_rate_hz = float(self.wire.sync_rate_hz)

    def _close_blocking(self) -> None:
        if self.wire.bus is not None:
            self.sends_refused += self.wire.bus.sends_refused
        self.wire.close()

    def _refuse(self, what: str):
        raise DriverMisuseError(f"{self.describe()} is listen-only: mebm cannot {what} (it sends no frame); the CNC "
                                "starts the round trip and mebm records it passively")

    async def _read_status(self) -> ControllerStatus:
        """What can be known without asking: nothing of the state or temperature (no frame is sent)."""
        return ControllerStatus(AxisState.IDLE, 0, float("nan"), self.servo_rate_hz)

    async def _start(self, program):
        self._refuse("start a round trip")

    async def _abort(self) -> None:
        return None  # nothing to stop: mebm never started anything

    async def _acknowledge(self) -> None:
        self._refuse("acknowledge a fault")

    def _take(self, finished: bool = False) -> SampleBlock:
        from acquisition.canopen.driver import SyncOrder

        frames = self.wire.take()
        if self._order is None:
            if not frames:
                return SampleBlock.empty(finished)
            self._order = SyncOrder(min(f[0] for f in frames), self.REORDER_HORIZON)
        for f in frames:
            self._order.take(*f)
        return self.wire.samples(self._order.release(finished), finished)

    async def _drain(self) -> SampleBlock:
        if self.wire.bus is None:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        return self._take()

    # -- passive acquisition (the base's): the CNC runs the round trip, the detector cuts it ----------
    async def _passive_drain(self) -> SampleBlock:
        if self.wire.bus is None:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        emcy = self.wire.listener.emcy
        if emcy is not None:  # heard, not asked: the drive reported a fault while mebm listened
            raise DeviceFaultError(f"drive node {self.node_id} sent EMCY {emcy[1].hex(' ')} while mebm listened: "
                                   "the round trip is not measured", code=emcy[0])
        return self._take()

    def _passive_trace(self, cycle, found, rate, skew_s, t_first_block, last_progress, clock_s=0.0) -> AcquiredTrace:
        """The base's trace, with the SYNCs of the round trip that have no sample counted as lost:
        every SYNC is a sample here (no polled rest), so any gap in the cut is a loss."""
        counter = np.rint(found.t_s * rate).astype(np.int64)
        span = int(counter[-1] - counter[0] + 1)
        lost = span - int(counter.size)
        allowed = max(self.max_lost_samples, int(self.max_lost_fraction * span))
        if lost > allowed:
            first_missing = int(counter[:-1][np.diff(counter) > 1][0] + 1)
            raise LostSamplesError(
                f"{lost} of the round trip's {span} SYNCs have no sample, at most {allowed} allowed "
                f"(max_lost_samples); on the bus so far: {_stats_text(self.listen_stats)}",
                lost_samples=lost, first_missing=first_missing)
        trace = super()._passive_trace(cycle, found, rate, skew_s, t_first_block, last_progress, clock_s)
        return replace(trace, lost_samples=lost, notes=(*trace.notes, "listen-only: mebm sent no frame"))


def _stats_text(st: dict[str, int]) -> str:
    """Where samples went missing, for the technician: not sent, not heard, or outside the window."""
    return (f"{st.get('syncs_heard', 0)} SYNCs heard ({st.get('syncs_missed', 0)} missed by this host), "
            f"{st.get('tpdos_heard', 0)} TPDOs heard, {st.get('late', 0)} outside the synchronous window, "
            f"{st.get('duplicates', 0)} duplicates")

"""Modbus TCP driver (pymodbus async client) for register map ``mebm-modbus/1``.

Only the wire lives here; the measurement loop is :class:`acquisition.driver.base.ControllerDriver`,
and every register word is decoded by the register map (:mod:`acquisition.modbus.register_map`,
``register_map``): this module sees typed values only. Modes: ``trace`` (default) drains
the controller's trace ring buffer in block reads, so every servo-cycle sample is kept;
``latched`` polls the latched sample (one read, both positions of one cycle, decimated);
``separate`` reads motor and table in two requests for controllers without latching,
labelled unlatched with a skew uncertainty. The client is made by ``client_factory``
(default: pymodbus' ``AsyncModbusTcpClient``), so tests can hand in a fake one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from acquisition.modbus import register_map as mm
from acquisition.driver.base import ControllerDriver, raise_device_fault
from acquisition.errors import (
    AcquisitionError,
    ControllerConnectionError,
    ControllerTimeoutError,
    DeviceBusyError,
    ProtocolError,
    TransientProtocolError,
)
from acquisition.types import AxisState, Command, ControllerStatus, RoundTripProgram, SampleBlock
from core.errors import InputError

MODES = ("trace", "latched", "separate")
_EXC_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure",
              5: "acknowledge", 6: "device busy", 8: "memory parity error", 10: "gateway path unavailable",
              11: "gateway target failed to respond"}
# the error class of each exception code: its class says whether a retry may succeed
_EXC_CLASSES: dict[int, type[ProtocolError]] = {5: DeviceBusyError, 6: DeviceBusyError,
                                                4: TransientProtocolError, 11: TransientProtocolError}


def exception_error(code: int, message: str) -> ProtocolError:
    """The error for a Modbus exception reply ``code``."""
    return _EXC_CLASSES.get(code, ProtocolError)(message, code=code)


@dataclass
class _RingCursor:
    """Where one cycle's reading of the trace ring stands (per cycle, in ``cycle.wire``)."""

    first_counter: int  # counter of the trace's record 0
    next_w: int = 0  # next record to read
    next_counter: int | None = None  # counter the next record should carry


@dataclass
class _Listening:
    """Passive mode's per-cycle state: the ring of a program seen running, and the last counter."""

    ring: _RingCursor | None = None
    last_counter: int | None = None
    run_start: bool = False  # the ring is read from the program's first record


class ModbusDriver(ControllerDriver):
    protocol = "modbus"
    wire_timeouts = True  # pymodbus' client timeout bounds each request
    supports_passive = True
    has_running_flag = True  # the status block's axis state: RUNNING while a program runs

    def __init__(self, host: str, port: int = 502, *, device_id: int = 1, mode: str = "trace",
                 blocks_per_drain: int = 16, client_factory=None, register_map=None, serial: dict | None = None,
                 **kwargs):
        """``serial``: Modbus RTU on the serial device ``host`` with these line settings
        (baudrate, parity, stopbits, bytesize) instead of Modbus TCP to ``host:port``."""
        super().__init__(**kwargs)
        if mode not in MODES:
            raise InputError(f"mode (={mode!r}) must be one of {MODES}")
        self.host, self.port, self.device_id = host, int(port), int(device_id)
        self.mode = mode
        if blocks_per_drain < 1:
            raise InputError(f"blocks_per_drain (={blocks_per_drain}) must be >= 1")
        self.blocks_per_drain = int(blocks_per_drain)
        self.continuous = mode == "trace"
        self.latched = mode != "separate"
        self.map = register_map or mm.MEBM_MODBUS_1
        self.serial = dict(serial) if serial is not None else None
        if self.serial is not None:
            self._client_factory = client_factory or (
                lambda: AsyncModbusSerialClient(host, timeout=self.timeout_s, retries=0, reconnect_delay=0,
                                                **self.serial))
        else:
            self._client_factory = client_factory or (
                lambda: AsyncModbusTcpClient(host, port=self.port, timeout=self.timeout_s, retries=0,
                                             reconnect_delay=0))
        self._client = None
        # what the connection read from the controller's configuration
        self.scale = None
        self.ring_records = 0

    def describe(self) -> str:
        if self.serial is not None:
            return f"modbus+rtu://{self.host}"
        return f"modbus://{self.host}:{self.port}"

    # -- requests ----------------------------------------------------------------------------
    async def _request(self, what: str, call):
        if self._client is None:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        try:
            rr = await call()
        except ConnectionException as exc:
            raise ControllerConnectionError(f"connection to {self.describe()} lost while {what}") from exc
        except ModbusIOException as exc:
            raise ControllerTimeoutError(f"no reply from {self.describe()} within {self.timeout_s:g} s while {what}") from exc
        except ModbusException as exc:
            raise ProtocolError(f"{self.describe()}: {what}: {exc}") from exc
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0) or 0)
            raise exception_error(code, f"{self.describe()} answered {what} with Modbus exception {code} "
                                        f"({_EXC_NAMES.get(code, 'unknown')})")
        return rr

    async def _read(self, where: tuple[int, int], what: str) -> list[int]:
        address, count = where
        rr = await self._request(
            what, lambda: self._client.read_holding_registers(address, count=count, device_id=self.device_id)
        )
        return rr.registers

    async def _write(self, where: tuple[int, list[int]], what: str) -> None:
        address, values = where
        await self._request(what, lambda: self._client.write_registers(address, values, device_id=self.device_id))

    # -- wire ---------------------------------------------------------------------------------
    async def _connect(self) -> None:
        await self._open()
        cfg = self.map.decode_header(await self._read(self.map.header, "reading the register map header"))
        if cfg.version != self.map.version:
            raise ProtocolError(
                f"{self.describe()} speaks register map version {cfg.version}, mebm speaks "
                f"version {self.map.version} (docs/register-map.md)"
            )
        if not self.map.layout_ok(cfg):
            raise ProtocolError(f"{self.describe()}: unexpected trace buffer layout {cfg}")
        self.scale, self.servo_rate_hz, self.ring_records = cfg.scale, cfg.servo_rate_hz, cfg.ring_records

    async def _open(self) -> None:
        """Open the TCP connection or the serial line (no request yet)."""
        await self._close()
        self._client = self._client_factory()
        try:
            ok = await self._client.connect()
        except (OSError, ModbusException) as exc:
            ok = False
            cause = exc
        else:
            cause = None
        if not ok:
            self._client = None
            raise ControllerConnectionError(
                f"cannot connect to {self.describe()}: " + (
                    "cannot open the serial device (does it exist, and may mebm use it?)" if self.serial is not None
                    else "connection refused or host unreachable (is the controller on and its Modbus TCP server "
                         "enabled?)")
            ) from cause

    async def _close(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except Exception:  # noqa: BLE001 - closing must never fail the caller
                pass
            self._client = None

    async def _status(self) -> mm.StatusBlock:
        return self.map.decode_status(await self._read(self.map.status, "reading the status block"))

    def _check_running(self, s: mm.StatusBlock) -> None:
        """A status read mid-cycle: anything but RUNNING/DONE ends the cycle with its reason."""
        if s.state is None:
            raise ProtocolError(f"{self.describe()}: unknown axis state {s.state_raw}")
        # passive: the CNC may acknowledge its program the moment it ends (DONE -> IDLE)
        ended = (AxisState.DONE, AxisState.IDLE) if self.trigger == "passive" else (AxisState.DONE,)
        if s.state != AxisState.RUNNING and s.state not in ended:
            raise_device_fault(ControllerStatus(s.state, s.fault_code), self.describe(), self.link_trouble)

    async def _read_status(self) -> ControllerStatus:
        s = await self._status()
        if s.state is None:
            raise ProtocolError(f"{self.describe()}: unknown axis state {s.state_raw}")
        return s.controller_status(self.servo_rate_hz)

    async def _start(self, program: RoundTripProgram) -> int | None:
        # parameters and command in one function-16 request: the controller never sees half a program
        await self._write(self.map.start(program), "starting the round trip")
        s = await self._status()
        self._check_running(s)
        self.cycle.wire = _RingCursor(first_counter=s.trace_first)
        return s.trace_first

    async def _abort(self) -> None:
        await self._write(self.map.command(Command.ABORT), "aborting the round trip")

    async def _acknowledge(self) -> None:
        await self._write(self.map.command(Command.ACKNOWLEDGE), "acknowledging")

    async def _drain(self) -> SampleBlock:
        if self.mode == "trace":
            return await self._drain_trace()
        return await self._poll_sample()

    async def _drain_trace(self) -> SampleBlock:
        """Read trace-buffer blocks until one is partly new (caught up) or ``blocks_per_drain``.

        Behind the controller (a full ring) several blocks are read per drain and decoded
        once, so the per-sample cost stays near a bare read loop's; each block's validity
        is checked on its first and last counter, then the batch for a record older than
        its predecessor (a torn read), where it is cut to be read again; the trace
        assembler checks every counter for gaps.
        A failed read after good blocks ends the batch: those blocks are handed over and
        the read is retried on the next drain, so nothing read is lost.
        """
        cur: _RingCursor = self.cycle.wire if isinstance(self.cycle.wire, _RingCursor) else self.cycle.wire.ring
        next_w = cur.next_w
        ref = cur.first_counter if cur.next_counter is None else cur.next_counter
        expected = ref
        regs_all: list[int] = []
        full = True
        for i in range(self.blocks_per_drain):
            where_addr, where_count, n = self.map.ring_read(next_w % self.ring_records, self.ring_records)
            try:
                regs = await self._read((where_addr, where_count), "reading the trace buffer")
            except AcquisitionError as exc:
                if i == 0:
                    raise
                # hand over the good blocks; the retry policy meets this read again on the
                # next drain. A timed-out or dropped link is closed first, as the base loop
                # does, so a late reply can never answer the next request.
                self.note_link_trouble(exc)
                if isinstance(exc, (ControllerConnectionError, ControllerTimeoutError)):
                    await self.close()
                break
            k, expected = self.map.new_records(regs, n, expected)
            regs_all.extend(regs[: self.map.record_words(k)] if k < n else regs)
            next_w += k
            if k < n:
                full = False
                break
        if regs_all:
            counter, motor, table = self.map.decode_records(regs_all, self.scale, ref)
            if int(counter[0]) - ref >= self.ring_records:
                skipped = await self._skip_lapped(cur)
                if skipped is not None:
                    return skipped
            older = np.flatnonzero(counter[1:] <= counter[:-1])
            if older.size:
                # a block read while the controller was writing it (a "torn" read: a record
                # older than its predecessor): keep the records before it, read the rest again
                j = int(older[0]) + 1
                counter, motor, table = counter[:j], motor[:j], table[:j]
                next_w = cur.next_w + j
                full = False
            # Record w sits in slot w mod N and carries counter first + w (one record per
            # servo cycle). A reader more than N records behind finds newer records in its
            # slots (their counters jump: lost samples, counted by the trace assembler); count
            # the laps from the counter so the read position stays the record's own index.
            laps = round((int(counter[-1]) - cur.first_counter - (next_w - 1)) / self.ring_records)
            if laps > 0:
                next_w += laps * self.ring_records
        finished = False
        if not full:
            # may raise (timeout, busy): nothing is committed yet, so the retry re-reads these
            # records from the ring instead of losing them
            s = await self._status()
            self._check_running(s)
            finished = s.state != AxisState.RUNNING and next_w >= s.trace_count
        cur.next_w = next_w
        if not regs_all:
            return SampleBlock.empty(finished)
        cur.next_counter = int(counter[-1]) + 1
        return SampleBlock(counter, motor, table, finished=finished, caught_up=not full)

    async def _skip_lapped(self, cur: _RingCursor) -> SampleBlock | None:
        """The controller has lapped the reader: the next record to read is overwritten. Go on
        from the oldest record the ring still holds (plus a block's worth of margin while the
        trace runs, as the controller keeps writing); the overwritten records show as a gap,
        counted by the trace assembler. Reading on slot by slot would find every next slot
        overwritten too, and lose the records the ring does hold. None: the ring was not
        overwritten past the reader (the controller's own counter jumped): read on."""
        s = await self._status()
        self._check_running(s)
        margin = 0 if s.state == AxisState.DONE else self.map.records_per_read
        oldest = s.trace_count - self.ring_records + margin
        if oldest <= cur.next_w:
            return None
        cur.next_w = oldest
        cur.next_counter = cur.first_counter + oldest
        return SampleBlock(*(np.zeros(0, dtype=t) for t in (np.int64, float, float)), caught_up=False)

    async def _poll_sample(self) -> SampleBlock:
        first = self.cycle.wire.first_counter
        t0 = time.monotonic()
        if self.mode == "separate":
            # unlatched: the table is read in a second request, a little later
            motor_regs = await self._read(self.map.separate_first, "reading the motor position")
            table_regs = await self._read(self.map.separate_table, "reading the table position")
            t1 = time.monotonic()
            s = self.map.join_separate(motor_regs, table_regs)
            # the controller updates its registers once per servo cycle, so the two reads
            # can straddle one update: the bound is the round trip of both plus one cycle
            skew = (t1 - t0) + (1.0 / self.servo_rate_hz if self.servo_rate_hz > 0 else 0.0)
        else:
            s = self.map.decode_status(await self._read(self.map.status, "reading the latched sample"))
            skew = 0.0
        self._check_running(s)
        counter, motor, table = self.map.latched_sample(s, self.scale, first)
        if counter[0] < first:
            return SampleBlock.empty()
        return SampleBlock(counter, motor, table, finished=s.state == AxisState.DONE, skew_s=skew)

    # -- passive ------------------------------------------------------------------------------
    async def _passive_drain(self) -> SampleBlock:
        """Samples without commanding anything: the latched sample of each status read while
        no program runs; in trace mode, the controller's trace ring while one runs (every
        servo cycle of the round trip, as in active mode). ``running``: axis state RUNNING."""
        lis = self.cycle.wire
        if lis is None:
            lis = self.cycle.wire = _Listening()
        if lis.ring is not None:
            first = lis.ring.first_counter
            block = await self._drain_trace()
            if block.finished:
                lis.ring = None  # the program ended and its trace is read: back to polling
            run_start = False
            if len(block):
                lis.last_counter = int(block.counter[-1])
                run_start, lis.run_start = lis.run_start and int(block.counter[0]) == first, False
            # caught up with a running trace: wait a poll interval; its end: poll again at once
            return SampleBlock(block.counter, block.motor_rev, block.table_mm,
                               caught_up=block.caught_up and lis.ring is not None,
                               running=np.ones(len(block), dtype=bool), run_start=run_start)
        t0 = time.monotonic()
        if self.mode == "separate":
            motor_regs = await self._read(self.map.separate_first, "reading the motor position")
            table_regs = await self._read(self.map.separate_table, "reading the table position")
            s = self.map.join_separate(motor_regs, table_regs)
            skew = (time.monotonic() - t0) + (1.0 / self.servo_rate_hz if self.servo_rate_hz > 0 else 0.0)
        else:
            s = self.map.decode_status(await self._read(self.map.status, "reading the latched sample"))
            skew = 0.0
        if s.state is None:
            raise ProtocolError(f"{self.describe()}: unknown axis state {s.state_raw}")
        running = s.state == AxisState.RUNNING
        if running and self.mode == "trace":
            # a program runs: read its trace from the record after the last sample delivered
            first = s.trace_first
            next_w = 0 if lis.last_counter is None else max(0, lis.last_counter + 1 - first)
            lis.ring = _RingCursor(first_counter=first, next_w=next_w,
                                   next_counter=first + next_w if next_w else None)
            # listening began while the program ran, but the ring still holds its first record
            # (with a block's margin): the run is read whole, from its start
            lis.run_start = (lis.last_counter is None and next_w == 0
                             and s.trace_count + self.map.records_per_read <= self.ring_records)
            return SampleBlock(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), caught_up=False)
        ref = lis.last_counter if lis.last_counter is not None else s.counter
        counter, motor, table = self.map.latched_sample(s, self.scale, ref)
        lis.last_counter = int(counter[-1])
        return SampleBlock(counter, motor, table, skew_s=skew, running=np.array([running]))

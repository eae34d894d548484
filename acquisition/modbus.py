"""Modbus TCP driver (pymodbus async client) for register map ``mebm-modbus/1``.

Only the wire lives here; the measurement loop is :class:`acquisition.driver.ControllerDriver`.
Modes: ``trace`` (default) drains the controller's trace ring buffer in block reads,
so every servo-cycle sample is kept; ``latched`` polls the latched sample (one read,
both positions of one cycle, decimated); ``separate`` reads motor and table in two
requests for controllers without latching, labelled unlatched with a skew uncertainty.
"""

from __future__ import annotations

import time

import numpy as np
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from acquisition import modbus_map as mm
from acquisition.driver import ControllerDriver, raise_device_fault
from acquisition.errors import AcquisitionError, ControllerConnectionError, ControllerTimeoutError, ProtocolError
from acquisition.types import AxisState, Command, ControllerStatus, RoundTripProgram, SampleBlock
from core.errors import InputError

MODES = ("trace", "latched", "separate")
_EXC_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure",
              5: "acknowledge", 6: "device busy", 8: "memory parity error", 10: "gateway path unavailable",
              11: "gateway target failed to respond"}
_TRANSIENT_CODES = {4, 5, 6, 11}  # the controller may answer normally on a retry


class ModbusDriver(ControllerDriver):
    protocol = "modbus"
    wire_timeouts = True  # pymodbus' client timeout bounds each request

    def __init__(self, host: str, port: int = 502, *, device_id: int = 1, mode: str = "trace",
                 blocks_per_drain: int = 16, client_factory=None, **kwargs):
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
        self._client_factory = client_factory or (
            lambda: AsyncModbusTcpClient(host, port=self.port, timeout=self.timeout_s, retries=0, reconnect_delay=0)
        )
        self._client = None
        self.scale = None
        self.ring_records = 0
        self._next_w = 0  # next trace record to read
        self._next_counter: int | None = None
        self._first_counter = 0

    def describe(self) -> str:
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
            err = ProtocolError(
                f"{self.describe()} answered {what} with Modbus exception {code} "
                f"({_EXC_NAMES.get(code, 'unknown')})", code=code,
            )
            err.transient = code in _TRANSIENT_CODES
            raise err
        return rr

    async def _read(self, address: int, count: int, what: str) -> list[int]:
        rr = await self._request(
            what, lambda: self._client.read_holding_registers(address, count=count, device_id=self.device_id)
        )
        return rr.registers

    async def _write(self, address: int, values: list[int], what: str) -> None:
        await self._request(what, lambda: self._client.write_registers(address, values, device_id=self.device_id))

    # -- wire ---------------------------------------------------------------------------------
    async def _connect(self) -> None:
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
                f"cannot connect to {self.describe()}: connection refused or host unreachable "
                "(is the controller on and its Modbus TCP server enabled?)"
            ) from cause
        regs = await self._read(0, mm.CONFIG_BASE + mm.CONFIG_WORDS, "reading the register map header")
        if regs[mm.MAP_VERSION_REG] != mm.MAP_VERSION:
            raise ProtocolError(
                f"{self.describe()} speaks register map version {regs[mm.MAP_VERSION_REG]}, mebm speaks "
                f"version {mm.MAP_VERSION} (docs/register-map.md)"
            )
        cfg = mm.decode_config(regs[mm.CONFIG_BASE:])
        if cfg["record_words"] != mm.RECORD_WORDS or cfg["ring_records"] < mm.RECORDS_PER_READ:
            raise ProtocolError(f"{self.describe()}: unexpected trace buffer layout {cfg}")
        self.scale, self.servo_rate_hz, self.ring_records = cfg["scale"], cfg["servo_rate_hz"], cfg["ring_records"]

    async def _close(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except Exception:  # noqa: BLE001 - closing must never fail the caller
                pass
            self._client = None

    async def _status(self) -> dict:
        return mm.decode_status(await self._read(0, mm.STATUS_WORDS, "reading the status block"))

    async def _read_status(self) -> ControllerStatus:
        s = await self._status()
        if s["state"] is None:
            raise ProtocolError(f"{self.describe()}: unknown axis state {s['state_raw']}")
        return ControllerStatus(s["state"], s["fault_code"], s["temperature_c"], self.servo_rate_hz)

    async def _start(self, program: RoundTripProgram) -> int | None:
        # parameters and command in one function-16 request: the controller never sees half a program
        await self._write(mm.COMMAND, mm.encode_program(program, Command.START), "starting the round trip")
        s = await self._status()
        if s["state"] not in (AxisState.RUNNING, AxisState.DONE):
            raise_device_fault(ControllerStatus(s["state"], s["fault_code"]), self.describe(), self.link_trouble)
        self._first_counter = s["trace_first"]
        self._next_w = 0
        self._next_counter = None
        self._last_poll = None
        return s["trace_first"]

    async def _abort(self) -> None:
        await self._write(mm.COMMAND, [int(Command.ABORT)], "aborting the round trip")

    async def _acknowledge(self) -> None:
        await self._write(mm.COMMAND, [int(Command.ACKNOWLEDGE)], "acknowledging")

    async def _drain(self) -> SampleBlock:
        if self.mode == "trace":
            return await self._drain_trace()
        return await self._poll_sample()

    async def _finished(self, s: dict, caught_up: bool) -> bool:
        if s["state"] == AxisState.RUNNING:
            return False
        if s["state"] == AxisState.DONE:
            return caught_up
        raise_device_fault(ControllerStatus(s["state"], s["fault_code"]), self.describe(), self.link_trouble)
        return False  # pragma: no cover

    async def _drain_trace(self) -> SampleBlock:
        """Read trace-buffer blocks until one is partly new (caught up) or ``blocks_per_drain``.

        Behind the controller (a full ring) several blocks are read per drain and decoded
        once, so the per-sample cost stays near a bare read loop's; each block's validity
        is checked on its first and last counter, then the batch for a record older than
        its predecessor (a torn read), where it is cut to be read again; the base loop
        checks every counter for gaps.
        A failed read after good blocks ends the batch: those blocks are handed over and
        the read is retried on the next drain, so nothing read is lost.
        """
        next_w = self._next_w
        ref = self._first_counter if self._next_counter is None else self._next_counter
        expected = ref
        regs_all: list[int] = []
        full = True
        for i in range(self.blocks_per_drain):
            slot = next_w % self.ring_records
            n = min(mm.RECORDS_PER_READ, self.ring_records - slot)
            try:
                regs = await self._read(mm.RING_BASE + slot * mm.RECORD_WORDS, n * mm.RECORD_WORDS,
                                        "reading the trace buffer")
            except AcquisitionError as exc:
                if i == 0:
                    raise
                # hand over the good blocks; the base loop's retry handling meets this read
                # again on the next drain. A timed-out or dropped link is closed first, as
                # the base loop does, so a late reply can never answer the next request.
                self.link_trouble = str(exc)
                if isinstance(exc, (ControllerConnectionError, ControllerTimeoutError)):
                    await self.close()
                break
            k, expected = _new_records(regs, n, expected)
            regs_all.extend(regs[: k * mm.RECORD_WORDS] if k < n else regs)
            next_w += k
            if k < n:
                full = False
                break
        if regs_all:
            counter_u32, motor, table = mm.decode_records(regs_all, self.scale)
            counter = mm.unwrap_u32(counter_u32, ref)
            older = np.flatnonzero(counter[1:] <= counter[:-1])
            if older.size:
                # a block read while the controller was writing it (a "torn" read: a record
                # older than its predecessor): keep the records before it, read the rest again
                j = int(older[0]) + 1
                counter, motor, table = counter[:j], motor[:j], table[:j]
                next_w = self._next_w + j
                full = False
            # Record w sits in slot w mod N and carries counter first + w (one record per
            # servo cycle). A reader more than N records behind finds newer records in its
            # slots (their counters jump: lost samples, reported by the base loop); count the
            # laps from the counter so the read position stays the record's own index.
            laps = round((int(counter[-1]) - self._first_counter - (next_w - 1)) / self.ring_records)
            if laps > 0:
                next_w += laps * self.ring_records
        finished = False
        if not full:
            # may raise (timeout, busy): nothing is committed yet, so the retry re-reads these
            # records from the ring instead of losing them
            s = await self._status()
            finished = await self._finished(s, caught_up=next_w >= s["trace_count"])
        self._next_w = next_w
        if not regs_all:
            return SampleBlock.empty(finished)
        self._next_counter = int(counter[-1]) + 1
        return SampleBlock(counter, motor, table, finished=finished, caught_up=not full)

    async def _poll_sample(self) -> SampleBlock:
        t0 = time.monotonic()
        regs = await self._read(0, mm.TABLE_POS if self.mode == "separate" else mm.STATUS_WORDS, "reading the latched sample")
        if self.mode == "separate":
            # unlatched: the table is read in a second request, a little later
            table_regs = await self._read(mm.TABLE_POS, 2, "reading the table position")
            t1 = time.monotonic()
            regs = list(regs) + list(table_regs) + [0] * (mm.STATUS_WORDS - mm.TABLE_POS - 2)
            # the controller updates its registers once per servo cycle, so the two reads
            # can straddle one update: the bound is the round trip of both plus one cycle
            skew = (t1 - t0) + (1.0 / self.servo_rate_hz if self.servo_rate_hz > 0 else 0.0)
        else:
            skew = 0.0
        s = mm.decode_status(regs)
        if s["state"] != AxisState.RUNNING and s["state"] != AxisState.DONE:
            raise_device_fault(ControllerStatus(s["state"], s["fault_code"]), self.describe(), self.link_trouble)
        counter = mm.unwrap_u32([s["counter"]], self._first_counter)
        if counter[0] < self._first_counter:
            return SampleBlock.empty()
        motor = self.scale.motor_rev([s["motor_counts"]])
        table = self.scale.table_mm([s["table_counts"]])
        return SampleBlock(counter, motor, table, finished=s["state"] == AxisState.DONE, skew_s=skew)


def _new_records(regs: list[int], n: int, expected: int) -> tuple[int, int]:
    """How many of a block's ``n`` records are new, given the next ``expected`` counter, and the
    counter expected after them. Records after the newest are older (not yet overwritten)."""
    w = mm.RECORD_WORDS
    e = expected & 0xFFFFFFFF
    first = (regs[0] << 16) | regs[1]
    last = (regs[(n - 1) * w] << 16) | regs[(n - 1) * w + 1]
    if first == e and last == (e + n - 1) & 0xFFFFFFFF:
        return n, expected + n  # the common case: n consecutive new records
    counter = mm.unwrap_u32(mm.join_u32(regs[0::w][:n], regs[1::w][:n]), expected)
    prev = np.concatenate([[expected - 1], counter[:-1]])
    ok = counter > prev
    k = int(np.argmin(ok)) if not ok.all() else n
    return k, (int(counter[k - 1]) + 1 if k else expected)

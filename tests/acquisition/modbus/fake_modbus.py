"""A scripted ``mebm-modbus/1`` controller behind a fake pymodbus client, for the driver's
``client_factory`` hook: the driver runs its real code path (map, ring reader, assembler,
retry policy) while a test decides exactly what each read returns. No server, no clock.

Replies are pymodbus' own response objects, so the driver cannot tell the difference.
Fault injection goes through ``inject(address, count)``: return a pymodbus response (an
``ExceptionResponse``) or raise a pymodbus exception instead of the normal reply.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pymodbus.pdu import ExceptionResponse
from pymodbus.pdu.register_message import ReadHoldingRegistersResponse, WriteMultipleRegistersResponse

from acquisition.modbus import register_map as mm
from acquisition.scale import EncoderScale
from acquisition.types import AxisState, Command


class FakeController:
    """Holds the register image; ``client()`` is the ``client_factory`` to hand the driver.

    ``ring[slot]`` is the record (counter, motor counts, table counts) in a ring slot;
    :meth:`write` appends records of the current trace as the controller would. The slots
    start with a previous trace's records (older counters), as a real ring does.
    ``on_start(fake)`` runs when START is written, ``on_status(fake)`` before each status
    read of a running trace is answered (the controller moving on while the reader is away).
    """

    def __init__(self, *, ring_records: int = 100, first_counter: int = 5000, servo_rate_hz: float = 1000.0,
                 scale: EncoderScale = EncoderScale()):
        self.ring_records, self.first_counter, self.servo_rate_hz, self.scale = ring_records, first_counter, servo_rate_hz, scale
        self.ring = [self._record(w - ring_records) for w in range(ring_records)]
        self.torn: dict[int, tuple[int, int, int]] = {}  # slot -> record returned once instead
        self.state, self.fault_code, self.trace_count = AxisState.IDLE, 0, 0
        self.on_start: Callable[[FakeController], None] | None = None
        self.on_status: Callable[[FakeController], None] | None = None
        self.inject: Callable[[int, int], object] | None = None
        self.reads: list[tuple[int, int]] = []  # every read request (address, count)
        self.commands: list[Command] = []
        self.connects = 0
        self.refuse = 0  # connection attempts still to refuse
        self.gate = None  # an asyncio.Event every read waits for (None: answer at once)
        self.waiting = None  # an asyncio.Event set when a read waits at the gate

    def _record(self, w: int) -> tuple[int, int, int]:
        # record w of the trace: a slow ramp, motor and table moving together
        return ((self.first_counter + w) & 0xFFFFFFFF, 40 * w, 50 * w)

    def write(self, n: int) -> None:
        """The controller latches ``n`` more servo cycles into the ring."""
        for w in range(self.trace_count, self.trace_count + n):
            self.ring[w % self.ring_records] = self._record(w)
        self.trace_count += n

    def ring_reads(self) -> list[int]:
        """Ring slot at which each ring read started, in order."""
        return [(a - mm.RING_BASE) // mm.RECORD_WORDS for a, _ in self.reads if a >= mm.RING_BASE]

    # -- the register image ---------------------------------------------------------------------
    def _image(self, address: int, count: int) -> list[int]:
        if address >= mm.RING_BASE:
            s0 = (address - mm.RING_BASE) // mm.RECORD_WORDS
            recs = [self.torn.pop(s) if s in self.torn else self.ring[s] for s in range(s0, s0 + count // mm.RECORD_WORDS)]
            return [int(x) for x in mm.encode_records(np.array(recs, dtype=np.int64))]
        last = self._record(self.trace_count - 1) if self.trace_count else (0, 0, 0)
        words = mm.encode_status(self.state, self.fault_code, *last, 20.0, self.first_counter, self.trace_count)
        words += [0] * (mm.CONFIG_BASE - len(words))
        words += mm.encode_config(self.scale, self.servo_rate_hz, self.ring_records)
        return words[address : address + count]

    def client(self) -> "FakeClient":
        return FakeClient(self)


class FakeClient:
    """The part of pymodbus' ``AsyncModbusTcpClient`` the driver uses."""

    def __init__(self, ctl: FakeController):
        self.ctl = ctl

    async def connect(self) -> bool:
        self.ctl.connects += 1
        if self.ctl.refuse:
            self.ctl.refuse -= 1
            return False
        return True

    def close(self) -> None:
        pass

    async def read_holding_registers(self, address: int, *, count: int, device_id: int = 1):
        ctl = self.ctl
        ctl.reads.append((address, count))
        if ctl.gate is not None:
            if ctl.waiting is not None:
                ctl.waiting.set()
            await ctl.gate.wait()
        if ctl.inject is not None:
            injected = ctl.inject(address, count)
            if injected is not None:
                return injected
        if address < mm.RING_BASE and count >= mm.STATUS_WORDS and ctl.state == AxisState.RUNNING and ctl.on_status:
            ctl.on_status(ctl)
        return ReadHoldingRegistersResponse(registers=self.ctl._image(address, count))

    async def write_registers(self, address: int, values: list[int], *, device_id: int = 1):
        ctl = self.ctl
        if address == mm.COMMAND:
            cmd = Command(values[0])
            ctl.commands.append(cmd)
            if cmd == Command.START:
                ctl.trace_count, ctl.state = 0, AxisState.RUNNING
                if ctl.on_start:
                    ctl.on_start(ctl)
            elif cmd == Command.ABORT:
                ctl.state = AxisState.ABORTED
            elif cmd == Command.ACKNOWLEDGE:
                ctl.state = AxisState.IDLE
        return WriteMultipleRegistersResponse(address=address, count=len(values))


def busy() -> ExceptionResponse:
    """Modbus exception 6 (device busy) to a read."""
    return ExceptionResponse(3, 6)

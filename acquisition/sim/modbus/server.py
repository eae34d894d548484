"""Simulated Modbus TCP controller: a pymodbus server whose registers are a :class:`SimAxis`.

The register map is ``mebm-modbus/1`` (docs/register-map.md). Every read sees the
samples whose servo cycle has passed; the trace ring buffer is computed from the
precomputed round trip, so it behaves exactly like a controller that latches every
servo cycle. Fault injection (acquisition.sim.faults) acts on the wire here:
dropped/refused connections, slow replies, exception codes.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.datastore.context import ModbusBaseDeviceContext
from pymodbus.server import ModbusTcpServer

from acquisition.modbus import register_map as mm
from acquisition.sim.axis import SimAxis
from acquisition.sim.modbus import wear as sim_wear
from acquisition.sim.modbus.loop_thread import LoopThread
from acquisition.types import AxisState, Command
from core.errors import InputError

_BUSY = ExcCodes.DEVICE_BUSY


class _Context(ModbusBaseDeviceContext):
    def __init__(self, controller: "SimModbusController"):
        self.controller = controller

    def reset(self):  # pragma: no cover - required by the interface
        pass

    async def async_getValues(self, func_code, address, count=1):
        return await self.controller.read(func_code, address, count)

    async def async_setValues(self, func_code, address, values):
        return await self.controller.write(func_code, address, values)


class SimModbusController(LoopThread):
    thread_name = "sim-modbus"
    what = "simulated Modbus controller"

    """A simulated controller on Modbus TCP. ``port=0`` binds a free port (see :attr:`port`)."""

    def __init__(self, axis: SimAxis, *, host: str = "127.0.0.1", port: int = 0):
        self.axis = axis
        self.host = host
        self.port = port
        self._control = [0] * mm.CONTROL_WORDS
        self._config = mm.encode_config(axis.scale, axis.servo_rate_hz, axis.ring_records)
        self._server: ModbusTcpServer | None = None
        self._watch: asyncio.Task | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._listening = False
        self._dropped_cycle = -1
        self.requests = 0

    # -- lifecycle -------------------------------------------------------------------------
    async def start(self) -> int:
        """Start serving on the running loop; returns the bound port."""
        self._loop = asyncio.get_running_loop()
        context = ModbusServerContext(devices=_Context(self), single=True)
        self._server = ModbusTcpServer(context, address=(self.host, self.port))
        refuse = self.axis.faults.startup("refuse")
        await self._listen()
        if refuse is not None:
            await self._stop_listening(refuse.for_s)
        self._watch = asyncio.create_task(self._watchdog())
        return self.port

    async def _listen(self) -> None:
        srv = self._server
        srv.transport = await self._loop.create_server(
            srv.handle_new_connection, self.host, self.port, reuse_address=True, start_serving=True
        )
        srv.is_listener = True
        self.port = srv.transport.sockets[0].getsockname()[1]
        self._listening = True

    async def _stop_listening(self, for_s: float) -> None:
        """Drop every connection and refuse new ones for ``for_s`` seconds."""
        srv = self._server
        if self._listening:
            srv.transport.close()
            self._listening = False
        for conn in list(srv.active_connections.values()):
            with contextlib.suppress(Exception):
                conn.close()
        srv.active_connections = {}
        if for_s != float("inf"):
            asyncio.get_running_loop().call_later(for_s, lambda: asyncio.ensure_future(self._relisten()))

    async def _relisten(self) -> None:
        if not self._listening and self._server is not None:
            await self._listen()

    async def stop(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
        if self._server is not None:
            if self._listening:
                self._server.transport.close()
                self._listening = False
            for conn in list(self._server.active_connections.values()):
                with contextlib.suppress(Exception):
                    conn.close()
            self._server.active_connections = {}

    async def _watchdog(self) -> None:
        """Time-triggered wire faults (connection drop) during a round trip."""
        while True:
            # every 5 ms while a drop fault is scheduled; otherwise rarely, since each wake-up
            # competes for the GIL with the host process (the service's event loop)
            await asyncio.sleep(0.005 if self.axis.faults.has("drop") else 0.25)
            f = self.axis.fault("drop")
            if (
                f is not None
                and self._dropped_cycle != self.axis.cycles_started
                and self.axis.progress() >= f.at
            ):
                self._dropped_cycle = self.axis.cycles_started
                await self._stop_listening(f.for_s)

    # -- threaded use (tests, benchmark) ---------------------------------------------------------

    def recover(self) -> None:
        """End every injected fault now and listen again (tests: the fault clears on cue,
        not after a wall-clock window). Threaded use only."""
        async def _recover():
            self.axis.clear_faults()
            await self._relisten()

        asyncio.run_coroutine_threadsafe(_recover(), self._loop).result(5.0)

    def __enter__(self) -> "SimModbusController":
        self.start_in_thread()
        return self

    def __exit__(self, *exc) -> None:
        self.stop_thread()

    # -- registers ---------------------------------------------------------------------------
    def _wire_fault(self, kind: str):
        f = self.axis.fault(kind)
        if f is None or self.axis.program is None or self.axis.update() != AxisState.RUNNING:
            return None  # wire faults strike during a round trip
        p = self.axis.progress()
        if p < f.at:
            return None
        if f.for_s != float("inf") and (p - f.at) * self.axis.duration_wall_s > f.for_s:
            return None
        return f

    def _header(self) -> np.ndarray:
        ax = self.axis
        now = ax.clock()
        state, counter, motor, table = ax.snapshot(now)
        words = np.zeros(mm.RING_BASE, dtype=np.int64)
        words[: mm.STATUS_WORDS] = mm.encode_status(
            state, ax.fault_code, counter, motor, table, ax.twin.temperature_c,
            ax.trace_first, ax.trace_count(now),
        )
        words[mm.CONFIG_BASE : mm.CONFIG_BASE + mm.CONFIG_WORDS] = self._config
        words[mm.COMMAND : mm.COMMAND + mm.CONTROL_WORDS] = self._control
        self._wear_words(words)
        return words

    def _wear_words(self, words: np.ndarray) -> None:
        """The simulator's wear block (acquisition.sim.modbus.wear): repairs and the wear now."""
        words[sim_wear.REPAIR_REG : sim_wear.REPAIR_REG + sim_wear.WEAR_WORDS] = sim_wear.wear_words(self.axis.twin)

    async def read(self, func_code: int, address: int, count: int):
        self.requests += 1
        if func_code not in (3, 16, 6):
            return ExcCodes.ILLEGAL_FUNCTION
        end = address + count
        if address < 0 or end > mm.register_count(self.axis.ring_records):
            return ExcCodes.ILLEGAL_ADDRESS
        slow = self._wire_fault("slow")
        if slow is not None:
            await asyncio.sleep(float(slow.value("s")))
        exc = self._wire_fault("exception")
        if exc is not None:
            return ExcCodes(int(exc.value("code")))
        if address >= mm.RING_BASE:
            return self._ring_words(address, end).tolist()
        words = self._header()
        if end <= mm.RING_BASE:
            return words[address:end].tolist()
        return np.concatenate([words[address:], self._ring_words(mm.RING_BASE, end)]).tolist()

    def _ring_words(self, address: int, end: int) -> np.ndarray:
        rel0, rel1 = address - mm.RING_BASE, end - mm.RING_BASE
        s0, s1 = rel0 // mm.RECORD_WORDS, -(-rel1 // mm.RECORD_WORDS)
        rec = self.axis.ring_records_at(s0, s1 - s0)
        w = mm.encode_records(rec).astype(np.int64)
        off = rel0 - s0 * mm.RECORD_WORDS
        return w[off : off + (end - address)]

    async def write(self, func_code: int, address: int, values):
        self.requests += 1
        repaired = sim_wear.repair_write(self.axis.twin, address, values)  # the simulator's repair
        if repaired is not None:
            return None if repaired else ExcCodes.ILLEGAL_VALUE
        lo, hi = mm.COMMAND, mm.COMMAND + mm.CONTROL_WORDS
        if address < lo or address + len(values) > hi:
            return ExcCodes.ILLEGAL_ADDRESS
        exc = self._wire_fault("exception")
        if exc is not None:
            return ExcCodes(int(exc.value("code")))
        for i, v in enumerate(values):
            self._control[address - lo + i] = int(v)
        if address == lo and values:
            return self._command(int(values[0]))
        return None

    def _command(self, command: int):
        self._control[0] = 0
        if command == Command.START:
            try:
                program = mm.decode_program(self._control[1:])
            except InputError:
                return ExcCodes.ILLEGAL_VALUE
            try:
                self.axis.start(program)
            except InputError:
                return _BUSY
        elif command == Command.ABORT:
            self.axis.abort()
        elif command == Command.ACKNOWLEDGE:
            self.axis.acknowledge()
        elif command != Command.NONE:
            return ExcCodes.ILLEGAL_VALUE
        return None



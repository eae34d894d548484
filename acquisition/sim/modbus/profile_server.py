"""A simulated PLC laid out by a register profile: the twin's round trip behind any layout.

Where :class:`~acquisition.sim.modbus.server.SimModbusController` speaks mebm's own
register map, this server puts the :class:`SimAxis`' latched positions, temperature,
running and done flags at the addresses, types and orders a profile
(:mod:`acquisition.modbus.profile`) names, as a PLC gateway would. Writing the start
value starts the PLC's own round-trip program (fixed at construction, as a part program
in the CNC is); writing the abort value aborts it. Modbus TCP or, with ``serial=``,
Modbus RTU on a serial device (a pseudo-terminal in the tests).
"""

from __future__ import annotations

import asyncio
import threading

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.datastore.context import ModbusBaseDeviceContext
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

from acquisition.modbus.profile import RegisterProfile
from acquisition.sim.axis import SimAxis
from acquisition.sim.modbus.loop_thread import LoopThread
from acquisition.types import AxisState, RoundTripProgram
from core.errors import InputError

_SPACE = {1: "coil", 5: "coil", 15: "coil", 2: "discrete_input", 3: "holding", 6: "holding", 16: "holding",
          4: "input"}


def profile_words(profile: RegisterProfile, axis: SimAxis, start_value: int = 0) -> dict[str, dict[int, int]]:
    """What the controller holds now: {function: {address: word or bit}} for every read value."""
    state, counter, motor_c, table_c = axis.snapshot()
    physical = {"motor": float(axis.scale.motor_rev(motor_c)), "table": float(axis.scale.table_mm(table_c)),
                "temperature": float(axis.twin.temperature_c), "running": float(state == AxisState.RUNNING),
                "done": float(state == AxisState.DONE), "start": float(start_value), "abort": 0.0}
    out: dict[str, dict[int, int]] = {}
    for name, spec in profile.values.items():
        if name in ("start", "abort", "running", "done"):
            flag = int(physical[name]) if name != "start" else start_value
            words = [int(bool(flag))] if spec.is_bit else [0] * (spec.count - 1) + [flag]
        else:
            words = spec.encode(physical[name])
        space = out.setdefault(spec.function, {})
        for i, w in enumerate(words):
            space[spec.address + i] = int(w)
    return out


class _Context(ModbusBaseDeviceContext):
    def __init__(self, sim: "SimProfileController"):
        self.sim = sim

    def reset(self):  # pragma: no cover - required by the interface
        pass

    async def async_getValues(self, func_code, address, count=1):
        return self.sim.read(func_code, address, count)

    async def async_setValues(self, func_code, address, values):
        return self.sim.write(func_code, address, values)


class SimProfileController(LoopThread):
    thread_name = "sim-profile-plc"
    what = "simulated PLC"

    """The simulated PLC. ``serial``: {port: device, baudrate, parity, stopbits, bytesize} for
    RTU; else TCP on ``host``:``port`` (0: a free port, see :attr:`port`)."""

    def __init__(self, axis: SimAxis, profile: RegisterProfile, program: RoundTripProgram, *,
                 host: str = "127.0.0.1", port: int = 0, serial: dict | None = None, device_id: int = 1):
        self.axis, self.profile, self.program = axis, profile, program
        self.host, self.port, self.serial, self.device_id = host, port, serial, device_id
        self.start_value = 0
        self.requests = 0
        self._server = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None

    def read(self, func_code: int, address: int, count: int):
        self.requests += 1
        space = _SPACE.get(func_code)
        if space is None:
            return ExcCodes.ILLEGAL_FUNCTION
        held = profile_words(self.profile, self.axis, self.start_value).get(space, {})
        if any(a not in held for a in range(address, address + count)) and func_code in (1, 2, 3, 4):
            # a read must lie within mapped values, gaps of up to the profile's max gap allowed
            lo, hi = (min(held), max(held)) if held else (0, -1)
            if address < lo or address + count - 1 > hi:
                return ExcCodes.ILLEGAL_ADDRESS
        return [held.get(a, 0) for a in range(address, address + count)]

    def write(self, func_code: int, address: int, values):
        self.requests += 1
        start, abort = self.profile.get("start"), self.profile.get("abort")
        space = _SPACE.get(func_code)
        for spec, act in ((start, "start"), (abort, "abort")):
            if spec is not None and spec.function == space and spec.address == address:
                v = int(values[0])
                if act == "abort" and v == spec.value:
                    self.axis.abort()
                elif act == "start":
                    if v == spec.value and self.start_value != spec.value:  # the rising edge starts
                        self.axis.acknowledge()
                        try:
                            self.axis.start(self.program)
                        except InputError:
                            return ExcCodes.DEVICE_BUSY
                    self.start_value = v
                return None
        return ExcCodes.ILLEGAL_ADDRESS

    # -- lifecycle -------------------------------------------------------------------------
    async def start(self) -> int:
        self._loop = asyncio.get_running_loop()
        context = ModbusServerContext(devices={self.device_id: _Context(self)}, single=False)
        if self.serial is not None:
            self._server = ModbusSerialServer(context, framer=FramerType.RTU, **self.serial)
            await self._server.listen()
            return 0
        self._server = ModbusTcpServer(context, address=(self.host, self.port))
        await self._server.listen()
        self.port = self._server.transport.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
            self._server = None


    def __enter__(self) -> "SimProfileController":
        self.start_in_thread()
        return self

    def __exit__(self, *exc) -> None:
        self.stop_thread()

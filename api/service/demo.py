"""The built-in simulated controller for the demo machine (and for tests).

A simulated Modbus TCP controller (``acquisition.sim``) on a free loopback port,
whose axis is the project's digital twin (``core.sim``): the paper's Y axis with a
cyclic lead error at the screw lead, a lead that grows with temperature, encoder
resolution and noise, and a backlash that follows a simulated shop temperature:
b(T) = b_20 + beta (T - 20 °C), T swinging sinusoidally, plus the wear of the chain
(``simulator.wear_um_per_day`` per utility day, acquisition.sim.wear). With `make run`'s
settings (config.DEMO_SIMULATOR) b̄ starts OK, is WARNING after about a minute and
crosses the paper's 236 µm limit after about three (an alert and a corrective work
order); a repair recorded on the axis (``mebm maintenance repair``) is simulated through
the controller's repair register and the verification measurement proves it.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import replace

import numpy as np

from acquisition.sim.axis import SimAxis
from acquisition.sim.modbus.server import SimModbusController
from acquisition.sim.twin import CoreSimTwin, TwinTrace
from acquisition.sim.modbus.wear import REPAIR_REG
from acquisition.sim.wear import REPAIR_MAGIC, Wear
from acquisition.types import RoundTripProgram
from api.service.config.settings import SimulatorSettings
from core.dataset import AxisSpec
from core.sim import AxisModel, CyclicError, Effects, Encoders, Thermal

# The seed paper's machine: e_p about -18..-38 µm/1000 mm, lead growing ~1.3 ppm/K.
DEMO_LEAD_ERROR_UM_PER_M = -25.0
DEMO_LEAD_GROWTH_PPM_PER_K = 1.3
DEMO_ENCODERS = Encoders(motor_counts_per_rev=2**20, table_resolution_um=0.05, motor_noise_um=0.1, table_noise_um=0.2)


class DriftingTwin:
    """The digital twin of the demo axis, its backlash following the simulated shop temperature.

    ``backlash_offset_um`` adds a step (tests raise and lower the backlash with it)."""

    def __init__(self, spec: AxisSpec, sim: SimulatorSettings, *, clock=time.monotonic, seed: int = 0):
        self.sim = sim
        self.clock = clock
        self.t0 = clock()
        self.backlash_offset_um = 0.0
        self.wear = Wear(sim.wear_um_per_day, sim.utility_days_per_s, clock=clock)  # use wears the chain
        self._lock = threading.Lock()
        effects = Effects(
            thermal=Thermal(lead_error_um_per_m=DEMO_LEAD_ERROR_UM_PER_M,
                            lead_growth_ppm_per_k=DEMO_LEAD_GROWTH_PPM_PER_K),
            cyclic_error=CyclicError.of((spec.screw_lead_mm, sim.cyclic_error_um, 0.0)) if sim.cyclic_error_um else None,
        )
        self._model = AxisModel.from_axis_spec(spec, sim.backlash_um_at_20c, effects=effects, encoders=DEMO_ENCODERS)
        self.inner = CoreSimTwin(self._model, rng=np.random.default_rng(seed))

    @property
    def temperature_c(self) -> float:
        s = self.sim
        phase = 2 * math.pi * (self.clock() - self.t0) / s.temperature_period_s
        return s.temperature_mean_c + s.temperature_amplitude_c * math.sin(phase)

    def backlash_um(self, temperature_c: float | None = None) -> float:
        t = self.temperature_c if temperature_c is None else temperature_c
        return max(self.sim.backlash_um_at_20c + self.sim.backlash_um_per_k * (t - 20.0) + self.backlash_offset_um
                   + self.wear.extra_um(), 0.0)

    def warm_up(self) -> None:
        """Compile the twin's kernels before the first START arrives."""
        self.inner.warm_up()

    def round_trip(self, program: RoundTripProgram, rate_hz: float) -> TwinTrace:
        with self._lock:
            t = self.temperature_c
            self.inner.model = replace(self._model, backlash_um=self.backlash_um(t))
            self.inner.temperature_c = t
            return self.inner.round_trip(program, rate_hz)


class DemoController:
    """A simulated Modbus controller serving one axis, on its own thread."""

    def __init__(self, spec: AxisSpec, sim: SimulatorSettings, *, host: str = "127.0.0.1", port: int = 0):
        self.twin = DriftingTwin(spec, sim)
        self.axis = SimAxis(self.twin, servo_rate_hz=sim.servo_rate_hz, time_scale=sim.time_scale,
                            ring_records=10000)
        self.server = SimModbusController(self.axis, host=host, port=port)
        self.port: int | None = None

    @property
    def url(self) -> str:
        return f"modbus://{self.server.host}:{self.port}"

    def start(self) -> str:
        self.twin.warm_up()  # numba compiles once (then cached on disk), not during the first cycle
        self.port = self.server.start_in_thread()
        return self.url

    def stop(self) -> None:
        self.server.stop_thread()

    def repair(self) -> None:
        """The technician's work, simulated: write the simulator's repair register over
        Modbus (acquisition.sim.wear), which restores the wear to zero."""
        from pymodbus.client import ModbusTcpClient

        client = ModbusTcpClient(self.server.host, port=self.port, timeout=3)
        try:
            if not client.connect():
                raise ConnectionError(f"simulated controller {self.url} does not answer")
            reply = client.write_register(REPAIR_REG, REPAIR_MAGIC)
            if reply.isError():
                raise ConnectionError(f"simulated controller {self.url} refused the repair: {reply}")
        finally:
            client.close()

"""The simulated controllers' view of the axis: a small "twin" interface.

A twin turns a programmed round trip into the arrays a real controller would latch
every servo cycle. :class:`CoreSimTwin` adapts the project's digital twin
(``core.sim``); :class:`KinematicTwin` is a light stand-in (trapezoidal command,
first-order position loop, play of width b, cyclic lead error) for tests that
exercise the wire rather than the mechanics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.signal import lfilter

from acquisition.types import RoundTripProgram
from core.errors import require_positive


@dataclass(frozen=True)
class TwinTrace:
    """One round trip sampled at the servo rate: time (s), command (mm), motor (rev), table (mm)."""

    time_s: np.ndarray
    command_mm: np.ndarray
    motor_rev: np.ndarray
    table_mm: np.ndarray

    def __len__(self) -> int:
        return int(self.time_s.shape[0])


class Twin(Protocol):
    """What a simulated controller needs from an axis model."""

    temperature_c: float

    def round_trip(self, program: RoundTripProgram, rate_hz: float) -> TwinTrace:
        """Simulate ``program`` at ``rate_hz``; keep internal state (nut side) for the next call."""
        ...

    def warm_up(self) -> None:
        """Pay imports and compilation now, leaving the state as it was (optional)."""
        ...


def trapezoid_round_trip(program: RoundTripProgram, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Commanded position (mm) of the round trip sampled at ``rate_hz``: the twin's own
    NC program (``core.sim.round_trip``, trapezoidal each way, dwelling before, between
    and after the strokes)."""
    from core.sim import round_trip

    prog = round_trip(program.start_mm, program.end_mm, program.feed_mm_min,
                      acceleration_mm_s2=program.acceleration_mm_s2, dwell_s=program.dwell_s)
    t = np.arange(int(math.ceil(prog.duration_s * rate_hz)) + 1) / rate_hz
    return t, prog.positions(t)[0]


class KinematicTwin:
    """Stand-in axis: first-order position loop, play of ``backlash_um``, cyclic lead error.

    table = play(nut) + cyclic error; motor_rev = nut / k_a. Deterministic, no numba.
    """

    def __init__(
        self,
        *,
        transmission_mm_per_rev: float = 6.857,
        screw_lead_mm: float = 16.0,
        position_gain_per_s: float = 30.0,
        backlash_um: float = 120.0,
        cyclic_amplitude_um: float = 0.0,
        temperature_c: float = 20.0,
    ):
        self.k_a = require_positive("transmission_mm_per_rev", transmission_mm_per_rev)
        self.lead_mm = require_positive("screw_lead_mm", screw_lead_mm)
        self.gain_per_s = require_positive("position_gain_per_s", position_gain_per_s)
        self.backlash_mm = backlash_um * 1e-3
        self.cyclic_mm = cyclic_amplitude_um * 1e-3
        self.temperature_c = temperature_c
        self._side = -1.0  # nut last pushed towards negative (table sits b/2 above the nut)

    def warm_up(self) -> None:
        """Import the NC program generator now (stateless): the first START is then quick."""
        trapezoid_round_trip(RoundTripProgram(0.0, 1.0, 600.0, dwell_s=0.0), 1000.0)

    def round_trip(self, program: RoundTripProgram, rate_hz: float) -> TwinTrace:
        t, cmd = trapezoid_round_trip(program, rate_hz)
        dt = 1.0 / rate_hz
        alpha = 1.0 - math.exp(-self.gain_per_s * dt)
        # nut follows the command through a first-order loop
        nut = lfilter([alpha], [1.0, alpha - 1.0], cmd, zi=[cmd[0] * (1 - alpha)])[0]
        h = self.backlash_mm / 2.0
        table = np.empty_like(nut)
        x = nut[0] - self._side * h
        for i, p in enumerate(nut):  # play operator: the table moves only when the nut pushes it
            x = min(max(x, p - h), p + h)
            table[i] = x
        if np.all(np.diff(nut[-10:]) <= 0):
            self._side = -1.0
        else:
            self._side = 1.0
        table_mm = table + self.cyclic_mm * np.sin(2 * np.pi * table / self.lead_mm)
        return TwinTrace(t, cmd, nut / self.k_a, table_mm)


class CoreSimTwin:
    """The project's digital twin (``core.sim``) behind the :class:`Twin` interface.

    Keeps the nut side between round trips: after a round trip the nut last pushed
    towards the start, so the next one begins with the backlash to take up.
    """

    def __init__(self, model, *, temperature_c: float = 20.0, rng: np.random.Generator | None = None):
        from core.sim import AxisModel

        if not isinstance(model, AxisModel):
            raise TypeError(f"model must be a core.sim.AxisModel, got {type(model).__name__}")
        self.model = model
        self.temperature_c = float(temperature_c)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._side = model.initial_side

    def round_trip(self, program: RoundTripProgram, rate_hz: float) -> TwinTrace:
        from dataclasses import replace

        from core.sim import round_trip, simulate

        name = self.model.name
        prog = round_trip(program.start_mm, program.end_mm, program.feed_mm_min,
                          acceleration_mm_s2=program.acceleration_mm_s2, dwell_s=program.dwell_s, axis=name)
        model = replace(self.model, initial_side=self._side)
        tr = simulate({name: model}, prog, temperature_c=self.temperature_c, rate_hz=rate_hz, rng=self.rng)
        self._side = "negative" if program.end_mm > program.start_mm else "positive"
        return TwinTrace(tr.time_s, tr.command_mm[name], tr.motor_rev[name], tr.table_mm[name])

    def warm_up(self) -> None:
        """Run a tiny round trip so a JIT-compiled twin answers the first START quickly."""
        side = self._side
        rng_state = self.rng.bit_generator.state
        self.round_trip(RoundTripProgram(0.0, 1.0, 600.0, dwell_s=0.0), 1000.0)
        self._side = side
        self.rng.bit_generator.state = rng_state

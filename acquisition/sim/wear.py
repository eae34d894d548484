"""Wear of a simulated axis, and its repair (a maintenance loop you can watch).

The backlash grows by ``wear_um_per_day`` per utility day; the simulated clock counts
``utility_days_per_s`` utility days per second of its own clock (a high rate: weeks of
use in minutes). :meth:`Wear.repair` restores the backlash to its value as built.

The simulated controllers expose it on the wire, outside the mebm register map and
object dictionary proper (a real controller has no "repair" register; the simulator's is
what a technician's work is in the demo), each wire in its own module: a write of
``REPAIR_MAGIC`` (0x5250, "RP") repairs, and the wear added now can be read
(:mod:`acquisition.sim.modbus.wear`: holding registers 60-63; :mod:`acquisition.sim.canopen.wear`:
objects 0x2100-0x2102).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import replace

from core.errors import InputError

REPAIR_MAGIC = 0x5250  # written to the repair register or object ("RP")


class Wear:
    """Backlash added by use since the last repair (µm), on its own clock."""

    def __init__(self, wear_um_per_day: float = 0.0, utility_days_per_s: float = 1.0 / 86400.0, *,
                 clock=time.monotonic):
        if not (math.isfinite(wear_um_per_day) and wear_um_per_day >= 0):
            raise InputError(f"wear_um_per_day (={wear_um_per_day!r}) must be >= 0")
        if not (math.isfinite(utility_days_per_s) and utility_days_per_s > 0):
            raise InputError(f"utility_days_per_s (={utility_days_per_s!r}) must be > 0")
        self.wear_um_per_day = float(wear_um_per_day)
        self.utility_days_per_s = float(utility_days_per_s)
        self.clock = clock
        self.repairs = 0
        self._since = clock()
        self._lock = threading.Lock()

    def utility_days(self) -> float:
        """Utility days since the last repair (or since start)."""
        with self._lock:
            return max(self.clock() - self._since, 0.0) * self.utility_days_per_s

    def extra_um(self) -> float:
        return self.wear_um_per_day * self.utility_days()

    def repair(self) -> None:
        """Restore the backlash to its value as built (the wear starts again from zero)."""
        with self._lock:
            self._since = self.clock()
            self.repairs += 1


class WearingTwin:
    """A twin whose backlash grows with :class:`Wear`: a
    :class:`~acquisition.sim.twin.CoreSimTwin` (its model's ``backlash_um``) or a
    :class:`~acquisition.sim.twin.KinematicTwin` (its ``backlash_mm``)."""

    def __init__(self, twin, wear: Wear):
        self.twin = twin
        self.wear = wear
        model = getattr(twin, "model", None)
        self.base_backlash_um = float(model.backlash_um if model is not None else twin.backlash_mm * 1000.0)

    @property
    def temperature_c(self) -> float:
        return self.twin.temperature_c

    @temperature_c.setter
    def temperature_c(self, value: float) -> None:
        self.twin.temperature_c = value

    def backlash_um(self) -> float:
        return self.base_backlash_um + self.wear.extra_um()

    def round_trip(self, program, rate_hz: float):
        if getattr(self.twin, "model", None) is not None:
            self.twin.model = replace(self.twin.model, backlash_um=self.backlash_um())
        else:
            self.twin.backlash_mm = self.backlash_um() / 1000.0
        return self.twin.round_trip(program, rate_hz)

    def warm_up(self) -> None:
        self.twin.warm_up()


def wear_of(twin) -> Wear | None:
    """The twin's wear, if it has one."""
    w = getattr(twin, "wear", None)
    return w if isinstance(w, Wear) else None

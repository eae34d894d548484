"""Wear of a simulated axis, and its repair (a maintenance loop you can watch).

The backlash grows by ``wear_um_per_day`` per utility day; the simulated clock counts
``utility_days_per_s`` utility days per second of its own clock (a high rate: weeks of
use in minutes). :meth:`Wear.repair` restores the backlash to its value as built.

The simulated controllers expose it on the wire, outside the mebm register map and
object dictionary proper (a real controller has no "repair" register; the simulator's is
what a technician's work is in the demo):

- Modbus (``mebm-modbus/1`` + this block): holding register ``REPAIR_REG`` (60): write
  ``REPAIR_MAGIC`` (0x5250, "RP") to repair; ``REPAIRS_REG`` (61, u16) counts repairs;
  ``WEAR_REG`` (62-63, u32, 0.01 µm) is the backlash the wear adds now.
- CANopen: object ``REPAIR_OBJECT`` 0x2100 (u16, write 0x5250 to repair),
  ``WEAR_OBJECT`` 0x2101 (u32, 0.01 µm, read-only), ``REPAIRS_OBJECT`` 0x2102 (u16).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import replace

from core.errors import InputError

REPAIR_MAGIC = 0x5250
REPAIR_REG, REPAIRS_REG, WEAR_REG = 60, 61, 62  # WEAR_REG: two words, high first
WEAR_WORDS = 4
REPAIR_OBJECT, WEAR_OBJECT, REPAIRS_OBJECT = 0x2100, 0x2101, 0x2102


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


# -- the wire -------------------------------------------------------------------------------------
def modbus_wear_words(twin) -> list[int]:
    """The words at REPAIR_REG..REPAIR_REG+3 (zeros without wear)."""
    w = wear_of(twin)
    if w is None:
        return [0] * WEAR_WORDS
    centi = int(min(round(w.extra_um() * 100), 2**32 - 1))
    return [0, w.repairs & 0xFFFF, (centi >> 16) & 0xFFFF, centi & 0xFFFF]


def modbus_repair_write(twin, address: int, values) -> bool | None:
    """Handle a write to the wear block: None if ``address`` is not in it, True when
    applied, False when refused (not the magic value, read-only word, no wear)."""
    if not REPAIR_REG <= address < REPAIR_REG + WEAR_WORDS:
        return None
    w = wear_of(twin)
    if w is None or address != REPAIR_REG or len(values) != 1 or int(values[0]) != REPAIR_MAGIC:
        return False
    w.repair()
    return True


def add_canopen_objects(od) -> None:
    """The wear objects, added to a simulated drive's object dictionary."""
    from canopen import objectdictionary as odm

    for name, index, dtype, access in (("Simulated repair", REPAIR_OBJECT, odm.UNSIGNED16, "rw"),
                                       ("Simulated wear 0.01 um", WEAR_OBJECT, odm.UNSIGNED32, "ro"),
                                       ("Simulated repairs", REPAIRS_OBJECT, odm.UNSIGNED16, "ro")):
        v = odm.ODVariable(name, index, 0)
        v.data_type, v.access_type, v.default = dtype, access, 0
        od.add_object(v)


def canopen_read(twin, index: int) -> int | None:
    w = wear_of(twin)
    if index == WEAR_OBJECT:
        return 0 if w is None else int(min(round(w.extra_um() * 100), 2**32 - 1))
    if index == REPAIRS_OBJECT:
        return 0 if w is None else w.repairs & 0xFFFF
    if index == REPAIR_OBJECT:
        return 0
    return None


def canopen_repair_write(twin, index: int, data: bytes) -> bool | None:
    """None if ``index`` is not the repair object; True when repaired; False when refused."""
    if index != REPAIR_OBJECT:
        return None
    w = wear_of(twin)
    if w is None or int.from_bytes(bytes(data)[:2], "little") != REPAIR_MAGIC:
        return False
    w.repair()
    return True


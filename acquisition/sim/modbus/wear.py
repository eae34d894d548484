"""The simulated axis' wear on Modbus (:mod:`acquisition.sim.wear`), beside ``mebm-modbus/1``:
holding register ``REPAIR_REG`` (60): write ``REPAIR_MAGIC`` (0x5250, "RP") to repair;
``REPAIRS_REG`` (61, u16) counts repairs; ``WEAR_REG`` (62-63, u32, 0.01 µm) is the
backlash the wear adds now."""

from __future__ import annotations

from acquisition.sim.wear import REPAIR_MAGIC, wear_of

REPAIR_REG, REPAIRS_REG, WEAR_REG = 60, 61, 62  # WEAR_REG: two words, high first
WEAR_WORDS = 4


def wear_words(twin) -> list[int]:
    """The words at REPAIR_REG..REPAIR_REG+3 (zeros without wear)."""
    w = wear_of(twin)
    if w is None:
        return [0] * WEAR_WORDS
    centi = int(min(round(w.extra_um() * 100), 2**32 - 1))
    return [0, w.repairs & 0xFFFF, (centi >> 16) & 0xFFFF, centi & 0xFFFF]


def repair_write(twin, address: int, values) -> bool | None:
    """Handle a write to the wear block: None if ``address`` is not in it, True when
    applied, False when refused (not the magic value, read-only word, no wear)."""
    if not REPAIR_REG <= address < REPAIR_REG + WEAR_WORDS:
        return None
    w = wear_of(twin)
    if w is None or address != REPAIR_REG or len(values) != 1 or int(values[0]) != REPAIR_MAGIC:
        return False
    w.repair()
    return True

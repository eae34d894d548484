"""The simulated axis' wear on CANopen (:mod:`acquisition.sim.wear`), beside the drive's own
objects: ``REPAIR_OBJECT`` 0x2100 (u16, write ``REPAIR_MAGIC`` 0x5250 to repair),
``WEAR_OBJECT`` 0x2101 (u32, 0.01 µm, read-only), ``REPAIRS_OBJECT`` 0x2102 (u16)."""

from __future__ import annotations

from canopen import objectdictionary as odm

from acquisition.sim.wear import REPAIR_MAGIC, wear_of

REPAIR_OBJECT, WEAR_OBJECT, REPAIRS_OBJECT = 0x2100, 0x2101, 0x2102


def add_objects(od) -> None:
    """The wear objects, added to a simulated drive's object dictionary."""
    for name, index, dtype, access in (("Simulated repair", REPAIR_OBJECT, odm.UNSIGNED16, "rw"),
                                       ("Simulated wear 0.01 um", WEAR_OBJECT, odm.UNSIGNED32, "ro"),
                                       ("Simulated repairs", REPAIRS_OBJECT, odm.UNSIGNED16, "ro")):
        v = odm.ODVariable(name, index, 0)
        v.data_type, v.access_type, v.default = dtype, access, 0
        od.add_object(v)


def read(twin, index: int) -> int | None:
    """The value of wear object ``index`` (None: not one of them)."""
    w = wear_of(twin)
    if index == WEAR_OBJECT:
        return 0 if w is None else int(min(round(w.extra_um() * 100), 2**32 - 1))
    if index == REPAIRS_OBJECT:
        return 0 if w is None else w.repairs & 0xFFFF
    if index == REPAIR_OBJECT:
        return 0
    return None


def repair_write(twin, index: int, data: bytes) -> bool | None:
    """None if ``index`` is not the repair object; True when repaired; False when refused."""
    if index != REPAIR_OBJECT:
        return None
    w = wear_of(twin)
    if w is None or int.from_bytes(bytes(data)[:2], "little") != REPAIR_MAGIC:
        return False
    w.repair()
    return True

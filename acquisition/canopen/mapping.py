"""Where a drive's TPDO carries the two positions, for listening without asking the drive.

A listen-only mebm sends no SDO, so it cannot read the PDO mapping from the drive: it
takes it from the configuration, or from the drive's EDS/DCF file through canopen's
EDS import (:func:`canopen.import_od`), which resolves ``$NODEID`` and reads a DCF's
``ParameterValue`` over its ``DefaultValue``. The TPDO whose mapping (0x1A00-0x1BFF)
holds 0x6064 (position actual value, motor) and 0x60E4 sub 1 (additional position
actual value, the table encoder) is the one listened to; the scale comes from 0x608F
(increments per motor revolutions) and 0x2005 (nm per table count) when the file has
them, else from the configuration. Errors name the configuration field.
"""

from __future__ import annotations

import io
import math
import struct
from dataclasses import dataclass
from pathlib import Path

from acquisition.canopen import objects as co
from acquisition.files import MIB, FileRefused, read_regular
from core.errors import InputError

MAX_EDS_BYTES = 4 * MIB  # a drive's EDS or DCF is tens of kB; larger is not one

_INT_TYPES = {  # CiA 301 data type -> (struct code, bytes)
    0x2: ("b", 1), 0x3: ("h", 2), 0x4: ("l", 4), 0x5: ("B", 1), 0x6: ("H", 2), 0x7: ("L", 4),
    0x15: ("q", 8), 0x1B: ("Q", 8),
}
_FMT_BY_TYPE_NAME = {"i16": "h", "i32": "l", "u16": "H", "u32": "L", "i64": "q"}


@dataclass(frozen=True)
class PdoField:
    """One value in a PDO: its byte offset and struct code (little endian, CiA 301)."""

    offset_bytes: int
    fmt: str = "l"

    @property
    def size_bytes(self) -> int:
        return struct.calcsize("<" + self.fmt)


@dataclass(frozen=True)
class ListenMapping:
    """What a listen-only mebm needs to know about the bus (see the module docstring).

    Errors name the field as the configuration does (``tpdo_cob_id (=...) ...``); the
    caller puts where it came from in front."""

    tpdo_cob_id: int
    motor: PdoField
    table: PdoField
    counts_per_rev: float
    table_nm_per_count: float
    sync_cob_id: int = co.SYNC_COB_ID
    sync_period_s: float | None = None  # the master's communication cycle period (0x1006), if known
    window_s: float | None = None  # the synchronous window (0x1007), if known
    source: str = "configuration"

    def __post_init__(self) -> None:
        check_cob_id(f"tpdo_cob_id", self.tpdo_cob_id)
        check_cob_id(f"sync_cob_id", self.sync_cob_id)
        if self.tpdo_cob_id == self.sync_cob_id:
            raise InputError(f"tpdo_cob_id and sync_cob_id (=0x{self.sync_cob_id:X}) must differ")
        for name, f in (("motor", self.motor), ("table", self.table)):
            if f.fmt not in "bhlqBHLQ" or len(f.fmt) != 1:
                raise InputError(f"{name}_type: unknown PDO data type {f.fmt!r}")
            if not 0 <= f.offset_bytes <= 8 - f.size_bytes:
                raise InputError(f"{name}_offset_bytes (={f.offset_bytes}) must leave its "
                                 f"{f.size_bytes} bytes inside the 8-byte PDO")
        a, b = self.motor, self.table
        if a.offset_bytes < b.offset_bytes + b.size_bytes and b.offset_bytes < a.offset_bytes + a.size_bytes:
            raise InputError(f"motor_offset_bytes (={a.offset_bytes}) and table_offset_bytes "
                             f"(={b.offset_bytes}) overlap")
        for name in ("counts_per_rev", "table_nm_per_count"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} (={v!r}) must be > 0")
        for name in ("sync_period_s", "window_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise InputError(f"{name} (={v!r}) must be > 0")

    @property
    def min_length(self) -> int:
        return max(self.motor.offset_bytes + self.motor.size_bytes, self.table.offset_bytes + self.table.size_bytes)

    def decode(self, data: bytes) -> tuple[int, int]:
        """TPDO payload -> (motor counts, table counts)."""
        return (struct.unpack_from("<" + self.motor.fmt, data, self.motor.offset_bytes)[0],
                struct.unpack_from("<" + self.table.fmt, data, self.table.offset_bytes)[0])


def check_cob_id(field: str, cob_id: int) -> None:
    if not isinstance(cob_id, int) or not 0x001 <= cob_id <= 0x7FF:
        shown = f"0x{cob_id:X}" if isinstance(cob_id, int) else repr(cob_id)
        raise InputError(f"{field} (={shown}) must be an 11-bit CAN identifier 0x001..0x7FF")


def pdo_type(field: str, name: str) -> str:
    try:
        return _FMT_BY_TYPE_NAME[name]
    except KeyError:
        raise InputError(f"{field} (={name!r}) must be one of {sorted(_FMT_BY_TYPE_NAME)}") from None


def default_mapping(node_id: int, **overrides) -> ListenMapping:
    """TPDO1 of mebm's own objects (docs/canopen-objects.md): 0x6064 at byte 0, 0x60E4 sub 1 at 4."""
    kw = dict(tpdo_cob_id=co.tpdo1_cob_id(node_id), motor=PdoField(0, "l"), table=PdoField(4, "l"),
              counts_per_rev=131072.0, table_nm_per_count=10.0)
    kw.update(overrides)
    return ListenMapping(**kw)


def mapping_from_eds(path: str | Path, node_id: int, *, counts_per_rev: float | None = None,
                     table_nm_per_count: float | None = None) -> ListenMapping:
    """The listen mapping from a drive's EDS or DCF (canopen's EDS import); arguments override the file."""
    import canopen

    where = f"eds (={str(path)!r})"
    try:  # a regular file of bounded size only: a FIFO or /dev/zero is refused, not read forever
        data = read_regular(path, MAX_EDS_BYTES, "EDS/DCF file")
    except FileRefused as exc:
        raise InputError(f"{where}: {exc}") from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # EDS files are ASCII by CiA 306; a vendor's comments may be Latin-1
    source = io.StringIO(text)
    source.name = str(path)  # canopen tells an EDS from a DCF by the name's suffix
    try:
        od = canopen.import_od(source, node_id)
    except Exception as exc:  # noqa: BLE001 - the library raises many kinds on a bad file
        raise InputError(f"{where}: not a readable EDS/DCF ({type(exc).__name__}: {exc})") from exc

    def value(index: int, sub: int = 0, *, configured_only: bool = False):
        """A DCF's ParameterValue, else the DefaultValue (unless only a configured value will do)."""
        try:
            obj = od[index]
            var = obj[sub] if hasattr(obj, "subindices") else obj
        except KeyError:
            return None
        if getattr(var, "value", None) is not None:
            return var.value
        return None if configured_only else var.default

    found = None
    for n in range(512):
        map_idx, comm_idx = 0x1A00 + n, 0x1800 + n
        if map_idx not in od:
            continue
        count = value(map_idx, 0) or 0
        entries = [value(map_idx, s) or 0 for s in range(1, int(count) + 1)]
        offset, fields = 0, {}
        for e in entries:
            index, sub, bits = e >> 16, (e >> 8) & 0xFF, e & 0xFF
            if bits % 8:
                break  # not byte aligned: not one we can read
            if (index, sub) in ((co.POSITION_ACTUAL, 0), (co.ADDITIONAL_POSITION, 1)):
                try:
                    var = od[index] if sub == 0 else od[index][sub]
                    fmt, size = _INT_TYPES[var.data_type]
                except KeyError:
                    raise InputError(f"{where}: 0x{index:04X} sub {sub} is mapped but not described as an "
                                     "integer in the file") from None
                if size * 8 != bits:
                    raise InputError(f"{where}: 0x{index:04X} sub {sub} is mapped with {bits} bits, its type has "
                                     f"{size * 8}")
                fields[index] = PdoField(offset // 8, fmt)
            offset += bits
        if len(fields) == 2:
            found = (n, comm_idx, fields)
            break
    if found is None:
        raise InputError(f"{where}: no TPDO maps both 0x6064 (position actual value) and 0x60E4 sub 1 "
                         "(additional position actual value): map them into one TPDO, or give the mapping in "
                         f"the configuration (tpdo_cob_id, motor_offset_bytes, table_offset_bytes)")
    n, comm_idx, fields = found
    cob = value(comm_idx, 1)
    if cob is None:
        raise InputError(f"{where}: TPDO{n + 1} has no COB-ID (0x{comm_idx:04X} sub 1)")
    if cob & 0x80000000:
        raise InputError(f"{where}: TPDO{n + 1} (0x{comm_idx:04X} sub 1 = 0x{cob:08X}) is not valid (bit 31 set)")
    ttype = value(comm_idx, 2)
    if ttype is not None and not 1 <= ttype <= 240:
        raise InputError(f"{where}: TPDO{n + 1} transmission type {ttype} is not synchronous (1..240): its "
                         "frames cannot be paired with the master's SYNC")
    if counts_per_rev is None:
        inc, revs = value(co.ENCODER_RESOLUTION, 1), value(co.ENCODER_RESOLUTION, 2)
        if not inc:
            raise InputError(f"{where}: no 0x608F (position encoder resolution) in the file: give "
                             f"counts_per_rev")
        counts_per_rev = inc / max(revs or 1, 1)
    if table_nm_per_count is None:
        table_nm_per_count = value(co.TABLE_NM_PER_COUNT)
        if not table_nm_per_count:
            raise InputError(f"{where}: the table encoder's resolution is not in the file (0x2005): give "
                             f"table_nm_per_count")
    # the cycle the master configured: only a DCF knows it (an EDS default says nothing of this bus)
    period_us = value(co.COMM_CYCLE_PERIOD, configured_only=True)
    window_us = value(co.SYNC_WINDOW, configured_only=True)
    sync_cob = value(0x1005)
    return ListenMapping(
        tpdo_cob_id=int(cob) & 0x7FF, motor=fields[co.POSITION_ACTUAL], table=fields[co.ADDITIONAL_POSITION],
        counts_per_rev=float(counts_per_rev), table_nm_per_count=float(table_nm_per_count),
        sync_cob_id=int(sync_cob) & 0x7FF if sync_cob else co.SYNC_COB_ID,
        sync_period_s=period_us * 1e-6 if period_us else None, window_s=window_us * 1e-6 if window_us else None,
        source=str(path))

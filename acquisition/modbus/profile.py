"""Modbus register profiles: where a controller that does not speak ``mebm-modbus/1`` keeps
the values mebm needs, and how to decode them (docs/controllers.md).

A profile (TOML, ``format = "mebm-modbus-profile/1"``) names, for one axis, the motor
position (-> revolutions), the table position (-> mm) and optionally the temperature
(-> °C), a "program running" flag, a done flag, a start value and an abort value. Each
value has a function (``holding`` 3, ``input`` 4, ``coil`` 1, ``discrete_input`` 2), a
0-based address, a data type (``int16`` ... ``float64``; ``bool`` for coils and discrete
inputs), a byte/word order as libmodbus and Telegraf name them (``ABCD`` big-endian,
``DCBA`` little-endian, ``BADC`` bytes swapped in each word, ``CDAB`` words swapped) and
``scale``/``offset`` (physical = raw * scale + offset).

Pure data and decoding: the words themselves are converted by pymodbus'
``convert_from_registers`` (this module applies the byte swap it lacks). The reads of one
sample are planned here: values of one function close enough together are read with one
request, so when motor and table share one request they come from one PDU (mode
``latched``); otherwise they are read in two requests (mode ``separate``) and the driver
reports the skew uncertainty. :data:`MEBM_MODBUS_1` is mebm's own register map, the
built-in default profile, served by its own wire with the trace ring
(:mod:`acquisition.modbus.register_map`).
"""

from __future__ import annotations

import math
import os
import stat
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from pymodbus.client.mixin import ModbusClientMixin

from core.errors import InputError

FORMAT = "mebm-modbus-profile/1"
BUILTIN = "mebm-modbus/1"  # the default: mebm's own register map with its trace ring

FUNCTIONS = {"coil": 1, "discrete_input": 2, "holding": 3, "input": 4}
_FUNCTION_ALIASES = {1: "coil", 2: "discrete_input", 3: "holding", 4: "input", "coils": "coil",
                     "discrete_inputs": "discrete_input", "holding_register": "holding",
                     "holding_registers": "holding", "input_register": "input", "input_registers": "input"}
BIT_FUNCTIONS = ("coil", "discrete_input")
# data type -> registers it takes (bool: one bit)
TYPES = {"bool": 0, "int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "int64": 4, "uint64": 4,
         "float32": 2, "float64": 4}
# byte/word order: (bytes swapped inside each register, registers least significant first);
# 64-bit values take the same names or their 8-letter forms (Telegraf's ABCDEFGH ...)
ORDERS = {"ABCD": (False, False), "DCBA": (True, True), "BADC": (True, False), "CDAB": (False, True),
          "ABCDEFGH": (False, False), "HGFEDCBA": (True, True), "BADCFEHG": (True, False),
          "GHEFCDAB": (False, True), "AB": (False, False), "BA": (True, False)}
MAX_REGISTERS_PER_READ = 125  # function 3/4 limit
MAX_BITS_PER_READ = 2000  # function 1/2 limit

VALUES = ("motor", "table", "temperature", "running", "done", "start", "abort")
_UNITS = {"motor": "rev", "table": "mm", "temperature": "°C"}
_READ = ("motor", "table", "temperature", "running", "done")  # polled every sample
_VALUE_KEYS = {"function", "address", "type", "order", "scale", "offset", "value", "description"}
_TOP_KEYS = {"format", "name", "description", "max_gap_registers", "update_period_ms", *VALUES}


class ProfileError(InputError):
    """A register profile is invalid; ``field`` is the offending key (``table.address``)."""

    def __init__(self, profile: str, field_: str, message: str):
        self.profile, self.field = profile, field_
        super().__init__(f"Modbus profile {profile!r}: {field_}: {message}")


@dataclass(frozen=True)
class ValueSpec:
    """Where one value lives and how its raw reading becomes a physical one."""

    name: str
    function: str
    address: int
    type: str = "uint16"
    order: str = "ABCD"
    scale: float = 1.0
    offset: float = 0.0
    value: int = 1  # start/abort: what is written

    @property
    def is_bit(self) -> bool:
        return self.function in BIT_FUNCTIONS

    @property
    def count(self) -> int:
        """Registers (or bits) the value takes."""
        return 1 if self.is_bit else TYPES[self.type]

    @property
    def end(self) -> int:
        return self.address + self.count  # one past the last register/bit

    def decode(self, raw: list) -> float:
        """Registers (or one bit) -> physical value (raw * scale + offset)."""
        if self.is_bit:
            return float(bool(raw[0]))
        swap_bytes, low_first = ORDERS[self.order]
        regs = [((r & 0xFF) << 8) | (r >> 8) if swap_bytes else r for r in raw]
        x = ModbusClientMixin.convert_from_registers(
            regs, ModbusClientMixin.DATATYPE[self.type.upper()], word_order="little" if low_first else "big")
        return float(x) * self.scale + self.offset

    def encode(self, physical: float) -> list[int]:
        """Physical value -> registers as this controller would hold them (simulators, tests)."""
        raw = (physical - self.offset) / self.scale
        if self.is_bit:
            return [int(bool(raw))]
        if not self.type.startswith("float"):
            raw = int(round(raw))
        swap_bytes, low_first = ORDERS[self.order]
        regs = ModbusClientMixin.convert_to_registers(
            raw, ModbusClientMixin.DATATYPE[self.type.upper()], word_order="little" if low_first else "big")
        return [((r & 0xFF) << 8) | (r >> 8) if swap_bytes else r for r in regs]

    def truth(self, raw: list) -> bool:
        """A flag's reading: a bit, or a register value other than zero (before scaling)."""
        if self.is_bit:
            return bool(raw[0])
        return any(int(r) for r in raw)


@dataclass(frozen=True)
class ReadRequest:
    """One read of a sample: ``count`` registers (bits) from ``address`` with ``function``,
    holding ``values`` (their names, in address order)."""

    function: str
    address: int
    count: int
    values: tuple[str, ...]

    @property
    def code(self) -> int:
        return FUNCTIONS[self.function]


@dataclass(frozen=True)
class RegisterProfile:
    """A validated register profile (build it with :func:`parse_profile` / :func:`load_profile`)."""

    name: str
    values: Mapping[str, ValueSpec]
    max_gap_registers: int = 8
    update_period_s: float = 0.01  # how often the controller refreshes the registers
    description: str = ""
    reads: tuple[ReadRequest, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "reads", plan_reads([self.values[n] for n in _READ if n in self.values],
                                                     self.max_gap_registers))

    def get(self, name: str) -> ValueSpec | None:
        return self.values.get(name)

    @property
    def latched(self) -> bool:
        """Motor and table come from one request (one PDU), so from one controller update."""
        return any({"motor", "table"} <= set(r.values) for r in self.reads)

    @property
    def mode(self) -> str:
        return "latched" if self.latched else "separate"

    @property
    def can_start(self) -> bool:
        return "start" in self.values

    def decode(self, payloads: list[list]) -> dict[str, float]:
        """The replies to :attr:`reads`, in order -> {value name: physical value}; flags as 0/1."""
        out = {}
        for req, regs in zip(self.reads, payloads, strict=True):
            for name in req.values:
                spec = self.values[name]
                raw = list(regs[spec.address - req.address: spec.end - req.address])
                out[name] = float(spec.truth(raw)) if name in ("running", "done") else spec.decode(raw)
        return out


def plan_reads(specs: list[ValueSpec], max_gap: int) -> tuple[ReadRequest, ...]:
    """Group values of one function into as few reads as the limits allow: a value joins the
    read before it when the registers between them are at most ``max_gap`` and the read stays
    within the function's size limit. Reads come in address order per function; the read
    holding the motor position comes first (a passive driver following the running flag
    reads the flag first: ``ProfileModbusDriver.poll``)."""
    by_fn: dict[str, list[ValueSpec]] = {}
    for s in specs:
        by_fn.setdefault(s.function, []).append(s)
    reads: list[ReadRequest] = []
    for fn, group in by_fn.items():
        limit = MAX_BITS_PER_READ if fn in BIT_FUNCTIONS else MAX_REGISTERS_PER_READ
        cur: list[ValueSpec] = []
        for s in sorted(group, key=lambda v: v.address):
            if cur and (s.address - max(v.end for v in cur) > max_gap or s.end - cur[0].address > limit):
                reads.append(_request(fn, cur))
                cur = []
            cur.append(s)
        reads.append(_request(fn, cur))
    reads.sort(key=lambda r: 0 if "motor" in r.values else 1)
    return tuple(reads)


def _request(fn: str, specs: list[ValueSpec]) -> ReadRequest:
    a0 = specs[0].address
    return ReadRequest(fn, a0, max(s.end for s in specs) - a0, tuple(s.name for s in specs))


# -- parsing and validation --------------------------------------------------------------------
def _num(profile: str, where: str, v, kind, default):
    if v is None:
        return default
    if kind is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, kind) or isinstance(v, bool):
        raise ProfileError(profile, where, f"(={v!r}) must be {'a number' if kind is float else 'an integer'}")
    if kind is float and not math.isfinite(v):
        raise ProfileError(profile, where, f"(={v!r}) must be finite")
    return v


def _value(profile: str, name: str, t) -> ValueSpec:
    if not isinstance(t, Mapping):
        raise ProfileError(profile, name, "must be a table {function, address, type, order, scale, offset}")
    extra = sorted(set(t) - _VALUE_KEYS)
    if extra:
        raise ProfileError(profile, f"{name}.{extra[0]}", f"unknown key (allowed: {sorted(_VALUE_KEYS)})")
    fn = t.get("function")
    fn = _FUNCTION_ALIASES.get(fn, fn)
    if fn not in FUNCTIONS:
        raise ProfileError(profile, f"{name}.function",
                           f"unknown function {t.get('function')!r} (one of {sorted(FUNCTIONS)} or 1..4)")
    if "address" not in t:
        raise ProfileError(profile, f"{name}.address", "must be given (0-based register or bit address)")
    address = _num(profile, f"{name}.address", t["address"], int, 0)
    if not 0 <= address <= 65535:
        raise ProfileError(profile, f"{name}.address", f"(={address}) must be 0..65535")
    bit = fn in BIT_FUNCTIONS
    typ = t.get("type", "bool" if bit else "uint16")
    if typ not in TYPES:
        raise ProfileError(profile, f"{name}.type", f"unknown data type {typ!r} (one of {sorted(TYPES)})")
    if bit != (typ == "bool"):
        raise ProfileError(profile, f"{name}.type", f"{typ!r} does not fit function {fn!r} "
                                                    "(coils and discrete inputs are bool, registers are not)")
    order = str(t.get("order", "ABCD")).upper()
    if order not in ORDERS:
        raise ProfileError(profile, f"{name}.order",
                           f"unknown byte/word order {t.get('order')!r} (ABCD, DCBA, BADC or CDAB)")
    scale = _num(profile, f"{name}.scale", t.get("scale"), float, 1.0)
    if scale == 0.0:
        raise ProfileError(profile, f"{name}.scale", "must not be zero (physical = raw * scale + offset)")
    spec = ValueSpec(name, fn, address, typ, order, scale, _num(profile, f"{name}.offset", t.get("offset"), float, 0.0),
                     _num(profile, f"{name}.value", t.get("value"), int, 1))
    if spec.end - 1 > 65535:
        raise ProfileError(profile, f"{name}.address",
                           f"(={address}) + {spec.count} registers of {typ} runs past register 65535")
    if name in ("motor", "table", "temperature") and bit:
        raise ProfileError(profile, f"{name}.function", f"{fn!r} holds one bit; a {_UNITS[name]} value needs registers")
    if name in ("start", "abort"):
        if fn not in ("coil", "holding"):
            raise ProfileError(profile, f"{name}.function", f"{fn!r} is read-only; {name} is written: coil or holding")
        if not 0 <= spec.value <= 65535 or (bit and spec.value not in (0, 1)):
            raise ProfileError(profile, f"{name}.value", f"(={spec.value}) must be {'0 or 1' if bit else '0..65535'}")
        if not bit and spec.count != 1:
            raise ProfileError(profile, f"{name}.type", f"{typ!r}: {name} is written to one register (int16/uint16)")
    return spec


def parse_profile(doc: Mapping, *, source: str = "profile") -> RegisterProfile:
    """A :class:`RegisterProfile` from a parsed TOML document; :class:`ProfileError` names the field."""
    name = doc.get("name") if isinstance(doc.get("name"), str) and doc.get("name") else source
    if doc.get("format") != FORMAT:
        raise ProfileError(name, "format", f"(={doc.get('format')!r}) must be {FORMAT!r}")
    extra = sorted(set(doc) - _TOP_KEYS)
    if extra:
        raise ProfileError(name, extra[0], f"unknown key (allowed: {sorted(_TOP_KEYS)})")
    values = {k: _value(name, k, doc[k]) for k in VALUES if k in doc}
    for req in ("motor", "table"):
        if req not in values:
            raise ProfileError(name, req, f"must be given (the {req} position is what mebm measures)")
    if "start" in values and not ({"done", "running"} & set(values)):
        raise ProfileError(name, "start", "needs a done or running flag: mebm must see the round trip end")
    # one address space per function (start/abort write the coil or holding table they name)
    specs = sorted(values.values(), key=lambda s: (s.function, s.address))
    for a, b in zip(specs, specs[1:]):
        if a.function == b.function and b.address < a.end:
            what = "coil" if a.function == "coil" else "discrete input" if a.is_bit else f"{a.function} register"
            if a.is_bit:
                raise ProfileError(name, f"{b.name}.address",
                                   f"two values on one {what}: {a.name} and {b.name} both at {b.address}")
            raise ProfileError(name, f"{b.name}.address",
                               f"overlapping registers: {b.name} ({b.function} {b.address}..{b.end - 1}) overlaps "
                               f"{a.name} ({a.function} {a.address}..{a.end - 1})")
    max_gap = _num(name, "max_gap_registers", doc.get("max_gap_registers"), int, 8)
    if not 0 <= max_gap <= MAX_REGISTERS_PER_READ:
        raise ProfileError(name, "max_gap_registers", f"(={max_gap}) must be 0..{MAX_REGISTERS_PER_READ}")
    period_ms = _num(name, "update_period_ms", doc.get("update_period_ms"), float, 10.0)
    if not period_ms > 0:
        raise ProfileError(name, "update_period_ms", f"(={period_ms}) must be > 0")
    desc = doc.get("description", "")
    return RegisterProfile(name, values, max_gap, period_ms / 1000.0, desc if isinstance(desc, str) else "")


MAX_PROFILE_BYTES = 65536  # a profile is a few dozen lines; a larger file is not one


def load_profile(path: str | Path) -> RegisterProfile:
    """Read and validate a profile file; errors name the file and the field.

    Only a regular file of at most ``MAX_PROFILE_BYTES`` is read, and never more than
    that (a device such as /dev/zero, a FIFO or a huge file is refused at once). An error
    never quotes the file's text or a parse position: the name may point at a file that is
    not a profile at all."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise ProfileError(str(p), "file", f"cannot read it: {exc.strerror or exc}") from exc
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ProfileError(str(p), "file", "not a regular file")
        if info.st_size > MAX_PROFILE_BYTES:
            raise ProfileError(str(p), "file", f"larger than {MAX_PROFILE_BYTES} bytes: not a register profile")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(MAX_PROFILE_BYTES + 1)
    except OSError as exc:
        raise ProfileError(str(p), "file", f"cannot read it: {exc.strerror or exc}") from exc
    finally:
        os.close(fd)
    if len(data) > MAX_PROFILE_BYTES:
        raise ProfileError(str(p), "file", f"larger than {MAX_PROFILE_BYTES} bytes: not a register profile")
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        raise ProfileError(str(p), "file", "not a valid TOML text in UTF-8") from None
    return parse_profile(doc, source=str(p))

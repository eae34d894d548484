"""Modbus TCP register map ``mebm-modbus/1`` (docs/register-map.md): addresses and word codecs.

All data are holding registers (function 3 read, 16 write), 0-based addresses.
32-bit values use two registers, high word first. Together with
:mod:`acquisition.scale`, this is the only module that sees raw register words: the
driver (:mod:`acquisition.modbus.driver`) asks :class:`RegisterMapV1` where to read and gets
typed values back (:class:`StatusBlock`, :class:`MapConfig`, unwrapped counters and
physical positions). A register profile for another controller is another
object with the same methods, handed to the driver as ``register_map``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.scale import EncoderScale
from acquisition.types import AxisState, Command, ControllerStatus, RoundTripProgram

MAP_VERSION = 1

# status block (read-only), one read returns a whole latched sample
MAP_VERSION_REG = 0
AXIS_STATE = 1
FAULT_CODE = 2
SAMPLE_COUNTER = 3  # u32
MOTOR_POS = 5  # i32 counts
TABLE_POS = 7  # i32 counts
TEMPERATURE = 9  # i16, 0.01 degC
TRACE_FIRST = 10  # u32: counter of the first sample of the current trace
TRACE_COUNT = 12  # u32: records written to the trace buffer in the current trace
STATUS_WORDS = 14

# configuration block (read-only)
COUNTS_PER_REV = 20  # u32
TABLE_NM_PER_COUNT = 22  # u32, nm
SERVO_RATE_HZ = 24  # u32, Hz
RING_RECORDS = 26  # u16
RECORD_WORDS_REG = 27  # u16
CONFIG_BASE, CONFIG_WORDS = 20, 8

# control block (write with one function-16 request: parameters then command)
COMMAND = 40  # u16: 1 start, 2 abort, 3 acknowledge
START_UM = 41  # i32 µm
END_UM = 43  # i32 µm
FEED_UM_MIN = 45  # u32 µm/min
ACCEL_MM_S2 = 47  # u16 mm/s²
DWELL_MS = 48  # u16 ms
CONTROL_WORDS = 9

# trace ring buffer: record w of the current trace at RING_BASE + RECORD_WORDS * (w % RING_RECORDS)
RING_BASE = 100
RECORD_WORDS = 6  # counter u32, motor i32, table i32
MAX_READ_WORDS = 125  # Modbus limit for function 3
RECORDS_PER_READ = MAX_READ_WORDS // RECORD_WORDS  # 20


def register_count(ring_records: int) -> int:
    return RING_BASE + RECORD_WORDS * ring_records


def split32(values) -> np.ndarray:
    """int array -> (n, 2) uint16 words, high word first (two's complement for negatives)."""
    v = np.asarray(values, dtype=np.int64) & 0xFFFFFFFF
    return np.stack([(v >> 16) & 0xFFFF, v & 0xFFFF], axis=-1).astype(np.uint16)


def join_u32(hi, lo) -> np.ndarray:
    return (np.asarray(hi, dtype=np.int64) << 16) | np.asarray(lo, dtype=np.int64)


def join_i32(hi, lo) -> np.ndarray:
    u = join_u32(hi, lo)
    return np.where(u >= 2**31, u - 2**32, u)


def words(regs) -> np.ndarray:
    return np.asarray(regs, dtype=np.int64)


@dataclass(frozen=True)
class StatusBlock:
    """The status block (registers 0..13): axis state and the sample latched in the last servo
    cycle. ``state`` is None for a state code mebm does not know (``state_raw`` keeps it);
    ``counter``, ``trace_first`` and ``trace_count`` are the u32 values on the wire."""

    version: int
    state: AxisState | None
    state_raw: int
    fault_code: int
    counter: int
    motor_counts: int
    table_counts: int
    temperature_c: float
    trace_first: int
    trace_count: int

    def controller_status(self, servo_rate_hz: float = float("nan")) -> ControllerStatus:
        """As the driver base class reads it (the caller has refused an unknown ``state``)."""
        return ControllerStatus(self.state, self.fault_code, self.temperature_c, servo_rate_hz)


@dataclass(frozen=True)
class MapConfig:
    """The configuration block (registers 20..27) with the map version of register 0."""

    version: int
    scale: EncoderScale
    servo_rate_hz: float
    ring_records: int
    record_words: int


def decode_status(regs) -> StatusBlock:
    """Status block (registers 0..13) -> :class:`StatusBlock`."""
    r = words(regs)
    temp = int(r[TEMPERATURE])
    temp = temp - 65536 if temp >= 32768 else temp
    raw = int(r[AXIS_STATE])
    return StatusBlock(
        version=int(r[MAP_VERSION_REG]),
        state=AxisState(raw) if raw in AxisState._value2member_map_ else None,
        state_raw=raw,
        fault_code=int(r[FAULT_CODE]),
        counter=int(join_u32(r[SAMPLE_COUNTER], r[SAMPLE_COUNTER + 1])),
        motor_counts=int(join_i32(r[MOTOR_POS], r[MOTOR_POS + 1])),
        table_counts=int(join_i32(r[TABLE_POS], r[TABLE_POS + 1])),
        temperature_c=temp / 100.0,
        trace_first=int(join_u32(r[TRACE_FIRST], r[TRACE_FIRST + 1])),
        trace_count=int(join_u32(r[TRACE_COUNT], r[TRACE_COUNT + 1])),
    )


def decode_config(regs, version: int = MAP_VERSION) -> MapConfig:
    """Configuration block (registers 20..27) -> :class:`MapConfig`."""
    r = words(regs)
    return MapConfig(
        version=int(version),
        scale=EncoderScale(counts_per_rev=int(join_u32(r[0], r[1])), table_nm_per_count=float(join_u32(r[2], r[3]))),
        servo_rate_hz=float(join_u32(r[4], r[5])),
        ring_records=int(r[6]),
        record_words=int(r[7]),
    )


def encode_config(scale: EncoderScale, servo_rate_hz: float, ring_records: int) -> list[int]:
    w = np.concatenate([
        split32([scale.counts_per_rev, int(round(scale.table_nm_per_count)), int(round(servo_rate_hz))]).ravel(),
        [ring_records, RECORD_WORDS],
    ])
    return [int(x) for x in w]


def encode_program(program: RoundTripProgram, command: int) -> list[int]:
    """Control block words (COMMAND..DWELL_MS) that start ``program``."""
    w = split32([
        round(program.start_mm * 1000), round(program.end_mm * 1000), round(program.feed_mm_min * 1000)
    ]).ravel()
    accel = min(int(round(program.acceleration_mm_s2)), 65535)
    dwell = min(int(round(program.dwell_s * 1000)), 65535)
    return [int(command)] + [int(x) for x in w] + [accel, dwell]


def decode_program(regs) -> RoundTripProgram:
    """Control words (START_UM..DWELL_MS, i.e. registers 41..48) -> program."""
    r = words(regs)
    return RoundTripProgram(
        start_mm=int(join_i32(r[0], r[1])) / 1000.0,
        end_mm=int(join_i32(r[2], r[3])) / 1000.0,
        feed_mm_min=int(join_u32(r[4], r[5])) / 1000.0,
        acceleration_mm_s2=float(r[6]),
        dwell_s=float(r[7]) / 1000.0,
    )


def encode_records(records: np.ndarray) -> np.ndarray:
    """(n, 3) int counter/motor/table -> flat uint16 words (n * RECORD_WORDS)."""
    return split32(records).reshape(-1)


def decode_records(regs, scale: EncoderScale) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat record words -> (u32 counters, motor rev, table mm)."""
    w = np.array(regs, dtype=">u2")  # big-endian words: high word first is plain big-endian 32 bit
    counter = w.view(">u4")[0::3].astype(np.int64)
    pos = w.view(">i4").reshape(-1, 3)
    return counter, scale.motor_rev(pos[:, 1]), scale.table_mm(pos[:, 2])


def encode_status(state: int, fault_code: int, counter: int, motor: int, table: int, temperature_c: float,
                  trace_first: int, trace_count: int) -> list[int]:
    t = int(round(temperature_c * 100)) & 0xFFFF
    w32 = split32([counter, motor, table]).ravel()
    tr = split32([trace_first, trace_count]).ravel()
    return [MAP_VERSION, int(state), int(fault_code) & 0xFFFF, *map(int, w32), t, *map(int, tr)]


def unwrap_u32(counter_u32, reference: int) -> np.ndarray:
    """Unwrap u32 counters to the int64 values nearest ``reference``."""
    c = np.asarray(counter_u32, dtype=np.int64)
    d = (c - reference) & 0xFFFFFFFF
    d = np.where(d >= 2**31, d - 2**32, d)
    return reference + d


def new_records(regs, n: int, expected: int) -> tuple[int, int]:
    """How many of a ring block's ``n`` records are new, given the next ``expected`` counter,
    and the counter expected after them. Records after the newest are older (not yet
    overwritten in this lap)."""
    w = RECORD_WORDS
    e = expected & 0xFFFFFFFF
    first = (regs[0] << 16) | regs[1]
    last = (regs[(n - 1) * w] << 16) | regs[(n - 1) * w + 1]
    if first == e and last == (e + n - 1) & 0xFFFFFFFF:
        return n, expected + n  # the common case: n consecutive new records
    counter = unwrap_u32(join_u32(regs[0::w][:n], regs[1::w][:n]), expected)
    prev = np.concatenate([[expected - 1], counter[:-1]])
    ok = counter > prev
    k = int(np.argmin(ok)) if not ok.all() else n
    return k, (int(counter[k - 1]) + 1 if k else expected)


class RegisterMapV1:
    """``mebm-modbus/1`` as the driver sees it: where each block is, and its decoding into
    typed values in physical units. Counters come back unwrapped to int64 against the
    reference the caller holds (the u32 wrap never leaves this module)."""

    name = "mebm-modbus/1"
    version = MAP_VERSION
    header = (0, CONFIG_BASE + CONFIG_WORDS)  # (address, count): version and configuration in one read
    status = (0, STATUS_WORDS)
    records_per_read = RECORDS_PER_READ

    def decode_header(self, regs) -> MapConfig:
        return decode_config(regs[CONFIG_BASE:CONFIG_BASE + CONFIG_WORDS], version=int(regs[MAP_VERSION_REG]))

    def layout_ok(self, cfg: MapConfig) -> bool:
        return cfg.record_words == RECORD_WORDS and cfg.ring_records >= RECORDS_PER_READ

    def decode_status(self, regs) -> StatusBlock:
        return decode_status(regs)

    def start(self, program: RoundTripProgram) -> tuple[int, list[int]]:
        """(address, words) of the one function-16 write that sends the program and START."""
        return COMMAND, encode_program(program, Command.START)

    def command(self, command: Command) -> tuple[int, list[int]]:
        return COMMAND, [int(command)]

    def ring_read(self, slot: int, ring_records: int) -> tuple[int, int, int]:
        """(address, count, records) of one block read from ring slot ``slot``."""
        n = min(RECORDS_PER_READ, ring_records - slot)
        return RING_BASE + slot * RECORD_WORDS, n * RECORD_WORDS, n

    def new_records(self, regs, n: int, expected: int) -> tuple[int, int]:
        return new_records(regs, n, expected)

    def record_words(self, k: int) -> int:
        return k * RECORD_WORDS

    def decode_records(self, regs, scale: EncoderScale, reference: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ring words -> (counter unwrapped near ``reference``, motor_rev, table_mm)."""
        counter_u32, motor, table = decode_records(regs, scale)
        return unwrap_u32(counter_u32, reference), motor, table

    def latched_sample(self, status: StatusBlock, scale: EncoderScale, reference: int):
        """The sample of a status read -> (counter unwrapped near ``reference``, motor_rev, table_mm), arrays of one."""
        return (unwrap_u32([status.counter], reference), scale.motor_rev([status.motor_counts]),
                scale.table_mm([status.table_counts]))

    # separate (unlatched) reads: motor with the status words before the table, table alone
    separate_first = (0, TABLE_POS)
    separate_table = (TABLE_POS, 2)

    def join_separate(self, first, table) -> StatusBlock:
        return decode_status(list(first) + list(table) + [0] * (STATUS_WORDS - TABLE_POS - 2))


MEBM_MODBUS_1 = RegisterMapV1()

"""CANopen objects used by mebm (docs/canopen-objects.md): indices, the object dictionary, PDO codec.

The drive maps motor position 0x6064 and the linear encoder 0x60E4 sub 1 (CiA 402
additional position actual value) together into TPDO1, transmitted on every SYNC.
Together with :mod:`acquisition.scale`, this is the only module that sees raw counts
on the CAN side.
"""

from __future__ import annotations

import struct

from canopen import objectdictionary as odm

OBJECTS_VERSION = 1

DEVICE_TYPE = 0x1000
COMM_CYCLE_PERIOD = 0x1006  # u32 µs: SYNC period (machine time per SYNC)
SYNC_WINDOW = 0x1007  # u32 µs: synchronous window; a sync TPDO not sent within it is discarded
PRODUCER_HEARTBEAT = 0x1017  # u16 ms
TPDO1_COMM = 0x1800  # sub1 COB-ID, sub2 transmission type (1: every SYNC)
TPDO1_MAP = 0x1A00
POSITION_ACTUAL = 0x6064  # i32 motor encoder counts
ADDITIONAL_POSITION = 0x60E4  # sub1: i32 linear (table) encoder counts
ENCODER_RESOLUTION = 0x608F  # sub1 increments, sub2 motor revolutions
PROGRAM = 0x2000  # sub1 start µm i32, sub2 end µm i32, sub3 feed µm/min u32, sub4 accel mm/s² u16, sub5 dwell ms u16
COMMAND = 0x2001  # u16: 1 start, 2 abort, 3 acknowledge
AXIS_STATE = 0x2002  # u16: 0 idle, 1 running, 2 done, 3 aborted, 4 fault
TEMPERATURE = 0x2003  # i16 0.01 degC
FAULT_CODE = 0x2004  # u16, last EMCY error code
TABLE_NM_PER_COUNT = 0x2005  # u32 nm
OBJECTS_VERSION_IDX = 0x2006  # u16
# CiA 402 (standard) objects, used by the active-cia402 mode and by a CNC master in CSP
CONTROLWORD = 0x6040  # u16
STATUSWORD = 0x6041  # u16
MODES_OF_OPERATION = 0x6060  # i8: 1 profile position, 8 cyclic synchronous position
MODES_DISPLAY = 0x6061  # i8
POSITION_WINDOW = 0x6067  # u32 increments: target reached within this of the target
TARGET_POSITION = 0x607A  # i32 increments (position factor 1: user units are encoder increments)
PROFILE_VELOCITY = 0x6081  # u32 increments/s
PROFILE_ACCELERATION = 0x6083  # u32 increments/s²
PROFILE_DECELERATION = 0x6084  # u32 increments/s²
RPDO1_COMM = 0x1400  # sub1 COB-ID, sub2 transmission type (1: applied on the next SYNC)
RPDO1_MAP = 0x1600
MODE_PROFILE_POSITION = 1
MODE_CYCLIC_SYNC_POSITION = 8
RPDO1_MAPPING = (0x60400010, 0x607A0020)  # controlword, target position (a CNC master in CSP)
RPDO_STRUCT = struct.Struct("<Hl")
# statusword bits (CiA 402)
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5
SW_SWITCH_ON_DISABLED = 1 << 6
SW_TARGET_REACHED = 1 << 10
SW_SETPOINT_ACK = 1 << 12  # PP: set-point acknowledge; CSP: drive follows the command value
# controlword commands (CiA 402 device control)
CW_SHUTDOWN = 0x06
CW_SWITCH_ON = 0x07
CW_ENABLE_OPERATION = 0x0F
CW_NEW_SETPOINT = 1 << 4  # PP: rising edge takes 0x607A
CW_FAULT_RESET = 1 << 7

DEVICE_TYPE_CIA402 = 0x00020192
TPDO1_MAPPING = (0x60640020, 0x60E40120)  # index << 16 | sub << 8 | bits
SYNC_COB_ID = 0x80
TPDO_STRUCT = struct.Struct("<ll")


def tpdo1_cob_id(node_id: int) -> int:
    return 0x180 + node_id


def decode_tpdo1(data: bytes) -> tuple[int, int]:
    """TPDO1 payload -> (motor counts, table counts)."""
    return TPDO_STRUCT.unpack_from(data)


def encode_tpdo1(motor_counts: int, table_counts: int) -> bytes:
    return TPDO_STRUCT.pack(int(motor_counts), int(table_counts))


def rpdo1_cob_id(node_id: int) -> int:
    return 0x200 + node_id


def encode_rpdo1(controlword: int, target_counts: int) -> bytes:
    return RPDO_STRUCT.pack(int(controlword), int(target_counts))


def decode_rpdo1(data: bytes) -> tuple[int, int]:
    """RPDO1 payload -> (controlword, target position counts)."""
    return RPDO_STRUCT.unpack_from(data)


def _var(name, index, sub, dtype, access="rw", default=None):
    v = odm.ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    return v


def _record(name, index, members):
    rec = odm.ODRecord(name, index)
    rec.add_member(_var(f"{name} entries", index, 0, odm.UNSIGNED8, "ro", len(members)))
    for sub, (mname, dtype, access, default) in enumerate(members, start=1):
        rec.add_member(_var(mname, index, sub, dtype, access, default))
    return rec


def object_dictionary(node_id: int, *, counts_per_rev: int = 131072, table_nm_per_count: int = 10) -> odm.ObjectDictionary:
    """The object dictionary of a mebm-compatible drive (used by the simulated drive and the driver)."""
    od = odm.ObjectDictionary()
    od.add_object(_var("Device type", DEVICE_TYPE, 0, odm.UNSIGNED32, "ro", DEVICE_TYPE_CIA402))
    od.add_object(_var("Communication cycle period", COMM_CYCLE_PERIOD, 0, odm.UNSIGNED32, "rw", 1000))
    od.add_object(_var("Synchronous window length", SYNC_WINDOW, 0, odm.UNSIGNED32, "rw", 0))
    od.add_object(_var("Producer heartbeat time", PRODUCER_HEARTBEAT, 0, odm.UNSIGNED16, "rw", 0))
    od.add_object(_record("TPDO1 communication", TPDO1_COMM, [
        ("COB-ID", odm.UNSIGNED32, "rw", tpdo1_cob_id(node_id)),
        ("Transmission type", odm.UNSIGNED8, "rw", 1),
    ]))
    od.add_object(_record("TPDO1 mapping", TPDO1_MAP, [
        ("Mapped object 1", odm.UNSIGNED32, "rw", TPDO1_MAPPING[0]),
        ("Mapped object 2", odm.UNSIGNED32, "rw", TPDO1_MAPPING[1]),
    ]))
    od.add_object(_var("Position actual value", POSITION_ACTUAL, 0, odm.INTEGER32, "ro", 0))
    add = odm.ODRecord("Additional position actual value", ADDITIONAL_POSITION)
    add.add_member(_var("Number of entries", ADDITIONAL_POSITION, 0, odm.UNSIGNED8, "ro", 1))
    add.add_member(_var("Linear encoder", ADDITIONAL_POSITION, 1, odm.INTEGER32, "ro", 0))
    od.add_object(add)
    od.add_object(_record("Position encoder resolution", ENCODER_RESOLUTION, [
        ("Encoder increments", odm.UNSIGNED32, "ro", counts_per_rev),
        ("Motor revolutions", odm.UNSIGNED32, "ro", 1),
    ]))
    od.add_object(_record("Round-trip program", PROGRAM, [
        ("Start position um", odm.INTEGER32, "rw", 0),
        ("End position um", odm.INTEGER32, "rw", 0),
        ("Feed um per min", odm.UNSIGNED32, "rw", 0),
        ("Acceleration mm per s2", odm.UNSIGNED16, "rw", 500),
        ("Dwell ms", odm.UNSIGNED16, "rw", 200),
    ]))
    od.add_object(_var("Command", COMMAND, 0, odm.UNSIGNED16, "rw", 0))
    od.add_object(_var("Axis state", AXIS_STATE, 0, odm.UNSIGNED16, "ro", 0))
    od.add_object(_var("Temperature", TEMPERATURE, 0, odm.INTEGER16, "ro", 2000))
    od.add_object(_var("Fault code", FAULT_CODE, 0, odm.UNSIGNED16, "ro", 0))
    od.add_object(_var("Table nm per count", TABLE_NM_PER_COUNT, 0, odm.UNSIGNED32, "ro", table_nm_per_count))
    od.add_object(_var("mebm objects version", OBJECTS_VERSION_IDX, 0, odm.UNSIGNED16, "ro", OBJECTS_VERSION))
    add_cia402_objects(od, node_id)
    return od


def add_cia402_objects(od: odm.ObjectDictionary, node_id: int) -> None:
    """The standard CiA 402 objects of position control (device control, PP and CSP), and
    RPDO1 (controlword, target position: what a CNC master sends each SYNC in CSP)."""
    od.add_object(_record("RPDO1 communication", RPDO1_COMM, [
        ("COB-ID", odm.UNSIGNED32, "rw", rpdo1_cob_id(node_id)),
        ("Transmission type", odm.UNSIGNED8, "rw", 1),
    ]))
    od.add_object(_record("RPDO1 mapping", RPDO1_MAP, [
        ("Mapped object 1", odm.UNSIGNED32, "rw", RPDO1_MAPPING[0]),
        ("Mapped object 2", odm.UNSIGNED32, "rw", RPDO1_MAPPING[1]),
    ]))
    od.add_object(_var("Controlword", CONTROLWORD, 0, odm.UNSIGNED16, "rw", 0))
    od.add_object(_var("Statusword", STATUSWORD, 0, odm.UNSIGNED16, "ro", 0))
    od.add_object(_var("Modes of operation", MODES_OF_OPERATION, 0, odm.INTEGER8, "rw", 0))
    od.add_object(_var("Modes of operation display", MODES_DISPLAY, 0, odm.INTEGER8, "ro", 0))
    od.add_object(_var("Position window", POSITION_WINDOW, 0, odm.UNSIGNED32, "rw", 200))
    od.add_object(_var("Target position", TARGET_POSITION, 0, odm.INTEGER32, "rw", 0))
    od.add_object(_var("Profile velocity", PROFILE_VELOCITY, 0, odm.UNSIGNED32, "rw", 0))
    od.add_object(_var("Profile acceleration", PROFILE_ACCELERATION, 0, odm.UNSIGNED32, "rw", 0))
    od.add_object(_var("Profile deceleration", PROFILE_DECELERATION, 0, odm.UNSIGNED32, "rw", 0))

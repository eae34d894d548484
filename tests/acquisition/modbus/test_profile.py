"""Register profiles: decoding of every type and order, read planning, refusals that name
the field, URLs."""

from __future__ import annotations

import struct
import textwrap
from pathlib import Path

import pytest

from acquisition.modbus.driver import ModbusDriver
from acquisition.modbus.polled import ProfileModbusDriver
from acquisition.modbus.profile import ProfileError, ValueSpec, load_profile, parse_profile
from acquisition.url import driver_from_url
from api.service.config.loading import load_settings
from api.service.config.settings import ConfigError
from core.errors import InputError

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "modbus-profiles"


def _doc(**values):
    doc = {"format": "mebm-modbus-profile/1", "name": "t",
           "motor": {"function": "holding", "address": 0, "type": "int32"},
           "table": {"function": "holding", "address": 2, "type": "int32"}}
    for k, v in values.items():
        if v is None:
            doc.pop(k, None)
        elif isinstance(v, dict) and k in doc and isinstance(doc[k], dict):
            doc[k] = {**doc[k], **v}
        else:
            doc[k] = v
    return doc


# -- decoding ------------------------------------------------------------------------------------
_FMT = {"int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f",
        "float64": "d"}


def _words(typ: str, order: str, x) -> list[int]:
    """The registers a controller holds for ``x``, built byte by byte from the order's letters."""
    big = struct.pack(">" + _FMT[typ], x)  # A B C D ... (most significant byte first)
    n = len(big)
    if n == 2:
        seq = big if order in ("ABCD", "CDAB") else big[::-1]
    else:
        letters = "ABCDEFGH"[:n]
        pattern = {"ABCD": letters, "DCBA": letters[::-1],
                   "BADC": "".join(letters[i + 1] + letters[i] for i in range(0, n, 2)),
                   "CDAB": "".join(letters[i:i + 2] for i in range(n - 2, -2, -2))}[order]
        seq = bytes(big[letters.index(ch)] for ch in pattern)
    return [seq[i] << 8 | seq[i + 1] for i in range(0, n, 2)]


@pytest.mark.parametrize("order", ["ABCD", "DCBA", "BADC", "CDAB"])
@pytest.mark.parametrize("typ,raw", [("int16", -1234), ("uint16", 54321), ("int32", -123456789),
                                     ("uint32", 3_000_000_000), ("int64", -(2**40) - 7), ("float32", -12.5),
                                     ("float64", 1234.5678901234)])
def test_every_type_and_order_decodes_to_the_physical_value(typ, order, raw):
    spec = ValueSpec("motor", "holding", 0, typ, order, scale=0.5, offset=1.0)
    regs = _words(typ, order, raw)
    assert spec.decode(regs) == pytest.approx(raw * 0.5 + 1.0, rel=1e-12)
    assert spec.encode(raw * 0.5 + 1.0) == regs


def test_float32_cdab_is_words_swapped():
    # 1.0f = 0x3F800000: CDAB puts the low word first
    assert _words("float32", "CDAB", 1.0) == [0x0000, 0x3F80]
    assert ValueSpec("m", "holding", 0, "float32", "CDAB").decode([0x0000, 0x3F80]) == 1.0


# -- read planning -------------------------------------------------------------------------------
def test_values_in_one_block_are_read_with_one_request_and_are_latched():
    p = parse_profile(_doc(temperature={"function": "holding", "address": 10, "type": "int16"}))
    assert p.mode == "latched" and p.latched
    assert [(r.function, r.address, r.count, r.values) for r in p.reads] == [
        ("holding", 0, 11, ("motor", "table", "temperature"))]


def test_values_too_far_apart_or_of_different_functions_are_read_separately():
    far = parse_profile(_doc(table={"address": 40}, max_gap_registers=8))
    assert far.mode == "separate" and len(far.reads) == 2
    near = parse_profile(_doc(table={"address": 40}, max_gap_registers=38))
    assert near.mode == "latched" and near.reads[0].count == 42
    other_fn = parse_profile(_doc(table={"function": "input"}))
    assert other_fn.mode == "separate"
    # one request may not exceed 125 registers, however small the gap allowed
    too_long = parse_profile(_doc(table={"address": 124}, max_gap_registers=125))
    assert too_long.mode == "separate"


def test_the_example_profiles_load_with_the_modes_they_document():
    assert load_profile(EXAMPLES / "plc-gateway-float32-cdab.toml").mode == "latched"
    assert load_profile(EXAMPLES / "drive-int32-input-separate.toml").mode == "separate"


# -- refusals naming the field ---------------------------------------------------------------------
@pytest.mark.parametrize("change,field,words", [
    (dict(table={"address": 1}), "table.address", "overlapping registers"),
    (dict(table={"type": "int24"}), "table.type", "unknown data type"),
    (dict(motor={"scale": 0}), "motor.scale", "must not be zero"),
    (dict(table={"address": 65536}), "table.address", "0..65535"),
    (dict(table={"address": 65535}), "table.address", "past register 65535"),
    (dict(running={"function": "coil", "address": 3}, start={"function": "coil", "address": 3}),
     "start.address", "two values on one coil"),
    (dict(running={"function": "discrete_input", "address": 5}, done={"function": "discrete_input", "address": 5}),
     "done.address", "two values on one discrete input"),
    (dict(motor={"order": "ACBD"}), "motor.order", "unknown byte/word order"),
    (dict(motor={"function": "fifo"}), "motor.function", "unknown function"),
    (dict(table={"function": "coil", "type": "bool"}), "table.function", "needs registers"),
    (dict(motor={"function": "coil"}), "motor.type", "does not fit"),
    (dict(start={"function": "discrete_input", "address": 0}, done={"function": "coil", "address": 0}),
     "start.function", "read-only"),
    (dict(start={"function": "coil", "address": 0}), "start", "needs a done or running flag"),
    (dict(table=None), "table", "must be given"),
    (dict(format="mebm-modbus-profile/2"), "format", "must be"),
    (dict(motor={"adress": 4}), "motor.adress", "unknown key"),
    (dict(update_period_ms=0), "update_period_ms", "> 0"),
])
def test_a_bad_profile_is_refused_naming_the_field(change, field, words):
    with pytest.raises(ProfileError) as ei:
        parse_profile(_doc(**change))
    assert ei.value.field == field
    assert field in str(ei.value) and words in str(ei.value)


def test_a_bad_profile_is_refused_when_the_configuration_loads(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(textwrap.dedent("""
        format = "mebm-modbus-profile/1"
        [motor]
        function = "holding"
        address = 0
        type = "float32"
        [table]
        function = "holding"
        address = 0
        type = "float32"
    """))
    cfg = tmp_path / "mebm.toml"
    cfg.write_text(textwrap.dedent(f"""
        [[machines]]
        name = "m"
        [[machines.axes]]
        name = "y"
        transmission_mm_per_rev = 6.857
        screw_lead_mm = 16.0
        position_gain_per_s = 30.0
        travel_mm = [0.0, 500.0]
        controller = "modbus://127.0.0.1:502"
        modbus_profile = "{bad}"
    """))
    with pytest.raises(ConfigError) as ei:
        load_settings(cfg)
    msg = str(ei.value)
    assert "machines[0].axes[0].modbus_profile" in msg and "table.address" in msg and "overlapping" in msg
    good = EXAMPLES / "plc-gateway-float32-cdab.toml"
    cfg.write_text(cfg.read_text().replace(str(bad), str(good)))
    url = load_settings(cfg).axes[0].settings.controller_url
    driver = driver_from_url(url)
    assert isinstance(driver, ProfileModbusDriver) and driver.profile.name == "plc-gateway-float32-cdab"


# -- URLs ----------------------------------------------------------------------------------------
def test_rtu_urls_carry_the_line_settings():
    d = driver_from_url("modbus+rtu:///dev/ttyUSB0?baudrate=38400&parity=E&stopbits=1&device_id=3")
    assert isinstance(d, ModbusDriver) and not isinstance(d, ProfileModbusDriver) and d.mode == "trace"
    assert d.serial == dict(baudrate=38400, parity="E", stopbits=1, bytesize=8) and d.device_id == 3
    assert d.describe() == "modbus+rtu:///dev/ttyUSB0"
    p = driver_from_url(f"modbus+rtu:///dev/ttyS1?profile={EXAMPLES / 'drive-int32-input-separate.toml'}")
    assert isinstance(p, ProfileModbusDriver) and p.mode == "separate" and p.serial["baudrate"] == 19200


@pytest.mark.parametrize("url,words", [
    ("modbus+rtu:///dev/ttyUSB0?parity=X", "parity"),
    ("modbus+rtu:///dev/ttyUSB0?stopbits=3", "stopbits"),
    ("modbus+rtu://host/dev/ttyUSB0", "modbus+rtu:///dev/"),
    ("modbus://plc:502?baudrate=9600", "unknown option"),
    ("modbus://plc:502?device_id=300", "device_id"),
    ("modbus://plc:502?profile=/nonexistent/p.toml", "cannot read"),
])
def test_bad_modbus_urls_are_refused_naming_the_option(url, words):
    with pytest.raises(InputError) as ei:
        driver_from_url(url)
    assert words in str(ei.value)


# -- the driver's two entry points: poll one sample (passive), start the PLC's program (active) ----
def _plc(profile):
    from acquisition.sim.axis import SimAxis
    from acquisition.sim.modbus.profile_server import SimProfileController
    from acquisition.sim.twin import KinematicTwin
    from tests.acquisition.conftest import PROGRAM

    axis = SimAxis(KinematicTwin(backlash_um=120.0), servo_rate_hz=1000.0, time_scale=10.0)
    return axis, SimProfileController(axis, profile, PROGRAM)


def test_poll_reads_one_sample_with_its_flags():
    import asyncio

    profile = load_profile(EXAMPLES / "plc-gateway-float32-cdab.toml")
    axis, sim = _plc(profile)
    with sim:
        d = ProfileModbusDriver("127.0.0.1", sim.port, profile=profile, timeout_s=2.0)

        async def two_polls():
            await d.connect()
            try:
                return await d.poll(), await d.poll()
            finally:
                await d.close()

        a, b = asyncio.run(two_polls())
    assert (a.motor_rev, a.table_mm, a.running, a.done) == (0.0, 0.0, False, False)
    assert a.temperature_c == pytest.approx(axis.twin.temperature_c, abs=0.1) and a.skew_s == 0.0
    assert b.t_s > a.t_s


def test_a_profile_without_start_refuses_an_active_measurement_and_moves_nothing():
    from acquisition.measurement import run_cycle
    from tests.acquisition.conftest import AXIS, PROGRAM

    doc = _doc(running={"function": "discrete_input", "address": 0})
    profile = parse_profile(doc)
    assert not profile.can_start
    axis, sim = _plc(profile)
    with sim:
        r = run_cycle(ProfileModbusDriver("127.0.0.1", sim.port, profile=profile, timeout_s=2.0), AXIS, PROGRAM)
    assert not r.ok and "no start value" in r.reason and r.result is None
    assert axis.cycles_started == 0


# -- reading a profile file: a regular file, bounded, errors that quote nothing ---------------
def test_a_device_or_a_folder_is_refused_at_once_without_being_read(tmp_path):
    for path in ("/dev/zero", tmp_path):
        with pytest.raises(ProfileError, match="not a regular file"):
            load_profile(path)


def test_a_file_larger_than_a_profile_is_refused(tmp_path):
    from acquisition.modbus.profile import MAX_PROFILE_BYTES

    big = tmp_path / "big.toml"
    big.write_text("# x\n" * (MAX_PROFILE_BYTES // 4 + 1))
    with pytest.raises(ProfileError, match="larger than 65536 bytes"):
        load_profile(big)


def test_a_file_that_is_not_toml_is_refused_without_quoting_it(tmp_path):
    secret = tmp_path / "secret.toml"
    secret.write_text("root:$6$s3cr3t-hash:19000:0:99999:7:::\n")
    with pytest.raises(ProfileError) as ei:
        load_profile(secret)
    assert "s3cr3t" not in str(ei.value) and "line" not in str(ei.value) and "column" not in str(ei.value)

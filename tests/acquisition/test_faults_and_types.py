"""Fault specs, encoder scale, program and URL parsing."""

from __future__ import annotations

import math

import pytest

from acquisition.canopen.driver import CanopenDriver
from acquisition.modbus.driver import ModbusDriver
from acquisition.scale import EncoderScale
from acquisition.sim.faults import Fault, parse_fault
from acquisition.types import RoundTripProgram
from acquisition.url import driver_from_url
from core.errors import InputError


def test_parse_fault():
    f = parse_fault("emcy:at=0.25,code=0x7305")
    assert f == Fault("emcy", at=0.25, params={"code": 0x7305})
    assert parse_fault("drop:for=2").for_s == 2.0
    assert parse_fault("lost").value("n") == 5
    assert math.isinf(parse_fault("slow").for_s)


@pytest.mark.parametrize("bad", ["nope", "emcy:at=2", "lost:n", "jump:mm=x", "drop:zzz=1", "stuck:cycles=0"])
def test_parse_fault_rejects(bad):
    with pytest.raises(InputError):
        parse_fault(bad)


def test_scale_round_trip():
    s = EncoderScale(counts_per_rev=131072, table_nm_per_count=10)
    assert s.motor_rev(s.motor_counts(1.25)) == 1.25
    assert s.table_mm(s.table_counts(12.34567)) == pytest.approx(12.34567, abs=5e-6)
    with pytest.raises(InputError):
        EncoderScale(counts_per_rev=0)


def test_program_validation_names_the_value():
    with pytest.raises(InputError, match="feed_mm_min"):
        RoundTripProgram(0, 10, 0)
    with pytest.raises(InputError, match="travel"):
        RoundTripProgram(5, 5, 100)
    assert RoundTripProgram(0, 100, 6000, acceleration_mm_s2=1e9, dwell_s=0).duration_s == pytest.approx(2.0, rel=1e-3)


def test_urls():
    d = driver_from_url("modbus://10.0.0.5:1502?mode=separate", timeout_s=0.5)
    assert isinstance(d, ModbusDriver) and d.port == 1502 and d.mode == "separate" and not d.latched
    d = driver_from_url("canopen://socketcan/can0?node=5&rate_hz=500&bitrate=500000&trigger=active")
    assert isinstance(d, CanopenDriver) and d.interface == "socketcan" and d.channel == "can0"
    assert d.bus_kwargs == {"bitrate": 500000}
    assert d.node_id == 5 and d.sync_rate_hz == 500
    for bad in ("http://x", "canopen://virtual/x", "canopen://virtual?node=3", "modbus://", "modbus://h?mode=q",
                "canopen://virtual/x?node=300"):
        with pytest.raises(InputError):
            driver_from_url(bad)


@pytest.mark.parametrize("url, says", [
    ("modbus://a b c", "contains a space"),
    ("modbus://plc-y.shop:502 ?mode=trace", "contains a space"),
    ("modbus://plc\x01y:502", "contains '\\x01'"),
    ("modbus://plc_y!:502", "neither an IP address nor a host name"),
    ("sim://-plc:502", "neither an IP address nor a host name"),
])  # fmt: skip
def test_a_controller_url_that_is_not_a_url_is_refused_naming_the_problem(url, says):
    with pytest.raises(InputError, match="controller URL") as e:
        driver_from_url(url)
    assert says in str(e.value)


@pytest.mark.parametrize("url", ["modbus://10.0.0.5:502", "modbus://[fd00::5]:502", "modbus://plc-y.hall-2.shop:1502",
                                 "modbus://localhost"])  # fmt: skip
def test_hosts_by_address_and_by_name_are_accepted(url):
    assert isinstance(driver_from_url(url), ModbusDriver)


def test_every_acquisition_error_names_its_own_reason_code():
    import inspect

    from acquisition import errors
    from acquisition.measurement import reason_code
    from core.errors import TraceError

    classes = [c for _, c in inspect.getmembers(errors, inspect.isclass) if issubclass(c, errors.AcquisitionError)]
    codes = {c: c.__dict__.get("reason_code") for c in classes}
    assert all(codes.values()), [c.__name__ for c, v in codes.items() if not v]  # declared, not inherited
    assert len(set(codes.values())) == len(classes)  # and distinct
    assert reason_code(errors.ControllerTimeoutError("x")) == "timeout"
    assert reason_code(TraceError("x")) == "trace" and reason_code(ValueError("x")) == "error"

"""``linuxcnc://`` URLs: what they configure, and bad ones refused with a clear error (no
LinuxCNC needed)."""

from __future__ import annotations

import pytest

from acquisition.linuxcnc import LinuxcncDriver
from acquisition.url import driver_from_url
from core.errors import InputError

BASE = "linuxcnc://127.0.0.1:5007?joint=1&motor_pin=y-motor.out&scale_pin=y-scale.out"


def test_a_linuxcnc_url_is_a_passive_driver_of_that_joint_by_default():
    d = driver_from_url(BASE)
    assert isinstance(d, LinuxcncDriver)
    assert (d.host, d.port, d.joint, d.axis_letter) == ("127.0.0.1", 5007, 1, "Y")
    assert d.trigger == "passive"  # mebm moves a real machine only when told to
    assert d.command_pin == "joint.1.pos-cmd" and d.sampler_channel == 0 and d.motor_units == "mm"


def test_the_url_sets_the_active_trigger_pins_and_sampler():
    d = driver_from_url(BASE + "&trigger=active&sampler=2&command_pin=joint.1.motor-pos-cmd&axis=u&motor_units=rev")
    assert d.trigger == "active" and d.sampler_channel == 2 and d.axis_letter == "U"
    assert d.command_pin == "joint.1.motor-pos-cmd" and d.motor_units == "rev"
    assert driver_from_url("linuxcnc://localhost?motor_pin=a&scale_pin=b").port == 5007


def test_the_active_round_trip_is_a_g53_program_with_its_dwells():
    from acquisition.types import RoundTripProgram

    d = driver_from_url(BASE + "&trigger=active")
    g = d.round_trip_gcode(RoundTripProgram(-2.0, 22.0, 1000.0, dwell_s=0.2))
    moves = [line for line in g.splitlines() if line.startswith("G53")]
    assert moves == ["G53 G1 Y22.0000 F1000.0", "G53 G1 Y-2.0000 F1000.0"]
    assert g.count("G4 P0.200") == 3 and g.rstrip().endswith("M2")


@pytest.mark.parametrize("url, word", [
    ("linuxcnc://127.0.0.1:5007?joint=0&scale_pin=x", "motor_pin"),
    ("linuxcnc://127.0.0.1:5007?joint=0&motor_pin=x", "scale_pin"),
    (BASE + "&colour=red", "unknown option"),
    (BASE.replace("joint=1", "joint=x"), "joint"),
    (BASE.replace("joint=1", "joint=99"), "joint"),
    (BASE + "&motor_units=deg", "motor_units"),
    (BASE + "&trigger=sometimes", "trigger"),
    (BASE + "&axis=Q", "axis_letter"),
    ("linuxcnc://127.0.0.1:99999?motor_pin=a&scale_pin=b", "port"),
    ("linuxcnc:///?motor_pin=a&scale_pin=b", "host"),
])
def test_a_bad_linuxcnc_url_is_refused_naming_what_is_wrong(url, word):
    with pytest.raises(InputError, match=word):
        driver_from_url(url)


def test_no_linuxcnc_at_the_address_is_a_connection_failure_saying_so():
    import socket

    from acquisition.measurement import run_cycle
    from tests.acquisition.linuxcnc.rig import AXIS, PROGRAM

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = run_cycle(driver_from_url(BASE.replace(":5007", f":{port}"), timeout_s=0.5), AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "connection" and "not running" in r.reason, r.reason

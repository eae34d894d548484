"""Passive round trips on the simulated Modbus controller: another process (the CNC stand-in,
tests/acquisition/cnc_process.py) starts the round trip, mebm only listens, detects and
measures it, and writes nothing to the controller."""

from __future__ import annotations

import random
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from acquisition.modbus import register_map as mm
from acquisition.measurement import run_cycle
from acquisition.errors import NoRoundTripSeen
from acquisition.modbus.driver import ModbusDriver
from acquisition.types import RoundTripProgram
from acquisition.trigger import default_trigger
from acquisition.url import driver_from_url
from core.errors import InputError
from tests.acquisition import cnc_process
from tests.acquisition.conftest import AXIS, modbus_peer

ROOT = Path(__file__).resolve().parents[2]
# a round trip with rest before, at the reversal and after (the twin dwells dwell_s at each)
PROGRAM = RoundTripProgram(-2.0, 22.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=0.3)
USEFUL = AXIS.travel_mm
# Polled samples (latched reads, a PLC profile) come at the host's pace: those round trips
# run at a slow feed (300 mm/min), so that a stall of a loaded host leaves no gap the
# analysis refuses, in real time or slower. Over a 10 mm travel (with the same 2 mm
# over-travel each side) each takes half the seconds the 20 mm axis does.
POLLED_AXIS = replace(AXIS, travel_mm=(0.0, 10.0))
POLLED_USEFUL = POLLED_AXIS.travel_mm


def polled_program(dwell_s: float) -> RoundTripProgram:
    return RoundTripProgram(-2.0, 12.0, 300.0, acceleration_mm_s2=500.0, dwell_s=dwell_s)


def start_cnc(port: int, delay_s: float, program: RoundTripProgram = PROGRAM, *, ack: bool = False) -> subprocess.Popen:
    args = [str(port), f"{delay_s:.3f}", *(repr(float(v)) for v in (
        program.start_mm, program.end_mm, program.feed_mm_min, program.acceleration_mm_s2, program.dwell_s))]
    args += ["--ack"] if ack else []
    return subprocess.Popen([sys.executable, "-m", "tests.acquisition.cnc_process", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def count_writes(sim_controller) -> list:
    """Record every write request the simulated controller serves (from anyone)."""
    writes = []
    inner = sim_controller.write

    async def write(func_code, address, values):
        writes.append((address, list(values)))
        return await inner(func_code, address, values)

    sim_controller.write = write
    return writes


def test_the_cnc_stand_in_writes_the_start_as_the_register_map_says():
    words = [cnc_process.COMMAND_START, *cnc_process.words_i32(-2000), *cnc_process.words_i32(22000),
             *cnc_process.words_i32(1_000_000), 500, 300]
    assert words == mm.encode_program(PROGRAM, mm.Command.START)


@pytest.mark.parametrize("running_flag", [True, False], ids=["running-flag", "positions-only"])
def test_a_round_trip_started_by_another_process_is_measured_as_an_active_one_is(running_flag):
    with modbus_peer(time_scale=3.0) as peer:
        # the same twin measured actively first (mebm starts the round trip)
        active = run_cycle(peer.driver(), AXIS, PROGRAM, useful_travel_mm=USEFUL)
        assert active.ok, active.reason
        sim = peer.axis
        started_before = sim.cycles_started
        server = peer.server
        writes = count_writes(server)
        driver = peer.driver(trigger="passive", running_flag=running_flag, passive={"start_timeout_s": 120.0})
        cnc = start_cnc(server.port, random.uniform(0.3, 1.5))
        try:
            passive = run_cycle(driver, AXIS, PROGRAM, useful_travel_mm=USEFUL)
        finally:
            out, err = cnc.communicate(timeout=60)
        assert cnc.returncode == 0, err
        assert passive.ok, passive.reason
        assert passive.trace.trigger == "passive"
        assert passive.result.backlash_mean_um == pytest.approx(active.result.backlash_mean_um, abs=1.0)
        # the program is what was observed: the table's rest positions and the cruise feed
        p = passive.program
        assert p.start_mm == pytest.approx(PROGRAM.start_mm, abs=0.2)
        assert p.end_mm == pytest.approx(PROGRAM.end_mm, abs=0.2)
        assert p.feed_mm_min == pytest.approx(PROGRAM.feed_mm_min, rel=0.02)
        # mebm wrote nothing: the only write is the CNC's start, the only round trip the CNC's
        assert [a for a, _ in writes] == [mm.COMMAND]
        assert sim.cycles_started == started_before + 1
        assert passive.to_run("rt").spec.extra["trigger"] == "passive"
        assert passive.to_dict()["acquisition"]["trigger"] == "passive"


def test_a_cnc_that_acknowledges_the_end_at_once_is_measured_all_the_same():
    """DONE -> IDLE while mebm is still reading the trace: the end of the program, not a fault."""
    with modbus_peer(time_scale=3.0) as peer:
        writes = count_writes(peer.server)
        driver = peer.driver(trigger="passive", passive={"start_timeout_s": 120.0})
        cnc = start_cnc(peer.server.port, 0.5, ack=True)
        try:
            res = run_cycle(driver, AXIS, PROGRAM, useful_travel_mm=USEFUL)
        finally:
            _, err = cnc.communicate(timeout=60)
        assert cnc.returncode == 0, err
        assert res.ok, res.reason
        assert res.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)
        assert [a for a, _ in writes] == [mm.COMMAND, mm.COMMAND]  # the CNC's start and acknowledge
        assert [v[0] for _, v in writes] == [1, 3]


def test_positions_only_on_polled_samples_without_a_trace_buffer():
    """What a controller without a trace buffer or a running flag gives: polled latched
    samples. The round trip is still found, from the positions alone, and measured."""
    slow = polled_program(dwell_s=0.5)
    with modbus_peer(time_scale=1.0, mode="latched") as peer:
        server = peer.server
        writes = count_writes(server)
        driver = peer.driver(trigger="passive", running_flag=False, passive={"start_timeout_s": 120.0})
        cnc = start_cnc(server.port, random.uniform(0.3, 1.0), slow)
        try:
            res = run_cycle(driver, POLLED_AXIS, slow, useful_travel_mm=POLLED_USEFUL)
        finally:
            cnc.communicate(timeout=60)
        assert res.ok, res.reason
        assert res.trace.mode == "latched" and res.trace.trigger == "passive"
        assert "found by the positions" in res.trace.notes[0]
        assert res.result.backlash_mean_um == pytest.approx(120.0, abs=3.0)
        assert [a for a, _ in writes] == [mm.COMMAND]


def test_no_round_trip_within_the_time_out_is_a_typed_failure_and_nothing_is_written():
    with modbus_peer(time_scale=3.0) as peer:
        writes = count_writes(peer.server)
        driver = peer.driver(trigger="passive", passive={"start_timeout_s": 1.0})
        res = run_cycle(driver, AXIS, PROGRAM, useful_travel_mm=USEFUL)
        assert not res.ok and res.reason_code == "no_round_trip"
        assert isinstance(res.error, NoRoundTripSeen)
        assert "no round trip seen within 1 s" in res.reason
        assert res.trace is None and res.result is None
        assert writes == [] and peer.axis.cycles_started == 0


def test_a_program_running_when_listening_begins_is_read_whole_from_the_trace_buffer():
    """The CNC started just before mebm listened; the controller's trace still holds the
    program's first record, so the run is taken whole, from its start."""
    with modbus_peer(time_scale=3.0) as peer:
        writes = count_writes(peer.server)
        peer.axis.start(PROGRAM)  # the CNC started it a moment before mebm connected
        driver = peer.driver(trigger="passive", passive={"start_timeout_s": 60.0})
        res = run_cycle(driver, AXIS, PROGRAM, useful_travel_mm=USEFUL)
        assert res.ok, res.reason
        assert res.trace.counter[0] == peer.axis.trace_first  # from the program's first sample
        assert res.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)
        assert writes == [] and peer.axis.cycles_started == 1


def test_a_program_running_when_listening_begins_without_its_start_is_waited_out():
    """Polled samples only (no trace buffer): a program under way at connect cannot be had
    whole, so it is waited out (the running flag must first be seen clear) and the next
    one, started by the CNC process, is measured."""
    slow = polled_program(dwell_s=0.5)
    with modbus_peer(time_scale=1.0, mode="latched") as peer:
        peer.axis.start(slow)  # under way before mebm listens
        driver = peer.driver(trigger="passive", passive={"start_timeout_s": 120.0})
        t_end = slow.duration_s + 1.0
        cnc = start_cnc(peer.server.port, t_end, slow)  # the next one, after the first has ended
        try:
            res = run_cycle(driver, POLLED_AXIS, slow, useful_travel_mm=POLLED_USEFUL)
        finally:
            cnc.communicate(timeout=120)
        assert res.ok, res.reason
        assert peer.axis.cycles_started == 2
        assert res.trace.counter[0] >= peer.axis.trace_first - 1  # within the second program's run


# -- the default: passive unless the controller is a simulator ------------------------------
def test_the_trigger_defaults_to_passive_except_for_a_simulator():
    assert default_trigger("modbus://10.0.0.5:502") == "passive"
    assert default_trigger("canopen://socketcan/can0?node=5") == "passive"
    assert default_trigger("sim://127.0.0.1:5020") == "active"
    assert default_trigger("canopen://virtual/sim?node=5") == "active"
    assert driver_from_url("modbus://10.0.0.5:502").trigger == "passive"
    assert driver_from_url("sim://127.0.0.1:5020").trigger == "active"
    assert driver_from_url("modbus://10.0.0.5:502?trigger=active").trigger == "active"
    d = driver_from_url("modbus://10.0.0.5:502?start_timeout_s=30&running_flag=0&min_stroke_mm=50")
    assert d.trigger == "passive" and d.running_flag is False
    s = d.detector_settings(AXIS)
    assert s.start_timeout_s == 30.0 and s.min_stroke_mm == 50.0
    # the defaults fit the axis: the stroke must cover most of its travel
    assert driver_from_url("modbus://h").detector_settings(AXIS).min_stroke_mm == pytest.approx(18.0)


@pytest.mark.parametrize("url, what", [
    ("modbus://h?trigger=maybe", "trigger"),
    ("modbus://h?start_timeout_s=soon", "start_timeout_s"),
    ("modbus://h?trigger=active&start_timeout_s=5", "trigger=passive only"),
    ("modbus://h?running_flag=2", "running_flag"),
    # CANopen's passive path is listen-only: an active mode cannot be passive
    ("canopen://socketcan/can0?node=5&mode=active-mebm&trigger=passive", "contradicts trigger=passive"),
    ("canopen://socketcan/can0?node=5&running_flag=1", "running_flag"),  # CiA 402 has no running flag
])
def test_bad_trigger_settings_in_the_url_name_what_is_wrong(url, what):
    with pytest.raises(InputError, match=what):
        driver_from_url(url)


def test_bad_detection_settings_are_refused_before_listening():
    with pytest.raises(InputError, match="rest_s"):
        ModbusDriver("h", trigger="passive", passive={"rest_s": -1.0}).detector_settings(AXIS)
    with pytest.raises(InputError, match="unknown option"):
        ModbusDriver("h", trigger="passive", passive={"rest_seconds": 1.0})


def test_the_passive_trace_counts_lost_samples_only_in_the_controllers_own_trace():
    """Polled rest around the round trip is decimated by design and not 'lost'."""
    with modbus_peer(time_scale=3.0) as peer:
        server = peer.server
        driver = peer.driver(trigger="passive", running_flag=False, passive={"start_timeout_s": 120.0})
        cnc = start_cnc(server.port, 0.5)
        try:
            res = run_cycle(driver, AXIS, PROGRAM, useful_travel_mm=USEFUL)
        finally:
            cnc.communicate(timeout=60)
    assert res.ok, res.reason
    dc = np.diff(res.trace.counter)
    assert dc.max() > 1  # the polled rest has gaps
    assert res.trace.lost_samples == 0


# -- register profiles: a polled PLC the CNC drives ---------------------------------------------
def test_a_start_between_the_flag_read_and_the_position_read_is_measured_from_its_true_start():
    """A start between two reads, forced: the CNC starts the round trip right after the PLC served a
    position read. The running flag is read before the positions in every poll, so the poll
    that saw the flag set also has positions of the round trip; read the other way round, it
    would pair the rest position (0 mm) with the set flag and the round trip, which
    starts at -2 mm, would be refused as cut short."""
    import time

    from acquisition.modbus.profile import load_profile
    from acquisition.sim.axis import SimAxis
    from acquisition.sim.modbus.profile_server import SimProfileController
    from acquisition.sim.twin import KinematicTwin

    profile_file = ROOT / "examples" / "modbus-profiles" / "plc-gateway-float32-cdab.toml"
    profile = load_profile(profile_file)
    slow = polled_program(dwell_s=0.3)
    axis = SimAxis(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), servo_rate_hz=1000.0, time_scale=0.5)
    axis.prepare(slow)  # the start takes effect at once
    armed_at = time.monotonic() + 1.0

    class StartsAfterAPositionRead(SimProfileController):
        def read(self, func_code, address, count):
            out = super().read(func_code, address, count)
            positions = profile.values["table"]
            if (func_code == 3 and address <= positions.address < address + count and axis.cycles_started == 0
                    and time.monotonic() >= armed_at):
                axis.start(slow)
            return out

    with StartsAfterAPositionRead(axis, profile, slow) as sim:
        driver = driver_from_url(f"modbus://127.0.0.1:{sim.port}?profile={profile_file}&start_timeout_s=60",
                                 timeout_s=2.0)
        res = run_cycle(driver, POLLED_AXIS, slow, useful_travel_mm=POLLED_USEFUL)
    assert axis.cycles_started == 1
    assert res.ok, res.reason
    assert "flag" in res.trace.notes[0]
    assert res.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)


@pytest.mark.parametrize("running_flag", [True, False], ids=["profile-running-flag", "profile-positions-only"])
def test_a_profile_controller_gets_passive_mode_from_its_polled_samples(running_flag):
    """The float32 CDAB gateway profile: polled samples (no trace ring), its [running] flag or
    the positions alone; mebm writes nothing (the profile's start coil stays untouched)."""
    import gc
    import threading

    from acquisition.modbus.profile import load_profile
    from acquisition.sim.axis import SimAxis
    from acquisition.sim.modbus.profile_server import SimProfileController
    from acquisition.sim.twin import KinematicTwin

    profile_file = ROOT / "examples" / "modbus-profiles" / "plc-gateway-float32-cdab.toml"
    profile = load_profile(profile_file)
    # polled on the host clock: the PLC runs at half speed so a stall of a loaded host leaves
    # no gap the analysis refuses (as tests/acquisition/modbus/test_paths.py does)
    slow = polled_program(dwell_s=0.3)
    axis = SimAxis(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), servo_rate_hz=1000.0, time_scale=0.5)
    gc.collect()
    gc.freeze()
    try:
        with SimProfileController(axis, profile, slow) as sim:
            writes = []
            inner = sim.write

            def write(func_code, address, values):
                writes.append((func_code, address))
                return inner(func_code, address, values)

            sim.write = write
            url = f"modbus://127.0.0.1:{sim.port}?profile={profile_file}&start_timeout_s=60"
            if not running_flag:
                url += "&running_flag=0"
            driver = driver_from_url(url, timeout_s=2.0)
            assert driver.trigger == "passive" and driver.running_flag is running_flag
            threading.Timer(1.0, axis.start, args=(slow,)).start()  # the CNC starts the PLC's program
            res = run_cycle(driver, POLLED_AXIS, slow, useful_travel_mm=POLLED_USEFUL)
    finally:
        gc.unfreeze()
    assert res.ok, res.reason
    assert res.trace.trigger == "passive" and res.trace.mode == "latched"
    assert ("flag" if running_flag else "positions") in res.trace.notes[0]
    assert res.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)
    assert writes == [] and axis.cycles_started == 1

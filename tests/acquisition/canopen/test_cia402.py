"""CiA 402 on CANopen: the simulated drive's state machine, PP and CSP, and mebm's active-cia402 mode."""

from __future__ import annotations

import pytest

from acquisition.canopen import objects as co
from acquisition.canopen.cia402 import CanopenCia402Driver
from acquisition.measurement import run_cycle
from acquisition.scale import EncoderScale
from acquisition.sim.canopen.cia402 import (
    OPERATION_ENABLED,
    READY_TO_SWITCH_ON,
    SWITCH_ON_DISABLED,
    SWITCHED_ON,
    Cia402Motion,
    PositionFollower,
)
from acquisition.sim.twin import KinematicTwin
from tests.acquisition.conftest import AXIS, PROGRAM, canopen_peer

SCALE = EncoderScale()
HOLD = (0.0, 0.0)


def _enabled(mode: int) -> Cia402Motion:
    m = Cia402Motion(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), SCALE)
    m.write(co.MODES_OF_OPERATION, mode, HOLD)
    for cw in (co.CW_SHUTDOWN, co.CW_SWITCH_ON, co.CW_ENABLE_OPERATION):
        m.write(co.CONTROLWORD, cw, HOLD)
    return m


def test_device_state_machine_follows_the_controlword():
    m = Cia402Motion(KinematicTwin(), SCALE)
    assert m.state == SWITCH_ON_DISABLED and m.statusword() & 0x4F == 0x40
    m.write(co.CONTROLWORD, co.CW_ENABLE_OPERATION, HOLD)  # enable before shutdown: not a transition
    assert m.state == SWITCH_ON_DISABLED
    expected = [(co.CW_SHUTDOWN, READY_TO_SWITCH_ON, 0x21), (co.CW_SWITCH_ON, SWITCHED_ON, 0x23),
                (co.CW_ENABLE_OPERATION, OPERATION_ENABLED, 0x27)]
    for cw, state, sw in expected:
        m.write(co.CONTROLWORD, cw, HOLD)
        assert m.state == state and m.statusword() & 0x6F == sw
    m.write(co.CONTROLWORD, 0x00, HOLD)  # disable voltage
    assert m.state == SWITCH_ON_DISABLED and m.engaged  # positions stay the CiA 402 axis'


def test_profile_position_moves_to_the_target_and_reports_it_reached():
    m = _enabled(co.MODE_PROFILE_POSITION)
    per_mm = SCALE.counts_per_rev / 6.857
    target = int(10.0 * per_mm)
    for idx, v in ((co.TARGET_POSITION, target), (co.PROFILE_VELOCITY, int(20 * per_mm)),
                   (co.PROFILE_ACCELERATION, int(500 * per_mm))):
        m.write(idx, v, HOLD)
    m.write(co.CONTROLWORD, co.CW_ENABLE_OPERATION | co.CW_NEW_SETPOINT, HOLD)
    assert m.statusword() & co.SW_SETPOINT_ACK and not m.statusword() & co.SW_TARGET_REACHED
    m.write(co.CONTROLWORD, co.CW_ENABLE_OPERATION, HOLD)
    peak = 0.0
    for _ in range(3000):  # 3 s at 1 kHz: the move takes 0.54 s, the loop settles in well under 1 s
        motor_rev, table_mm = m.step(0.001)
        peak = max(peak, table_mm)
        if m.statusword() & co.SW_TARGET_REACHED:
            break
    assert m.statusword() & co.SW_TARGET_REACHED
    assert motor_rev * 6.857 == pytest.approx(10.0, abs=0.02)  # within the position window
    assert table_mm == pytest.approx(10.0 - 0.06, abs=0.02)  # the table lags the nut by b/2
    assert peak <= 10.0  # a first-order loop does not overshoot


def test_cyclic_synchronous_position_applies_each_target_on_the_next_sync():
    m = _enabled(co.MODE_CYCLIC_SYNC_POSITION)
    assert m.statusword() & co.SW_SETPOINT_ACK  # CSP: the drive follows the command value
    m.rpdo(co.CW_ENABLE_OPERATION, 1000, HOLD)
    assert m.demand == 0.0  # not before the SYNC
    m.step(0.002)
    assert m.demand == 1000.0 and m.csp_targets == 1
    m.step(0.002)  # no new target: holds
    assert m.demand == 1000.0 and m.csp_targets == 1


def test_follower_reproduces_the_kinematic_twin_round_trip():
    # the CiA 402 axis must be the same axis as the twin's precomputed round trip: same backlash
    twin = KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0, cyclic_amplitude_um=3.0)
    trace = KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0, cyclic_amplitude_um=3.0).round_trip(
        PROGRAM, 1000.0)
    f = PositionFollower.from_twin(twin, trace.command_mm[0] / twin.k_a, float("nan"))
    out = [f.step(c, 0.001) for c in trace.command_mm]
    motor = [o[0] for o in out]
    table = [o[1] for o in out]
    assert max(abs(a - b) for a, b in zip(motor, trace.motor_rev)) < 1e-9
    assert max(abs(a - b) for a, b in zip(table, trace.table_mm)) < 1e-9


def _cia402_driver(peer_channel, **kw):
    kw.setdefault("table_nm_per_count", 10.0)
    return CanopenCia402Driver(peer_channel, 5, sync_rate_hz=200.0, time_scale=5.0, heartbeat_ms=100,
                               timeout_s=0.5, **kw)


def test_active_cia402_measures_the_backlash_through_standard_objects_only():
    with canopen_peer() as peer:
        drive = peer.axis.on_fault.__self__
        r = run_cycle(_cia402_driver(drive.channel), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)
        assert drive.cia402.moves == 3  # to the start, out, back: Profile Position set-points
        assert drive.axis.cycles_started == 0  # mebm's manufacturer START was never used
        assert drive.cia402.mode == co.MODE_PROFILE_POSITION
        r2 = run_cycle(_cia402_driver(drive.channel), AXIS, PROGRAM)  # DONE is acknowledged, then again
        assert r2.ok, r2.reason
        assert r2.result.backlash_mean_um == pytest.approx(r.result.backlash_mean_um, abs=0.5)


def test_active_cia402_needs_the_table_resolution_when_the_drive_has_no_0x2005():
    with canopen_peer() as peer:
        drive = peer.axis.on_fault.__self__
        del drive.od[co.TABLE_NM_PER_COUNT]
        r = run_cycle(_cia402_driver(drive.channel, table_nm_per_count=None), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "protocol"
        assert "table_nm_per_count" in r.reason
        assert drive.cia402.moves == 0  # refused before anything moved


def test_active_cia402_reports_a_drive_fault():
    with canopen_peer() as peer:
        drive = peer.axis.on_fault.__self__
        d = _cia402_driver(drive.channel)
        orig = drive.cia402.statusword
        calls = {"n": 0}

        def faulty():  # the drive faults once the round trip is under way
            calls["n"] += 1
            return co.SW_FAULT if drive.cia402.moves >= 2 else orig()

        drive.cia402.statusword = faulty
        r = run_cycle(d, AXIS, PROGRAM)
        assert not r.ok and r.reason_code in ("device_fault", "protocol"), r.reason
        assert "fault" in r.reason.lower()

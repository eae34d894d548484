"""The simulated CANopen drive's own SYNC-loss reaction (CiA 402 0x6007-style)."""

from __future__ import annotations

import can

from acquisition.canopen import objects as co
from acquisition.sim.canopen.drive import SimCanopenDrive, SyncLossTimer
from acquisition.sim.twin import KinematicTwin
from acquisition.types import AxisState
from tests.acquisition.conftest import PROGRAM
from tests.waiting import until


def _ticks(timer, times, syncs=1):
    return [timer.tick(t, syncs, running=True) for t in times]


def test_sync_is_lost_after_its_time_of_silent_ticks():
    timer = SyncLossTimer(0.5, tick_s=0.125)
    lost = _ticks(timer, [0.125 * k for k in range(1, 8)])
    assert lost == [False] * 5 + [True, False]  # 0.625 s of silence after the first tick: over 0.5 s
    assert timer.silent_s == 0.125  # lost once, then counted again from nothing


def test_a_new_sync_or_a_program_not_running_restarts_the_count():
    t = [0.125 * k for k in range(1, 40)]
    timer = SyncLossTimer(0.5, tick_s=0.125)
    assert not any(timer.tick(x, syncs=1 + k // 3, running=True) for k, x in enumerate(t))  # a SYNC every 0.375 s
    timer = SyncLossTimer(0.5, tick_s=0.125)
    assert not any(timer.tick(x, syncs=1, running=False) for x in t)
    timer = SyncLossTimer(0.5, tick_s=0.125)
    assert not any(timer.tick(x, syncs=0, running=True) for x in t)  # no SYNC yet: nothing to lose


def test_a_stall_of_the_host_counts_two_ticks_not_its_length():
    timer = SyncLossTimer(0.5, tick_s=0.125)
    assert _ticks(timer, [0.125, 0.25, 3.25]) == [False, False, False]  # 3 s stalled: 0.25 s counted
    assert timer.silent_s == 0.375
    assert _ticks(timer, [3.375, 3.5]) == [False, True]  # the drive's own 0.25 s more make 0.625 s


def test_a_running_program_stops_when_sync_stops_coming():
    channel = "mebm-sync-loss"
    with SimCanopenDrive(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), node_id=5,
                         channel=channel) as drive, can.Bus(interface="virtual", channel=channel) as bus:
        drive.node.nmt.state = "OPERATIONAL"
        drive.axis.start(PROGRAM)
        for k in range(1, 6):
            bus.send(can.Message(arbitration_id=co.SYNC_COB_ID, is_extended_id=False, data=[k]))
        until(lambda: drive.syncs == 5, "the drive to take five SYNCs")
        until(lambda: drive.axis.state == AxisState.ABORTED, "the drive to abort the program once SYNC stopped")
        assert drive.syncs == 5 and drive.axis.cycles_started == 1

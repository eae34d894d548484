"""CANopen specifics: wrong node id, PDO mapping check, heartbeat loss, SYNC counter."""

from __future__ import annotations

import struct

import numpy as np

from acquisition.canopen import objects as co
from acquisition.measurement import run_cycle
from acquisition.types import AxisState
from tests.acquisition.conftest import AXIS, PROGRAM, canopen_peer


def test_tpdo_codec():
    data = co.encode_tpdo1(-123456, 2**31 - 1)
    assert len(data) == 8
    assert co.decode_tpdo1(data) == (-123456, 2**31 - 1)


def test_wrong_node_id_fails_after_one_unanswered_request():
    with canopen_peer() as peer:
        d = peer.driver(node_id=9, timeout_s=0.5)
        r = run_cycle(d, AXIS, PROGRAM)
        assert d.connect_attempts == 1  # an unanswered request is not retried: one timeout, not three
        assert not r.ok and r.reason_code == "timeout"
        assert "node 9" in r.reason and "\n" not in r.reason


def test_pdo_mapping_is_verified():
    with canopen_peer() as peer:
        # a drive whose TPDO1 is not (0x6064, 0x60E4 sub 1) on SYNC cannot give simultaneous samples
        node = peer.axis.on_fault.__self__.node  # the simulated drive's LocalNode
        node.data_store.setdefault(co.TPDO1_MAP, {})[2] = struct.pack("<L", 0x60630020)
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "protocol" and "TPDO1" in r.reason


def test_silent_drive_loses_heartbeat_then_recovers():
    with canopen_peer(faults=["drop:at=0.3"]) as peer:  # silent until recover()
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code in ("connection", "timeout"), r.reason
        peer.recover()
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason


def test_sync_counter_numbers_every_sample():
    with canopen_peer() as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason
        t = r.trace
        assert t.mode == "sync" and np.all(np.diff(t.counter) == 1)
        assert np.allclose(np.diff(t.time_s), 1 / 200.0)
        assert peer.axis.state == AxisState.DONE


def test_duplicated_and_reordered_tpdos_lose_nothing_and_are_counted():
    faults = ["duplicate:at=0.3,n=4", "reorder:at=0.6,n=5"]
    with canopen_peer(faults=faults, reply_delay_s=0.0001, reply_jitter_s=0.0003) as peer:
        d = peer.driver()
        r = run_cycle(d, AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)
        assert d.sync_stats["duplicates"] == 4 and d.sync_stats["late"] == 0


def test_tpdos_outside_the_synchronous_window_are_discarded_by_the_drive_and_counted_as_lost():
    # every reply takes 0.1-0.9 of the window: about half miss the window the driver sets (0.5 period)
    with canopen_peer(reply_delay_s=0.0, reply_jitter_s=0.001) as peer:
        d = peer.driver(max_lost_samples=10**6)
        r = run_cycle(d, AXIS, PROGRAM)
        drive = peer.axis.on_fault.__self__
        assert r.trace is not None and drive.late_discards > 0
        gaps = int(np.sum(np.diff(r.trace.counter) - 1))
        assert r.trace.lost_samples >= gaps > 0  # every gap counted (and any before the first sample)
        assert d.sync_stats["late"] == 0  # what the drive sent all arrived within its window

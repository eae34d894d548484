"""CANopen specifics: wrong node id, PDO mapping check, heartbeat loss, SYNC counter."""

from __future__ import annotations

import struct

import numpy as np

from acquisition import canopen_od as co
from acquisition.cycle import run_cycle
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

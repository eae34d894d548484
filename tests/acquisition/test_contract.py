"""Contract suite: the same checks against both drivers and their simulated peers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from acquisition.measurement import run_cycle
from acquisition.types import AxisState
from tests.acquisition.conftest import AXIS, PROGRAM


def _ok(peer, **kw):
    r = run_cycle(peer.driver(**kw), AXIS, PROGRAM)
    assert r.ok, r.reason
    return r


def test_clean_cycle_is_latched_continuous_and_measures_b(peer_factory):
    with peer_factory() as peer:
        r = _ok(peer)
        t = r.trace
        assert t.latched and t.lost_samples == 0
        # the combined standard uncertainty of b̄ (GUM), no sampling term when latched
        budget = {c.name: c.standard_um for c in r.result.budgets["backlash_mean"].components}
        assert budget["sampling"] == 0.0 and r.uncertainty_um == r.result.budgets["backlash_mean"].combined_um > 0
        assert np.all(np.diff(t.counter) == 1)
        assert np.all(np.diff(t.time_s) > 0)
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0
        assert peer.axis.state == AxisState.DONE
        # a second cycle on the same axis (nut on the other side now) measures the same
        r2 = _ok(peer)
        assert abs(r2.result.backlash_mean_um - 120.0) < 1.0


def test_device_fault_aborts_with_code_then_next_cycle_succeeds(peer_factory):
    with peer_factory(faults=["emcy:at=0.4,code=0x7305"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "device_fault"
        assert "0x7305" in r.reason and r.result is None
        assert peer.axis.state != AxisState.RUNNING
        _ok(peer)


def test_lost_samples_are_reported_never_interpolated(peer_factory):
    with peer_factory(faults=["lost:at=0.5,n=3"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "lost_samples", r.reason
        assert "lost" in r.reason and r.result is None
        _ok(peer)


def test_lost_samples_counted_when_tolerated(peer_factory):
    with peer_factory(faults=["lost:at=0.5,n=3"]) as peer:
        r = run_cycle(peer.driver(max_lost_samples=100), AXIS, PROGRAM)
        assert r.trace is not None and r.trace.lost_samples >= 1
        assert np.sum(np.diff(r.trace.counter) - 1) == r.trace.lost_samples


def test_stuck_encoder_fails_and_leaves_axis_stopped(peer_factory):
    with peer_factory(faults=["stuck:at=0.2"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "encoder_fault", r.reason
        assert "stuck" in r.reason and "abort sent" in r.reason
        assert peer.axis.state == AxisState.ABORTED
        _ok(peer)


def test_jumping_encoder_fails(peer_factory):
    with peer_factory(faults=["jump:at=0.3,mm=0.5"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "encoder_fault", r.reason
        assert "jumped" in r.reason
        _ok(peer)


def test_busy_axis_is_not_started(peer_factory):
    # someone else's program, at 10 mm/min: still running when the driver first asks,
    # however loaded the host (the Modbus controller's axis runs on the wall clock, ten
    # times faster than real: at the test feed the program is over in 0.3 s, and a slow
    # first read would find the axis idle and start a cycle of its own)
    with peer_factory() as peer:
        peer.axis.start(replace(PROGRAM, feed_mm_min=10.0))
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "axis_busy" and "RUNNING" in r.reason


def test_dropped_connection_fails_after_retries_and_next_cycle_succeeds(peer_factory):
    with peer_factory(faults=["drop:at=0.3"]) as peer:  # off the line until recover()
        d = peer.driver()
        r = run_cycle(d, AXIS, PROGRAM)
        assert not r.ok and r.reason_code in ("connection", "timeout"), r.reason
        assert r.result is None and "abort could NOT be sent" in r.reason
        assert d.connect_attempts >= 2  # it reconnected, boundedly, before giving up
        peer.recover()
        _ok(peer)


def test_slow_replies_time_out(peer_factory):
    # real time, so the program is still running when the replies turn slow
    with peer_factory(faults=["slow:at=0.2,s=1.5"], time_scale=1.0) as peer:
        r = run_cycle(peer.driver(timeout_s=0.3, retries=1), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "timeout", r.reason
        assert "gave up after 2 attempts" in r.reason
        peer.recover()
        _ok(peer)



def test_one_driver_measures_again_after_a_failed_cycle(peer_factory):
    # per-cycle state lives in the cycle, not on the driver: the same driver object runs a
    # clean cycle right after one that failed mid-way, with nothing carried over
    with peer_factory(faults=["lost:at=0.5,n=3"]) as peer:
        d = peer.driver()
        r1 = run_cycle(d, AXIS, PROGRAM)
        assert not r1.ok and r1.reason_code == "lost_samples", r1.reason
        failed = d.last_cycle
        r2 = run_cycle(d, AXIS, PROGRAM)
        assert r2.ok, r2.reason
        assert d.last_cycle is not failed and r2.trace.lost_samples == 0
        assert np.all(np.diff(r2.trace.counter) == 1) and r2.trace.counter[0] > r1.error.first_missing
        assert abs(r2.result.backlash_mean_um - 120.0) < 1.0

"""Modbus TCP specifics: register codec, modes, exception codes, refused and recovered connections."""

from __future__ import annotations

import asyncio
import socket

import numpy as np
import pytest

from acquisition import modbus_map as mm
from acquisition.cycle import run_cycle
from acquisition.errors import ControllerConnectionError, ControllerTimeoutError, ProtocolError
from acquisition.modbus import ModbusDriver
from acquisition.modbus import _new_records as mm_new
from acquisition.scale import EncoderScale
from acquisition.types import AxisState, RoundTripProgram
from tests.acquisition.conftest import AXIS, PROGRAM, modbus_peer


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_words_round_trip_signed_and_unsigned():
    vals = np.array([0, 1, -1, 2**31 - 1, -(2**31), 123456789, -987654])
    w = mm.split32(vals)
    assert np.array_equal(mm.join_i32(w[:, 0], w[:, 1]), vals)
    u = np.array([0, 2**32 - 1, 70000])
    w = mm.split32(u)
    assert np.array_equal(mm.join_u32(w[:, 0], w[:, 1]), u)


def test_records_decode_to_physical_units_through_the_scale():
    scale = EncoderScale(counts_per_rev=1000, table_nm_per_count=10)
    rec = np.array([[5, 2500, -300], [6, -1000, 100000]])
    counter, motor_rev, table_mm = mm.decode_records(mm.encode_records(rec), scale)
    assert counter.tolist() == [5, 6]
    assert motor_rev.tolist() == [2.5, -1.0]
    assert table_mm == pytest.approx([-0.003, 1.0])


def test_program_words_round_trip():
    p = RoundTripProgram(-8.5, 108.25, 1234.5, acceleration_mm_s2=700, dwell_s=0.35)
    words = mm.encode_program(p, 1)
    assert len(words) == mm.CONTROL_WORDS and words[0] == 1
    assert mm.decode_program(words[1:]) == p


def test_counter_unwraps_across_u32_overflow():
    ref = 2**32 - 2
    got = mm.unwrap_u32([2**32 - 2, 2**32 - 1, 0, 1], ref)
    assert got.tolist() == [ref, ref + 1, ref + 2, ref + 3]


def test_refused_connection_fails_fast_with_one_clear_reason():
    port = _free_port()  # nothing listens here
    d = ModbusDriver("127.0.0.1", port, timeout_s=1.0)
    r = run_cycle(d, AXIS, PROGRAM)
    assert 1 <= d.connect_attempts <= d.retries + 1  # refused: retried within the timeout, boundedly
    assert not r.ok and r.reason_code == "connection"
    assert f"127.0.0.1:{port}" in r.reason and "\n" not in r.reason
    assert isinstance(r.error, ControllerConnectionError) and isinstance(r.error, ConnectionError)


def test_persistent_exception_code_fails_with_the_code():
    with modbus_peer(faults=["exception:at=0.3,code=4"], time_scale=2.0) as peer:
        r = run_cycle(peer.driver(timeout_s=0.5, retries=2), AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "protocol", r.reason
        assert "exception 4" in r.reason and "device failure" in r.reason
        assert "gave up after 3 attempts" in r.reason
        assert peer.axis.state in (AxisState.ABORTED, AxisState.DONE)


def test_brief_exception_is_retried_without_losing_samples():
    with modbus_peer(faults=["exception:at=0.3,code=6,for=0.05"], time_scale=2.0) as peer:
        r = run_cycle(peer.driver(timeout_s=0.5, retries=3), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0


class _StatusFailsOnce(ModbusDriver):
    """Fails the first status read that follows a partly new trace block with a transient
    exception (device busy): the records of that block were read but not yet handed over."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.injected = 0
        self._after_partial = False

    async def _drain_trace(self):
        self._after_partial = True
        try:
            return await super()._drain_trace()
        finally:
            self._after_partial = False

    async def _status(self):
        if self._after_partial and not self.injected and self._next_w > 100:
            self.injected += 1
            err = ProtocolError("injected: Modbus exception 6 (device busy)", code=6)
            err.transient = True
            raise err
        return await super()._status()


def test_records_read_before_a_failed_status_read_are_not_lost():
    # deterministic form of the brief-exception case: the failure lands between reading a
    # block of records and handing it over, which once dropped that block
    with modbus_peer(time_scale=2.0) as peer:
        d = _StatusFailsOnce("127.0.0.1", peer.driver().port, timeout_s=0.5, retries=3)
        r = run_cycle(d, AXIS, PROGRAM)
        assert d.injected == 1
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)


class _ReadFailsMidBatch(ModbusDriver):
    """Fails the third trace-block read of one drain with a timeout, once."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.reads_this_drain = 0
        self.injected = 0

    async def _drain_trace(self):
        self.reads_this_drain = 0
        return await super()._drain_trace()

    async def _read(self, address, count, what):
        if address >= mm.RING_BASE:
            self.reads_this_drain += 1
            if self.reads_this_drain == 3 and not self.injected:
                self.injected += 1
                raise ControllerTimeoutError("injected: no reply within 0.5 s while reading the trace buffer")
        return await super()._read(address, count, what)


def test_a_failed_read_mid_batch_loses_no_sample():
    # time_scale 50: the controller runs ahead, so drains read several blocks at once
    with modbus_peer(time_scale=50.0) as peer:
        d = _ReadFailsMidBatch("127.0.0.1", peer.driver().port, timeout_s=0.5, retries=3)
        r = run_cycle(d, AXIS, PROGRAM)
        assert d.injected == 1
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_block_validity_from_first_and_last_counter():
    def block(counters):
        rec = np.array([[c, 10 * c, -c] for c in counters])
        return mm.encode_records(rec).astype(int).tolist()

    n = mm.RECORDS_PER_READ
    assert mm_new(block(range(500, 500 + n)), n, 500) == (n, 500 + n)
    # the ring's newest record is 506: the rest of the block is an older lap
    assert mm_new(block([*range(500, 507), *range(507 - 2000, 507 - 2000 + n - 7)]), n, 500) == (7, 507)
    assert mm_new(block(range(400, 400 + n)), n, 500) == (0, 500)  # nothing new yet
    # across the u32 wrap of the counter
    top = 2**32 - 5
    wrapped = [(top + i) % 2**32 for i in range(n)]
    assert mm_new(block(wrapped), n, top) == (n, top + n)
    # a gap (samples never latched) is not hidden: the block is new, the base loop reports the gap
    assert mm_new(block([*range(500, 505), *range(510, 510 + n - 5)]), n, 500) == (n, 510 + n - 5)


class _FakeRing(ModbusDriver):
    """The trace-buffer wire without a server: ``ring[slot]`` is the record (counter, motor,
    table) a read returns; ``torn`` = {slot: record} is returned once instead, as a read
    racing the controller's write would."""

    def __init__(self, ring, torn, trace_count, state=AxisState.RUNNING):
        super().__init__("127.0.0.1", 1)
        self.ring, self.torn, self.trace_count, self.state = ring, dict(torn), trace_count, state
        self.scale, self.ring_records, self._first_counter = EncoderScale(), len(ring), int(ring[0][0])

    async def _read(self, address, count, what):
        s0 = (address - mm.RING_BASE) // mm.RECORD_WORDS
        rec = []
        for slot in range(s0, s0 + count // mm.RECORD_WORDS):
            rec.append(self.torn.pop(slot) if slot in self.torn else self.ring[slot])
        return mm.encode_records(np.array(rec)).astype(int).tolist()

    async def _status(self):
        return {"state": self.state, "fault_code": 0, "trace_count": self.trace_count}


def test_a_torn_block_is_cut_at_the_older_record_and_read_again():
    ring = [(1000 + i, 10 * i, -i) for i in range(100)]
    # slot 25 still held a record of the previous lap when the read passed it
    d = _FakeRing(ring, {25: (1000 + 25 - 100, 0, 0)}, trace_count=100)
    first = asyncio.run(d._drain_trace())
    assert first.counter.tolist() == list(range(1000, 1025)) and first.caught_up and not first.finished
    second = asyncio.run(d._drain_trace())
    assert second.counter.tolist() == list(range(1025, 1100))
    assert second.table_mm.tolist() == pytest.approx([-i * 1e-5 for i in range(25, 100)])


@pytest.mark.parametrize("behind", [99, 100, 101, 150, 199, 200, 201, 350])
def test_a_reader_behind_the_ring_loses_nothing_silently(behind):
    # a ring of 100 records; the reader has read records 0..9 when it looks again, and the
    # program is DONE with 10 + behind records written (the ring holds the last 100)
    n_ring, done_at = 100, 10 + behind
    ring = [None] * n_ring
    for w in range(done_at):
        ring[w % n_ring] = (5000 + w, w, -w)
    d = _FakeRing(ring, {}, trace_count=done_at, state=AxisState.DONE)
    d._first_counter, d._next_w, d._next_counter = 5000, 10, 5010
    got = []
    for _ in range(20):
        block = asyncio.run(d._drain_trace())
        got += block.counter.tolist()
        if block.finished:
            break
    assert block.finished  # it ends, it does not spin
    assert got == sorted(set(got)) and got[-1] == 5000 + done_at - 1  # in order, up to the last record
    if behind <= n_ring:  # nothing was overwritten: every record is read
        assert got == list(range(5010, 5000 + done_at))
    else:  # overwritten records show as a gap in the counters (the base loop reports them)
        assert len(got) < done_at - 10 and (got[0] > 5010 or np.any(np.diff(got) > 1))


class _SlowStatusRing(_FakeRing):
    """The controller writes ``during`` more records and ends while one status read is
    under way (a status reply slower than the ring's span)."""

    def __init__(self, ring, trace_count, during):
        super().__init__(ring, {}, trace_count)
        self.during = during

    async def _status(self):
        if self.during:
            for w in range(self.trace_count, self.trace_count + self.during):
                self.ring[w % len(self.ring)] = (5000 + w, w, -w)
            self.trace_count += self.during
            self.during, self.state = 0, AxisState.DONE
        return await super()._status()


@pytest.mark.parametrize("during", [99, 100, 101])
def test_records_written_during_a_slow_status_read_are_still_read(during):
    n_ring = 100
    ring = [(5000 + w - n_ring, 0, 0) for w in range(n_ring)]  # the previous trace's records
    for w in range(30):
        ring[w] = (5000 + w, w, -w)
    d = _SlowStatusRing(ring, trace_count=30, during=during)
    d._first_counter, d._next_w, d._next_counter = 5000, 10, 5010
    got = []
    for _ in range(20):
        block = asyncio.run(d._drain_trace())
        got += block.counter.tolist()
        if block.finished:
            break
    assert block.finished
    end = 5000 + 30 + during
    if during <= n_ring:  # all of it still in the ring when the reader looks again
        assert got == list(range(5010, end))
    else:
        assert got[-1] == end - 1 and np.any(np.diff(got) > 1)  # the overwritten ones show as a gap


def test_a_ring_overrun_over_the_wire_is_counted_and_the_cycle_still_ends():
    # replies slowed to 50 ms while the controller writes 5000 records/s into a 64-record
    # ring: the reader is lapped again and again; with losses tolerated the trace must still
    # run in order to the controller's last record, its gaps being exactly the lost count
    with modbus_peer(faults=["slow:at=0.3,s=0.05"], ring_records=64) as peer:
        tr = peer.driver(max_lost_samples=10**6).acquire(PROGRAM, AXIS)
        c = tr.counter
        assert tr.lost_samples > 0 and np.all(np.diff(c) >= 1)
        assert int(np.sum(np.diff(c) - 1)) == tr.lost_samples
        assert int(c[-1]) == peer.axis.trace_first + peer.axis.trace_count() - 1


def test_brief_drop_is_recovered_from_the_trace_buffer():
    with modbus_peer(faults=["drop:at=0.4,for=0.2"], time_scale=2.0) as peer:
        r = run_cycle(peer.driver(timeout_s=0.5, retries=3), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_latched_poll_mode_is_latched_but_decimated():
    with modbus_peer(mode="latched", time_scale=1.0) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.mode == "latched" and r.trace.latched
        sampling = next(c for c in r.result.budgets["backlash_mean"].components if c.name == "sampling")
        assert sampling.standard_um == 0.0 and r.uncertainty_um == r.result.budgets["backlash_mean"].combined_um
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_separate_reads_are_labelled_and_carry_skew_uncertainty():
    with modbus_peer(mode="separate", time_scale=1.0) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason
        t = r.trace
        assert t.mode == "separate" and not t.latched
        # worst-case skew times the programmed speed (16.7 mm/s): > 0, and stated as the uncertainty
        assert t.skew_uncertainty_um > 0
        # the skew bound enters the GUM budget of b̄ as its (rectangular) sampling component
        budget = {c.name: c.standard_um for c in r.result.budgets["backlash_mean"].components}
        assert budget["sampling"] == pytest.approx(t.skew_uncertainty_um / 3**0.5)
        assert r.uncertainty_um == r.result.budgets["backlash_mean"].combined_um >= budget["sampling"]
        assert r.to_run("rt.csv").spec.extra["latched"] is False


def test_peer_that_never_answers_times_out_quickly():
    # a plain TCP peer that is not a mebm controller: connection then garbage -> clear error, no hang
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    try:
        d = ModbusDriver("127.0.0.1", port, timeout_s=0.3, retries=0)
        r = run_cycle(d, AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "timeout"
        assert d.connect_attempts == 1  # an unanswered request ends the set-up: no hang, no retry loop
    finally:
        srv.close()


def test_controller_refusing_connections_fails_then_succeeds_once_it_accepts():
    with modbus_peer(faults=["refuse"]) as peer:  # refuses until recover()
        d = peer.driver(timeout_s=0.3)
        r = run_cycle(d, AXIS, PROGRAM)
        assert not r.ok and r.reason_code == "connection"
        assert 1 <= d.connect_attempts <= d.retries + 1
        peer.recover()
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason

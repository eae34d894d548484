"""Modbus TCP specifics: register codec, modes, exception codes, refused and recovered connections."""

from __future__ import annotations

import asyncio
import socket

import numpy as np
import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from acquisition.modbus import register_map as mm
from acquisition.measurement import run_cycle, run_cycle_async
from acquisition.errors import ControllerConnectionError, DeviceBusyError, ProtocolError
from acquisition.modbus.driver import ModbusDriver
from acquisition.scale import EncoderScale
from acquisition.driver.retry import RetryPolicy
from acquisition.types import AxisState, Command, RoundTripProgram
from tests.acquisition.conftest import AXIS, PROGRAM, modbus_peer
from tests.acquisition.modbus.fake_modbus import FakeController, busy
from tests.ports import free_port


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
    port = free_port()  # nothing listens here
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


class _Relay:
    """A ``client_factory`` that hands the driver a real pymodbus client (to the simulated
    controller) with one fault injected into its replies, as the network or the controller
    would produce it; ``injected`` counts them."""

    def __init__(self, port: int, fault):
        self.port, self.fault, self.injected = port, fault, 0
        self.ring_records_read = 0  # records read from the trace ring so far
        self.ring_reads_since_status = 0
        self.last_was_ring = False

    def __call__(self):
        return _RelayClient(self, AsyncModbusTcpClient("127.0.0.1", port=self.port, timeout=0.5, retries=0,
                                                       reconnect_delay=0))


class _RelayClient:
    def __init__(self, relay: _Relay, client):
        self.relay, self.client = relay, client

    async def connect(self):
        return await self.client.connect()

    def close(self):
        self.client.close()

    async def write_registers(self, *a, **kw):
        return await self.client.write_registers(*a, **kw)

    async def read_holding_registers(self, address, *, count, device_id=1):
        r = self.relay
        ring = address >= mm.RING_BASE
        try:
            reply = r.fault(r, address, count)
        except Exception:
            r.injected += 1
            raise
        r.last_was_ring = ring
        if ring:
            r.ring_records_read += count // mm.RECORD_WORDS
            r.ring_reads_since_status += 1
        elif count >= mm.STATUS_WORDS:
            r.ring_reads_since_status = 0
        if reply is not None:
            r.injected += 1
            return reply
        return await self.client.read_holding_registers(address, count=count, device_id=device_id)


def _busy_once_after_a_partly_new_block(r: _Relay, address, count):
    # a status read straight after a ring read is the one a partly new block triggers: its
    # records were read but not yet handed over when the status read fails
    if not r.injected and not address and count == mm.STATUS_WORDS and r.last_was_ring and r.ring_records_read > 100:
        return busy()
    return None


def test_records_read_before_a_failed_status_read_are_not_lost():
    # deterministic form of the brief-exception case: the failure lands between reading a
    # block of records and handing it over, which once dropped that block
    with modbus_peer(time_scale=2.0) as peer:
        relay = _Relay(peer.driver().port, _busy_once_after_a_partly_new_block)
        d = ModbusDriver("127.0.0.1", relay.port, timeout_s=0.5, retries=3, client_factory=relay)
        r = run_cycle(d, AXIS, PROGRAM)
        assert relay.injected == 1
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)


def _timeout_on_third_block_of_a_drain(r: _Relay, address, count):
    # blocks_per_drain is 16: the third ring read of a batch since the last status read
    if not r.injected and address >= mm.RING_BASE and r.ring_reads_since_status % 16 == 2:
        raise ModbusIOException("injected: no reply")
    return None


def test_a_failed_read_mid_batch_loses_no_sample():
    # time_scale 50: the controller runs ahead, so drains read several blocks at once
    with modbus_peer(time_scale=50.0) as peer:
        relay = _Relay(peer.driver().port, _timeout_on_third_block_of_a_drain)
        d = ModbusDriver("127.0.0.1", relay.port, timeout_s=0.5, retries=3, client_factory=relay)
        r = run_cycle(d, AXIS, PROGRAM)
        assert relay.injected == 1
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_block_validity_from_first_and_last_counter():
    def block(counters):
        rec = np.array([[c, 10 * c, -c] for c in counters])
        return mm.encode_records(rec).astype(int).tolist()

    n = mm.RECORDS_PER_READ
    assert mm.new_records(block(range(500, 500 + n)), n, 500) == (n, 500 + n)
    # the ring's newest record is 506: the rest of the block is an older lap
    assert mm.new_records(block([*range(500, 507), *range(507 - 2000, 507 - 2000 + n - 7)]), n, 500) == (7, 507)
    assert mm.new_records(block(range(400, 400 + n)), n, 500) == (0, 500)  # nothing new yet
    # across the u32 wrap of the counter
    top = 2**32 - 5
    wrapped = [(top + i) % 2**32 for i in range(n)]
    assert mm.new_records(block(wrapped), n, top) == (n, top + n)
    # a gap (samples never latched) is not hidden: the block is new, the base loop reports the gap
    assert mm.new_records(block([*range(500, 505), *range(510, 510 + n - 5)]), n, 500) == (n, 510 + n - 5)


def _fake_driver(ctl: FakeController, **kw) -> ModbusDriver:
    kw.setdefault("max_lost_samples", 10**6)
    return ModbusDriver("fake", 1, client_factory=ctl.client, timeout_s=0.5, poll_interval_s=1e-4, **kw)


def test_a_torn_block_is_cut_at_the_older_record_and_read_again():
    ctl = FakeController(ring_records=100, first_counter=1000)

    def run_whole_trace(c):
        c.write(100)
        c.state = AxisState.DONE  # all latched before the first read
        c.torn = {25: (1000 + 25 - 100, 0, 0)}  # slot 25 still held the previous lap when the read passed it

    ctl.on_start = run_whole_trace
    tr = _fake_driver(ctl, max_lost_samples=0).acquire(PROGRAM, AXIS)
    assert tr.counter.tolist() == list(range(1000, 1100)) and tr.lost_samples == 0
    assert tr.table_mm == pytest.approx([50 * w * 1e-5 for w in range(100)])
    reads = ctl.ring_reads()  # the batch with the torn record is cut there and read again from slot 25
    assert reads[:2] == [0, 20] and 25 in reads and reads.index(25) > 1


@pytest.mark.parametrize("during", [99, 100, 101, 150, 199, 200, 201, 350])
def test_records_written_while_the_reader_is_away_are_read_or_counted_lost(during):
    # a ring of 100 records; the reader has read records 0..29 when a status read takes so
    # long that the controller writes ``during`` more and ends (the ring holds the last 100)
    ctl = FakeController(ring_records=100, first_counter=5000)
    ctl.on_start = lambda c: c.write(30)

    def away(c):
        if not c.ring_reads():
            return  # the status read of the start
        c.on_status = None
        c.write(during)
        c.state = AxisState.DONE

    ctl.on_status = away
    tr = _fake_driver(ctl).acquire(PROGRAM, AXIS)
    got = tr.counter.tolist()
    end = 5000 + 30 + during
    assert got[-1] == end - 1 and np.all(np.diff(got) >= 1)  # in order, up to the last record
    if during <= 100:  # nothing was overwritten: every record is read
        assert got == list(range(5000, end)) and tr.lost_samples == 0
    else:  # overwritten records show as a gap in the counters, every one of them counted
        assert tr.lost_samples == int(np.sum(np.diff(got) - 1)) == during - 100
    assert ctl.commands.count(Command.ABORT) == 0


class _SkippingController(FakeController):
    """A controller whose servo counter jumps by more than the ring at record 30 (cycles it
    never latched): a gap to count, not a lapped reader."""

    def _record(self, w):
        c, m, t = super()._record(w)
        return ((c + 150) & 0xFFFFFFFF if w >= 30 else c), m, t


def test_a_counter_jump_larger_than_the_ring_is_counted_not_mistaken_for_a_lap():
    ctl = _SkippingController(ring_records=100, first_counter=5000)

    def run(c):
        c.write(60)
        c.state = AxisState.DONE

    ctl.on_start = run
    tr = _fake_driver(ctl).acquire(PROGRAM, AXIS)
    assert len(tr) == 60 and tr.lost_samples == 150
    assert tr.counter.tolist() == [*range(5000, 5030), *range(5180, 5210)]


def test_a_trace_across_the_counter_wrap_is_continuous():
    ctl = FakeController(ring_records=64, first_counter=2**32 - 70)

    def run(c):
        c.write(40)
        c.on_status = later

    def later(c):
        if c.ring_reads():
            c.write(20)
            c.state, c.on_status = AxisState.DONE, None

    ctl.on_start = run
    tr = _fake_driver(ctl, max_lost_samples=0).acquire(PROGRAM, AXIS)
    assert tr.counter.tolist() == list(range(2**32 - 70, 2**32 - 10)) and tr.lost_samples == 0
    assert np.allclose(np.diff(tr.time_s), 1e-3)


def test_a_persistently_busy_controller_fails_as_device_busy_after_its_retries():
    ctl = FakeController()
    ctl.on_start = lambda c: c.write(10)
    ring_reads = []

    def busy_ring(address, count):
        if address >= mm.RING_BASE:
            ring_reads.append(address)
            return busy()
        return None

    ctl.inject = busy_ring
    r = run_cycle(_fake_driver(ctl, retries=2, retry=RetryPolicy(attempts=3, sleep=_no_sleep)), AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "device_busy" and "gave up after 3 attempts" in r.reason
    assert len(ring_reads) == 3 and isinstance(r.error, DeviceBusyError) and r.error.code == 6
    assert ctl.commands[-1] == Command.ABORT and "abort sent" in r.reason


async def _no_sleep(_s: float) -> None:
    return None


def test_exception_codes_map_to_classes_whose_transience_is_fixed():
    from acquisition.modbus.driver import exception_error

    assert type(exception_error(6, "x")) is DeviceBusyError and DeviceBusyError.transient
    assert type(exception_error(2, "x")) is ProtocolError and not ProtocolError.transient
    assert exception_error(4, "x").transient and exception_error(4, "x").code == 4
    assert "transient" not in vars(exception_error(6, "x"))  # a class fact, never set per instance


def test_status_block_is_a_typed_decode_of_the_register_map():
    words = mm.encode_status(AxisState.RUNNING, 0x7305, 2**32 - 1, -5, 7, -3.25, 123, 456)
    s = mm.decode_status(words)
    assert isinstance(s, mm.StatusBlock)
    assert (s.state, s.fault_code, s.counter, s.motor_counts, s.table_counts) == (AxisState.RUNNING, 0x7305, 2**32 - 1, -5, 7)
    assert (s.temperature_c, s.trace_first, s.trace_count) == (-3.25, 123, 456)
    unknown = mm.decode_status([1, 9] + words[2:])
    assert unknown.state is None and unknown.state_raw == 9


def test_a_ring_overrun_over_the_wire_is_counted_and_the_cycle_still_ends():
    # replies slowed to 50 ms while the controller writes 5000 records/s into a 64-record
    # ring: the reader is lapped again and again; with losses tolerated the trace must still
    # run in order to the controller's last record, and every record from the first to the
    # last is either kept or counted lost. (The losses are gaps between kept records, or
    # records before the first one kept: on a loaded host the whole program can be written
    # before the first read gets through, and then only the ring's
    # last 64 records are kept and every earlier one is counted.)
    with modbus_peer(faults=["slow:at=0.3,s=0.05"], ring_records=64) as peer:
        tr = peer.driver(max_lost_samples=10**6).acquire(PROGRAM, AXIS)
        c = tr.counter
        assert tr.lost_samples > 0 and np.all(np.diff(c) >= 1)
        lost_before_first = int(c[0]) - peer.axis.trace_first
        assert lost_before_first >= 0
        assert lost_before_first + int(np.sum(np.diff(c) - 1)) == tr.lost_samples
        assert int(c[-1]) == peer.axis.trace_first + peer.axis.trace_count() - 1


def test_brief_drop_is_recovered_from_the_trace_buffer():
    with modbus_peer(faults=["drop:at=0.4,for=0.2"], time_scale=2.0) as peer:
        r = run_cycle(peer.driver(timeout_s=0.5, retries=3), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.lost_samples == 0 and np.all(np.diff(r.trace.counter) == 1)
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


# The polled modes' simulated controller runs at half speed: a stall of this host while it
# polls leaves half the travel without samples, so one of 0.25 s on a loaded machine stays
# under the analysis' 2 mm hole limit at 1000 mm/min.
POLLED_TIME_SCALE = 0.5


def test_latched_poll_mode_is_latched_but_decimated():
    with modbus_peer(mode="latched", time_scale=POLLED_TIME_SCALE) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.trace.mode == "latched" and r.trace.latched
        sampling = next(c for c in r.result.budgets["backlash_mean"].components if c.name == "sampling")
        assert sampling.standard_um == 0.0 and r.uncertainty_um == r.result.budgets["backlash_mean"].combined_um
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_separate_reads_are_labelled_and_carry_skew_uncertainty():
    with modbus_peer(mode="separate", time_scale=POLLED_TIME_SCALE) as peer:
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


# A polled wire has no buffer: a pause of the host or the network leaves a stretch of travel
# without samples. "slow" delays the controller's replies by 0.6 s for 0.3 s of the run,
# in the first round trip only (cycles=1) or in two (cycles=2): 5 mm of travel at half speed.
def test_a_hole_in_a_polled_trace_runs_the_round_trip_once_more():
    with modbus_peer(mode="separate", time_scale=POLLED_TIME_SCALE, faults=["slow:at=0.3,s=0.6,for=0.3"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
        assert r.ok, r.reason
        assert r.attempts == 2 and "no samples between" in r.repeated_after and "paused" in r.repeated_after
        # unlatched reads: b̄ within the skew bound the result carries
        assert abs(r.result.backlash_mean_um - 120.0) < r.trace.skew_uncertainty_um + 1.0
        assert r.to_dict()["attempts"] == 2 and r.to_dict()["repeated_after"] == r.repeated_after
        assert r.to_run("rt.csv").spec.extra["repeated_after"] == r.repeated_after


def test_a_hole_is_repeated_once_only_and_not_when_asked_not_to():
    with modbus_peer(mode="separate", time_scale=POLLED_TIME_SCALE, faults=["slow:at=0.3,s=0.6,for=0.3,cycles=2"]) as peer:
        r = asyncio.run(run_cycle_async(peer.driver(), AXIS, PROGRAM))  # the asyncio path repeats alike
        assert not r.ok and r.reason_code == "trace" and r.attempts == 2
        assert "run twice" in r.reason and r.result is None
    with modbus_peer(mode="separate", time_scale=POLLED_TIME_SCALE, faults=["slow:at=0.3,s=0.6,for=0.3"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM, repeat_on_hole=False)
        assert not r.ok and r.reason_code == "trace" and r.attempts == 1 and r.repeated_after is None
        assert "no samples between" in r.reason

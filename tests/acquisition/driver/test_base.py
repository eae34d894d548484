"""The driver base class through a scripted controller (the ``client_factory`` hook): every
exchange under the one retry policy, and nothing carried from one cycle to the next."""

from __future__ import annotations

import asyncio

import pytest
from pymodbus.exceptions import ModbusIOException

from acquisition.modbus import register_map as mm
from acquisition.measurement import run_cycle
from acquisition.errors import DriverMisuseError
from acquisition.modbus.driver import ModbusDriver
from acquisition.driver.retry import RetryPolicy
from acquisition.types import AxisState, Command
from tests.acquisition.conftest import AXIS, PROGRAM
from tests.acquisition.modbus.fake_modbus import FakeController


async def _no_sleep(_s: float) -> None:
    return None


def _driver(ctl: FakeController, attempts: int = 3, **kw) -> ModbusDriver:
    return ModbusDriver("fake", 1, client_factory=ctl.client, timeout_s=0.5, poll_interval_s=1e-4,
                        retry=RetryPolicy(attempts=attempts, sleep=_no_sleep), **kw)


def _whole_trace(n: int = 90):
    def start(c: FakeController) -> None:
        c.write(n)
        c.state = AxisState.DONE
    return start


def test_refused_connections_are_retried_by_the_policy_then_succeed():
    ctl = FakeController()
    ctl.on_start = _whole_trace()
    ctl.refuse = 2
    d = _driver(ctl, attempts=3)
    tr = d.acquire(PROGRAM, AXIS)
    assert len(tr) == 90 and d.connect_attempts == 3 and ctl.connects == 3


def test_refused_connections_end_after_the_policys_attempts():
    ctl = FakeController()
    ctl.refuse = 10
    d = _driver(ctl, attempts=4)
    r = run_cycle(d, AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "connection" and d.connect_attempts == ctl.connects == 4


def test_a_timed_out_read_is_retried_after_a_reconnect_and_noted():
    ctl = FakeController()
    ctl.on_start = _whole_trace()
    failed = []

    def once_on_the_ring(address, count):
        if address >= mm.RING_BASE and not failed:
            failed.append(address)
            raise ModbusIOException("injected: no reply")

    ctl.inject = once_on_the_ring
    d = _driver(ctl)
    tr = d.acquire(PROGRAM, AXIS)
    assert len(tr) == 90 and tr.lost_samples == 0
    assert ctl.connects == 2  # the link was closed after the timeout, so no late reply can answer the retry
    assert "no reply" in d.last_cycle.link_trouble


def test_the_abort_is_retried_by_the_same_policy():
    ctl = FakeController()
    ctl.on_start = lambda c: c.write(10)
    ctl.inject = lambda address, count: (_ for _ in ()).throw(ModbusIOException("injected")) if address >= mm.RING_BASE else None
    writes = []
    client_write = ctl.client

    def client():
        c = client_write()
        orig = c.write_registers

        async def write_registers(address, values, *, device_id=1):
            writes.append(values[0])
            if values[0] == Command.ABORT and writes.count(Command.ABORT) < 3:
                raise ModbusIOException("injected: the abort got no reply")
            return await orig(address, values, device_id=device_id)

        c.write_registers = write_registers
        return c

    d = ModbusDriver("fake", 1, client_factory=client, timeout_s=0.5,
                     retry=RetryPolicy(attempts=2, sleep=_no_sleep))
    r = run_cycle(d, AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "timeout" and "gave up after 2 attempts" in r.reason
    assert writes.count(Command.ABORT) == 3 and "abort sent" in r.reason and ctl.state == AxisState.ABORTED


def test_a_driver_is_reusable_across_cycles_without_stale_state():
    ctl = FakeController(ring_records=100)
    d = _driver(ctl)

    # cycle 1: the reader is lapped (samples lost: the cycle fails) after a recovered timeout
    def lapped(c):
        c.write(30)
        c.on_status = overrun

    def overrun(c):
        if len(c.ring_reads()) >= 2:
            c.on_status = None
            c.write(250)
            c.state = AxisState.DONE

    timeouts = []

    def one_timeout(address, count):
        if address >= mm.RING_BASE and not timeouts:
            timeouts.append(1)
            raise ModbusIOException("injected")

    ctl.on_start, ctl.inject = lapped, one_timeout
    r1 = run_cycle(d, AXIS, PROGRAM)
    assert not r1.ok and r1.reason_code == "lost_samples", r1.reason
    first = d.last_cycle
    assert first.link_trouble and first.wire.next_w > 100 and first.assembler.lost_samples > 0

    # cycle 2 on the same driver: a clean trace, a fresh cycle (read position, losses, link trouble)
    ctl.first_counter += 10**6
    ctl.on_start, ctl.inject = _whole_trace(90), None
    r2 = run_cycle(d, AXIS, PROGRAM)
    assert r2.reason_code in (None, "incomplete_trace"), r2.reason  # a 90-sample ramp is no round trip
    second = d.last_cycle
    assert second is not first and second.link_trouble is None and d.link_trouble is None
    assert second.assembler.lost_samples == 0 and second.wire.next_w == 90
    assert r2.trace.counter[0] == ctl.first_counter and len(r2.trace) == 90


def test_one_cycle_at_a_time_per_driver_is_a_programming_error():
    ctl = FakeController()
    ctl.on_start = _whole_trace()

    async def both():
        ctl.gate, ctl.waiting = asyncio.Event(), asyncio.Event()  # hold the first cycle in its first read
        d = _driver(ctl)
        first = asyncio.create_task(d.acquire_async(PROGRAM, AXIS))
        await ctl.waiting.wait()
        with pytest.raises(DriverMisuseError) as err:
            await d.acquire_async(PROGRAM, AXIS)
        ctl.gate.set()
        return err.value, await first

    err, trace = asyncio.run(both())
    assert isinstance(err, RuntimeError) and "one cycle at a time" in str(err)
    assert len(trace) == 90  # the cycle under way was not disturbed


def test_blocking_acquire_inside_an_event_loop_is_a_programming_error():
    async def inside():
        with pytest.raises(DriverMisuseError, match="acquire_async") as err:
            _driver(FakeController()).acquire(PROGRAM, AXIS)
        return err.value

    assert isinstance(asyncio.run(inside()), RuntimeError)

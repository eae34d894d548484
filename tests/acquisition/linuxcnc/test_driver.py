"""mebm's LinuxCNC driver on LinuxCNC itself: the simulated machine of
acquisition/linuxcnc/sim, started once for the module, its X axis with a 120 µm backlash
between motor and table, loop closed by LinuxCNC's pid on the motor encoder.

Asserts: an active round trip's b̄ within 1 µm of the chain's backlash, from samples of
consecutive servo periods; a round trip LinuxCNC runs from a program mebm did not send,
found passively; each typed failure (e-stop before and during the trace, machine off, a
bad pin, a pin the sampler does not record, a sampler overrun, LinuxCNC stopped
mid-trace and not running); a command linuxcncrsh refuses on its stale copy of the
machine's state (switched on elsewhere) is sent again once the state is asked, mebm's
session takes control back from a client that took it, and names the machine's state when
linuxcncrsh refuses a command with the machine off. The test that stops LinuxCNC is the
module's last.
"""

from __future__ import annotations

import asyncio
import os
import signal
import time

import numpy as np
import pytest

from acquisition.linuxcnc.errors import CommandRefusedError
from acquisition.linuxcnc.rsh import RshClient
from acquisition.measurement import run_cycle
from acquisition.url import driver_from_url
from tests.acquisition.linuxcnc.rig import (
    AXIS,
    BACKLASH_UM,
    PROGRAM,
    in_thread,
    run_operator_program,
    running_sim,
    switch_on_elsewhere,
)
from tests.waiting import until


@pytest.fixture(scope="module")
def sim():
    with running_sim() as s:
        yield s


@pytest.fixture
def powered(sim):
    """The machine out of e-stop and on, whatever the test before left."""
    sim.power_on()
    return sim


def driver(sim, extra: str = "", **kw):
    kw.setdefault("timeout_s", 2.0)
    return driver_from_url(sim.url + extra, **kw)


def cycle_in_thread(drv, program=PROGRAM):
    return in_thread(run_cycle, drv, AXIS, program)


def wait_for_samples(drv, n: int = 200):
    """Until the driver has read ``n`` samples of the round trip under way."""
    until(lambda: drv.samples_read >= n, "samples of the round trip flowing from halsampler")


def result_of(thread, out):
    thread.join(60.0)
    assert not thread.is_alive(), "the cycle did not end"
    assert "error" not in out, out.get("error")
    return out["value"]


def test_an_active_round_trip_gives_the_chain_s_backlash_within_1_um(powered):
    drv = driver(powered, "&trigger=active")
    r = run_cycle(drv, AXIS, PROGRAM)
    assert r.ok, r.reason
    assert abs(r.result.backlash_mean_um - BACKLASH_UM) <= 1.0, r.result.backlash_mean_um
    t = r.trace
    assert t.protocol == "linuxcnc" and t.latched and t.lost_samples == 0
    assert np.all(np.diff(t.counter) == 1)  # one sample every servo period, none missing
    assert t.servo_rate_hz == pytest.approx(1000.0)
    # the commanded position was recorded beside the encoders, one value per sample
    assert drv.last_command_mm.size == len(t)
    assert drv.last_command_mm.max() == pytest.approx(PROGRAM.end_mm, abs=1e-6)


def test_a_round_trip_linuxcnc_runs_from_its_own_program_is_found_passively(powered):
    drv = driver(powered, "&start_timeout_s=30")
    assert drv.trigger == "passive"  # the default: mebm only records
    thread, out = cycle_in_thread(drv)
    wait_for_samples(drv, 100)
    run_operator_program(powered, "G21 G90 G61\nG53 G1 X-2 F1500\nG4 P0.3\nG53 G1 X14 F1500\nG4 P0.2\n"
                                  "G53 G1 X-2 F1500\nG4 P0.4\nM2\n")
    r = result_of(thread, out)
    assert r.ok, r.reason
    assert r.trace.trigger == "passive"
    assert r.program.start_mm == pytest.approx(-2.0, abs=0.2) and r.program.end_mm == pytest.approx(14.0, abs=0.2)
    assert abs(r.result.backlash_mean_um - BACKLASH_UM) <= 1.0, r.result.backlash_mean_um


def test_estop_before_the_round_trip_is_a_typed_failure_and_nothing_moves(powered):
    powered.rsh("set estop on")
    before = powered.rsh("get abs_act_pos")
    r = run_cycle(driver(powered, "&trigger=active"), AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "estop", r.reason
    assert powered.rsh("get abs_act_pos") == before
    assert powered.rsh("get estop") == ["ESTOP ON"]  # mebm left it as it was


def test_estop_during_the_round_trip_fails_the_cycle_as_estop(powered):
    drv = driver(powered, "&trigger=active")
    thread, out = cycle_in_thread(drv)
    wait_for_samples(drv)
    powered.rsh("set estop on")
    r = result_of(thread, out)
    assert not r.ok and r.reason_code == "estop", r.reason


def test_machine_off_is_a_typed_failure(powered):
    powered.rsh("set machine off")
    r = run_cycle(driver(powered, "&trigger=active"), AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "machine_off", r.reason


class RecordingRsh(RshClient):
    """An RshClient that keeps each line it exchanged with its reply."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.exchanged: list[tuple[str, str]] = []

    async def exchange(self, line: str) -> str:
        reply = await super().exchange(line)
        self.exchanged.append((line, reply))
        return reply


def test_a_command_refused_on_linuxcncrsh_s_stale_machine_state_is_sent_again_once_the_state_is_asked(powered):
    assert powered.rsh("set machine off", "get machine")[-1] == "MACHINE OFF"  # linuxcncrsh's last read
    switch_on_elsewhere()  # LinuxCNC is ON; linuxcncrsh has not read it since

    async def body():
        rsh = RecordingRsh("127.0.0.1", powered.settings.port, timeout_s=5.0)
        await rsh.open(enable=True)
        try:
            await rsh.set("mode auto")
        finally:
            await rsh.close()
        return rsh.exchanged

    exchanged = asyncio.run(body())
    assert exchanged[-4:] == [("set mode auto", "SET MODE NAK"), ("get enable", "ENABLE ON"),
                              ("get machine", "MACHINE ON"), ("set mode auto", "SET MODE ACK")], exchanged


async def _enabled_session_then(sim, operator_command: str, command: str) -> tuple[BaseException | None, str]:
    """mebm's session enabled, then the operator's ``operator_command`` on a session of their
    own (which enables itself), then ``command`` on mebm's: what it raised and whether mebm's
    session is the enabled one after it."""
    rsh = RshClient("127.0.0.1", sim.settings.port, timeout_s=5.0)
    await rsh.open(enable=True)
    try:
        sim.rsh(operator_command)
        try:
            await rsh.set(command)
            error = None
        except CommandRefusedError as exc:
            error = exc
        return error, (await rsh.get("enable"))[0]
    finally:
        await rsh.close()


def test_a_session_another_client_took_control_of_takes_it_back_and_sends_again(powered):
    assert asyncio.run(_enabled_session_then(powered, "get enable", "mode mdi")) == (None, "ON")


def test_a_command_refused_with_the_machine_off_names_the_state(powered):
    # the operator's session took control too: mebm's is not enabled either, and says so
    error, enabled = asyncio.run(_enabled_session_then(powered, "set machine off", "mode mdi"))
    assert isinstance(error, CommandRefusedError), error
    assert (error.estop, error.machine_on, error.enabled, enabled) == (False, False, False, "OFF")
    assert "machine OFF, E-STOP off, this session not enabled" in str(error), str(error)
    assert "the operator switches it on" in str(error), str(error)


@pytest.mark.parametrize("pins", ["scale_pin=x-scael.out", "scale_pin=y-scale.out"], ids=["no-such-pin", "not-sampled"])
def test_a_wrong_pin_is_a_typed_failure_naming_it(powered, pins):
    url = powered.url.replace("scale_pin=x-scale.out", pins)
    r = run_cycle(driver_from_url(url + "&trigger=active", timeout_s=5.0), AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "hal_pin", r.reason
    assert pins.split("=")[1] in r.reason


def test_a_sampler_overrun_fails_the_cycle_with_the_samples_lost(powered):
    # FIFO 1 of the simulated machine holds a quarter of a second: halsampler held still
    # for longer overruns it, as a busy host would
    drv = driver(powered, "&trigger=active&sampler=1")
    thread, out = cycle_in_thread(drv)
    wait_for_samples(drv)
    pid = drv.sampler_pid
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(0.6)
    finally:
        os.kill(pid, signal.SIGCONT)
    r = result_of(thread, out)
    assert not r.ok and r.reason_code == "lost_samples", r.reason
    assert r.error.lost_samples >= 1  # counted from the sampler's overruns pin as soon as it moved
    assert "abort sent" in r.reason  # and mebm stopped the round trip it had started
    until(lambda: powered.rsh("get program_status") == ["PROGRAM_STATUS IDLE"], "the program stopped")


def test_linuxcnc_stopped_mid_trace_then_not_running_are_connection_failures(powered):
    drv = driver(powered, "&trigger=active", retries=1)
    thread, out = cycle_in_thread(drv)
    wait_for_samples(drv)
    powered.stop()
    r = result_of(thread, out)
    assert not r.ok and r.reason_code == "connection", r.reason
    again = run_cycle(driver(powered, "&trigger=active"), AXIS, PROGRAM)
    assert not again.ok and again.reason_code == "connection" and "not running" in again.reason, again.reason

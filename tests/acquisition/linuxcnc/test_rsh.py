"""RshClient.set against a linuxcncrsh that refuses as LinuxCNC 2.9's does (fake_rsh): a
refusal on a stale copy of the task state or on a session another client took control of is
asked about and sent once more; a refusal the state explains (machine off, e-stop) or that
persists is a CommandRefusedError naming the state found and what to do."""

from __future__ import annotations

import asyncio

import pytest

from acquisition.errors import ProtocolError
from acquisition.linuxcnc.errors import CommandRefusedError
from acquisition.linuxcnc.rsh import RshClient
from tests.acquisition.linuxcnc.fake_rsh import FakeLinuxcncrsh


def after_enable(fake: FakeLinuxcncrsh, session: int) -> list[tuple[str, str | None]]:
    """The session's lines after it enabled itself (``set verbose on`` and on)."""
    lines = fake.lines_of(session)
    return lines[[line for line, _ in lines].index("set verbose on") + 1:]


async def _set_on(fake: FakeLinuxcncrsh, command: str) -> None:
    rsh = RshClient("127.0.0.1", fake.port)
    await rsh.open(enable=True)
    try:
        await rsh.set(command)
    finally:
        await rsh.close()


def set_on(command: str, **fake_kwargs) -> tuple[FakeLinuxcncrsh, BaseException | None]:
    """Send ``set command`` on an enabled session of a fake linuxcncrsh: the fake and what was raised."""
    async def body():
        async with FakeLinuxcncrsh(**fake_kwargs) as fake:
            try:
                await _set_on(fake, command)
            except Exception as exc:  # noqa: BLE001 - handed to the test
                return fake, exc
            return fake, None
    return asyncio.run(body())


def test_a_set_refused_on_a_stale_copy_of_the_machine_state_is_sent_again_once_the_state_is_asked():
    # linuxcncrsh's copy says OFF (no get since the machine was switched on); LinuxCNC is ON
    fake, error = set_on("mode auto", task_state="ON", copied_state="OFF")
    assert error is None, error
    assert after_enable(fake, 1) == [("set mode auto", "SET MODE NAK"), ("get enable", "ENABLE ON"),
                                     ("get machine", "MACHINE ON"), ("set mode auto", "SET MODE ACK")]
    assert fake.applied == ["mode auto"]


def test_a_session_another_client_took_control_of_takes_it_back_and_sends_again():
    async def body():
        async with FakeLinuxcncrsh() as fake:
            ours, other = RshClient("127.0.0.1", fake.port), RshClient("127.0.0.1", fake.port)
            await ours.open(enable=True)
            await other.open(enable=True)  # the last set enable takes control
            await ours.set("mode auto")
            assert await other.get("enable") == ["OFF"]
            await ours.close()
            await other.close()
            return fake
    fake = asyncio.run(body())
    assert after_enable(fake, 1) == [("set mode auto", "SET MODE NAK"), ("get enable", "ENABLE OFF"),
                                     ("get machine", "MACHINE ON"), ("set enable EMCTOO", "SET ENABLE ACK"),
                                     ("set mode auto", "SET MODE ACK")]
    assert fake.applied == ["mode auto"]


@pytest.mark.parametrize("task_state, estop, found, todo", [
    ("OFF", False, "machine OFF, E-STOP off, this session enabled", "the operator switches it on"),
    ("ESTOP", True, "machine OFF, E-STOP ON, this session enabled", "the operator resets it at the machine"),
])  # fmt: skip
def test_a_set_refused_with_the_machine_not_on_is_not_sent_again_and_names_the_state(task_state, estop, found,
                                                                                     todo):
    fake, error = set_on("mode auto", task_state=task_state)
    assert isinstance(error, CommandRefusedError) and isinstance(error, ProtocolError), error
    assert (error.command, error.estop, error.machine_on, error.enabled) == ("mode auto", estop, False, True)
    assert found in str(error) and todo in str(error) and "mebm never does" in str(error), str(error)
    assert error.reason_code == "command_refused"
    assert [line for line, _ in after_enable(fake, 1)] == ["set mode auto", "get enable", "get machine", "get estop"]
    assert fake.applied == []


def test_a_refusal_the_state_does_not_explain_is_sent_once_more_then_named():
    fake, error = set_on("open /no/such.ngc", refuse=["OPEN"])
    assert isinstance(error, CommandRefusedError), error
    assert (error.estop, error.machine_on, error.enabled) == (None, True, True)
    assert "machine ON, this session enabled" in str(error) and "LinuxCNC's log" in str(error), str(error)
    assert [line for line, _ in after_enable(fake, 1)] == ["set open /no/such.ngc", "get enable", "get machine",
                                                           "set open /no/such.ngc", "get enable", "get machine"]
    assert fake.applied == []


def test_an_acknowledged_set_asks_nothing():
    fake, error = set_on("mode auto")
    assert error is None, error
    assert after_enable(fake, 1) == [("set mode auto", "SET MODE ACK")]

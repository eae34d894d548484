"""A client of linuxcncrsh, LinuxCNC's text interface (``hello EMC x 1.0``, ``get estop``,
``set mdi ...``), on asyncio streams.

linuxcncrsh answers ``get`` with ``KEY VALUE...`` and, once ``set verbose on``, every
``set`` with ``SET KEY ACK`` or ``SET KEY NAK``; replies end in CR, LF or both, in either
order. The session is read-only until ``set enable`` (mebm enables it only for an active
round trip).

linuxcncrsh (2.9, ``commandSet``) refuses a ``set`` for two reasons of its own: another
session enabled itself after this one (the last ``set enable`` takes control), or its copy
of LinuxCNC's task state is not ON. It refreshes that copy on every ``get`` and while it
waits for a command to be received, never before it checks a ``set``: a ``set`` with no
``get`` before it (the first of a session) is judged on whatever state linuxcncrsh last
read, for any session. :meth:`RshClient.set` asks why once, and sends the command again
when the answer allows.
"""

from __future__ import annotations

import asyncio

from acquisition.errors import ControllerConnectionError, ControllerTimeoutError, ProtocolError
from acquisition.linuxcnc.errors import CommandRefusedError


class RshClient:
    """One linuxcncrsh session. ``connect_pw``/``enable_pw``: linuxcncrsh's passwords
    (``--connectpw``, ``--enablepw``; EMC and EMCTOO unless LinuxCNC was started otherwise)."""

    def __init__(self, host: str, port: int, *, timeout_s: float = 1.0, connect_pw: str = "EMC",
                 enable_pw: str = "EMCTOO"):
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self.connect_pw, self.enable_pw = connect_pw, enable_pw
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.enabled = False

    @property
    def where(self) -> str:
        return f"linuxcncrsh at {self.host}:{self.port}"

    async def open(self, *, enable: bool = False) -> None:
        try:
            self._reader, self._writer = await asyncio.wait_for(
                asyncio.open_connection(self.host, self.port), self.timeout_s)
        except asyncio.TimeoutError:
            raise ControllerTimeoutError(f"no answer from {self.where} within {self.timeout_s:g} s") from None
        except OSError as exc:
            raise ControllerConnectionError(
                f"LinuxCNC is not running, or not with linuxcncrsh on port {self.port} ({self.where}: "
                f"{exc.strerror or exc}): start it (DISPLAY = linuxcncrsh, or linuxcncrsh beside the GUI)") from exc
        hello = await self.exchange(f"hello {self.connect_pw} mebm 1.0")
        if not hello.upper().startswith("HELLO ACK"):
            raise ProtocolError(f"{self.where} refused the hello ({hello!r}): check the connect password")
        await self.exchange("set echo off")  # the last line it echoes
        if enable:
            await self.send(f"set enable {self.enable_pw}")  # no reply before verbose is on
            ack = await self.exchange("set verbose on")
            if "NAK" in ack.upper():
                raise ProtocolError(f"{self.where} refused to enable the session ({ack!r}): check the enable "
                                    "password")
            self.enabled = True

    async def close(self) -> None:
        w, self._writer, self._reader = self._writer, None, None
        self.enabled = False
        if w is not None:
            try:
                w.close()
                await asyncio.wait_for(w.wait_closed(), 0.5)
            except (OSError, asyncio.TimeoutError):
                pass

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    async def send(self, line: str) -> None:
        if self._writer is None:
            raise ControllerConnectionError(f"not connected to {self.where}")
        try:
            self._writer.write(line.encode() + b"\r\n")
            await self._writer.drain()
        except OSError as exc:
            raise ControllerConnectionError(f"{self.where} dropped the connection: LinuxCNC stopped?") from exc

    async def _line(self) -> str:
        while True:
            try:
                raw = await asyncio.wait_for(self._reader.readuntil(b"\n"), self.timeout_s)
            except asyncio.TimeoutError:
                raise ControllerTimeoutError(f"no reply from {self.where} within {self.timeout_s:g} s") from None
            except (asyncio.IncompleteReadError, OSError) as exc:
                raise ControllerConnectionError(
                    f"{self.where} closed the connection: LinuxCNC stopped") from exc
            text = raw.decode(errors="replace").strip("\r\n ")
            if text:
                return text

    async def exchange(self, line: str) -> str:
        await self.send(line)
        return await self._line()

    async def get(self, key: str) -> list[str]:
        """``get KEY``: the reply's words after the key (``get estop`` -> ``["OFF"]``)."""
        reply = await self.exchange(f"get {key}")
        words = reply.split()
        if not words or words[0].upper() != key.upper() or "NAK" in (w.upper() for w in words[1:2]):
            raise ProtocolError(f"{self.where}: 'get {key}' answered {reply!r}")
        return words[1:]

    async def set(self, command: str) -> None:
        """``set COMMAND`` on an enabled session. On a NAK the session asks why (``get enable``,
        ``get machine``; each ``get`` also refreshes linuxcncrsh's copy of the task state):
        with the machine ON it takes control back if another session has it and sends the
        command once more. A machine found off, or a second NAK, is a
        :class:`~acquisition.linuxcnc.errors.CommandRefusedError` naming the state found."""
        reply = await self.exchange(f"set {command}")
        if _acked(reply):
            return
        if not self.enabled:
            raise ProtocolError(f"{self.where} refused 'set {command}' on a session that is not enabled: {reply!r}")
        estop, machine_on, enabled = await self._state()
        if machine_on:
            if not enabled:
                await self.exchange(f"set enable {self.enable_pw}")  # verbose is on: it answers
            reply = await self.exchange(f"set {command}")
            if _acked(reply):
                return
            estop, machine_on, enabled = await self._state()
        raise CommandRefusedError(self._refusal(command, reply, estop, machine_on, enabled), command=command,
                                  estop=estop, machine_on=machine_on, enabled=enabled)

    async def _state(self) -> tuple[bool | None, bool, bool]:
        """(e-stop, machine on, this session enabled) as linuxcncrsh sees them now; e-stop is
        asked only when the machine is not on (None otherwise)."""
        enabled = (await self.get("enable"))[0].upper() == "ON"
        machine_on = (await self.get("machine"))[0].upper() == "ON"
        estop = None if machine_on else (await self.get("estop"))[0].upper() == "ON"
        return estop, machine_on, enabled

    def _refusal(self, command: str, reply: str, estop: bool | None, machine_on: bool, enabled: bool) -> str:
        found = (f"machine {'ON' if machine_on else 'OFF'}"
                 + ("" if estop is None else f", E-STOP {'ON' if estop else 'off'}")
                 + f", this session {'enabled' if enabled else 'not enabled'}")
        if estop:
            todo = "LinuxCNC is in E-STOP: the operator resets it at the machine; mebm never does"
        elif not machine_on:
            todo = "the machine is OFF: the operator switches it on; mebm never does"
        elif not enabled:
            todo = ("another linuxcncrsh client holds control (each 'set enable' takes it from the last) or "
                    "the enable password was refused: let no other client (a second mebm, a pendant, a script) "
                    "command LinuxCNC while mebm measures, and check the enable password")
        else:
            todo = ("linuxcncrsh refused the command itself on a machine that accepts commands: check "
                    "LinuxCNC's log for why it cannot run it (the program file, the mode)")
        return f"{self.where} refused 'set {command}' ({reply!r}; found {found}): {todo}"


def _acked(reply: str) -> bool:
    """Whether a ``set`` reply is linuxcncrsh's ``SET KEY ACK``."""
    return "ACK" in reply.upper() and "NAK" not in reply.upper()

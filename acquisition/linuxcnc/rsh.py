"""A client of linuxcncrsh, LinuxCNC's text interface (``hello EMC x 1.0``, ``get estop``,
``set mdi ...``), on asyncio streams.

linuxcncrsh answers ``get`` with ``KEY VALUE...`` and, once ``set verbose on``, every
``set`` with ``SET KEY ACK`` or ``SET KEY NAK``; replies end in CR, LF or both, in either
order. The session is read-only until ``set enable`` (mebm enables it only for an active
round trip).
"""

from __future__ import annotations

import asyncio

from acquisition.errors import ControllerConnectionError, ControllerTimeoutError, ProtocolError


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
        """``set COMMAND`` on an enabled session; a NAK is a :class:`ProtocolError`."""
        reply = await self.exchange(f"set {command}")
        if "NAK" in reply.upper() or "ACK" not in reply.upper():
            raise ProtocolError(f"{self.where} refused 'set {command}': {reply!r}")

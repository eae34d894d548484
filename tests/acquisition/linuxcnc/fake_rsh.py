"""A linuxcncrsh of the tests' own, on asyncio: the rules by which LinuxCNC 2.9's
(``commandSet``, ``commandGet`` in src/emc/usr_intf/emcrsh.cc) answers ACK or NAK, with
LinuxCNC's task state held apart from linuxcncrsh's copy of it. Every ``get`` refreshes the
copy, no ``set`` does before it is checked; a ``set`` past ``MACHINE`` is refused unless the
copy is ON, one past ``COMM_PROT`` unless the session is the one the last ``set enable``
named. A real LinuxCNC cannot be made to hold a stale copy on demand; this peer can.
"""

from __future__ import annotations

import asyncio
import itertools
from typing import Self

#: ``set`` keys any linked session may send (before ``INI_FILE`` in linuxcncrsh's table).
OPEN_TO_ALL = {"ECHO", "VERBOSE", "ENABLE", "CONFIG", "COMM_MODE", "COMM_PROT"}
#: ``set`` keys that need an enabled session but not the machine on (up to ``MACHINE``).
MACHINE_STATE_FREE = OPEN_TO_ALL | {"INI_FILE", "PLAT", "INI", "DEBUG", "SET_WAIT", "WAIT", "SET_TIMEOUT",
                                    "UPDATE", "ERROR", "OPERATOR_DISPLAY", "OPERATOR_TEXT", "TIME", "ESTOP",
                                    "MACHINE"}


class FakeLinuxcncrsh:
    """``task_state``: LinuxCNC's (``ESTOP``, ``ESTOP_RESET``, ``OFF``, ``ON``);
    ``copied_state``: linuxcncrsh's copy of it until the next ``get``. ``refuse``: ``set`` keys
    whose command LinuxCNC itself refuses. ``log``: (session, line, reply or None) as
    received; ``applied``: the ``set`` commands acknowledged, in order."""

    def __init__(self, *, task_state: str = "ON", copied_state: str | None = None, refuse=(),
                 connect_pw: str = "EMC", enable_pw: str = "EMCTOO"):
        self.task_state = task_state
        self.copied_state = copied_state or task_state
        self.refuse = {k.upper() for k in refuse}
        self.connect_pw, self.enable_pw = connect_pw, enable_pw
        self.enabled_session: int | None = None
        self.log: list[tuple[int, str, str | None]] = []
        self.applied: list[str] = []
        self._ids = itertools.count(1)
        self._server: asyncio.Server | None = None
        self.port = 0

    async def __aenter__(self) -> Self:
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc) -> None:
        self._server.close()
        await self._server.wait_closed()

    def lines_of(self, session: int) -> list[tuple[str, str | None]]:
        return [(line, reply) for s, line, reply in self.log if s == session]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = next(self._ids)
        linked, echo, verbose = False, True, False
        try:
            while raw := await reader.readline():
                line = raw.decode().strip("\r\n ")
                if not line:
                    continue
                if echo and linked:
                    writer.write(raw)
                words = line.split()
                verb = words[0].upper()
                reply: str | None
                if verb == "HELLO":
                    linked = len(words) >= 2 and words[1] == self.connect_pw
                    reply = "HELLO ACK EMCNETSVR 1.1" if linked else "HELLO NAK"
                elif verb == "GET":
                    self.copied_state = self.task_state
                    reply = self._get(words[1].upper() if len(words) > 1 else "", session)
                elif verb == "SET" and linked and len(words) > 1:
                    key = words[1].upper()
                    ok = self._set(key, words[2:], session)
                    if key == "ECHO" and ok:
                        echo = words[2].upper() != "OFF"
                    if key == "VERBOSE" and ok:
                        verbose = words[2].upper() == "ON"
                    reply = f"SET {key} ACK" if ok and verbose else None if ok else f"SET {key} NAK"
                else:
                    reply = "SET NAK"
                self.log.append((session, line, reply))
                if reply is not None:
                    writer.write(reply.encode() + b"\r\n")
                await writer.drain()
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    def _get(self, key: str, session: int) -> str:
        state = self.copied_state
        values = {"ENABLE": "ON" if self.enabled_session == session else "OFF",
                  "MACHINE": "ON" if state == "ON" else "OFF",
                  "ESTOP": "ON" if state == "ESTOP" else "OFF"}
        return f"{key} {values[key]}" if key in values else f"GET {key} NAK"

    def _set(self, key: str, args: list[str], session: int) -> bool:
        if key not in OPEN_TO_ALL and self.enabled_session != session:
            return False
        if key not in MACHINE_STATE_FREE and self.copied_state != "ON":
            return False
        if key == "ENABLE":
            if args and args[0] == self.enable_pw:
                self.enabled_session = session
            elif args and args[0].upper() == "OFF":
                self.enabled_session = None
            else:
                return False
        elif key in self.refuse:
            return False
        if key not in OPEN_TO_ALL:
            self.applied.append(" ".join([key.lower(), *args]))
        return True

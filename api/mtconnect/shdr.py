"""An SHDR adapter port, so a site's own MTConnect agent (cppagent) can ingest mebm as
one more adapter (``[mtconnect] shdr_port``, 7878 by convention; off unless set).

The agent connects over TCP; on connection it gets the current value of every DataItem,
then each new observation as it enters the buffer, one per line:
``<timestamp>|<DataItem id>|<value>`` (``UNAVAILABLE`` when there is none), and for the
condition ``<timestamp>|<id>|<level>|<native code>|<native severity>|<qualifier>|<message>``.
Condition lines: ``normal||||`` (clears the condition), ``warning|BACKLASH|WARNING|HIGH|...``
and ``fault|BACKLASH|ALARM|HIGH|...`` (one native code, so a warning turning into a fault
is the same activation), ``unavailable||||``. ``* PING`` is answered ``* PONG <ms>``. The
DataItem ids are those of ``/mtconnect/probe``: that document is the agent's device file.
"""

from __future__ import annotations

import logging
import socket
import threading

from api.mtconnect.buffer import Observation, ObservationBuffer
from api.mtconnect.model import iso

log = logging.getLogger("mebm.mtconnect")
HEARTBEAT_MS = 10000
NATIVE_CODE = "BACKLASH"


def _field(text: str) -> str:
    return text.replace("|", "/").replace("\r", " ").replace("\n", " ")


def shdr_line(o: Observation) -> str:
    v, di = o.v, o.v.data_item
    ts = iso(v.timestamp)
    if di.category == "CONDITION":
        level = (v.level or "Unavailable").lower()
        if level in ("warning", "fault"):
            return f"{ts}|{di.id}|{level}|{NATIVE_CODE}|{v.native_code}|HIGH|{_field(v.value or '')}"
        return f"{ts}|{di.id}|{level}||||"
    value = "UNAVAILABLE" if v.value is None else (v.value if isinstance(v.value, str) else repr(float(v.value)))
    return f"{ts}|{di.id}|{_field(value)}"


class _Connection:
    def __init__(self, sock: socket.socket, buffer: ObservationBuffer, closing: threading.Event):
        self.sock = sock
        self.buffer = buffer
        self.closing = closing
        self._send_lock = threading.Lock()
        self._gone = threading.Event()

    def send(self, lines: list[str]) -> None:
        if lines:
            with self._send_lock:
                self.sock.sendall(("\n".join(lines) + "\n").encode())

    def snapshot(self) -> int:
        w = self.buffer.current()
        self.send([shdr_line(o) for o in w.observations])
        return w.next

    def serve(self) -> None:
        reader = threading.Thread(target=self._read, daemon=True, name="mebm-shdr-read")
        reader.start()
        try:
            pos = self.snapshot()
            while not (self.closing.is_set() or self._gone.is_set()):
                if not self.buffer.wait(pos, 0.5):
                    continue
                first, _, _ = self.buffer.bounds()
                if pos < first:  # this client fell behind the ring: start again from the current values
                    pos = self.snapshot()
                    continue
                w = self.buffer.sample(pos, self.buffer.size)
                self.send([shdr_line(o) for o in w.observations])
                pos = w.next
        except OSError as exc:
            log.info("SHDR client left: %s", exc)
        finally:
            self._gone.set()
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.sock.close()

    def _read(self) -> None:
        buf = b""
        try:
            while not self.closing.is_set():
                chunk = self.sock.recv(4096)
                if not chunk:
                    break
                buf += chunk
                *lines, buf = buf.split(b"\n")
                for line in lines:
                    if line.strip().startswith(b"* PING"):
                        self.send([f"* PONG {HEARTBEAT_MS}"])
                buf = buf[-4096:]  # nothing else is expected from the agent
        except OSError:
            pass
        finally:
            self._gone.set()


class ShdrAdapter:
    """Listens on ``host:port`` (0: a free port; ``.port`` says which) and serves every client."""

    def __init__(self, buffer: ObservationBuffer, host: str, port: int):
        self.buffer = buffer
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(16)
        self.sock.settimeout(0.5)
        self.host, self.port = host, self.sock.getsockname()[1]
        self.clients = 0
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True, name="mebm-shdr")
        self._thread.start()
        log.info("SHDR adapter listens on %s:%s", host, self.port)

    def _accept(self) -> None:
        while not self._closing.is_set():
            try:
                conn, addr = self.sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.settimeout(None)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.clients += 1
            log.info("SHDR client %s:%s connected", *addr[:2])
            threading.Thread(target=_Connection(conn, self.buffer, self._closing).serve, daemon=True,
                             name="mebm-shdr-client").start()  # fmt: skip

    def close(self) -> None:
        self._closing.set()
        self.sock.close()
        self._thread.join(5)

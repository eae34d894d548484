"""A TCP port on loopback that nothing listens on when asked: for a server a test starts
later or in another process, or for a refused connection (a server the test starts in its
own process binds port 0 and reports its port)."""

from __future__ import annotations

import socket


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

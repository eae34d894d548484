"""The request head is bounded at the server ([limits] max_header_bytes, max_headers):
beyond, 431 and the connection closed, and the server goes on answering. A real uvicorn
server configured as ``mebm serve`` configures it, and raw sockets."""

from __future__ import annotations

import socket
import threading

import httpx
import pytest

from tests.api.rest.conftest import ServedApp


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    s = ServedApp(tmp_path_factory.mktemp("heads"))
    yield s
    s.close()


def _read_until_closed(sock: socket.socket) -> bytes:
    """What the server sent until it closed the connection (or the socket's timeout ended the wait)."""
    got = b""
    try:
        while chunk := sock.recv(65536):
            got += chunk
    except OSError:
        pass
    return got


def _exchange(url: str, head: bytes, body: bytes = b"") -> bytes:
    """Sends ``head`` and ``body`` (from a thread: the server may stop reading) and
    returns what the server answered before it closed the connection."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        def send():
            try:
                sock.sendall(head + body)
            except OSError:
                pass  # the server closed: what it answered is read below

        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        got = _read_until_closed(sock)
        sender.join(30)
    return got


def _get(path: str, fields: list[bytes]) -> bytes:
    return b"GET " + path.encode() + b" HTTP/1.1\r\nHost: x\r\n" + b"".join(f + b"\r\n" for f in fields) \
        + b"Connection: close\r\n\r\n"


def test_a_one_megabyte_header_is_refused_with_431_and_the_server_goes_on(served):
    before = httpx.get(f"{served.url}/healthz", timeout=30).status_code
    got = _exchange(served.url, _get("/healthz", [b"X-Big: " + b"a" * 1_000_000]))
    assert got.startswith(b"HTTP/1.1 431 "), got[:200]
    assert b"max_header_bytes" not in got and b"header fields too large" in got
    assert httpx.get(f"{served.url}/healthz", timeout=30).status_code == before


def test_too_many_header_fields_are_refused_with_431(served):
    got = _exchange(served.url, _get("/healthz", [b"X-F%d: v" % i for i in range(150)]))
    assert got.startswith(b"HTTP/1.1 431 ") and b"more than 100 header fields" in got


def test_heads_within_the_bounds_are_served(served):
    fields = [b"X-F%d: " % i + b"v" * 500 for i in range(90)]  # 45 kB in 90 fields
    got = _exchange(served.url, _get("/healthz", fields))
    assert got.startswith(b"HTTP/1.1 ") and not got.startswith(b"HTTP/1.1 431 ")


def test_a_large_body_is_not_counted_as_head(served):
    body = b"x" * 600_000  # read with its small head in large chunks
    head = (b"POST /api/v1/machines HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\nConnection: close\r\n\r\n" % len(body))
    got = _exchange(served.url, head, body)
    assert got.startswith(b"HTTP/1.1 422 ") and b"not JSON" in got, got[:200]  # the app read the whole body


def test_the_bound_holds_for_each_request_of_a_kept_alive_connection(served):
    host, port = served.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        first = sock.recv(65536)
        assert first.startswith(b"HTTP/1.1 ") and not first.startswith(b"HTTP/1.1 431 ")
        sock.sendall(_get("/healthz", [b"X-Big: " + b"a" * 200_000]))
        second = b""
        while chunk := sock.recv(65536):
            second += chunk
    assert b"HTTP/1.1 431 " in second and second.count(b"HTTP/1.1 ") == 1  # (after any rest of the first)


@pytest.fixture(scope="module")
def impatient(tmp_path_factory):
    from api.service.config.settings import LimitSettings

    s = ServedApp(tmp_path_factory.mktemp("slow-heads"), limits=LimitSettings(header_timeout_s=0.5))
    yield s
    s.close()


def _answer_to_a_stalled_head(url: str, head: bytes) -> bytes:
    """Sends ``head`` (not a whole head, or nothing) and stops; what the server answered
    before it closed the connection (the socket's own timeout, generous, ends a wait for a
    server that never answers)."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        sock.sendall(head)
        got = _read_until_closed(sock)
    return got


@pytest.mark.parametrize("head", [b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: a", b""])
def test_a_head_not_complete_in_time_is_answered_408_and_closed(impatient, head):
    got = _answer_to_a_stalled_head(impatient.url, head)
    assert got.startswith(b"HTTP/1.1 408 ") and b"not complete within 0.5 s" in got, got[:200]
    assert httpx.get(f"{impatient.url}/healthz", timeout=30).status_code in (200, 503)  # the server goes on


def test_a_whole_head_is_served_not_timed_out(impatient):
    host, port = impatient.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        first = sock.recv(65536)
        assert first.startswith(b"HTTP/1.1 ") and not first.startswith(b"HTTP/1.1 408 "), first[:200]

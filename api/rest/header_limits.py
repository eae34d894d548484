"""Bounds on a request's head (request line and header fields), at the server: past
``max_header_bytes`` in all or ``max_headers`` fields, the answer is 431 Request Header
Fields Too Large and the connection is closed, before the rest of the head is read.

Hand-written because uvicorn cannot do it: its httptools protocol (the one
``uvicorn[standard]`` runs) has no bound on the head at all, so a 100 MB header is read
and parsed whole before the app sees anything; httptools buffers a header's value until it
ends, so the bound must be kept on the bytes received, not in the parser's callbacks
alone. Its h11 protocol bounds the head (``h11_max_incomplete_event_size``) but answers
400, not 431. ASGI middleware cannot help either: it runs after the head is read.

The protocol counts the bytes received while a head is open (checked after each chunk,
so at most one read, 256 kB, more is buffered) and, in the parser's callbacks, the exact
size and number of fields. After a 431 it stops parsing and discards what the client goes
on sending for a short while (a lingering close, so the client can read the 431 before the
connection ends), then closes.

A head must also arrive within ``header_timeout_s`` of its first byte (or of the
connection's opening): a client that sends its head a byte at a time, or opens a
connection and sends nothing (a slowloris), is answered 408 Request Timeout and the
connection closed, so it holds no connection for longer. uvicorn has no such bound: its
``timeout_keep_alive`` runs only between requests of a kept-alive connection.
"""

from __future__ import annotations

import logging

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("mebm.api")

LINGER_BYTES = 4 * 1024 * 1024  # discarded after a 431 at most, then the connection is closed...
LINGER_S = 5.0  # ...or after this long


class _HeadTooLarge(Exception):
    pass


class BoundedHeadProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a bounded request head; make one with
    :func:`bounded_head_protocol`."""

    max_header_bytes = 65536
    max_headers = 100
    header_timeout_s = 10.0

    def connection_made(self, transport) -> None:
        self._head_timer = None
        self._head_open = True  # between a request's first byte and its end of head
        self._head_bytes = 0  # received while the head is open
        self._field_bytes = 0  # the request line and fields, as parsed
        self._fields = 0
        self._head_restarted = False
        self._refusal: str | None = None
        self._discarded = 0
        self._linger = None
        super().connection_made(transport)
        self._arm_head_timer()  # a connection that sends nothing holds it no longer than a slow head

    def data_received(self, data: bytes) -> None:
        if self._refusal is not None:  # lingering after a 431
            self._discarded += len(data)
            if self._discarded > LINGER_BYTES:
                self.transport.close()
            return
        self._head_restarted = False
        if self._head_open and self._head_timer is None:
            self._arm_head_timer()
        super().data_received(data)
        if self._refusal is None and self._head_open and not self._head_restarted:
            self._head_bytes += len(data)
            if self._head_bytes > self.max_header_bytes:
                self._refuse(f"more than {self.max_header_bytes} bytes of header fields")

    def connection_lost(self, exc) -> None:
        if self._linger is not None:
            self._linger.cancel()
        self._cancel_head_timer()
        super().connection_lost(exc)

    # parser callbacks
    def on_message_begin(self) -> None:
        self._field_bytes, self._fields = 0, 0
        super().on_message_begin()

    def on_url(self, url: bytes) -> None:
        self._count(len(url), 0)
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self._count(len(name) + len(value) + 4, 1)  # "name: value\r\n"
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self._head_open = False
        self._cancel_head_timer()
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._head_open, self._head_bytes = True, 0
        self._head_restarted = True  # this chunk held the end of a request: not all of it is the next head
        super().on_message_complete()

    def _count(self, n_bytes: int, n_fields: int) -> None:
        self._field_bytes += n_bytes
        self._fields += n_fields
        if self._field_bytes > self.max_header_bytes:
            self._refusal = f"more than {self.max_header_bytes} bytes of header fields"
        elif self._fields > self.max_headers:
            self._refusal = f"more than {self.max_headers} header fields"
        else:
            return
        raise _HeadTooLarge(self._refusal)  # the parser stops; uvicorn calls send_400_response

    def send_400_response(self, msg: str) -> None:
        if self._refusal is None:
            return super().send_400_response(msg)
        reason, self._refusal = self._refusal, None
        self._refuse(reason)

    def _arm_head_timer(self) -> None:
        self._head_timer = self.loop.call_later(self.header_timeout_s, self._head_timed_out)

    def _cancel_head_timer(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_timed_out(self) -> None:
        self._head_timer = None
        if not self._head_open or self._refusal is not None or self.transport.is_closing():
            return
        if self.cycle is not None and not self.cycle.response_complete:
            self._arm_head_timer()  # a response still on its way: the next head waits for it
            return
        client = "%s:%d" % self.client if self.client else "unknown"
        log.info("request head from %s not complete within %g s: 408, connection closed ([limits] "
                 "header_timeout_s)", client, self.header_timeout_s)
        body = f'{{"detail": "request head not complete within {self.header_timeout_s:g} s"}}'.encode()
        self.transport.write(b"HTTP/1.1 408 Request Timeout\r\n"
                             b"content-type: application/json\r\n"
                             b"content-length: " + str(len(body)).encode() + b"\r\n"
                             b"connection: close\r\n\r\n" + body)
        self.transport.close()

    def _refuse(self, reason: str) -> None:
        self._refusal = reason
        self._cancel_head_timer()
        client = "%s:%d" % self.client if self.client else "unknown"
        log.warning("request head from %s refused with 431: %s ([limits] max_header_bytes, max_headers)",
                    client, reason)
        if self.cycle is not None and not self.cycle.response_complete:
            self.transport.close()  # a response is on its way: a 431 would be mixed into it
            return
        body = f'{{"detail": "request header fields too large: {reason}"}}'.encode()
        self.transport.write(b"HTTP/1.1 431 Request Header Fields Too Large\r\n"
                             b"content-type: application/json\r\n"
                             b"content-length: " + str(len(body)).encode() + b"\r\n"
                             b"connection: close\r\n\r\n" + body)
        if self.transport.can_write_eof():
            self.transport.write_eof()
        self._linger = self.loop.call_later(LINGER_S, self.transport.close)


def bounded_head_protocol(max_header_bytes: int, max_headers: int,
                          header_timeout_s: float = BoundedHeadProtocol.header_timeout_s) -> type[BoundedHeadProtocol]:
    """A protocol class for ``uvicorn.Config(http=...)`` with these bounds."""
    return type("BoundedHeadProtocol", (BoundedHeadProtocol,),
                {"max_header_bytes": max_header_bytes, "max_headers": max_headers,
                 "header_timeout_s": header_timeout_s})

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

    def connection_made(self, transport) -> None:
        self._head_open = True  # between a request's first byte and its end of head
        self._head_bytes = 0  # received while the head is open
        self._field_bytes = 0  # the request line and fields, as parsed
        self._fields = 0
        self._head_restarted = False
        self._refusal: str | None = None
        self._discarded = 0
        self._linger = None
        super().connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self._refusal is not None:  # lingering after a 431
            self._discarded += len(data)
            if self._discarded > LINGER_BYTES:
                self.transport.close()
            return
        self._head_restarted = False
        super().data_received(data)
        if self._refusal is None and self._head_open and not self._head_restarted:
            self._head_bytes += len(data)
            if self._head_bytes > self.max_header_bytes:
                self._refuse(f"more than {self.max_header_bytes} bytes of header fields")

    def connection_lost(self, exc) -> None:
        if self._linger is not None:
            self._linger.cancel()
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

    def _refuse(self, reason: str) -> None:
        self._refusal = reason
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


def bounded_head_protocol(max_header_bytes: int, max_headers: int) -> type[BoundedHeadProtocol]:
    """A protocol class for ``uvicorn.Config(http=...)`` with these bounds."""
    return type("BoundedHeadProtocol", (BoundedHeadProtocol,),
                {"max_header_bytes": max_header_bytes, "max_headers": max_headers})

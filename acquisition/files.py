"""Files a user names (a register or trace-import profile, a trace, an EDS, the service's
configuration) are read only as regular files of bounded size.

A FIFO, a device such as ``/dev/zero`` or a terminal is refused at once, not read until
it ends (it never does, or it fills the memory); a file larger than the reader's bound
is refused before a byte is read. The file is opened without blocking (a FIFO without a
writer would hold the open) and checked on the opened descriptor, so what is checked is
what is read.
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path
from typing import IO

from core.errors import InputError

KIB = 1024
MIB = 1024 * KIB


class FileRefused(InputError):
    """A named file is not a regular file, is larger than its bound, or cannot be opened."""


def open_regular(path: str | os.PathLike, max_bytes: int, what: str, *, encoding: str | None = None,
                 newline: str | None = None) -> IO:
    """``path`` opened for reading (binary, or text in ``encoding``) once it is known to be a
    regular file of at most ``max_bytes``; else :class:`FileRefused` naming ``what`` and the
    path. A text ``encoding`` Python does not know raises :class:`LookupError`, as ``open``."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise FileRefused(f"{what} {p}: cannot be read ({exc.strerror or exc})") from exc
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileRefused(f"{what} {p}: not a regular file (a device, a FIFO or a folder is not read)")
        if info.st_size > max_bytes:
            raise FileRefused(f"{what} {p}: {info.st_size} bytes, larger than the {max_bytes} bytes a {what} may "
                              "have")
        os.set_blocking(fd, True)
        raw = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    if encoding is None:
        return raw
    try:
        return io.TextIOWrapper(raw, encoding=encoding, newline=newline)
    except BaseException:
        raw.close()
        raise


def read_regular(path: str | os.PathLike, max_bytes: int, what: str) -> bytes:
    """The bytes of the regular file ``path`` of at most ``max_bytes`` (see :func:`open_regular`);
    never more than ``max_bytes`` are read, should the file grow meanwhile."""
    with open_regular(path, max_bytes, what) as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise FileRefused(f"{what} {Path(path)}: larger than the {max_bytes} bytes a {what} may have")
    return data

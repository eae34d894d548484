"""Secrets the service hands to its operator (the demo admin key, the dashboard's one-time
sign-in link) go to files of the data folder, never to stdout: a service's stdout ends in
a journal that many can read and that is kept for months.

A secret file is created mode 600 from its first byte (``O_CREAT | O_EXCL`` with mode
0o600 under a temporary name, then renamed over the old one): it is never readable by
another user, not even for an instant, a file or symbolic link planted under its name is
replaced rather than written through, and a reader never sees half a secret."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

DEMO_KEYS_FILE = "demo-keys.json"  # the demo read and operate keys (JSON)
ADMIN_KEY_FILE = "admin-key"  # the demo admin key, created at first start
SIGN_IN_LINK_FILE = "sign-in-link"  # the dashboard sign-in link of the last start


def write_secret_file(path: Path, text: str) -> Path:
    """Write ``text`` to ``path``, mode 600, atomically. Raises ``OSError`` (a full disk:
    ``ENOSPC``) and leaves no partial file then."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    try:
        try:
            data = text.encode("utf-8")
            while data:
                data = data[os.write(fd, data):]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path

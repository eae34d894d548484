"""Secrets the service hands to its operator (the demo admin key, the dashboard's one-time
sign-in link) go to files of the data folder, never to stdout: a service's stdout ends in
a journal that many can read and that is kept for months.

A secret file is created mode 600 from its first byte (``O_CREAT | O_EXCL`` with mode
0o600 under a temporary name, then renamed over the old one): it is never readable by
another user, not even for an instant, a file or symbolic link planted under its name is
replaced rather than written through, and a reader never sees half a secret.

Each secret file belongs to one database: the keys in it exist only there. The plain
names (``demo-keys.json``, ``admin-key``, ``sign-in-link``, ``keys/<id>.key``) belong to
the first database that wrote key files in the data folder; ``key-files.database`` (mode
600, written once) names it. Any other database's files carry its identity in the name:
``demo-keys.<tag>.json``, ``admin-key.<tag>``, ``sign-in-link.<tag>``, ``keys/<id>.<tag>.key``
(:func:`secret_path`; ``<tag>``: the first 12 hex digits of the SHA-256 of
:func:`database_identity`, the URL without its password). ``demo-keys*.json`` also names its
database in the field ``database``. So a data folder used with another database never
overwrites the key files of the first: an operator who switches ``database_url`` keeps the
admin key of the database before, and switching back finds its files again."""

from __future__ import annotations

import hashlib
import os
import secrets
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

DEMO_KEYS_FILE = "demo-keys.json"  # the demo read and operate keys (JSON)
ADMIN_KEY_FILE = "admin-key"  # the demo admin key, created at first start
SIGN_IN_LINK_FILE = "sign-in-link"  # the dashboard sign-in link of the last start
OWNER_FILE = "key-files.database"  # the database the plain-named key files belong to


def database_identity(data_dir: Path, database_url: str | None) -> str:
    """What names a database for its key files: the URL without password, query or
    fragment, an SQLite file's path made absolute; the default database is the SQLite
    file ``mebm.sqlite3`` of ``data_dir``."""
    if not database_url:
        return f"sqlite:///{(Path(data_dir) / 'mebm.sqlite3').resolve()}"
    try:
        parts = urlsplit(database_url)
    except ValueError:
        return database_url
    if parts.scheme.startswith("sqlite"):
        db = database_url.split(":///", 1)[1] if ":///" in database_url else ""
        db = db.split("?", 1)[0]
        return f"sqlite:///{Path(db).resolve()}" if db and db != ":memory:" else "sqlite://"
    netloc = parts.netloc.rsplit("@", 1)
    host = netloc[-1]
    user = netloc[0].split(":", 1)[0] + "@" if len(netloc) == 2 else ""
    return urlunsplit((parts.scheme.split("+", 1)[0], user + host, parts.path, "", ""))


def secret_path(data_dir: Path, database_url: str | None, name: str, *, claim: bool = False) -> Path:
    """The path of secret file ``name`` (one of the ``*_FILE`` names, or ``<id>.key``) for
    this database: the plain name if the data folder's plain names are this database's (or
    nobody's yet: ``claim`` then makes them this database's), the database's tag in the
    name otherwise."""
    data_dir = Path(data_dir)
    identity = database_identity(data_dir, database_url)
    owner = _owner(data_dir)
    if owner is None and claim:
        owner = _claim(data_dir, identity)
    if owner is None or owner == identity:
        return data_dir / name
    tag = hashlib.sha256(identity.encode("utf-8")).hexdigest()[:12]
    stem, dot, ext = name.partition(".")
    return data_dir / (f"{stem}.{tag}.{ext}" if dot else f"{name}.{tag}")


def _owner(data_dir: Path) -> str | None:
    try:
        return (data_dir / OWNER_FILE).read_text(encoding="utf-8").strip() or None
    except (OSError, UnicodeDecodeError):
        return None


def _claim(data_dir: Path, identity: str) -> str | None:
    """Record ``identity`` as the plain names' database unless one is recorded already
    (created exclusively: of two processes starting at once one wins); returns the owner."""
    path = data_dir / OWNER_FILE
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    except FileExistsError:
        return _owner(data_dir) or identity
    except OSError:  # no data folder yet, a full disk: nothing recorded, the plain names
        return None
    try:
        os.write(fd, (identity + "\n").encode("utf-8"))
        os.fsync(fd)
    finally:
        os.close(fd)
    return identity


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


def move_aside(path: Path) -> Path:
    """Rename ``path`` to ``<name>.aside-<UTC time>`` (never over an existing file): a key
    file that is not this database's is kept, not overwritten. Returns the new path."""
    from datetime import datetime, timezone

    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S")
    for i in range(1000):
        target = path.with_name(f"{path.name}.aside-{stamp}" + (f"-{i}" if i else ""))
        if not target.exists():
            os.rename(path, target)
            return target
    raise FileExistsError(f"no free name to move {path} aside")

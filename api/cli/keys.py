"""``mebm keys create|list|revoke``: access keys of the REST API (stored hashed)."""

from __future__ import annotations

import argparse
from pathlib import Path

from api.cli.output import print_json, print_table
from api.service.config.loading import load_settings
from api.service.secret_files import secret_path, write_secret_file
from core.errors import InputError
from storage.db import config_repo, make_engine, make_session_factory, session_scope, upgrade


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("keys", help="create, list and revoke API keys")
    ksub = p.add_subparsers(dest="keys_command", metavar="ACTION")
    ksub.required = True

    def common(q):
        q.add_argument("--config", type=Path, help="TOML configuration file (for the database URL)")
        q.add_argument("--json", action="store_true", help="print JSON")

    c = ksub.add_parser("create", help="create a key; its secret goes to a mode-600 file of the data directory",
                        description="Create a key. Its secret is written to <data_dir>/keys/<id>.key (mode 600) and "
                                    "the file named; --show-keys prints the secret instead (stdout may be logged).")
    c.add_argument("--role", required=True, choices=("read", "operate", "admin"),
                   help="read: an MES; operate: trigger cycles, acknowledge alerts; admin: configure")
    c.add_argument("--name", help="a name for the key (default: <role>-<n>)")
    c.add_argument("--show-keys", action="store_true", help="print the secret (once) instead of writing it to a file")
    common(c)
    c.set_defaults(func=_create)
    ls = ksub.add_parser("list", help="list keys (never their secrets)")
    common(ls)
    ls.set_defaults(func=_list)
    rv = ksub.add_parser("revoke", help="revoke a key by id or name")
    rv.add_argument("key", help="key id or name")
    common(rv)
    rv.set_defaults(func=_revoke)


def _factory(a, settings=None):
    settings = settings or load_settings(a.config)
    engine = make_engine(settings.db_url)
    upgrade(engine)
    return make_session_factory(engine)


def key_file(data_dir: Path, key_id: int, database_url: str | None = None) -> Path:
    """Where ``mebm keys create`` writes the secret of key ``key_id``: ``keys/<id>.key`` for
    the default database, ``keys/<id>.<tag>.key`` for any other (ids repeat across
    databases; :func:`api.service.secret_files.secret_path`)."""
    return Path(data_dir) / "keys" / secret_path(data_dir, database_url, f"{key_id}.key", claim=True).name


def _create(a) -> int:
    settings = load_settings(a.config)
    with session_scope(_factory(a, settings)) as s:
        name = a.name
        if not name:
            n = sum(1 for k in config_repo.list_keys(s) if k.role == a.role) + 1
            name = f"{a.role}-{n}"
            while config_repo.find_key(s, name) is not None:
                n += 1
                name = f"{a.role}-{n}"
        rec, secret = config_repo.create_key(s, name, a.role)
        path = None
        if not a.show_keys:  # written before the commit: a key whose secret is nowhere is never created
            path = key_file(settings.data_dir, rec.id, settings.database_url)
            try:
                path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
                write_secret_file(path, secret + "\n")
            except OSError as exc:
                raise InputError(f"cannot write the key to {path}: {exc.strerror or exc} (no key created; "
                                 "--show-keys prints it instead)") from exc
    if a.json:
        print_json({"id": rec.id, "name": rec.name, "role": rec.role,
                    **({"key": secret} if a.show_keys else {"key_file": str(path)})})
    elif a.show_keys:
        print(f"created key {rec.name!r} (id {rec.id}, role {rec.role}); it is shown only now:")
        print(secret)
    else:
        print(f"created key {rec.name!r} (id {rec.id}, role {rec.role}); its secret is in {path} (mode 600): "
              "hand it over and delete the file")
    return 0


def _list(a) -> int:
    with session_scope(_factory(a)) as s:
        keys = config_repo.list_keys(s)
    rows = [{"id": k.id, "name": k.name, "role": k.role, "prefix": k.key_prefix,
             "created_at": k.created_at.isoformat(), "revoked_at": k.revoked_at.isoformat() if k.revoked_at else None}
            for k in keys]
    if a.json:
        print_json(rows)
    else:
        print_table(["id", "name", "role", "prefix", "created", "revoked"],
                    [[r["id"], r["name"], r["role"], r["prefix"] + "…", r["created_at"][:19],
                      (r["revoked_at"] or "")[:19]] for r in rows])
    return 0


def _revoke(a) -> int:
    with session_scope(_factory(a)) as s:
        rec = config_repo.find_key(s, a.key)
        if rec is None and a.key.isdigit():
            rec = next((k for k in config_repo.list_keys(s) if k.id == int(a.key)), None)
        if rec is None:
            raise InputError(f"no key with id or name {a.key!r}")
        rec = config_repo.revoke_key(s, rec.id)
    if a.json:
        print_json({"id": rec.id, "name": rec.name, "revoked_at": rec.revoked_at.isoformat()})
    else:
        print(f"revoked key {rec.name!r} (id {rec.id})")
    return 0

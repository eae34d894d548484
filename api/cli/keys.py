"""``mebm keys create|list|revoke``: access keys of the REST API (stored hashed)."""

from __future__ import annotations

import argparse
from pathlib import Path

from api.cli.output import print_json, print_table
from api.service.config import load_settings
from core.errors import InputError
from storage.db import config_repo, make_engine, make_session_factory, session_scope, upgrade


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("keys", help="create, list and revoke API keys")
    ksub = p.add_subparsers(dest="keys_command", metavar="ACTION")
    ksub.required = True

    def common(q):
        q.add_argument("--config", type=Path, help="TOML configuration file (for the database URL)")
        q.add_argument("--json", action="store_true", help="print JSON")

    c = ksub.add_parser("create", help="create a key; the secret is printed once")
    c.add_argument("--role", required=True, choices=("read", "operate", "admin"),
                   help="read: an MES; operate: trigger cycles, acknowledge alerts; admin: configure")
    c.add_argument("--name", help="a name for the key (default: <role>-<n>)")
    common(c)
    c.set_defaults(func=_create)
    ls = ksub.add_parser("list", help="list keys (never their secrets)")
    common(ls)
    ls.set_defaults(func=_list)
    rv = ksub.add_parser("revoke", help="revoke a key by id or name")
    rv.add_argument("key", help="key id or name")
    common(rv)
    rv.set_defaults(func=_revoke)


def _factory(a):
    settings = load_settings(a.config)
    engine = make_engine(settings.db_url)
    upgrade(engine)
    return make_session_factory(engine)


def _create(a) -> int:
    with session_scope(_factory(a)) as s:
        name = a.name
        if not name:
            n = sum(1 for k in config_repo.list_keys(s) if k.role == a.role) + 1
            name = f"{a.role}-{n}"
            while config_repo.find_key(s, name) is not None:
                n += 1
                name = f"{a.role}-{n}"
        rec, secret = config_repo.create_key(s, name, a.role)
    if a.json:
        print_json({"id": rec.id, "name": rec.name, "role": rec.role, "key": secret})
    else:
        print(f"created key {rec.name!r} (id {rec.id}, role {rec.role}); it is shown only now:")
        print(secret)
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

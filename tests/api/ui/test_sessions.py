"""Dashboard sessions live in the database: they survive a restart, are shared by
several service processes on one database, and end when their key is revoked."""

from __future__ import annotations

import hashlib
import re

from fastapi.testclient import TestClient
from sqlalchemy import select

from api.rest import create_app
from storage.db import config_repo, session_scope
from storage.db.models import UiSession
from tests.api.rest.conftest import FakeRunner, make_settings


def app_on(url: str, tmp):
    return create_app(make_settings(url, tmp, scheduler_enabled=False), runner=FakeRunner())


def with_session(client: TestClient, token: str) -> TestClient:
    client.cookies.set("mebm_session", token)
    return client


def csrf_of(html: str) -> str:
    return re.search(r'name="csrf" value="([^"]+)"', html).group(1)


def test_sessions_survive_a_restart_and_are_shared_by_processes(tmp_path):
    url = f"sqlite:///{tmp_path}/mebm.sqlite3"
    a, b = app_on(url, tmp_path / "a"), app_on(url, tmp_path / "b")
    with TestClient(a) as ca, TestClient(b) as cb:
        with session_scope(a.state.service.factory) as s:
            key, secret = config_repo.create_key(s, "shop-pc", "operate")
        link = f"/ui/sign-in/{a.state.ui.sessions.issue_link(secret)}"  # printed by one process...
        assert cb.get(link).status_code == 200  # ...opened on another; the GET spends nothing
        page = cb.get(link)
        assert page.status_code == 200 and "Sign in as shop-pc" in page.text
        signed = cb.post(link, data={"csrf": csrf_of(page.text)})
        assert signed.status_code == 200
        token = signed.cookies["mebm_session"]
        assert ca.post(link, data={"csrf": csrf_of(ca.get("/ui/sign-in").text)}).status_code == 403  # spent
        # the session opened on b is good on a, CSRF token included
        fleet = with_session(ca, token).get("/ui/")
        assert fleet.status_code == 200 and "shop-pc · operate" in fleet.text
        assert csrf_of(fleet.text) == csrf_of(cb.get("/ui/").text)
        with session_scope(a.state.service.factory) as s:
            stored = s.scalars(select(UiSession.token_sha256)).all()
        assert hashlib.sha256(token.encode()).hexdigest() in stored and token not in stored  # only the hash
    # a restart: a new process on the same database still knows the session
    c = app_on(url, tmp_path / "c")
    with TestClient(c) as cc:
        assert "shop-pc · operate" in with_session(cc, token).get("/ui/").text
        with session_scope(c.state.service.factory) as s:
            config_repo.revoke_key(s, key.id)  # as `mebm keys revoke` does, from outside the service
        gone = cc.get("/ui/", follow_redirects=False)
        assert gone.status_code == 303 and gone.headers["location"] == "/ui/sign-in"
        with session_scope(c.state.service.factory) as s:
            assert s.scalar(select(UiSession.revoked_at).where(UiSession.key_id == key.id)) is not None


def test_signing_out_ends_the_session_everywhere(tmp_path):
    url = f"sqlite:///{tmp_path}/mebm.sqlite3"
    a, b = app_on(url, tmp_path / "a"), app_on(url, tmp_path / "b")
    with TestClient(a) as ca, TestClient(b) as cb:
        with session_scope(a.state.service.factory) as s:
            _, secret = config_repo.create_key(s, "tablet", "read")
        form = ca.get("/ui/sign-in")
        signed = ca.post("/ui/sign-in", data={"key": secret, "csrf": csrf_of(form.text)})
        token = signed.cookies["mebm_session"]
        fleet = with_session(cb, token).get("/ui/")
        out = cb.post("/ui/sign-out", data={"csrf": csrf_of(fleet.text)}, follow_redirects=False)
        assert out.status_code == 303
        assert ca.get("/ui/", follow_redirects=False).status_code == 303  # ca holds the cookie since sign-in


def test_an_idle_session_expires(tmp_path):
    from datetime import timedelta

    from storage.db import utcnow

    app = app_on(f"sqlite:///{tmp_path}/mebm.sqlite3", tmp_path)
    with TestClient(app) as c:
        with session_scope(app.state.service.factory) as s:
            _, secret = config_repo.create_key(s, "tablet", "read")
        form = c.get("/ui/sign-in")
        assert c.post("/ui/sign-in", data={"key": secret, "csrf": csrf_of(form.text)}).status_code == 200
        ui = app.state.ui.sessions
        later = utcnow() + timedelta(seconds=ui.idle_s - 60)
        ui.clock = lambda: later
        assert c.get("/ui/", follow_redirects=False).status_code == 200  # used in time: it slides on
        later += timedelta(seconds=ui.idle_s - 60)
        assert c.get("/ui/", follow_redirects=False).status_code == 200
        later += timedelta(seconds=ui.idle_s + 1)  # then left idle past the expiry
        gone = c.get("/ui/", follow_redirects=False)
        assert gone.status_code == 303 and gone.headers["location"] == "/ui/sign-in"


def test_a_valid_key_signs_in_after_many_failed_sign_ins_from_its_address(tmp_path):
    app = app_on(f"sqlite:///{tmp_path}/mebm.sqlite3", tmp_path)
    with TestClient(app) as c:
        with session_scope(app.state.service.factory) as s:
            _, secret = config_repo.create_key(s, "tablet", "read")
        wrong = "wrong-key-000000000000"
        codes = [c.post("/ui/sign-in", data={"key": wrong, "csrf": csrf_of(c.get("/ui/sign-in").text)},
                        follow_redirects=False).status_code for _ in range(25)]
        assert codes[:20] == [303] * 20 and codes[20:] == [429] * 5
        signed = c.post("/ui/sign-in", data={"key": secret, "csrf": csrf_of(c.get("/ui/sign-in").text)})
        assert signed.status_code == 200 and signed.cookies.get("mebm_session")

"""Odd input to the dashboard is answered as the REST API answers it, as a page: an id out
of range is a 422 (never an overflow, a 500), a non-ASCII CSRF token is refused, a task
named like a formula or a mathtext string is drawn and exported as written, and a 429 is
an HTML page with Retry-After."""

from __future__ import annotations

import csv
import io
import re
import threading

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from core.tbe import MachiningTask
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings

CSRF = re.compile(r'name="csrf" value="([^"]+)"')
ODD_TASKS = ('a "quoted" circle', '=HYPERLINK("http://x")', r"$\frac{$")
TOO_BIG = (2**63, 2**31)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ui-odd")
    runner = FakeRunner()
    app = create_app(make_settings(f"sqlite:///{tmp}/m.sqlite3", tmp), runner=runner)
    with TestClient(app) as c:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            keys = {r: config_repo.create_key(s, f"ui-{r}", r)[1] for r in ("read", "operate")}
            axis = config_repo.list_axes(s)[0]
            gain = axis.settings.spec.position_gain_per_s
            config_repo.set_tasks(s, axis.id, [
                MachiningTask(name=n, profile="circle", radius_mm=200.0, feed_mm_min=200.0, tolerance_um=45.0,
                              gain_per_s=gain) for n in ODD_TASKS])
        svc.trigger(axis.id, "test")
        assert svc.scheduler.idle(60)
        yield c, svc, keys, axis.id, runner


def sign_in(c: TestClient, secret: str) -> str:
    c.cookies.clear()
    token = CSRF.search(c.get("/ui/sign-in").text).group(1)
    assert c.post("/ui/sign-in", data={"key": secret, "csrf": token}).status_code == 200
    return CSRF.search(c.get("/ui/").text).group(1)


def test_a_non_ascii_csrf_token_and_cookie_are_refused_not_a_500(env):
    c = env[0]
    c.cookies.clear()
    r = c.post("/ui/sign-in", data={"key": "x", "csrf": "é" * 8}, headers={"Cookie": ("mebm_signin_csrf=" + "é" * 8).encode("utf-8")},
               follow_redirects=False)
    assert r.status_code == 403 and "CSRF" in r.text and r.headers["content-type"].startswith("text/html")
    csrf = sign_in(c, env[2]["operate"])  # and a session's form with a non-ASCII token
    assert csrf.isascii()
    r = c.post(f"/ui/axes/{env[3]}/measure", data={"csrf": "ü" + csrf[1:]}, follow_redirects=False)
    assert r.status_code == 403 and "CSRF" in r.text


@pytest.mark.parametrize("path", ["/ui/axes/{id}", "/ui/axes/{id}/part/verdict.frag", "/ui/axes/{id}/part/cycles.frag",
                                  "/ui/axes/{id}/plots/tbe_vs_backlash.png", "/ui/axes/{id}/history.csv",
                                  "/ui/axes/{id}/gap", "/ui/axes/{id}/gap.frag", "/ui/axes/{id}/gap/residuals/0.png",
                                  "/ui/config/axes/{id}", "/ui/config/machines/{id}/axes/new"])
def test_an_id_out_of_range_is_a_422_page_naming_it(env, path):
    c = env[0]
    sign_in(c, env[2]["read"])
    for big in TOO_BIG:
        url = path.format(id=big)
        r = c.get(url)
        assert r.status_code == 422, (url, r.status_code, r.text[:300])
        assert r.headers["content-type"].startswith("text/html") and "_id" in r.text, r.text[:300]
    r = c.get(f"/ui/axes/{env[3]}/gap?job={2**63}")
    assert r.status_code == 422 and "job" in r.text


def test_the_history_csv_doubles_quotes_and_neutralises_formula_cells(env):
    c, axis_id = env[0], env[3]
    sign_in(c, env[2]["read"])
    r = c.get(f"/ui/axes/{axis_id}/history.csv?range=all")
    assert r.status_code == 200
    rows = list(csv.reader(io.StringIO(r.text)))
    assert rows[0][0] == "measurement_id" and len(rows) == 2 and all(len(row) == len(rows[0]) for row in rows)
    cell = rows[1][-1]
    assert 'a "quoted" circle=' in cell and r"$\frac{$=" in cell and '=HYPERLINK("http://x")=' in cell
    assert not cell.startswith(("=", "+", "-", "@", "\t", "\r"))
    assert '""quoted""' in r.text  # the quote doubled in the file itself


def test_a_task_named_like_mathtext_draws_its_tbe_plots(env):
    c, axis_id = env[0], env[3]
    sign_in(c, env[2]["read"])
    for name in ("tbe_vs_backlash", "tbe_history"):
        r = c.get(f"/ui/axes/{axis_id}/plots/{name}.png?range=all")
        assert r.status_code == 200 and r.content.startswith(b"\x89PNG"), (name, r.status_code, r.text[:200])


def test_a_measurement_already_waiting_is_a_429_page_with_retry_after(env):
    c, svc, keys, axis_id, runner = env
    csrf = sign_in(c, keys["operate"])
    runner.gate = threading.Event()
    try:
        svc.trigger(axis_id, "test")  # running, held by the gate...
        assert runner.running.wait(30)
        svc.trigger(axis_id, "test")  # ...and one waiting
        r = c.post(f"/ui/axes/{axis_id}/measure", data={"csrf": csrf}, follow_redirects=False)
        assert r.status_code == 429 and r.headers["content-type"].startswith("text/html"), r.text[:300]
        assert int(r.headers["retry-after"]) >= 1 and "<html" in r.text.lower() and "waiting" in r.text.lower()
    finally:
        runner.gate.set()
        assert svc.scheduler.idle(60)
        runner.gate = None

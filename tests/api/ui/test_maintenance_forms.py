"""The dashboard's maintenance forms without a browser (api/ui/maintenance.py): who may
post, CSRF, the REST API's validation with the message in the form, the state machine's
refusals, and the summary's CSV being the API's."""

from __future__ import annotations

import re
from html import unescape
from datetime import datetime, timedelta, timezone

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.ui.maintenance import verification_rows
from storage.db import config_repo, maintenance_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings

CSRF = re.compile(r'name="csrf" value="([^"]+)"')


@pytest.fixture
def env(tmp_path):
    runner = FakeRunner()
    app = create_app(make_settings(f"sqlite:///{tmp_path}/m.sqlite3", tmp_path), runner=runner)
    with TestClient(app) as c:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            keys = {r: config_repo.create_key(s, f"ui-{r}", r)[1] for r in ("read", "operate")}
            axis_id = config_repo.list_axes(s)[0].id
        for b in (200.0, 250.0):  # a good measurement, then one past the limit: ALARM, a corrective order
            runner.backlash_um = b
            svc.trigger(axis_id, "test")
            assert svc.scheduler.idle(60)
        with session_scope(svc.factory) as s:
            order = maintenance_repo.active_order(s, axis_id)
        assert order is not None and order.state == "open" and order.kind == "corrective"
        yield c, svc, keys, axis_id, order, runner


def sign_in(c: TestClient, secret: str) -> str:
    """Sign in with ``secret``; the session's CSRF token."""
    c.cookies.clear()
    token = CSRF.search(c.get("/ui/sign-in").text).group(1)
    assert c.post("/ui/sign-in", data={"key": secret, "csrf": token}).status_code == 200
    return CSRF.search(c.get("/ui/").text).group(1)


def state_of(svc, order_id: int):
    with session_scope(svc.factory) as s:
        return maintenance_repo.get_order(s, order_id).state, len(maintenance_repo.list_repairs(s))


def test_a_read_key_sees_the_order_but_no_form_and_its_posts_are_refused(env):
    c, svc, keys, axis_id, order, _ = env
    csrf = sign_in(c, keys["read"])
    html = c.get(f"/ui/axes/{axis_id}").text
    assert f'data-order-id="{order.id}" data-state="open"' in html
    assert re.search(r"Restore the backlash below <strong>\d+\.\d µm", html)
    for form_id in ("repair-form", "ack-form", "cancel-form"):
        assert f'id="{form_id}"' not in html
    for url, data in ((f"/ui/axes/{axis_id}/repairs", {"kind": "nut_replaced"}),
                      (f"/ui/maintenance/orders/{order.id}/ack", {}),
                      (f"/ui/maintenance/orders/{order.id}/cancel", {"note": "no"})):
        r = c.post(url, data={"csrf": csrf, **data}, follow_redirects=False)
        assert r.status_code == 403 and "needs 'operate'" in unescape(r.text), url
    assert state_of(svc, order.id) == ("open", 0)


def test_an_operate_key_without_the_csrf_token_is_refused(env):
    c, svc, keys, axis_id, order, _ = env
    sign_in(c, keys["operate"])
    assert 'id="repair-form"' in c.get(f"/ui/axes/{axis_id}").text
    for csrf in (None, "forged"):
        data = {"kind": "nut_replaced"} | ({"csrf": csrf} if csrf else {})
        assert c.post(f"/ui/axes/{axis_id}/repairs", data=data, follow_redirects=False).status_code == 403
        assert c.post(f"/ui/maintenance/orders/{order.id}/ack", data=data, follow_redirects=False).status_code == 403
    assert state_of(svc, order.id) == ("open", 0)


@pytest.mark.parametrize("sent, field, words", [
    ({"kind": ""}, "f-kind", "choose what was done"),
    ({"kind": "welded"}, "f-kind", "preload_adjusted"),  # the REST model's message lists the six kinds
    ({"kind": "lubricated", "performed_at": "yesterday"}, "f-performed_at", "datetime"),
    ({"kind": "lubricated", "performed_at": "2999-01-01T08:00"}, "f-performed_at", "is in the future"),
    ({"kind": "lubricated", "compensation_measurement_id": "1"}, "f-compensation_measurement_id",
     "only for a repair of kind 'compensation_loaded'"),
    ({"kind": "compensation_loaded", "compensation_measurement_id": "x"}, "f-compensation_measurement_id",
     "integer"),
    ({"kind": "compensation_loaded", "compensation_measurement_id": "999"}, "f-compensation_measurement_id",
     "is not an ok measurement of axis"),
])
def test_a_refused_repair_says_why_next_to_its_field_and_keeps_the_form(env, sent, field, words):
    c, svc, keys, axis_id, order, _ = env
    csrf = sign_in(c, keys["operate"])
    r = c.post(f"/ui/axes/{axis_id}/repairs", data={"csrf": csrf, "note": "nut of X, 3 h", **sent},
               follow_redirects=False)
    assert r.status_code == 422
    msg = re.search(rf'id="{field}-error">([^<]*)<', r.text)
    assert msg and words in unescape(msg.group(1)), r.text[r.text.find('id="repair-form"'):][:3000]
    assert 'value="nut of X, 3 h"' in r.text  # what was typed is still there
    assert state_of(svc, order.id) == ("open", 0)  # nothing recorded


def test_steps_the_state_forbids_and_a_cancel_without_reason_are_refused_in_the_form(env):
    c, svc, keys, axis_id, order, _ = env
    csrf = sign_in(c, keys["operate"])
    r = c.post(f"/ui/maintenance/orders/{order.id}/cancel", data={"csrf": csrf, "note": "  "}, follow_redirects=False)
    assert r.status_code == 422 and "needs a reason" in unescape(re.search(r'id="cancel-error">([^<]*)<', r.text).group(1))
    r = c.post(f"/ui/maintenance/orders/{order.id}/ack", data={"csrf": csrf, "note": "on it"}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"].startswith(f"/ui/axes/{axis_id}?msg=")
    assert state_of(svc, order.id) == ("acknowledged", 0)
    # acknowledged twice: the REST API's 409 and its message, on the page (the form is gone)
    r = c.post(f"/ui/maintenance/orders/{order.id}/ack", data={"csrf": csrf}, follow_redirects=False)
    assert r.status_code == 409
    assert "is 'acknowledged': it cannot be acknowledged" in unescape(r.text) and 'id="ack-form"' not in r.text
    assert c.post("/ui/maintenance/orders/9999/ack", data={"csrf": csrf}).status_code == 404
    assert c.post(f"/ui/maintenance/orders/{10**30}/ack", data={"csrf": csrf}).status_code == 422
    r = c.post(f"/ui/maintenance/orders/{order.id}/cancel", data={"csrf": csrf, "note": "x" * 4001},
               follow_redirects=False)
    assert r.status_code == 422 and "at most 4000" in r.text
    r = c.post(f"/ui/maintenance/orders/{order.id}/cancel", data={"csrf": csrf, "note": "machine sold"},
               follow_redirects=False)
    assert r.status_code == 303
    with session_scope(svc.factory) as s:
        o = maintenance_repo.get_order(s, order.id)
    assert o.state == "cancelled" and [(t.to_state, t.by, t.note) for t in o.transitions][1:] == [
        ("acknowledged", "ui-operate", "on it"), ("cancelled", "ui-operate", "machine sold")]
    html = c.get(f"/ui/axes/{axis_id}").text
    assert 'id="no-work-order"' in html and "was <strong>cancelled</strong>" in html


def test_a_repair_recorded_on_the_form_is_the_apis_and_is_verified(env):
    c, svc, keys, axis_id, order, runner = env
    csrf = sign_in(c, keys["operate"])
    done = (datetime.now(timezone.utc) - timedelta(hours=2)).strftime("%Y-%m-%dT%H:%M")
    runner.backlash_um = 20.0  # what the verification measures: the play restored
    r = c.post(f"/ui/axes/{axis_id}/repairs", data={"csrf": csrf, "kind": "nut_replaced", "note": "new nut",
                                                     "performed_at": done}, follow_redirects=False)
    assert r.status_code == 303 and "repaired" in unescape(r.headers["location"])
    assert svc.scheduler.idle(60)
    with session_scope(svc.factory) as s:
        o = maintenance_repo.get_order(s, order.id)
        (rep,) = maintenance_repo.list_repairs(s, axis_id)
    assert (rep.kind, rep.note, rep.recorded_by, rep.order_id) == ("nut_replaced", "new nut", "ui-operate", order.id)
    assert rep.performed_at.strftime("%Y-%m-%dT%H:%M") == done  # the form's time is UTC
    assert [t.to_state for t in o.transitions] == ["open", "repaired", "verified"]
    html = c.get(f"/ui/axes/{axis_id}").text
    assert 'id="verification-verdict" class="ok-text"><strong>Verified</strong>' in html
    assert html.count('<tr class="task-after">') == len(o.verification["tasks_after"])
    assert 'data-key="backlash_mean_um"' in html
    # the polled verification line says the order moved on (and stops the polling)
    frag = c.get(f"/ui/axes/{axis_id}/maintenance/verification.frag?order={order.id}").text
    assert '<strong id="order-now">verified</strong>' in frag and "data-poll-stop" in frag
    assert c.get(f"/ui/axes/{axis_id + 1}/maintenance/verification.frag?order={order.id}").status_code == 404

    # the fleet page lists the axis, and its CSV is the API's, byte for byte
    page = c.get("/ui/maintenance").text
    assert re.search(r'<tr data-axis-id="%d">.*?<td class="num">1</td>' % axis_id, page, re.S)
    # a history of minutes: no fixed-plan repair yet, so nothing saved or lost to show
    assert re.search(r'<tr data-axis-id="%d">.*?<span class="muted" title="nothing to compare yet: 0.0 days of '
                     r'history, the comparison with the fixed plan needs at least 90 \(one period of it\)">–</span>'
                     % axis_id, page, re.S)
    assert ('<p class="small muted" id="saved-note">Saved: nothing to compare yet: no axis has a history of one '
            'fixed-plan period (90 days).</p>') in page
    csv = c.get("/ui/maintenance/summary.csv")
    assert csv.headers["content-type"].startswith("text/csv")
    api = c.get("/api/v1/maintenance/summary?format=csv", headers={"X-API-Key": keys["read"]})
    assert csv.text == api.text and csv.text.splitlines()[-1].startswith("(fleet),")


def test_the_verification_table_labels_the_lead_criteria_with_iso_3408_3s_names():
    changes = {k: {"before": 10.0, "after": 8.0, "change": -2.0}
               for k in ("e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um")}
    labels = {r["key"]: r["label"] for r in verification_rows({"changes": changes})}
    assert labels == {"e_p_um_per_1000mm": "Mean travel deviation e_p",
                      "v_u_um": "Travel variation over the useful travel v_u",
                      "v_300_um": "Travel variation within 300 mm v_300",
                      "v_2pi_um": "Travel variation within one revolution (2π rad) v_2π"}

"""What a first-time user reads on the dashboard along the README's tour: where the
sign-in keys are, the work order's recommendation once, what acknowledging an alert and
a work order each do, and an icon for every page (no /favicon.ico answered 404)."""

from __future__ import annotations

import re
from html import unescape

import pytest

from storage.db import config_repo, maintenance_repo, session_scope
from tests.api.ui.test_maintenance_forms import env, sign_in  # noqa: F401 (env: the fixture alarm uses)

TAGS = re.compile(r"<[^>]+>")


def text(html: str) -> str:
    """The words of ``html``, one space between them."""
    return re.sub(r"\s+", " ", unescape(TAGS.sub(" ", html)))


@pytest.fixture
def alarm(env):
    """A service with one axis in ALARM: an active alert and the corrective order it opened."""
    c, _svc, keys, axis_id, order, _runner = env
    assert order.alert_id is not None
    return c, keys, axis_id, order


def maintenance_section(html: str) -> str:
    start = html.index('<section class="card maintenance" id="maintenance">')
    return html[start:html.index("</section>", start)]


def test_the_sign_in_form_says_which_files_of_the_data_folder_hold_the_keys(alarm):
    c, *_ = alarm
    c.cookies.clear()
    words = text(c.get("/ui/sign-in").text)
    for name in ("demo-keys.json", "admin-key", "sign-in-link", "data folder"):
        assert name in words, name
    assert "printed by" not in words  # no secret is printed: they are in files


def test_the_work_orders_recommendation_reads_once_in_the_maintenance_panel(alarm):
    c, keys, axis_id, order = alarm
    sign_in(c, keys["operate"])
    panel = text(maintenance_section(c.get(f"/ui/axes/{axis_id}").text))
    restore = f"restore the backlash below {order.restore_below_um:.1f} µm"
    assert restore.lower() in order.recommendation.lower()  # the stored recommendation carries the target...
    assert panel.lower().count("restore the backlash below") == 1  # ...which the panel shows once
    first = order.recommendation.split(". ")[0]
    assert first.startswith("corrective maintenance") and panel.count(first) == 1
    assert "the recommendation above" in panel  # the opening step of the timeline points to it


def test_acknowledging_the_alert_and_the_work_order_are_told_apart_where_each_is_done(alarm):
    c, keys, axis_id, order = alarm
    sign_in(c, keys["operate"])
    fleet = text(c.get("/ui/").text)
    assert "Acknowledging an alert says it was seen" in fleet and "work order the alert opened" in fleet
    panel = text(maintenance_section(c.get(f"/ui/axes/{axis_id}").text))
    assert f"Acknowledge work order {order.id}" in panel
    assert "takes the repair on" in panel and f"The alert {order.alert_id} on the fleet page" in panel
    assert "leaves this order as it is" in panel
    # and so it is: the alert acknowledged, the order is still open, its button still there
    csrf = re.search(r'name="csrf" value="([^"]+)"', c.get("/ui/").text).group(1)
    r = c.post(f"/ui/alerts/{order.alert_id}/ack", data={"csrf": csrf})
    assert r.status_code == 200
    flash = text(re.search(r'<p class="flash"[^>]*>(.*?)</p>', r.text, flags=re.S).group(1))
    assert f"alert {order.alert_id} acknowledged by ui-operate" in flash
    assert f"work order {order.id} (open)" in flash  # what follows the repair, and where
    with session_scope(c.app.state.service.factory) as s:
        assert maintenance_repo.get_order(s, order.id).state == "open"
    assert 'id="ack-form"' in c.get(f"/ui/axes/{axis_id}").text


def test_every_page_names_an_icon_that_is_served_and_favicon_ico_answers_too(alarm):
    c, *_ = alarm
    c.cookies.clear()
    html = c.get("/ui/sign-in").text
    href = re.search(r'<link rel="icon" href="([^"]+)"', html).group(1)
    for url in (href, "/favicon.ico"):  # /favicon.ico: what a browser asks on the API's JSON or XML pages
        r = c.get(url)
        assert r.status_code == 200, url
        assert r.content[:4] == b"\x00\x00\x01\x00", url  # an ICO file's header
        assert r.headers["content-type"] in ("image/x-icon", "image/vnd.microsoft.icon"), url

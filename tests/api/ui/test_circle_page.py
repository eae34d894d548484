"""The circular tests panel of the axis page in a real headless chromium: the empty state,
then a test posted through the REST API, shown with its figures and its polar plot."""

from __future__ import annotations

import json
import re

import pytest

from storage.db import circles_repo, config_repo, session_scope
from tests.api.rest.test_circle_plot import BACKLASH_UM, RING, circle_plane, simulated
from tests.api.ui.conftest import SCREENSHOTS
from tests.api.ui.test_browser import sign_in
from tests.waiting import poll


@pytest.fixture(scope="module")
def page(browser):
    p = browser.new_page()
    yield p
    p.close()


def open_axis(page, srv, axis_id: int) -> None:
    page.goto(f"{srv.url}/ui/axes/{axis_id}")
    page.wait_for_selector("#circles")


def test_an_axis_without_a_test_says_how_to_run_one(page, ui_server):
    sign_in(page, ui_server, "read")
    open_axis(page, ui_server, ui_server.axis_id)
    text = page.locator("#no-circle").inner_text()
    assert "No circular test of axis y yet" in text
    assert "mebm circle measure" in text and "mebm circle import" in text
    # at the radius and feed of the axis' circle task, posted to the axis' machine
    with session_scope(ui_server.svc.factory) as s:
        axis = config_repo.get_axis(s, ui_server.axis_id)
    (task,) = [t for t in axis.tasks if t.profile == "circle"]
    how = page.locator("#no-circle-how").inner_text()
    assert f"--radius-mm {task.radius_mm:g} --feed-mm-min {task.feed_mm_min:g}" in how
    assert f"{ui_server.url}/api/v1/machines/{axis.machine_id}/circles" in how
    assert f"{task.name}: R {task.radius_mm:g} mm" in text
    assert page.locator("#circle-plot").count() == 0


@pytest.fixture(scope="module")
def posted(ui_server, page):
    """Axis y measured (b̄ = its simulated play), then a circular test of x/y posted with an
    operate key through the REST API, as a client would."""
    machine_id, x_id = circle_plane(ui_server.svc, ui_server.axis_id)
    ui_server.measure(BACKLASH_UM["y"])
    r = page.request.post(f"{ui_server.url}/api/v1/machines/{machine_id}/circles", data=json.dumps(simulated()),
                          headers={"X-API-Key": ui_server.keys["operate"], "Content-Type": "application/json"})
    assert r.status == 201, r.text()
    with session_scope(ui_server.svc.factory) as s:
        rec = circles_repo.get_circular_test(s, r.json()["id"])
    return rec, x_id


def pm(value: float, u: float, nd: int = 2) -> str:
    return f"{value:.{nd}f} ± {u:.{nd}f} µm"


def test_the_panel_shows_the_stored_test_and_its_polar_plot(page, ui_server, posted):
    rec, _x_id = posted
    sign_in(page, ui_server, "read")
    open_axis(page, ui_server, ui_server.axis_id)
    assert page.locator("#no-circle").count() == 0
    latest = page.locator("#circle-latest")
    assert latest.get_attribute("data-circle-id") == str(rec.id)
    f, a, d = rec.figures, rec.agreement["y"], rec.decision["y"]
    # the figures shown are the stored ones
    assert page.locator("#circle-when").inner_text() == rec.measured_at.strftime("%Y-%m-%d %H:%M UTC")
    assert page.locator("#circle-radius").inner_text() == "50 mm"
    assert page.locator("#circle-feed").inner_text() == "1000 mm/min"
    g = pm(f["circular_deviation_um"], f["circular_deviation_uncertainty_um"])
    assert page.locator("#circle-g").inner_text() == g
    assert page.locator("#circle-g-mz").inner_text() == f"{f['circular_deviation_mz_um']:.2f} µm"
    assert page.locator("#circle-h").inner_text() == pm(f["hysteresis_um"], f["hysteresis_uncertainty_um"])
    assert page.locator("#circle-spike").inner_text() == pm(a["measured_um"], a["measured_uncertainty_um"])
    assert page.locator("#circle-eq8").inner_text() == pm(a["predicted_um"], a["predicted_uncertainty_um"])
    verdict = page.locator("#circle-verdict")
    assert verdict.get_attribute("data-verdict") == a["verdict"]
    assert page.locator("#circle-meaning").inner_text().lower().startswith(a["meaning"].lower())
    decision = page.locator("#circle-decision").inner_text()
    assert d["state"] in decision and RING.name in decision and pm(d["error_um"], d["uncertainty_um"]) in decision
    assert f"{RING.tolerance_um:g} µm" in decision
    # the polar plot loads (it is lazy: scrolled to first)
    img = page.locator("#circle-plot")
    img.scroll_into_view_if_needed()
    assert poll(lambda: img.evaluate("e => e.complete && e.naturalWidth > 0"), 60.0), img.get_attribute("src")
    assert img.evaluate("e => e.naturalWidth") == 1100
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.locator("#circles").screenshot(path=str(SCREENSHOTS / "circle.png"))
    # the dashboard's plot is the REST API's figure for this axis
    ui_png = page.request.get(f"{ui_server.url}{img.get_attribute('src')}").body()
    api_png = page.request.get(f"{ui_server.url}/api/v1/circles/{rec.id}/plot.png?axis=y",
                               headers={"X-API-Key": ui_server.keys["read"]}).body()
    assert ui_png == api_png and ui_png[:4] == b"\x89PNG"


def test_the_other_axis_of_the_plane_shows_the_same_test_without_eq8(page, ui_server, posted):
    rec, x_id = posted
    sign_in(page, ui_server, "read")
    open_axis(page, ui_server, x_id)
    assert page.locator("#circle-latest").get_attribute("data-circle-id") == str(rec.id)
    # x has no round trip stored: its spikes are listed, not compared with Eq. 8
    text = page.locator("#circle-agreement").inner_text()
    assert "not compared with Eq. 8" in text
    assert sum(1 for sp in rec.figures["spikes"] if sp["axis"] == "x") == len(re.findall(r"° \d+\.\d\d ±", text))
    assert page.locator("#circle-verdict").count() == 0
    img = page.locator("#circle-plot")
    img.scroll_into_view_if_needed()
    assert poll(lambda: img.evaluate("e => e.complete && e.naturalWidth > 0"), 60.0)


def test_a_test_of_another_plane_is_not_the_axis_plot(page, ui_server, posted):
    rec, _x_id = posted
    sign_in(page, ui_server, "read")
    other = ui_server.add_axis("hmc-630", "z")
    r = page.request.get(f"{ui_server.url}/ui/axes/{other}/circles/{rec.id}/plot.png")
    assert r.status == 404

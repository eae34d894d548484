"""The circular tests panel without a browser: what it says for a test with one direction and
no judged task, and for figures JSON keeps as null (an infinite E_n), and the plot's 404s."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from html import unescape

import numpy as np
import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from core.circle import CirclePass, CircularTest, Instrument, analyze, compare_with_backlash
from storage.db import circles_repo, config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.api.rest.test_circle_plot import circle_plane
from tests.api.ui.test_maintenance_forms import sign_in


def one_direction_test() -> CircularTest:
    """A ccw pass with a spike of 6 µm after each quadrant point (decaying over ~2°)."""
    a = np.arange(0.0, 360.0, 0.25)
    radial = 0.8 * np.cos(np.deg2rad(2 * a))
    for q in (0.0, 90.0, 180.0, 270.0):
        ahead = (a - q) % 360.0
        radial = radial + np.where(ahead < 15.0, 6.0 * np.exp(-ahead / 2.0), 0.0)
    return CircularTest(radius_mm=40.0, feed_mm_min=800.0, plane=("x", "y"),
                        passes=(CirclePass("ccw", a, radial),),
                        instrument=Instrument("ballbar", resolution_um=0.1, name="QC20-W"), source="imported: t.csv")


@pytest.fixture
def env(tmp_path):
    app = create_app(make_settings(f"sqlite:///{tmp_path}/c.sqlite3", tmp_path, scheduler_enabled=False),
                     runner=FakeRunner())
    with TestClient(app) as c:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, "ui-read", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        machine_id, x_id = circle_plane(svc, axis_id)
        sign_in(c, key)
        yield c, svc, machine_id, axis_id, x_id


def text_of(html: str, element_id: str) -> str:
    """The text of the element with ``element_id`` (its own tag closes it: no nesting of the same tag)."""
    m = re.search(rf'<(\w+)[^>]*\bid="{element_id}"[^>]*>(.*?)</\1>', html, re.S)
    assert m, element_id
    return " ".join(unescape(re.sub(r"<[^>]+>", "", m.group(2))).split())


def test_one_direction_and_no_task_at_its_radius(env):
    c, svc, machine_id, axis_id, _x = env
    test = one_direction_test()
    figures = analyze(test)
    with session_scope(svc.factory) as s:
        test_id = circles_repo.add_circular_test(s, machine_id, test, figures=figures, agreement={}, decision={})
    html = c.get(f"/ui/axes/{axis_id}").text
    assert f'data-circle-id="{test_id}"' in html
    assert text_of(html, "circle-h") == "one direction only"
    assert "Not judged" in text_of(html, "circle-decision")  # ring-50's R and feed are not this test's
    spikes = text_of(html, "circle-agreement")
    assert "not compared with Eq. 8" in spikes
    for sp in figures.spikes_of("y"):
        assert f"{sp.height_um:.2f} ± {sp.height_uncertainty_um:.2f} µm" in spikes
    assert "QC20-W" in html
    png = c.get(f"/ui/axes/{axis_id}/circles/{test_id}/plot.png")
    assert png.status_code == 200 and png.content[:4] == b"\x89PNG"


def test_a_figure_json_keeps_as_null_is_a_dash(env):
    c, svc, machine_id, axis_id, _x = env
    test = one_direction_test()
    figures = analyze(test)
    agreement = compare_with_backlash(figures, axis="y", backlash_um=0.0, backlash_uncertainty_um=0.0, gain_per_s=10.0)
    agreement = replace(agreement, normalised_error=math.inf)  # as when both U are 0 and they differ
    with session_scope(svc.factory) as s:
        test_id = circles_repo.add_circular_test(s, machine_id, test, figures=figures, agreement={"y": agreement})
    r = c.get(f"/ui/axes/{axis_id}")
    assert r.status_code == 200
    assert "(En –)" in text_of(r.text, "circle-agreement")
    assert text_of(r.text, "circle-verdict") == "spikes larger than Eq. 8"
    assert c.get(f"/ui/axes/{axis_id}/circles/{test_id}/plot.png").status_code == 200


def test_the_plot_of_a_test_the_axis_is_not_in_is_not_found(env):
    c, svc, machine_id, axis_id, _x = env
    with session_scope(svc.factory) as s:
        test_id = circles_repo.add_circular_test(s, machine_id, one_direction_test())
    assert c.get(f"/ui/axes/{axis_id}/circles/{test_id + 1}/plot.png").status_code == 404
    assert c.get(f"/ui/axes/{axis_id}/circles/0/plot.png").status_code == 422
    # stored without figures: analysed when drawn
    assert c.get(f"/ui/axes/{axis_id}/circles/{test_id}/plot.png").status_code == 200


def test_a_circle_larger_than_eq_8_s_loop_traces_says_so_beside_the_spikes(env):
    """The test's path lies on the nominal radius, where a P loop at K 10/s would trace it
    22 µm inside: the panel says the loop is not Eq. 8's and what that means."""
    c, svc, machine_id, axis_id, _x = env
    test = one_direction_test()
    figures = analyze(test)
    agreement = compare_with_backlash(figures, axis="y", backlash_um=10.0, backlash_uncertainty_um=1.0, gain_per_s=10.0)
    assert agreement.loop.verdict == "larger"
    with session_scope(svc.factory) as s:
        circles_repo.add_circular_test(s, machine_id, test, figures=figures, agreement={"y": agreement})
    loop = text_of(c.get(f"/ui/axes/{axis_id}").text, "circle-loop")
    assert f"{agreement.loop.measured_um:.2f} ± {agreement.loop.measured_uncertainty_um:.2f} µm" in loop
    assert f"{agreement.loop.predicted_um:.2f} ± {agreement.loop.predicted_uncertainty_um:.2f} µm" in loop
    assert "feeds the commanded velocity forward" in loop

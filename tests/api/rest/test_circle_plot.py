"""GET /circles/{id}/plot.png: a stored circular test's polar plot, drawn from what was stored."""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import pytest

from api.service.figures import circle_record
from core.circle import to_json
from core.circle.simulate import simulated_test
from core.tbe import MachiningTask
from storage.db import circles_repo, config_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.storage.db import factories as f

# a circle task at the test's own radius and feed: the test is that task's machining error
RING = MachiningTask("ring-50", "circle", feed_mm_min=1000.0, gain_per_s=10.0, tolerance_um=30.0, radius_mm=50.0)
BACKLASH_UM = {"x": 25.0, "y": 30.0}  # the simulated chains' play


@lru_cache(maxsize=1)
def simulated() -> dict:
    """A circular test of x/y on the project's twin of a feed drive (K = 10/s, as the axes'),
    in core.circle.io's JSON."""
    return to_json(simulated_test(radius_mm=50.0, feed_mm_min=1000.0, gain_per_s=10.0,
                                  backlash_um=(BACKLASH_UM["x"], BACKLASH_UM["y"]), noise_um=0.2, resolution_um=0.1))


def circle_plane(svc, axis_id: int) -> tuple[int, int]:
    """The machine of ``axis_id`` (axis y) gets an axis x; both get the task ring-50. Returns
    (machine id, x's axis id)."""
    with session_scope(svc.factory) as s:
        y = config_repo.set_tasks(s, axis_id, [RING])
        x = config_repo.find_axis(s, y.machine_name, "x") or config_repo.create_axis(
            s, y.machine_id, f.settings(spec=replace(f.AXIS, name="x"), tasks=(RING,),
                                        controller_url="modbus://127.0.0.1:1"))
    svc.axis_changed(y)
    svc.axis_changed(x)
    return y.machine_id, x.id


def measure(svc, runner, axis_id: int, backlash_um: float) -> None:
    runner.backlash_um = backlash_um
    svc.trigger(axis_id, "test")
    assert svc.scheduler.idle(60)


def post_circle(client, machine_id: int, operate_key: str) -> dict:
    r = client.post(f"/api/v1/machines/{machine_id}/circles", json=simulated(), headers=hdr(operate_key))
    assert r.status_code == 201, r.text
    return r.json()


@pytest.fixture
def stored(app_env, runner):
    client, svc, keys, axis_id = app_env
    machine_id, _x = circle_plane(svc, axis_id)
    measure(svc, runner, axis_id, BACKLASH_UM["y"])  # y has b̄: its spikes are compared with Eq. 8
    doc = post_circle(client, machine_id, keys["operate"])
    return client, svc, keys, doc


def test_the_polar_plot_of_a_stored_test(stored):
    client, svc, keys, doc = stored
    r = client.get(f"/api/v1/circles/{doc['id']}/plot.png", headers=hdr(keys["read"]))
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.content[:8] == b"\x89PNG\r\n\x1a\n" and len(r.content) > 30000
    # a stored test never changes: the second request is the cached figure
    hits = svc.figures.hits
    again = client.get(f"/api/v1/circles/{doc['id']}/plot.png", headers=hdr(keys["read"]))
    assert again.content == r.content and svc.figures.hits == hits + 1
    # by default the strictest judged task's band (a tie: the plane's first axis); another axis' is another figure
    x = client.get(f"/api/v1/circles/{doc['id']}/plot.png?axis=x", headers=hdr(keys["read"]))
    y = client.get(f"/api/v1/circles/{doc['id']}/plot.png?axis=y", headers=hdr(keys["read"]))
    assert x.status_code == y.status_code == 200 and x.content == r.content != y.content


def test_the_plot_is_drawn_from_what_was_stored(stored):
    _client, svc, _keys, doc = stored
    with session_scope(svc.factory) as s:
        rec = circles_repo.get_circular_test(s, doc["id"])
    kw = circle_record.plot_inputs(rec, "y")
    assert kw["band"].tolerance_um == RING.tolerance_um == doc["decision"]["y"]["tolerance_um"]
    assert kw["band"].warning_um == doc["decision"]["y"]["warning_um"] and "ring-50" in kw["band"].task
    assert len(kw["spikes"]) == len(doc["figures"]["spikes"]) == 8
    y_marks = [m for m in kw["spikes"] if m.axis == "y"]
    assert {m.predicted_um for m in y_marks} == {doc["agreement"]["y"]["predicted_um"]}
    assert all(m.predicted_um is None for m in kw["spikes"] if m.axis == "x")  # x has no b̄ yet
    assert {(m.height_um, m.peak_deg) for m in kw["spikes"]} == {(sp["height_um"], sp["peak_deg"])
                                                              for sp in doc["figures"]["spikes"]}
    assert kw["summary"].circular_deviation_um == doc["figures"]["circular_deviation_um"]
    assert f"{doc['agreement']['y']['verdict']} (E_n" in kw["summary"].agreements["y"]
    assert set(kw["passes"]) == {"ccw", "cw"}
    # the figure: the band and the marks, on its artists
    fig = circle_record.circle.polar_figure(**kw)
    gids = {a.get_gid() for a in fig.axes[0].get_children()}
    assert {"tolerance-band", "warning-ring", "pass-ccw", "pass-cw"} <= gids
    assert sum(g.startswith("eq8-y-") for g in gids if g) == 4 and not any(g.startswith("eq8-x-") for g in gids if g)


def test_unknown_tests_and_axes_are_not_found(stored):
    client, _svc, keys, doc = stored
    read = hdr(keys["read"])
    assert client.get(f"/api/v1/circles/{doc['id'] + 1000}/plot.png", headers=read).status_code == 404
    assert client.get(f"/api/v1/circles/{doc['id']}/plot.png?axis=z", headers=read).status_code == 404
    assert client.get("/api/v1/circles/0/plot.png", headers=read).status_code == 422
    assert client.get(f"/api/v1/circles/{doc['id']}/plot.png").status_code == 401

"""Circular tests over REST on SQLite and PostgreSQL: posted, analysed, compared with the
TBE at the axis' b̄, judged against the axis' circle task, stored, listed and read back;
bad bodies are typed 4xx naming the fault; a test at the task's radius and feed on a
machine whose axis is past its limit raises the tbe_exceeded alert and opens the
corrective order with the test as their evidence, and a later test below the limit
verifies the repair."""

from __future__ import annotations

import json
import math
import threading
from dataclasses import replace
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.settings import AxisConfig
from api.service.events import order_document
from core.circle import to_json
from core.circle.simulate import simulated_test
from core.tbe import MachiningTask
from storage.db import Schedule, config_repo, maintenance_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.storage.db import factories as f
from tests.waiting import poll

V1 = "/api/v1"
# a 50 mm circle at 1000 mm/min, K 10 1/s: Eq. 8 gives a TBE of about 93 µm at 150 µm of play (OK),
# 165 µm at 300 µm (ALARM)
TASK = MachiningTask("circle R50", "circle", feed_mm_min=1000.0, gain_per_s=10.0, tolerance_um=120.0, radius_mm=50.0)


def circle_axis(name: str) -> AxisConfig:
    return AxisConfig("vmc-850", f.settings(spec=replace(f.AXIS, name=name), controller_url="modbus://127.0.0.1:1",
                                            schedule=Schedule(interval_s=3600.0), tasks=(TASK,)))


@pytest.fixture
def env(engine, db_url, tmp_path):  # noqa: ARG001 - engine empties the database
    runner = FakeRunner(backlash_um=150.0)
    settings = replace(make_settings(db_url, tmp_path), axes=(circle_axis("x"), circle_axis("y")))
    app = create_app(settings, runner=runner)
    with TestClient(app) as client:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            keys = {role: config_repo.create_key(s, f"test-{role}", role)[1] for role in ("read", "operate")}
            axes = {a.name: a for a in config_repo.list_axes(s)}
        yield client, svc, keys, axes, runner


def circle_body(backlash_um=(0.0, 0.0), *, radius_mm=TASK.radius_mm, feed_mm_min=TASK.feed_mm_min, **kw) -> dict:
    test = simulated_test(radius_mm=radius_mm, feed_mm_min=feed_mm_min, gain_per_s=TASK.gain_per_s,
                          backlash_um=backlash_um, noise_um=0.2, resolution_um=0.1, seed=1, **{"rate_hz": 100.0, **kw})
    return to_json(replace(test, temperature_c=21.0, utility_day=12.5))


def _measure(client, keys, axis_id) -> dict:
    """A round trip of the axis (the fake runner's 150 µm play), for its b̄."""
    def newest_ok():
        items = client.get(f"{V1}/axes/{axis_id}/measurements?status=ok&limit=1", headers=hdr(keys["read"])).json()
        return items["items"][0] if items["items"] else None

    before = newest_ok()
    assert client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["operate"])).status_code == 202
    return poll(lambda: m if (m := newest_ok()) is not None and m != before else None)


def test_a_posted_test_is_analysed_compared_judged_stored_and_listed(env):
    client, svc, keys, axes, runner = env
    machine_id = axes["x"].machine_id
    _measure(client, keys, axes["y"].id)  # y has a b̄ to compare with; x has none
    r = client.post(f"{V1}/machines/{machine_id}/circles", json=circle_body((0.0, 150.0)), headers=hdr(keys["operate"]))
    assert r.status_code == 201, r.text
    doc = r.json()
    assert r.headers["location"] == f"{V1}/circles/{doc['id']}"
    assert doc["plane"] == ["x", "y"] and doc["axis_ids"] == {"x": axes["x"].id, "y": axes["y"].id}
    assert (doc["radius_mm"], doc["feed_mm_min"], doc["directions"]) == (50.0, 1000.0, ["ccw", "cw"])
    assert (doc["temperature_c"], doc["utility_day"], doc["recorded_by"]) == (21.0, 12.5, "test-operate")
    fig = doc["figures"]
    assert fig["circular_deviation_um"] > 0 and fig["circular_deviation_uncertainty_um"] > 0
    assert fig["hysteresis_um"] is not None and fig["hysteresis_uncertainty_um"] > 0
    # agreement only where the axis has a round trip: y's spikes against Eq. 8 at its b̄ of 150 µm
    assert set(doc["agreement"]) == {"y"}
    ag = doc["agreement"]["y"]
    assert ag["backlash_um"] == pytest.approx(150.0, abs=5.0) and ag["verdict"] in ("agree", "larger", "smaller")
    assert ag["predicted_uncertainty_um"] > 0 and math.isfinite(ag["normalised_error"])
    assert ag["measured_um"] == pytest.approx(ag["predicted_um"], rel=0.1)  # the twin's play is the round trip's
    # both axes judged against the circle task at its own radius and feed
    for name in ("x", "y"):
        d = doc["decision"][name]
        assert d["task"] == TASK.name and d["tolerance_um"] == TASK.tolerance_um and d["uncertainty_um"] > 0
    assert doc["decision"]["y"]["error_um"] > doc["decision"]["x"]["error_um"]  # y has the play
    assert doc["state"] == "OK" and doc["alerts"] == []

    # beside the TBE in the status an MES polls: the newest test's G, H, the axis' spike, the agreement
    st = client.get(f"{V1}/axes/{axes['y'].id}/status", headers=hdr(keys["read"])).json()
    ct = st["circular_test"]
    assert (ct["id"], ct["href"], ct["state"], ct["task"]) == (doc["id"], f"{V1}/circles/{doc['id']}", "OK", TASK.name)
    assert ct["circular_deviation_um"] == fig["circular_deviation_um"] and ct["hysteresis_um"] == fig["hysteresis_um"]
    assert ct["spike_um"] == pytest.approx(doc["decision"]["y"]["error_um"]) and ct["spike_uncertainty_um"] > 0
    assert (ct["agreement"], ct["normalised_error"]) == (ag["verdict"], ag["normalised_error"])
    assert st["tasks"][0]["tbe_um"] == pytest.approx(ct["predicted_tbe_um"], rel=1e-6)  # the same Eq. 8 at b̄
    x_ct = client.get(f"{V1}/axes/{axes['x'].id}/status", headers=hdr(keys["read"])).json()["circular_test"]
    assert x_ct["agreement"] is None and x_ct["spike_um"] < ct["spike_um"]  # x: no b̄ yet, no play

    # a second test, at another radius: stored, not judged
    other = client.post(f"{V1}/machines/{machine_id}/circles", json=circle_body(radius_mm=40.0),
                        headers=hdr(keys["operate"]))
    assert other.status_code == 201 and other.json()["decision"] == {"x": None, "y": None}
    assert other.json()["state"] is None

    read = hdr(keys["read"])
    page = client.get(f"{V1}/machines/{machine_id}/circles", headers=read).json()
    assert [i["id"] for i in page["items"]] == [other.json()["id"], doc["id"]] and page["total"] == 2
    assert "test" not in page["items"][0]
    assert client.get(f"{V1}/machines/{machine_id}/circles?axis=y&limit=1", headers=read).json()["total"] == 2
    one = client.get(f"{V1}/circles/{doc['id']}", headers=read).json()
    assert one["figures"] == doc["figures"] and one["decision"] == doc["decision"]
    posted = circle_body((0.0, 150.0))
    assert [p["direction"] for p in one["test"]["passes"]] == ["ccw", "cw"]
    assert one["test"]["passes"][0]["radial_um"] == pytest.approx(posted["passes"][0]["radial_um"])
    assert "test" not in client.get(f"{V1}/circles/{doc['id']}?samples=false", headers=read).json()


def test_keys_and_bad_bodies_get_typed_errors(env):
    client, svc, keys, axes, runner = env
    machine_id = axes["x"].machine_id
    url = f"{V1}/machines/{machine_id}/circles"
    body = circle_body()
    assert client.post(url, json=body).status_code == 401
    assert client.post(url, json=body, headers=hdr(keys["read"])).status_code == 403
    op = hdr(keys["operate"])
    assert client.post(f"{V1}/machines/999/circles", json=body, headers=op).status_code == 404
    r = client.post(url, json=dict(body, plane=["x", "z"]), headers=op)
    assert r.status_code == 422 and "no axis 'z'" in r.json()["detail"]
    nan = dict(body, passes=[dict(body["passes"][0], radial_um=[float("nan")] + body["passes"][0]["radial_um"][1:])])
    r = client.post(url, content=json.dumps(nan), headers={**op, "Content-Type": "application/json"})
    assert r.status_code == 422 and "radial_um" in r.json()["detail"]
    p = body["passes"][0]  # a partial arc: the samples of the first half only
    half = [i for i, a in enumerate(p["angle_deg"]) if a < 180.0]
    partial = dict(body, passes=[{"direction": p["direction"], "angle_deg": [p["angle_deg"][i] for i in half],
                                  "radial_um": [p["radial_um"][i] for i in half]}])
    r = client.post(url, json=partial, headers=op)
    assert r.status_code == 422 and "quadrant" in r.json()["detail"].lower()
    for when in ("yesterday", "2026-03-01T08:00:00", "2999-01-01T00:00:00Z"):  # not a time, no zone, future
        r = client.post(url, json=dict(body, measured_at=when), headers=op)
        assert r.status_code == 422 and "measured_at" in r.json()["detail"], when
    r = client.post(url, json=dict(body, passes=body["passes"] * 2), headers=op)  # a direction twice
    assert r.status_code == 422 and "repeated" in r.json()["detail"]
    r = client.post(url, json=[1, 2], headers=op)
    assert r.status_code == 422
    read = hdr(keys["read"])
    assert client.get(f"{V1}/machines/{machine_id}/circles?axis=z", headers=read).status_code == 404
    assert client.get(f"{V1}/machines/999/circles", headers=read).status_code == 404
    assert client.get(f"{V1}/circles/999", headers=read).status_code == 404
    assert client.get(f"{V1}/machines/{machine_id}/circles", headers=read).json()["total"] == 0  # none stored
    # a test at a stated time is stored at it
    r = client.post(url, json=dict(body, measured_at="2026-03-01T08:00:00Z"), headers=op)
    assert r.status_code == 201 and r.json()["measured_at"] == "2026-03-01T08:00:00Z"


def test_a_test_past_the_limit_raises_the_alert_and_order_and_a_test_after_the_repair_verifies_it(env):
    client, svc, keys, axes, runner = env
    machine_id, y = axes["y"].machine_id, axes["y"].id
    op, read = hdr(keys["operate"]), hdr(keys["read"])
    events = []
    sub = svc.events.subscribe("t", lambda ev: events.append(ev) if ev.kind == "work_order_changed" else None)
    r = client.post(f"{V1}/machines/{machine_id}/circles", json=circle_body((0.0, 300.0)), headers=op)  # past the limit
    assert r.status_code == 201, r.text
    doc = r.json()
    poll(lambda: events)
    svc.events.unsubscribe(sub)
    step = order_document(events[0])  # as MQTT and webhooks send the order's opening
    assert (step["state"], step["opened_by_circular_test_id"], step["by"]) == ("open", doc["id"], "mebm")
    d = doc["decision"]["y"]
    assert d["state"] == "ALARM" and d["error_um"] > TASK.tolerance_um and doc["state"] == "ALARM"
    assert doc["decision"]["x"]["state"] == "OK"
    (alert,) = client.get(f"{V1}/alerts?axis_id={y}", headers=read).json()["items"]
    assert (alert["kind"], alert["active"], alert["task_name"]) == ("tbe_exceeded", True, TASK.name)
    assert alert["raised_by_circular_test_id"] == doc["id"] and alert["raised_by_measurement_id"] is None
    assert alert["tbe_um"] == pytest.approx(d["error_um"]) and alert["tolerance_um"] == TASK.tolerance_um
    assert client.get(f"{V1}/alerts?axis_id={axes['x'].id}", headers=read).json()["items"] == []
    (order,) = poll(lambda: client.get(f"{V1}/maintenance/orders?axis_id={y}", headers=read).json()["items"])
    assert order["kind"] == "corrective" and order["alert_id"] == alert["id"]
    assert order["opened_by_circular_test_id"] == doc["id"] and order["tbe_um"] == pytest.approx(d["error_um"])
    assert f"circular test {doc['id']}" in order["recommendation"]

    # the nut re-preloaded: a test at the task's radius and feed verifies the repair and clears the alert
    runner.gate = threading.Event()  # the verification round trip waits until the test has verified the repair
    r = client.post(f"{V1}/axes/{y}/repairs", json={"kind": "preload_adjusted"}, headers=op)
    assert r.status_code == 201 and r.json()["order"]["state"] == "repaired"
    after = client.post(f"{V1}/machines/{machine_id}/circles", json=circle_body((0.0, 5.0)), headers=op).json()
    assert after["decision"]["y"]["state"] == "OK"
    assert [a["active"] for a in after["alerts"]] == [False]
    o = client.get(f"{V1}/maintenance/orders/{order['id']}", headers=read).json()
    assert o["state"] == "verified" and o["verification"]["passed"] is True
    assert o["verification"]["after"]["circular_test_id"] == after["id"]
    assert f"circular test {after['id']}" in o["verified_against"]
    runner.gate.set()  # the round trip then finds the order concluded: an ordinary measurement
    assert poll(lambda: any(m["trigger"] == "verification" and m["status"] == "ok" for m in
                            client.get(f"{V1}/axes/{y}/measurements", headers=read).json()["items"]))
    with session_scope(svc.factory) as s:
        assert maintenance_repo.active_order(s, y) is None


PROFILE = Path(__file__).resolve().parents[3] / "examples" / "circle-profiles" / "ballbar-direction-column.toml"


def ballbar_csv(backlash_um=(0.0, 0.0)) -> bytes:
    """A ballbar's export of the twin's circle: angle, deviation and direction, in the order run."""
    doc = circle_body(backlash_um)
    lines = ["Angle (deg),Deviation (um),Direction"]
    for p in doc["passes"]:
        lines += [f"{a!r},{r!r},{p['direction'].upper()}" for a, r in zip(p["angle_deg"], p["radial_um"])]
    return ("\n".join(lines) + "\n").encode()


def test_an_exported_csv_is_imported_through_its_profile_and_judged_as_a_posted_test(env):
    client, svc, keys, axes, runner = env
    url = f"{V1}/machines/{axes['y'].machine_id}/circles/import"
    op = hdr(keys["operate"])
    files = {"file": ("vmc-850_xy.csv", ballbar_csv((0.0, 300.0)), "text/csv"),
             "profile": ("ballbar.toml", PROFILE.read_bytes(), "application/toml")}
    form = {"radius_mm": str(TASK.radius_mm), "feed_mm_min": str(TASK.feed_mm_min), "temperature_c": "21.0"}
    r = client.post(url, files=files, data=form, headers=op)
    assert r.status_code == 201, r.text
    doc = r.json()
    assert doc["source"] == "imported: vmc-850_xy.csv" and doc["instrument"]["kind"] == "ballbar"
    assert doc["temperature_c"] == 21.0 and doc["directions"] == ["ccw", "cw"]
    posted = client.post(f"{V1}/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 300.0)),
                         headers=op).json()  # the same circle posted as JSON
    assert doc["decision"]["y"]["state"] == posted["decision"]["y"]["state"] == "ALARM"
    assert doc["figures"]["circular_deviation_um"] == pytest.approx(posted["figures"]["circular_deviation_um"],
                                                                    rel=1e-6)
    assert [a["raised_by_circular_test_id"] for a in doc["alerts"]] == [doc["id"]]
    # faults name the uploaded file and what fixes them, never the server's folders
    bad = {"file": ("bb.csv", b"Angle,Dev\n1,2\n", "text/csv"), "profile": files["profile"]}
    r = client.post(url, files=bad, data=form, headers=op)
    assert r.status_code == 422 and "bb.csv" in r.json()["detail"] and "no column" in r.json()["detail"]
    assert "mebm-circle-" not in r.json()["detail"]
    r = client.post(url, files=files, headers=op)  # no radius: the profile does not give it either
    assert r.status_code == 422 and "radius_mm" in r.json()["detail"]
    r = client.post(url, files={**files, "profile": ("p.toml", b"format = [", "application/toml")}, data=form,
                    headers=op)
    assert r.status_code == 422 and "profile" in r.json()["detail"]
    assert client.post(url, files=files, data=form, headers=hdr(keys["read"])).status_code == 403


def test_a_test_in_alarm_on_an_axis_with_an_order_opens_no_second_one_and_a_round_trip_keeps_its_alert(env):
    client, svc, keys, axes, runner = env
    y, read = axes["y"].id, hdr(keys["read"])
    runner.backlash_um = 400.0  # the round trip finds ALARM first: its alert and its corrective order
    _measure(client, keys, y)
    (order,) = poll(lambda: client.get(f"{V1}/maintenance/orders?axis_id={y}", headers=read).json()["items"])
    assert order["opened_by_measurement_id"] is not None and order["opened_by_circular_test_id"] is None
    r = client.post(f"{V1}/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 300.0)),
                    headers=hdr(keys["operate"]))
    assert r.status_code == 201 and r.json()["decision"]["y"]["state"] == "ALARM"
    alerts = client.get(f"{V1}/alerts?axis_id={y}", headers=read).json()["items"]
    assert sorted((a["raised_by_circular_test_id"] is not None, a["active"]) for a in alerts) == [
        (False, True), (True, True)]  # each evidence its own alert
    orders = client.get(f"{V1}/maintenance/orders?axis_id={y}&state=all", headers=read).json()["items"]
    assert [o["id"] for o in orders] == [order["id"]]  # one active order per axis
    runner.backlash_um = 150.0  # a good round trip clears its own alert, not the test's
    _measure(client, keys, y)
    active = [a for a in client.get(f"{V1}/alerts?axis_id={y}", headers=read).json()["items"] if a["active"]]
    assert [a["raised_by_circular_test_id"] for a in active] == [r.json()["id"]]


def test_a_recording_at_the_servo_rate_is_posted_whole_while_other_bodies_keep_their_limit(env):
    client, svc, keys, axes, runner = env
    body = json.dumps(circle_body(rate_hz=1000.0)).encode()  # 1 kHz: about 38,000 samples
    assert len(body) > svc.settings.limits.max_body_bytes
    op = {**hdr(keys["operate"]), "Content-Type": "application/json"}
    r = client.post(f"{V1}/machines/{axes['y'].machine_id}/circles", content=body, headers=op)
    assert r.status_code == 201, r.text[:300]
    assert client.get(f"{V1}/circles/{r.json()['id']}", headers=hdr(keys["read"])).json()["test"]["passes"][0][
        "angle_deg"].__len__() > 15_000
    r = client.post(f"{V1}/alerts/1/ack", content=body, headers=op)  # any other route: the general limit
    assert r.status_code == 413 and "limits.max_body_bytes" in r.json()["detail"]


def test_a_test_in_warning_opens_a_condition_based_order_when_the_prognosis_dates_the_limit_within_the_horizon(env):
    from tests.api.rest.test_prognosis import bulk_history

    client, svc, keys, axes, runner = env
    y, read = axes["y"].id, hdr(keys["read"])
    _measure(client, keys, y)  # the round trip's 150 µm: OK (TBE 93 µm), opens nothing
    bulk_history(svc, y)  # b̄ = 200 + 2 (T - 20) + 0.02 d: at the worst-case 30 °C past the task's limit
    _measure(client, keys, y)
    st = client.get(f"{V1}/axes/{y}/status", headers=read).json()
    assert st["prognosis"]["limit_date"] is not None, st["prognosis"]
    assert client.get(f"{V1}/maintenance/orders?axis_id={y}&state=all", headers=read).json()["items"] == []
    r = client.post(f"{V1}/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 192.0)),
                    headers=hdr(keys["operate"]))
    d = r.json()["decision"]["y"]
    assert d["state"] == "WARNING" and d["warning_um"] < d["error_um"] < d["tolerance_um"], d
    assert r.json()["alerts"] == []  # WARNING raises no alert...
    (order,) = poll(lambda: client.get(f"{V1}/maintenance/orders?axis_id={y}", headers=read).json()["items"])
    assert order["kind"] == "condition_based" and order["opened_by_circular_test_id"] == r.json()["id"]  # ...an order
    assert order["due_at"][:16] == st["prognosis"]["limit_date"][:16] and order["alert_id"] is None

"""The maintenance REST API and `mebm maintenance`, with the injected runner:
keys and roles, a compensation verified against the compensated error, the summary of a
generated year with known repairs (JSON and CSV), the events' documents, and the CLI
against a real server."""

from __future__ import annotations

import csv
import io
import json
import socket
import threading
from datetime import datetime, timedelta, timezone

import pytest

from api.cli.main import main
from api.service.events import Event, order_document
from storage.db import OrderRequest, maintenance_repo, results_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.storage.db import factories as f
from tests.waiting import until

V1 = "/api/v1"


def _measure(svc, runner, axis_id, backlash_um):
    runner.backlash_um = backlash_um
    svc.trigger(axis_id, "test")
    assert svc.scheduler.idle(60)


def _order(client, keys, state="all"):
    return client.get(f"{V1}/maintenance/orders?state={state}", headers=hdr(keys["read"])).json()["items"]


def test_roles_and_a_compensation_verified_against_the_compensated_error(app_env, runner):
    client, svc, keys, axis_id = app_env
    _measure(svc, runner, axis_id, 150.0)
    assert _order(client, keys) == []
    _measure(svc, runner, axis_id, 260.0)
    (o,) = _order(client, keys, "active")
    assert o["kind"] == "corrective" and o["binding_task"] == "circle R200"
    alarm_id = o["opened_by_measurement_id"]
    body = {"kind": "compensation_loaded", "note": "LinuxCNC comp table",
            "compensation_measurement_id": alarm_id, "compensation_file": "vmc-850_y_m2.comp"}
    assert client.post(f"{V1}/axes/{axis_id}/repairs", json=body, headers=hdr(keys["read"])).status_code == 403
    assert client.post(f"{V1}/axes/{axis_id}/repairs", json={"kind": "glued"},
                       headers=hdr(keys["operate"])).status_code == 422
    r = client.post(f"{V1}/maintenance/orders/{o['id']}/cancel", json={"note": ""}, headers=hdr(keys["operate"]))
    assert r.status_code == 422 and "reason" in r.json()["detail"]
    r = client.post(f"{V1}/axes/{axis_id}/repairs", json=body, headers=hdr(keys["operate"]))
    assert r.status_code == 201, r.text
    assert r.json()["repair"]["compensation_measurement_id"] == alarm_id
    assert svc.scheduler.idle(60)  # the verification measurement: the mechanics unchanged (260 µm)
    done = client.get(f"{V1}/maintenance/orders/{o['id']}", headers=hdr(keys["read"])).json()
    assert done["state"] == "verified", done["verification"]
    assert done["verified_against"].startswith("compensated error: residual backlash")
    assert "table of measurement" in done["verified_against"] and "vmc-850_y_m2.comp" in done["verified_against"]
    assert done["verification"]["after"]["backlash_mean_um"] == pytest.approx(260.0, abs=3.0)
    reps = client.get(f"{V1}/axes/{axis_id}/repairs", headers=hdr(keys["read"])).json()["items"]
    assert [x["kind"] for x in reps] == ["compensation_loaded"]
    r = client.post(f"{V1}/maintenance/orders/{o['id']}/cancel", json={"note": "x"}, headers=hdr(keys["operate"]))
    assert r.status_code == 409 and "'verified'" in r.json()["detail"] and "final" in r.json()["detail"]
    assert client.get(f"{V1}/maintenance/orders/999", headers=hdr(keys["read"])).status_code == 404


def test_summary_of_a_generated_year_with_known_repairs(app_env):
    client, svc, keys, axis_id = app_env
    start = datetime(2025, 1, 1, tzinfo=timezone.utc)
    repair_days = (100.0, 190.0, 300.0)
    with session_scope(svc.factory) as s:
        results_repo.save_finished_cycle(s, f.finished(axis_id, 150.0, when=start))
        for k, d in enumerate(repair_days):
            opened = start + timedelta(days=d - 2.0)
            o, _ = maintenance_repo.open_order(s, OrderRequest(axis_id, "corrective", opened, "restore"))
            maintenance_repo.record_repair(s, axis_id, "preload_adjusted", by="bob",
                                           performed_at=start + timedelta(days=d))
            maintenance_repo.conclude_verification(s, o.id, passed=True, verification={"passed": True}, note="ok",
                                                   when=start + timedelta(days=d, hours=6))
        maintenance_repo.record_repair(s, axis_id, "lubricated", by="bob", performed_at=start + timedelta(days=200))
    until = (start + timedelta(days=365)).isoformat()
    d = client.get(f"{V1}/maintenance/summary", params={"until": until, "fixed_interval_days": 30},
                   headers=hdr(keys["read"])).json()
    (ax,) = d["axes"]
    assert ax["history_days"] == pytest.approx(365.0) and ax["repairs_called_by_error"] == 3
    assert ax["repairs_other"] == 1 and ax["orders_verified"] == 3
    assert ax["intervals_days"] == pytest.approx([100.0, 90.0, 110.0])
    assert ax["alarm_to_verified_days"] == pytest.approx([2.25, 2.25, 2.25])
    assert ax["fixed_interval_repairs"] == 12 and ax["repairs_saved"] == 9
    assert d["fleet"]["repairs_called_by_error"] == 3 and d["fleet"]["fixed_interval_repairs"] == 12
    r = client.get(f"{V1}/maintenance/summary", params={"until": until, "fixed_interval_days": 90, "format": "csv"},
                   headers=hdr(keys["read"]))
    assert r.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert [x["machine"] for x in rows] == ["vmc-850", "(fleet)"]
    assert rows[0]["repairs_called_by_error"] == "3" and rows[0]["fixed_interval_repairs"] == "4"
    assert rows[1]["repairs_saved"] == "1"


def test_order_events_carry_the_step_for_mqtt_webhooks(app_env, runner):
    client, svc, keys, axis_id = app_env
    seen = []
    sub = svc.events.subscribe("t", lambda ev: seen.append(ev) if ev.kind == "work_order_changed" else None)
    _measure(svc, runner, axis_id, 260.0)
    (o,) = _order(client, keys)
    client.post(f"{V1}/maintenance/orders/{o['id']}/ack", json={"note": "seen"}, headers=hdr(keys["operate"]))
    until(lambda: len(seen) >= 2, "the order's two events", 60.0)
    svc.events.unsubscribe(sub)
    docs = [order_document(ev) for ev in seen]
    assert [(x["from"], x["state"], x["by"]) for x in docs] == [(None, "open", "mebm"),
                                                               ("open", "acknowledged", "test-operate")]
    assert docs[1]["note"] == "seen" and docs[0]["machine"] == "vmc-850" and docs[0]["tbe_um"] > 45
    json.dumps(docs)  # as MQTT and webhooks send them
    assert isinstance(seen[0], Event) and seen[0].order.id == o["id"]


@pytest.fixture
def server(tmp_path):
    import uvicorn

    from api.rest import create_app
    from storage.db import config_repo

    runner = FakeRunner()
    app = create_app(make_settings(f"sqlite:///{tmp_path}/mebm.sqlite3", tmp_path), runner=runner)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    srv = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))
    th = threading.Thread(target=srv.run, kwargs={"sockets": [sock]}, daemon=True)
    th.start()
    until(lambda: srv.started, "the server's start", 60.0)
    svc = app.state.service
    keys = {}
    with session_scope(svc.factory) as s:
        for role in ("read", "operate"):
            keys[role] = config_repo.create_key(s, f"cli-{role}", role)[1]
        axis_id = config_repo.list_axes(s)[0].id
    yield f"http://127.0.0.1:{sock.getsockname()[1]}", svc, runner, keys, axis_id
    srv.should_exit = True
    th.join(10)


def test_cli_records_a_repair_and_shows_the_order_verified(server, capsys, tmp_path):
    url, svc, runner, keys, axis_id = server
    _measure(svc, runner, axis_id, 260.0)
    assert main(["maintenance", "orders", "--url", url, "--key", keys["read"], "--json"]) == 0
    (o,) = json.loads(capsys.readouterr().out)["items"]
    assert main(["maintenance", "repair", "--url", url, "--key", keys["read"], "--axis", str(axis_id),
                 "--kind", "nut_replaced"]) != 0
    assert "HTTP 403" in capsys.readouterr().err
    runner.backlash_um = 120.0  # the new nut
    assert main(["maintenance", "repair", "--url", url, "--key", keys["operate"], "--axis", str(axis_id),
                 "--kind", "nut_replaced", "--note", "new nut, preload class P2", "--wait-s", "60"]) == 0
    out = capsys.readouterr().out
    assert f"order {o['id']} on axis {axis_id}: verified (corrective)" in out
    assert "repaired -> verified" in out and "verified against the measured backlash" in out
    assert main(["maintenance", "summary", "--url", url, "--key", keys["read"], "--csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert rows[0]["repairs_called_by_error"] == "1" and rows[0]["orders_verified"] == "1"
    assert rows[0]["repairs_saved"] == "" and rows[0]["repairs_saved_note"].startswith("nothing to compare yet: 0.0 days")
    assert main(["maintenance", "summary", "--url", url, "--key", keys["read"]]) == 0
    assert ("saved, fleet: nothing to compare yet: no axis has a history of one fixed-plan period (90 days)"
            in capsys.readouterr().out)
    (tmp_path / "demo-keys.json").write_text(json.dumps({"operate": keys["operate"]}))
    assert main(["maintenance", "show", str(o["id"]), "--url", url, "--data-dir", str(tmp_path)]) == 0
    assert "new nut, preload class P2" in capsys.readouterr().out


def test_history_plots_mark_the_repairs(app_env, runner):
    from api.service.figures import plots

    client, svc, keys, axis_id = app_env
    for b in (150.0, 160.0):
        _measure(svc, runner, axis_id, b)
    before = client.get(f"{V1}/axes/{axis_id}/plots/backlash_trend.png", headers=hdr(keys["read"])).content
    r = client.post(f"{V1}/axes/{axis_id}/repairs", json={"kind": "screw_replaced"}, headers=hdr(keys["operate"]))
    assert r.status_code == 201 and r.json()["order"] is None  # no order: recorded, nothing to verify
    after = client.get(f"{V1}/axes/{axis_id}/plots/backlash_trend.png", headers=hdr(keys["read"])).content
    assert after[:8] == b"\x89PNG\r\n\x1a\n" and after != before
    t = [datetime(2026, 1, d, tzinfo=timezone.utc) for d in (1, 2, 3)]
    plain = plots.tbe_history({"c": (t, [30.0, 40.0, 20.0], [45.0] * 3)}, title="x")
    marked = plots.tbe_history({"c": (t, [30.0, 40.0, 20.0], [45.0] * 3)}, title="x",
                               repairs=[(datetime(2026, 1, 2, 12, tzinfo=timezone.utc), "nut_replaced")])
    assert plain != marked

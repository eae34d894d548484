"""The REST API with an injected cycle runner, on SQLite and PostgreSQL."""

from __future__ import annotations

import pytest

from tests.api.rest.conftest import hdr

V1 = "/api/v1"


def run_cycle(client, svc, keys, axis_id):
    r = client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
    assert r.status_code == 202, r.text
    assert svc.scheduler.idle(30)
    return r.json()


def test_every_endpoint_but_healthz_needs_a_key(app_env):
    client, svc, keys, axis_id = app_env
    assert client.get("/healthz").json()["database"] == "ok"
    for path in ("/metrics", f"{V1}/machines", f"{V1}/axes/{axis_id}/status", f"{V1}/alerts",
                 f"{V1}/axes/{axis_id}/plots/tbe_vs_backlash.png"):
        r = client.get(path)
        assert r.status_code == 401, path
        assert "key" in r.json()["detail"]
    assert client.get(f"{V1}/machines", headers=hdr("not-a-key-at-all")).status_code == 401
    assert client.get(f"{V1}/machines", headers={"Authorization": f"Bearer {keys['read']}"}).status_code == 200


def test_mes_key_reads_but_cannot_trigger_or_configure(app_env, runner):
    client, svc, keys, axis_id = app_env
    r = client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["read"]))
    assert r.status_code == 403 and "operate" in r.json()["detail"]
    assert runner.calls == 0
    body = {"tasks": [{"name": "c", "profile": "circle", "radius_mm": 50, "feed_mm_min": 500, "tolerance_um": 20}]}
    assert client.put(f"{V1}/axes/{axis_id}/tasks", json=body, headers=hdr(keys["operate"])).status_code == 403
    assert client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).status_code == 200


def test_status_before_any_measurement_is_unknown(app_env):
    client, svc, keys, axis_id = app_env
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["state"] == "UNKNOWN" and st["measured_at"] is None and st["age_s"] is None


def test_trigger_measure_status_measurement_and_trend(app_env, runner):
    client, svc, keys, axis_id = app_env
    runner.backlash_um, runner.temperature_c = 150.0, 18.0
    out = run_cycle(client, svc, keys, axis_id)
    mid = out["measurement"]["id"]
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["state"] == "OK" and st["measurement_id"] == mid
    assert st["backlash_mean_um"] == pytest.approx(150.0, abs=3)
    assert st["backlash_limit_um"] == pytest.approx(236.0, abs=0.1)
    assert st["backlash_reduction_needed_um"] == 0.0
    assert st["tasks"][0]["tolerance_um"] == 45.0 and st["tasks"][0]["tbe_um"] < 45.0
    assert st["temperature_c"] == 18.0 and 0 <= st["age_s"] < 60
    m = client.get(f"{V1}/measurements/{mid}", headers=hdr(keys["read"])).json()
    assert m["status"] == "ok" and m["uncertainty_um"] == 0.8
    assert set(m["result"]["lead"]) == {"positive", "negative"}
    assert len(m["curves"]["position_mm"]) == len(m["curves"]["backlash_um"]) > 100
    assert m["result"]["run_file"].endswith(".csv")
    for i, (b, t) in enumerate([(170.0, 22.0), (190.0, 26.0)]):
        runner.backlash_um, runner.temperature_c = b, t
        run_cycle(client, svc, keys, axis_id)
    tr = client.get(f"{V1}/axes/{axis_id}/trend", headers=hdr(keys["read"])).json()
    assert tr["points"] == 3 and tr["series"]["temperature_c"] == [18.0, 22.0, 26.0]
    assert tr["correlation"]["backlash_mean_um"]["temperature_c"] == pytest.approx(1.0, abs=0.02)
    assert set(tr["correlation"]) == {"backlash_mean_um", "e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um"}
    assert tr["thermal_model"]["beta_um_per_k"] == pytest.approx(5.0, abs=0.3)
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["backlash_mean_20c_um"] == pytest.approx(160.0, abs=3)
    page = client.get(f"{V1}/axes/{axis_id}/measurements?limit=2", headers=hdr(keys["read"])).json()
    assert page["total"] == 3 and len(page["items"]) == 2 and page["items"][0]["temperature_c"] == 26.0


def test_alert_raised_acknowledged_and_cleared(app_env, runner):
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 250.0
    run_cycle(client, svc, keys, axis_id)
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["state"] == "ALARM" and st["backlash_reduction_needed_um"] == pytest.approx(14.0, abs=3)
    (alert,) = client.get(f"{V1}/alerts", headers=hdr(keys["read"])).json()["items"]
    assert alert["active"] and alert["tbe_um"] > 45 and "236" in alert["message"]
    assert client.post(f"{V1}/alerts/{alert['id']}/ack", headers=hdr(keys["read"])).status_code == 403
    ack = client.post(f"{V1}/alerts/{alert['id']}/ack", headers=hdr(keys["operate"])).json()
    assert ack["acknowledged_by"] == "test-operate"
    runner.backlash_um = 200.0
    run_cycle(client, svc, keys, axis_id)
    assert client.get(f"{V1}/alerts?state=active", headers=hdr(keys["read"])).json()["total"] == 0
    (cleared,) = client.get(f"{V1}/alerts?state=cleared", headers=hdr(keys["read"])).json()["items"]
    assert cleared["cleared_at"] is not None and cleared["cleared_by_measurement_id"] is not None
    text = client.get("/metrics", headers=hdr(keys["read"])).text
    assert f'mebm_cycles_total{{axis_id="{axis_id}",status="ok"}} 2.0' in text
    assert "mebm_active_alerts_total 0.0" in text


def test_failed_cycle_is_recorded_with_reason(app_env, runner):
    client, svc, keys, axis_id = app_env
    runner.fail = "ControllerTimeoutError: no answer from modbus://127.0.0.1:1 within 2 s"
    run_cycle(client, svc, keys, axis_id)
    page = client.get(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()
    assert page["items"][0]["status"] == "failed" and "no answer" in page["items"][0]["failure_reason"]
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["last_cycle_status"] == "failed" and "no answer" in st["last_failure_reason"]
    assert 'mebm_cycles_failed_total{axis_id="%d"} 1.0' % axis_id in client.get("/metrics", headers=hdr(keys["read"])).text


def test_put_tasks_changes_the_status_at_once(app_env, runner):
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 200.0
    run_cycle(client, svc, keys, axis_id)
    body = {"tasks": [{"name": "fine circle", "profile": "circle", "radius_mm": 200, "feed_mm_min": 200,
                       "tolerance_um": 30},
                      {"name": "line", "profile": "line", "angle_deg": 30, "feed_mm_min": 1000, "tolerance_um": 80}]}
    r = client.put(f"{V1}/axes/{axis_id}/tasks", json=body, headers=hdr(keys["admin"]))
    assert r.status_code == 200, r.text
    assert [t["name"] for t in r.json()["tasks"]] == ["fine circle", "line"]
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["state"] == "ALARM" and st["binding_task"] == "fine circle"


@pytest.mark.parametrize("body, field", [
    ({"tasks": [{"name": "c", "profile": "circle", "feed_mm_min": 200, "tolerance_um": 45}]}, "radius_mm"),
    ({"tasks": [{"name": "c", "profile": "circle", "radius_mm": 200, "feed_mm_min": -1, "tolerance_um": 45}]},
     "feed_mm_min"),
    ({"tasks": [{"name": "c", "profile": "oval", "radius_mm": 1, "feed_mm_min": 1, "tolerance_um": 1}]}, "profile"),
    ({"tasks": []}, "tasks"),
])
def test_bad_input_is_422_naming_the_field(app_env, body, field):
    client, svc, keys, axis_id = app_env
    r = client.put(f"{V1}/axes/{axis_id}/tasks", json=body, headers=hdr(keys["admin"]))
    assert r.status_code == 422 and field in r.json()["detail"], r.text


def test_unknown_ids_are_404_and_bad_ids_422(app_env):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["admin"])
    for path in (f"{V1}/axes/9999/status", f"{V1}/measurements/9999", f"{V1}/machines/9999/axes",
                 f"{V1}/axes/9999/trend", f"{V1}/axes/9999/plots/backlash_trend.png"):
        assert client.get(path, headers=h).status_code == 404, path
    assert client.post(f"{V1}/alerts/9999/ack", headers=h).status_code == 404
    assert client.post(f"{V1}/axes/9999/measurements", headers=h).status_code == 404
    assert client.get(f"{V1}/axes/0/status", headers=h).status_code == 422
    assert client.get(f"{V1}/axes/99999999999/status", headers=h).status_code == 422
    assert client.get(f"{V1}/axes/{axis_id}/plots/nothing.png", headers=h).status_code == 422
    r = client.get(f"{V1}/alerts?state=maybe", headers=h)
    assert r.status_code == 422 and "state" in r.json()["detail"]


def test_plots_are_pngs(app_env, runner):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["read"])
    assert client.get(f"{V1}/axes/{axis_id}/plots/backlash_profile.png", headers=h).content[:4] == b"\x89PNG"
    runner.backlash_um = 240.0
    run_cycle(client, svc, keys, axis_id)
    run_cycle(client, svc, keys, axis_id)
    for name in ("backlash_profile", "lead_deviation", "tbe_vs_backlash", "tbe_history", "backlash_trend"):
        r = client.get(f"{V1}/axes/{axis_id}/plots/{name}.png", headers=h)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png", name
        assert r.content[:4] == b"\x89PNG" and len(r.content) > 10000, name


def test_keys_admin(app_env):
    client, svc, keys, axis_id = app_env
    r = client.post(f"{V1}/keys", json={"name": "mes-2", "role": "read"}, headers=hdr(keys["admin"]))
    assert r.status_code == 201
    new = r.json()
    assert client.get(f"{V1}/machines", headers=hdr(new["key"])).status_code == 200
    assert client.delete(f"{V1}/keys/{new['id']}", headers=hdr(keys["admin"])).status_code == 200
    assert client.get(f"{V1}/machines", headers=hdr(new["key"])).status_code == 401
    assert client.get(f"{V1}/keys", headers=hdr(keys["operate"])).status_code == 403


def test_schedule_and_new_axis(app_env):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["admin"])
    r = client.put(f"{V1}/axes/{axis_id}/schedule", json={"cron": "0 6 * * *"}, headers=h)
    assert r.status_code == 200 and r.json()["schedule"]["next_run_at"] is not None
    for bad in ("61 * * * *", "0 0 31 2 *"):  # invalid; valid but never fires
        r = client.put(f"{V1}/axes/{axis_id}/schedule", json={"cron": bad}, headers=h)
        assert r.status_code == 422 and "cron" in r.json()["detail"], bad
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    body = {"name": "x", "transmission_mm_per_rev": 10, "screw_lead_mm": 10, "position_gain_per_s": 20,
            "travel_mm": [0, 500], "controller_url": "modbus://10.0.0.5:502",
            "tasks": [{"name": "c", "profile": "circle", "radius_mm": 50, "feed_mm_min": 1000, "tolerance_um": 20}]}
    r = client.post(f"{V1}/machines/{machine_id}/axes", json=body, headers=h)
    assert r.status_code == 201, r.text
    assert client.post(f"{V1}/machines/{machine_id}/axes", json=body, headers=h).status_code == 409
    assert len(client.get(f"{V1}/machines/{machine_id}/axes", headers=h).json()) == 2
    # a controller URL a cycle would refuse is refused on create, naming the option
    for url, says in (("modbus://10.0.0.5:502?trigger=sometimes", "trigger"),
                      ("modbus://10.0.0.5:502?speed=9", "unknown option"),
                      ("modbus://10.0.0.5:502?device_id=300", "device_id"),
                      ("modbus://10.0.0.5:502?trigger=active&rest_s=2", "trigger=passive only"),
                      ("modbus+rtu:///dev/ttyUSB0?parity=X", "parity"),
                      ("modbus://10.0.0.5:502?profile=/nonexistent/profile.toml", "profile")):
        r = client.post(f"{V1}/machines/{machine_id}/axes", json={**body, "name": "z", "controller_url": url}, headers=h)
        assert r.status_code == 422 and "controller_url" in r.json()["detail"] and says in r.json()["detail"], (url, r.text)
    assert len(client.get(f"{V1}/machines/{machine_id}/axes", headers=h).json()) == 2


def test_backlash_outside_the_tbe_model_is_stored_without_a_decision(app_env, runner):
    client, svc, keys, axis_id = app_env
    body = {"tasks": [{"name": "tiny fast circle", "profile": "circle", "radius_mm": 0.5, "feed_mm_min": 2000,
                       "tolerance_um": 5}]}
    assert client.put(f"{V1}/axes/{axis_id}/tasks", json=body, headers=hdr(keys["admin"])).status_code == 200
    runner.backlash_um = 300.0  # Eq. 8 does not hold there for this task
    out = run_cycle(client, svc, keys, axis_id)
    m = client.get(f"{V1}/measurements/{out['measurement']['id']}", headers=hdr(keys["read"])).json()
    assert m["status"] == "ok" and m["result"]["backlash_mean_um"] == pytest.approx(300, abs=3)
    assert m["result"]["tbe"] == []
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["state"] == "UNKNOWN" and "cannot evaluate" in st["message"]
    r = client.get(f"{V1}/axes/{axis_id}/plots/tbe_vs_backlash.png", headers=hdr(keys["read"]))
    assert r.status_code == 200 and r.content[:4] == b"\x89PNG"


def test_status_carries_the_uncertainty_and_the_decision_rule(app_env, runner):
    # no more bare 'uncertainty_um: 0.0'; the rule that decided is named
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 200.0
    run_cycle(client, svc, keys, axis_id)
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
    assert st["decision_rule"] == "guarded" and "guarded decision rule" in st["message"]
    assert st["backlash_mean_uncertainty_um"] > 0
    for key in ("e_p", "v_u", "v_300", "v_2pi"):
        assert st[f"{key}_uncertainty_um"] > 0
    assert st["outliers_removed"] == 0
    (task,) = st["tasks"]
    assert task["decision_rule"] == "guarded" and task["tbe_uncertainty_um"] > 0
    assert task["backlash_limit_uncertainty_um"] > 0


def test_a_truncated_json_body_is_422_naming_the_position_and_the_fault(app_env):
    client, svc, keys, axis_id = app_env
    body = '{"name": "vmc-2",\n   "description": "second mill'  # cut short inside a string on line 2
    r = client.post(f"{V1}/machines", content=body, headers={**hdr(keys["admin"]), "Content-Type": "application/json"})
    assert r.status_code == 422
    msg = ("not valid JSON: Unterminated string starting at line 2, column 19 (character 36): "
           "the body is cut short or not JSON; send the whole JSON document")
    assert r.json() == {"detail": f"body: {msg}",
                        "errors": [{"field": "body", "message": msg, "line": 2, "column": 19, "position": 36}]}

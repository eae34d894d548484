"""The maintenance loop end to end on the built-in simulated Modbus controller:
the chain wears (the simulator's wear, on its own clock), a measurement finds ALARM, the
service opens a corrective order, a read key cannot record a repair, an operate key
records one that does not restore the play (lubrication: the verification fails and the
order goes back to open with both sets of figures), then one that does (the preload,
which the simulator takes through its repair register): the verification measurement
passes and the order is verified. The database is checked at the end: the order's
transitions, both repairs and the measurements before and after them."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from acquisition.sim.wear import Wear
from api.rest import create_app
from api.service.config.settings import MaintenanceSettings, Settings, SimulatorSettings, demo_axis
from storage.db import integrity_problems, maintenance_repo, results_repo, session_scope
from tests.waiting import poll, until
from tests.clock import ManualClock

V1 = "/api/v1"
pytestmark = pytest.mark.slow
WEAR_UM_PER_DAY = 10.0


@pytest.fixture
def live(engine, db_url, tmp_path):  # noqa: ARG001 - engine empties the database
    axis = demo_axis(travel_mm=(0.0, 200.0), interval_s=3600.0)
    # no wear until the test installs its own, on a clock it steps: with the simulator's wear
    # on wall time (10 µm per second here), a start-up measurement that a loaded host delays
    # by 5 s finds ALARM and opens an order before the test begins
    sim = SimulatorSettings(time_scale=20.0, temperature_mean_c=20.0, temperature_amplitude_c=0.0,
                            backlash_um_at_20c=190.0, wear_um_per_day=0.0, utility_days_per_s=1.0)
    settings = Settings(data_dir=tmp_path, database_url=db_url, machines=((axis.machine, "loopback"),), axes=(axis,),
                        simulator=sim, demo_keys=True, catch_up_missed=False,
                        maintenance=MaintenanceSettings(verify_at="now"))
    app = create_app(settings)  # the production runner: Modbus driver + acquisition cycle
    with TestClient(app) as client:
        yield client, app.state.service


def test_wear_alarm_order_repair_verification_verified(live):
    client, svc = live
    keys = svc.report.demo_keys
    read, operate = {"X-API-Key": keys["read"]}, {"X-API-Key": keys["operate"]}
    axis_id = next(iter(svc.simulators))
    sim = svc.simulators[axis_id]
    clock = ManualClock()
    sim.twin.wear = Wear(WEAR_UM_PER_DAY, 1.0, clock=clock)  # the chain's use, stepped by the test
    events = []
    sub = svc.events.subscribe("test", lambda ev: events.append(ev) if ev.kind == "work_order_changed" else None)

    def measurements():
        return client.get(f"{V1}/axes/{axis_id}/measurements?limit=100", headers=read).json()["items"]

    def measure(trigger="manual"):
        n = sum(1 for m in measurements() if m["status"] in ("ok", "failed"))
        if trigger == "manual":
            assert client.post(f"{V1}/axes/{axis_id}/measurements", headers=operate).status_code == 202
        assert poll(lambda: sum(1 for m in measurements() if m["status"] in ("ok", "failed")) > n)
        m = measurements()[0]
        assert m["status"] == "ok", m
        return m

    def orders(state="all"):
        return client.get(f"{V1}/maintenance/orders?state={state}", headers=read).json()["items"]

    # new chain: OK, no order (the start-up catch-up measurement may come first)
    poll(lambda: measurements() and measurements()[-1]["status"] in ("ok", "failed"))
    def status():
        return client.get(f"{V1}/axes/{axis_id}/status", headers=read).json()

    measure()
    assert status()["state"] == "OK" and status()["work_order"] is None
    assert orders() == []

    # six utility days of wear: +60 µm, past the 236 µm limit -> ALARM and a corrective order
    clock.t = 6.0
    alarm_m = measure()
    assert alarm_m["state"] == "ALARM"
    (order,) = poll(lambda: orders("active"))
    assert order["kind"] == "corrective" and order["state"] == "open"
    assert order["opened_by_measurement_id"] == alarm_m["id"] and order["alert_id"] is not None
    assert order["backlash_um"] == pytest.approx(250.0, abs=5.0) and order["tbe_um"] > order["tolerance_um"]
    assert f"Restore the backlash below {order['restore_below_um']:.1f} µm" in order["recommendation"]
    assert order["restore_below_um"] < order["backlash_limit_um"]
    # the status an MES polls names the order once the service has published it, which it
    # does right after the order's commit (a reader between the two gets the cached status)
    wo = until(lambda: status()["work_order"], "the status naming the open order")
    assert (wo["id"], wo["kind"], wo["state"], wo["href"]) == (order["id"], "corrective", "open",
                                                               f"{V1}/maintenance/orders/{order['id']}")
    assert wo["restore_below_um"] == order["restore_below_um"] and wo["recommendation"] == order["recommendation"]
    # another ALARM does not open a second order
    measure()
    assert len(orders("all")) == 1

    # an MES key cannot record a repair; a refused step says why
    body = {"kind": "lubricated", "note": "way lube refilled"}
    assert client.post(f"{V1}/axes/{axis_id}/repairs", json=body, headers=read).status_code == 403
    assert client.post(f"{V1}/maintenance/orders/{order['id']}/ack", headers=read).status_code == 403
    r = client.post(f"{V1}/maintenance/orders/{order['id']}/ack", json={"note": "on it"}, headers=operate)
    assert r.status_code == 200 and r.json()["state"] == "acknowledged"
    assert status()["work_order"]["state"] == "acknowledged"  # the step shows at once (the cache is invalidated)
    r = client.post(f"{V1}/maintenance/orders/{order['id']}/ack", headers=operate)
    assert r.status_code == 409 and "'acknowledged'" in r.json()["detail"]

    # lubrication does not take up play: the verification fails, the order is open again with the figures
    r = client.post(f"{V1}/axes/{axis_id}/repairs", json=body, headers=operate)
    assert r.status_code == 201, r.text
    assert r.json()["order"]["state"] == "repaired" and r.json()["repair"]["before_measurement_id"] > alarm_m["id"]
    back = poll(lambda: [o for o in orders("open") if o["verification"]])
    assert back, orders()
    failed = back[0]
    assert failed["verification"]["passed"] is False and failed["transitions"][-1]["figures"]["after"]
    assert failed["transitions"][-1]["to"] == "open" and failed["transitions"][-1]["by"] == "mebm"
    assert failed["verification"]["after"]["backlash_mean_um"] == pytest.approx(250.0, abs=5.0)

    # the nut re-preloaded: the simulator's wear is restored through its repair register
    r = client.post(f"{V1}/axes/{axis_id}/repairs", headers=operate,
                    json={"kind": "preload_adjusted", "note": "nut preload restored, 2 shims"})
    assert r.status_code == 201, r.text
    done = poll(lambda: orders("verified"))
    assert done, orders()
    v = done[0]["verification"]
    assert v["passed"] is True and v["against"] == "measured backlash"
    assert v["after"]["backlash_mean_um"] == pytest.approx(190.0, abs=5.0)
    assert v["changes"]["backlash_mean_um"]["change"] < -40 and v["changes"]["backlash_mean_um"]["significant"]
    assert sim.twin.wear.repairs == 1
    assert orders("active") == []
    assert poll(lambda: status()["work_order"] is None)  # published after the verification's commit
    assert status()["state"] == "OK"

    # the prognosis now fits only the measurements after the last repair
    p = client.get(f"{V1}/axes/{axis_id}/prognosis", headers=read).json()
    assert p["fitted_since_repair"] is not None and p["rows_used"] == 1 and p["rows_total"] == 1

    # the database: transitions, repairs, the measurements before and after each repair
    with session_scope(svc.factory) as s:
        o = maintenance_repo.get_order(s, done[0]["id"])
        _, cycles = results_repo.list_measurements(s, axis_id, limit=100)
    assert [(t.from_state, t.to_state) for t in o.transitions] == [
        (None, "open"), ("open", "acknowledged"), ("acknowledged", "repaired"), ("repaired", "open"),
        ("open", "repaired"), ("repaired", "verified")]
    assert [t.by for t in o.transitions] == ["mebm", "demo-operate", "demo-operate", "mebm", "demo-operate", "mebm"]
    assert all(t.at is not None for t in o.transitions) and o.transitions[1].note == "on it"
    assert [r.kind for r in o.repairs] == ["lubricated", "preload_adjusted"]
    by_id = {c.id: c for c in cycles}
    verifications = [c for c in cycles if c.trigger == "verification"]
    assert len(verifications) == 2 and all(c.status == "ok" for c in verifications)
    before, after = by_id[o.repairs[1].before_measurement_id], by_id[o.verification_measurement_id]
    assert before.trigger == "verification" and before.backlash_mean_um > 240  # the failed verification's
    assert after.trigger == "verification" and after.backlash_mean_um < 200 and after.state == "OK"
    assert o.verification["before"]["measurement_id"] == before.id
    # every step went out on the internal event source, which MQTT, webhooks and MTConnect consume
    assert poll(lambda: len(events) >= 6)
    assert [ev.order.state for ev in events] == ["open", "acknowledged", "repaired", "open", "repaired", "verified"]
    svc.events.unsubscribe(sub)
    assert integrity_problems(svc.engine) == []

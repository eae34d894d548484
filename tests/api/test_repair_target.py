"""One repair target for an axis in ALARM: the alert, the work order, the status body,
MTConnect and OPC UA all name the same backlash to restore the chain below, the warning
level (the backlash limit times the warning fraction), and say why."""

from __future__ import annotations

import asyncio
import re
import uuid
from html import unescape

import pytest
from asyncua import Client
from fastapi.testclient import TestClient
from lxml import etree

from api.rest import create_app
from api.service.config.settings import OpcuaSettings, demo_axis
from storage.db import config_repo, session_scope
from tests.api.opcua.test_opcua import mebm_namespace
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.api.ui.test_maintenance_forms import sign_in
from tests.waiting import until

V1 = "/api/v1"
NS = {"m": "urn:mtconnect.org:MTConnectStreams:2.4", "x": "urn:mebm:MTConnectStreams:2.4"}
EXPLANATION = ("below the warning level, 90 % of the largest permissible backlash 236.0 µm, "
               "so that the repaired axis does not warn again at once")


@pytest.fixture
def alarm(tmp_path):
    axis = demo_axis(travel_mm=(0.0, 200.0), interval_s=3600.0)
    settings = make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path, machines=((axis.machine, "demo"),),
                             axes=(axis,), opcua=OpcuaSettings(enabled=True, endpoint="opc.tcp://127.0.0.1:0/mebm/"))
    app = create_app(settings, runner=FakeRunner(backlash_um=250.0))  # past the demo task's 236.0 µm limit
    with TestClient(app) as client:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, f"read-{uuid.uuid4().hex[:6]}", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        before = app.state.opcua.updates
        svc.scheduler.request(axis_id, "manual")
        assert svc.scheduler.idle(30)
        until(lambda: app.state.opcua.updates > before, "the OPC UA update")
        yield client, {"X-API-Key": key}, axis_id, app.state.opcua.endpoint, axis.machine


async def _opcua_restore_below(endpoint: str, machine: str) -> tuple[float, float]:
    async with Client(endpoint, timeout=10) as c:
        idx = await mebm_namespace(c)
        axis = await c.nodes.objects.get_child([f"{idx}:Machines", f"{idx}:{machine}", f"{idx}:y"])
        target = await (await axis.get_child(f"{idx}:RestoreBelow")).read_value()
        limit = await (await axis.get_child(f"{idx}:BacklashLimit")).read_value()
        return target, limit


def test_alert_order_status_mtconnect_and_opcua_name_one_repair_target(alarm):
    client, key, axis_id, endpoint, machine = alarm
    status = client.get(f"{V1}/axes/{axis_id}/status", headers=key).json()
    assert status["state"] == "ALARM"
    target_um = status["restore_below_um"]
    assert target_um == pytest.approx(0.9 * status["backlash_limit_um"]) and target_um == pytest.approx(212.4, abs=0.1)
    assert status["restore_below_explanation"] == EXPLANATION
    figure = f"{target_um:.1f} µm"

    (alert,) = client.get(f"{V1}/alerts?state=active", headers=key).json()["items"]
    assert f"restore the backlash below {figure} ({EXPLANATION})" in alert["message"]
    assert status["message"] == alert["message"]

    (order,) = until(lambda: client.get(f"{V1}/maintenance/orders?state=active", headers=key).json()["items"],
                     "the corrective work order")
    order = client.get(f"{V1}/maintenance/orders/{order['id']}", headers=key).json()
    assert order["restore_below_um"] == pytest.approx(target_um)
    assert order["restore_below_explanation"] == EXPLANATION
    assert f"Restore the backlash below {figure} ({EXPLANATION})." in order["recommendation"]
    wo = client.get(f"{V1}/axes/{axis_id}/status", headers=key).json()["work_order"]
    assert wo["restore_below_um"] == pytest.approx(target_um) and wo["restore_below_explanation"] == EXPLANATION

    doc = etree.fromstring(client.get("/mtconnect/current").content)
    (mt,) = doc.iterfind(".//x:RestoreBelow", NS)
    assert float(mt.text) * 1000.0 == pytest.approx(target_um, abs=1e-3)  # MILLIMETER

    ua_target, ua_limit = asyncio.run(_opcua_restore_below(endpoint, machine))
    assert ua_target == pytest.approx(target_um) and ua_limit == pytest.approx(status["backlash_limit_um"])

    sign_in(client, key["X-API-Key"])
    page = unescape(client.get(f"/ui/axes/{axis_id}").text)
    assert re.search(rf'id="repair-target"[^>]*>below {re.escape(figure)}<', page)
    assert f"Repair target: {EXPLANATION}." in page
    assert f"Restore the backlash below <strong>{figure}</strong> ({EXPLANATION})." in page

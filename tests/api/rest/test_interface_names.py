"""Two machines (or two axes of one machine) whose names map to one MQTT topic level would
publish under one topic with one client id: the second is refused where it is created
(REST, dashboard, configuration file), naming the first."""

from __future__ import annotations

from html import unescape

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError
from storage.db import ConflictError, config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings

V1 = "/api/v1"
AXIS = {"transmission_mm_per_rev": 10, "screw_lead_mm": 10, "position_gain_per_s": 20, "travel_mm": [0, 500],
        "controller_url": "modbus://10.0.0.5:502"}


def test_rest_refuses_a_machine_whose_name_maps_to_the_topic_of_another_naming_it(client, app_env):
    h = hdr(app_env[2]["admin"])
    assert client.post(f"{V1}/machines", json={"name": "m a"}, headers=h).status_code == 201
    for twin in ("m_a", "m  a", "m a_", "m_a "):
        r = client.post(f"{V1}/machines", json={"name": twin}, headers=h)
        assert r.status_code == 409, (twin, r.text)
        assert "'m a'" in r.json()["detail"] and "m_a" in r.json()["detail"], r.text
    assert client.post(f"{V1}/machines", json={"name": "m-a"}, headers=h).status_code == 201  # another topic
    names = [m["name"] for m in client.get(f"{V1}/machines", headers=h).json()]
    assert names.count("m a") == 1 and "m-a" in names and "m_a" not in names


def test_rest_refuses_an_axis_whose_name_maps_to_the_topic_of_another_of_its_machine(client, app_env):
    h = hdr(app_env[2]["admin"])
    first = client.post(f"{V1}/machines", json={"name": "lathe"}, headers=h).json()["id"]
    second = client.post(f"{V1}/machines", json={"name": "mill"}, headers=h).json()["id"]
    assert client.post(f"{V1}/machines/{first}/axes", json={**AXIS, "name": "x1"}, headers=h).status_code == 201
    r = client.post(f"{V1}/machines/{first}/axes", json={**AXIS, "name": "x1_"}, headers=h)
    assert r.status_code == 409 and "'x1'" in r.json()["detail"] and "lathe" in r.json()["detail"], r.text
    # another machine's axis has topics of its own
    assert client.post(f"{V1}/machines/{second}/axes", json={**AXIS, "name": "x1_"}, headers=h).status_code == 201


@pytest.mark.parametrize("machines, where, other", [
    ([{"name": "m a"}, {"name": "m_a"}], "machines[1].name", "'m a'"),
    ([{"name": "m", "axes": [{"name": "y2"}, {"name": "y2_"}]}], "machines[0].axes[1].name", "'y2'"),
])
def test_the_configuration_file_refuses_names_that_share_a_topic_at_load(machines, where, other):
    axis = {k: v for k, v in AXIS.items() if k != "controller_url"}
    doc = {"machines": [{**m, "axes": [{**axis, **a} for a in m.get("axes", [])]} for m in machines]}
    with pytest.raises(ConfigError) as err:
        parse_settings(doc)
    assert str(err.value).startswith(where) and other in str(err.value), err.value


def test_the_configuration_file_keeps_names_that_map_to_distinct_topics():
    axis = {k: v for k, v in AXIS.items() if k != "controller_url"}
    doc = {"machines": [{"name": "m a", "axes": [{**axis, "name": "y"}]}, {"name": "m-a", "axes": [{**axis, "name": "y"}]}]}
    assert [m for m, _ in parse_settings(doc).machines] == ["m a", "m-a"]


def test_a_configured_machine_whose_name_meets_a_stored_one_stops_the_start_naming_it(tmp_path):
    url = f"sqlite:///{tmp_path}/db.sqlite3"
    with TestClient(create_app(make_settings(url, tmp_path), runner=FakeRunner())) as c:
        with session_scope(c.app.state.service.factory) as s:
            config_repo.create_machine(s, "m a")
    clashing = make_settings(url, tmp_path, machines=(("m_a", ""),), axes=())
    with pytest.raises(ConflictError, match="'m a'"):
        with TestClient(create_app(clashing, runner=FakeRunner())):
            pass


def test_the_dashboard_refuses_a_machine_whose_name_maps_to_the_topic_of_another_naming_it(tmp_path):
    from tests.api.ui.test_maintenance_forms import sign_in

    with TestClient(create_app(make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path),
                               runner=FakeRunner())) as c:
        with session_scope(c.app.state.service.factory) as s:
            admin = config_repo.create_key(s, "ui-admin", "admin")[1]
        csrf = sign_in(c, admin)
        first = c.post("/ui/config/machines", data={"name": "m a", "description": "", "csrf": csrf})
        assert first.status_code == 200 and "machine 'm a' added" in unescape(first.text)
        twin = c.post("/ui/config/machines", data={"name": "m_a", "description": "", "csrf": csrf})
        assert twin.status_code == 409
        assert "as the machine 'm a' does already" in unescape(twin.text)
        with session_scope(c.app.state.service.factory) as s:
            assert [m.name for m in config_repo.list_machines(s)].count("m_a") == 0

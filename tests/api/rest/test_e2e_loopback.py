"""The whole loop on loopback: the scheduler starts cycles on the built-in simulated
Modbus controller (a real pymodbus server on 127.0.0.1, a free port), results land
in the database, status and trend answer, an alert is raised when the simulated
backlash is raised past the 236 µm limit and cleared when it is lowered, and an MES
(read) key can read but not trigger."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.settings import Settings, SimulatorSettings, demo_axis
from storage.db import config_repo, integrity_problems, session_scope
from storage.dataset import read_dataset
from tests.waiting import poll

V1 = "/api/v1"
pytestmark = pytest.mark.slow


@pytest.fixture
def live(engine, db_url, tmp_path):  # noqa: ARG001 - engine empties the database
    axis = demo_axis(travel_mm=(0.0, 200.0), interval_s=2.0)
    sim = SimulatorSettings(time_scale=20.0, temperature_mean_c=20.0, temperature_amplitude_c=0.0,
                            backlash_um_at_20c=226.0)
    settings = Settings(data_dir=tmp_path, database_url=db_url, machines=((axis.machine, "loopback"),), axes=(axis,),
                        simulator=sim, demo_keys=True)
    app = create_app(settings)  # the production runner: Modbus driver + acquisition cycle
    with TestClient(app) as client:
        yield client, app.state.service


def test_scheduler_simulator_database_status_trend_alert(live):
    client, svc = live
    keys = svc.report.demo_keys
    read = {"X-API-Key": keys["read"]}
    axis_id = next(iter(svc.simulators))
    sim = svc.simulators[axis_id]
    assert sim.url.startswith("modbus://127.0.0.1:")

    def ok_count():
        page = client.get(f"{V1}/axes/{axis_id}/measurements?status=ok", headers=read).json()
        return page["total"]

    assert poll(lambda: ok_count() >= 1), client.get(f"{V1}/axes/{axis_id}/measurements", headers=read).json()
    # the status is published just after the cycle's commit (StatusCache.prepare): a list read
    # in between sees the cycle before the status does (seen on a loaded machine)
    def measured_status():
        body = client.get(f"{V1}/axes/{axis_id}/status", headers=read).json()
        return body if body["measurement_id"] is not None else None

    st = poll(measured_status, 5.0)
    assert st["backlash_mean_um"] == pytest.approx(226.0, abs=4.0)
    assert st["state"] == "WARNING" and st["temperature_c"] == pytest.approx(20.0, abs=0.05)
    assert st["backlash_limit_um"] == pytest.approx(236.0, abs=0.1)

    # an MES reads but cannot move the axis
    assert client.post(f"{V1}/axes/{axis_id}/measurements", headers=read).status_code == 403

    sim.twin.backlash_offset_um = 30.0  # wear the chain past the limit
    n = ok_count()
    assert poll(lambda: client.get(f"{V1}/alerts", headers=read).json()["total"] == 1)
    (alert,) = client.get(f"{V1}/alerts", headers=read).json()["items"]
    assert alert["backlash_um"] == pytest.approx(256.0, abs=4.0) and alert["tbe_um"] > 45.0
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=read).json()
    assert st["state"] == "ALARM" and st["active_alert_id"] == alert["id"]
    assert st["backlash_reduction_needed_um"] == pytest.approx(20.0, abs=4.0)

    sim.twin.backlash_offset_um = -40.0  # the maintenance team re-preloads the nut
    assert poll(lambda: client.get(f"{V1}/alerts?state=cleared", headers=read).json()["total"] == 1)
    assert client.get(f"{V1}/alerts?state=active", headers=read).json()["total"] == 0
    assert client.get(f"{V1}/axes/{axis_id}/status", headers=read).json()["state"] == "OK"

    tr = client.get(f"{V1}/axes/{axis_id}/trend", headers=read).json()
    assert tr["points"] >= n + 2 and max(tr["series"]["backlash_mean_um"]) > 250
    m = client.get(f"{V1}/measurements/{tr['series']['measurement_id'][-1]}", headers=read).json()
    assert m["result"]["lead"]["positive"]["v_2pi_um"] > 0 and len(m["curves"]["backlash_um"]) > 100
    # every good cycle's raw run is in the dataset folder
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    ds = read_dataset(svc.executor.dataset_folder(axis))
    assert len(ds.runs) >= tr["points"]
    svc.scheduler.stop()
    assert integrity_problems(svc.engine) == []


def test_the_demo_axis_budget_keeps_the_scale_and_the_thermometer_and_the_page_lists_them(live):
    """The simulated encoders are perfect: U(b̄) still holds the scale's accuracy and the
    thermometer's tolerance, and the status body and the axis page list every component."""
    from html import unescape

    from tests.api.ui.test_maintenance_forms import sign_in

    client, svc = live
    read = {"X-API-Key": svc.report.demo_keys["read"]}
    axis_id = next(iter(svc.simulators))

    def measured_status():
        body = client.get(f"{V1}/axes/{axis_id}/status", headers=read).json()
        return body if body["measurement_id"] is not None else None

    st = poll(measured_status)
    budget = st["uncertainty_budget"]["backlash_mean"]
    comp = {c["name"]: c for c in budget["components"]}
    # the demo's glass scale, ±1 µm short-range, rectangular; a Pt100 of class B at the shop's 20 °C
    assert comp["scale"]["standard_um"] == pytest.approx(1 / 3**0.5)
    assert comp["temperature"]["standard_um"] > 0 and "class B ±0.40 °C at 20.0 °C" in comp["temperature"]["note"]
    assert st["backlash_mean_uncertainty_um"] >= 2 * comp["scale"]["standard_um"] > 1.0
    for c in budget["components"]:
        assert c["standard_um"] > 0 or c["note"].startswith("0: "), c
    ep = {c["name"]: c for c in st["uncertainty_budget"]["positive.e_p"]["components"]}
    # over the 200 mm travel the class's ±5 µm/m is no more than the short-range ±1 µm
    assert ep["scale"]["standard_um"] == pytest.approx(1 / 3**0.5) and "short-range" in ep["scale"]["note"]
    assert ep["temperature"]["standard_um"] > 0.1 and "the useful travel" in ep["temperature"]["note"]
    assert st["tasks"][0]["tbe_uncertainty_um"] > 0.05
    axis = client.get(f"{V1}/axes/{axis_id}", headers=read).json()
    assert (axis["scale_accuracy_um"], axis["thermometer_class"]) == (1.0, "B")

    sign_in(client, svc.report.demo_keys["read"])
    html = unescape(client.get(f"/ui/axes/{axis_id}").text)
    assert f"± {st['backlash_mean_uncertainty_um']:.1f} µm" in html
    table = html[html.index('data-quantity="backlash_mean"'):]
    table = table[:table.index("</table>")]
    assert '<tr data-component="scale"><td>scale</td><td class="num">0.577</td>' in table
    assert "linear scale short-range accuracy: ±1 µm, rectangular" in table
    assert 'data-component="temperature"' in table and "Pt100 class B" in table

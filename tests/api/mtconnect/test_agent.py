"""The MTConnect agent under /mtconnect, checked with parts we did not write:
the official MTConnect 2.4 XSDs (../shared/mtconnect-schemas/: Devices and Error with
xmlschema's XSD 1.1 validator, Streams and Error with libxml2 through lxml, as that
folder's README says), and the pymtconnect client library over a real HTTP server.
SQLite only: the agent reads the database through the service like REST does."""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import threading
import uuid
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from lxml import etree

from api.rest import create_app
from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError, MtconnectSettings
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.waiting import until

SCHEMAS = Path(__file__).resolve().parents[4] / "shared" / "mtconnect-schemas"
EXTENSION = Path(__file__).resolve().parents[3] / "api" / "mtconnect" / "mebm_streams_2.4.xsd"
NS = {"m": "urn:mtconnect.org:MTConnectStreams:2.4", "x": "urn:mebm:MTConnectStreams:2.4",
      "d": "urn:mtconnect.org:MTConnectDevices:2.4", "e": "urn:mtconnect.org:MTConnectError:2.4"}
JSON = {"Accept": "application/json"}


class Schemas:
    """The official 2.4 XSDs, loaded once per test process."""

    def __init__(self, tmp: Path):
        import xmlschema

        self.devices = xmlschema.XMLSchema11(str(SCHEMAS / "MTConnectDevices_2.4.xsd"))
        self.error_11 = xmlschema.XMLSchema11(str(SCHEMAS / "MTConnectError_2.4.xsd"))
        # the x: observations are declared by our extension schema, which imports the
        # official Streams schema from beside it
        shutil.copy(SCHEMAS / "MTConnectStreams_2.4.xsd", tmp)
        shutil.copy(EXTENSION, tmp)
        self.streams = etree.XMLSchema(etree.parse(str(tmp / EXTENSION.name)))
        self.error = etree.XMLSchema(etree.parse(str(SCHEMAS / "MTConnectError_2.4.xsd")))

    def assets_ok(self, body: bytes) -> etree._Element:
        import xmlschema

        # Assets loads in xmlschema only leniently, and libxml2 cannot compile it (the README)
        schema = xmlschema.XMLSchema11(str(SCHEMAS / "MTConnectAssets_2.4.xsd"), validation="lax")
        schema.validate(body.decode())
        return etree.fromstring(body)

    def streams_ok(self, body: bytes) -> etree._Element:
        doc = etree.fromstring(body)
        assert self.streams.validate(doc), self.streams.error_log
        return doc

    def devices_ok(self, body: bytes) -> etree._Element:
        self.devices.validate(body.decode())  # raises naming the fault
        return etree.fromstring(body)

    def error_ok(self, body: bytes) -> etree._Element:
        doc = etree.fromstring(body)
        assert self.error.validate(doc), self.error.error_log
        self.error_11.validate(body.decode())
        return doc


@pytest.fixture(scope="module")
def schemas(tmp_path_factory):
    if not SCHEMAS.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"{SCHEMAS} is missing: CI checks the documents against the official schemas")
        pytest.skip(f"{SCHEMAS} is missing")
    return Schemas(tmp_path_factory.mktemp("xsd"))


def _app(tmp_path, runner, **kw):
    return create_app(make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path, **kw), runner=runner)


def _axis(svc) -> int:
    with session_scope(svc.factory) as s:
        return config_repo.list_axes(s)[0].id


def _measure(svc, axis_id, agent, seen_before: int):
    """One cycle, then wait until the agent's queue has delivered its events."""
    sub = agent.subscription
    svc.scheduler.request(axis_id, "manual")
    assert svc.scheduler.idle(30)
    until(lambda: sub.pending == 0 and sub.delivered > seen_before, "the agent got the events")
    assert sub.failed == 0


def _header(doc) -> dict:
    h = doc.find("m:Header", NS)
    return {k: int(h.get(k)) for k in ("firstSequence", "lastSequence", "nextSequence")}


def _observations(doc) -> list:
    return [el for el in doc.iter() if el.get("sequence") is not None]


def test_probe_current_and_sample_validate_and_say_what_rest_says(tmp_path, schemas):
    runner = FakeRunner(backlash_um=183.4, temperature_c=21.5)
    app = _app(tmp_path, runner)
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        axis_id = _axis(svc)
        # before any measurement: every DataItem UNAVAILABLE, the condition Unavailable
        doc = schemas.streams_ok(client.get("/mtconnect/current").content)
        assert doc.find(".//m:Displacement", NS).text == "UNAVAILABLE"
        assert doc.find(".//m:Condition/m:Unavailable", NS).get("nativeCode") == "UNKNOWN"
        _measure(svc, axis_id, agent, 0)
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, f"read-{uuid.uuid4().hex[:6]}", "read")[1]
        rest = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(key)).json()

        probe = client.get("/mtconnect/probe")
        assert probe.status_code == 200 and probe.headers["content-type"].startswith("application/xml")
        dev = schemas.devices_ok(probe.content).find(".//d:Device", NS)
        assert dev.get("name") == "vmc-850"
        linear = dev.find("d:Components/d:Linear", NS)
        assert linear.get("name") == rest["axis_name"]
        items = {di.get("id"): di for di in linear.iter("{%s}DataItem" % NS["d"])}
        assert dict(items[f"a{axis_id}_backlash"].attrib) == {
            "category": "SAMPLE", "id": f"a{axis_id}_backlash", "type": "DISPLACEMENT", "name": "backlash_mean",
            "units": "MILLIMETER", "statistic": "AVERAGE"}  # fmt: skip
        assert items[f"a{axis_id}_temp"].get("type") == "TEMPERATURE"
        assert items[f"a{axis_id}_backlash_cond"].get("category") == "CONDITION"
        tbe_items = [di for di in items.values() if di.get("type") == "x:TRANSIENT_BACKLASH_ERROR"]
        assert [di.get("name") for di in tbe_items] == [t["name"] for t in rest["tasks"]]

        cur = schemas.streams_ok(client.get("/mtconnect/current").content)
        stream = cur.find(".//m:ComponentStream[@component='Linear']", NS)
        assert float(stream.find("m:Samples/m:Displacement", NS).text) == pytest.approx(rest["backlash_mean_um"] / 1000)
        assert float(stream.find("m:Samples/x:BacklashUncertainty", NS).text) == pytest.approx(
            rest["backlash_mean_uncertainty_um"] / 1000, abs=1e-7)
        assert float(stream.find("m:Samples/x:BacklashLimit", NS).text) == pytest.approx(
            rest["backlash_limit_um"] / 1000, abs=1e-7)
        (tbe,) = stream.findall("m:Samples/x:TransientBacklashError", NS)
        assert float(tbe.text) == pytest.approx(rest["tasks"][0]["tbe_um"] / 1000, abs=1e-7)
        assert float(stream.find("m:Samples/m:Temperature", NS).text) == 21.5
        assert stream.find("m:Events/x:LastCycleStatus", NS).text == rest["last_cycle_status"] == "ok"
        normal = stream.find("m:Condition/m:Normal", NS)
        assert (normal.get("nativeCode"), normal.text) == (rest["state"], rest["message"]) and rest["state"] == "OK"

        sample = schemas.streams_ok(client.get("/mtconnect/sample", params={"from": 1, "count": 5}).content)
        assert [int(o.get("sequence")) for o in _observations(sample)] == [1, 2, 3, 4, 5]
        assert _header(sample)["nextSequence"] == 6
        info = client.get("/api/v1/interfaces", headers=hdr(key)).json()
        assert info["mtconnect"]["next_sequence"] == _header(cur)["nextSequence"]
        assert info["mtconnect"]["devices"] == 1 and info["event_consumers"]["mtconnect"]["failed"] == 0

        # past the limit: ALARM is a Fault, with the active alert as its conditionId
        runner.backlash_um = 400.0
        _measure(svc, axis_id, agent, agent.subscription.delivered)
        rest = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(key)).json()
        cur = schemas.streams_ok(client.get("/mtconnect/current").content)
        fault = cur.find(".//m:Condition/m:Fault", NS)
        assert rest["state"] == "ALARM" and fault.get("nativeCode") == "ALARM" and fault.text == rest["message"]
        assert fault.get("conditionId") == f"alert-{rest['active_alert_id']}" and fault.get("qualifier") == "HIGH"
        assert cur.find(".//m:Displacement", NS).text == "0.4"


def test_sequence_numbers_continue_across_new_measurements(tmp_path, schemas):
    runner = FakeRunner(backlash_um=200.0)
    app = _app(tmp_path, runner)
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        axis_id = _axis(svc)
        _measure(svc, axis_id, agent, 0)
        before = _header(schemas.streams_ok(client.get("/mtconnect/current").content))
        assert before["firstSequence"] == 1 and before["lastSequence"] == before["nextSequence"] - 1
        runner.backlash_um = 210.0
        _measure(svc, axis_id, agent, agent.subscription.delivered)
        doc = schemas.streams_ok(client.get("/mtconnect/sample", params={"from": before["nextSequence"]}).content)
        seqs = [int(o.get("sequence")) for o in _observations(doc)]
        assert seqs == list(range(before["nextSequence"], before["nextSequence"] + len(seqs))) and seqs
        assert float(doc.find(".//m:Displacement", NS).text) == pytest.approx(0.21)
        after = _header(doc)
        assert after["firstSequence"] == 1 and after["nextSequence"] == after["lastSequence"] + 1 == seqs[-1] + 1
        # a client polling from nextSequence gets nothing new, and no error
        empty = schemas.streams_ok(client.get("/mtconnect/sample", params={"from": after["nextSequence"]}).content)
        assert _observations(empty) == [] and _header(empty)["nextSequence"] == after["nextSequence"]


def test_current_is_right_after_a_restart(tmp_path, schemas):
    runner = FakeRunner(backlash_um=190.0)
    app = _app(tmp_path, runner)
    with TestClient(app):
        svc, agent = app.state.service, app.state.mtconnect
        _measure(svc, _axis(svc), agent, 0)
    again = _app(tmp_path, FakeRunner())  # a new process on the same database: nothing measured since
    with TestClient(again) as client:
        doc = schemas.streams_ok(client.get("/mtconnect/current").content)
        # a new instance, even within the same second: clients know the sequences began anew
        assert again.state.mtconnect.instance_id > agent.instance_id
        assert int(doc.find("m:Header", NS).get("instanceId")) == again.state.mtconnect.instance_id
        assert float(doc.find(".//m:Displacement", NS).text) == pytest.approx(0.19)
        assert doc.find(".//x:LastCycleStatus", NS).text == "ok"
        assert doc.find(".//m:Condition/m:Normal", NS) is not None


def test_errors_are_mtconnect_error_documents(tmp_path, schemas):
    app = _app(tmp_path, FakeRunner(), mtconnect=MtconnectSettings(buffer_size=4))
    with TestClient(app) as client:
        cases = [("/mtconnect/sample?from=1", 400, "OUT_OF_RANGE"),  # 18 seeded observations, 4 kept: first is 15
                 ("/mtconnect/sample?from=99", 400, "OUT_OF_RANGE"),
                 ("/mtconnect/sample?count=0", 400, "OUT_OF_RANGE"),
                 ("/mtconnect/sample?count=5", 400, "OUT_OF_RANGE"),  # more than the buffer holds
                 ("/mtconnect/sample?from=abc", 400, "INVALID_REQUEST"),
                 ("/mtconnect/sample?count=1_0", 400, "INVALID_REQUEST"),
                 ("/mtconnect/sample?from=99999999999999999999", 400, "INVALID_REQUEST"),
                 ("/mtconnect/current?interval=1000", 400, "UNSUPPORTED"),
                 ("/mtconnect/no-such-machine/current", 404, "NO_DEVICE"),
                 ("/mtconnect/vmc-850/current/extra", 404, "INVALID_URI")]  # fmt: skip
        for url, status, code in cases:
            r = client.get(url)
            assert r.status_code == status, url
            err = schemas.error_ok(r.content).find("e:Errors/e:Error", NS)
            assert err.get("errorCode") == code, (url, err.text)
        j = client.get("/mtconnect/sample?from=1", headers=JSON).json()["MTConnectError"]
        assert j["Errors"]["Error"][0]["errorCode"] == "OUT_OF_RANGE" and "greater than or equal to 15" in \
            j["Errors"]["Error"][0]["value"]
        # the buffer keeps the newest 4; a device asked for by name or uuid
        doc = schemas.streams_ok(client.get("/mtconnect/sample?from=15").content)
        assert [int(o.get("sequence")) for o in _observations(doc)] == [15, 16, 17, 18]
        uuid_ = schemas.devices_ok(client.get("/mtconnect/vmc-850").content).find(".//d:Device", NS).get("uuid")
        assert schemas.streams_ok(client.get(f"/mtconnect/{uuid_}/current").content).find(
            ".//m:DeviceStream", NS).get("name") == "vmc-850"
        # read-only: no other method
        assert client.post("/mtconnect/current").status_code == 405
        # no assets: an empty document, and ASSET_NOT_FOUND for any one asked for
        assets = schemas.assets_ok(client.get("/mtconnect/assets").content)
        assert assets.find("{urn:mtconnect.org:MTConnectAssets:2.4}Header").get("assetCount") == "0"
        r = client.get("/mtconnect/asset/T1")
        assert r.status_code == 404
        assert schemas.error_ok(r.content).find("e:Errors/e:Error", NS).get("errorCode") == "ASSET_NOT_FOUND"


def test_a_key_is_needed_only_when_configured(tmp_path, schemas):
    app = _app(tmp_path, FakeRunner(), mtconnect=MtconnectSettings(require_key=True))
    with TestClient(app) as client:
        with session_scope(app.state.service.factory) as s:
            key = config_repo.create_key(s, "mes", "read")[1]
        r = client.get("/mtconnect/probe")
        assert r.status_code == 401
        assert schemas.error_ok(r.content).find("e:Errors/e:Error", NS).get("errorCode") == "UNAUTHORIZED"
        assert client.get("/mtconnect/probe", headers={"X-API-Key": "wrong"}).status_code == 401
        assert client.get("/mtconnect/probe", headers=hdr(key)).status_code == 200
        assert client.get("/mtconnect/current", headers={"Authorization": f"Bearer {key}"}).status_code == 200
    off = _app(tmp_path / "off", FakeRunner(), mtconnect=MtconnectSettings(enabled=False))
    with TestClient(off) as client:
        assert off.state.mtconnect is None and client.get("/mtconnect/probe").status_code == 404


def test_failed_keys_are_throttled_per_address_with_the_rest_apis_budget(tmp_path, schemas):
    from api.service.config.settings import LimitSettings

    settings_kw = dict(mtconnect=MtconnectSettings(require_key=True),
                       limits=LimitSettings(auth_failures_per_minute=1.0, auth_failure_burst=3,
                                            auth_address_failures_per_minute=1.0, auth_address_failure_burst=3))
    app = _app(tmp_path, FakeRunner(), **settings_kw)
    with TestClient(app) as client:
        with session_scope(app.state.service.factory) as s:
            key = config_repo.create_key(s, "mes", "read")[1]
        codes = [client.get("/mtconnect/current", headers={"X-API-Key": f"guess{i}"}).status_code for i in range(3)]
        assert codes == [401, 401, 401]
        r = client.get("/mtconnect/current", headers={"X-API-Key": "guess3"})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
        assert schemas.error_ok(r.content).find("e:Errors/e:Error", NS).get("errorCode") == "UNAUTHORIZED"
        assert client.get("/mtconnect/current", headers=hdr(key)).status_code == 200  # a right key always passes
        assert client.get("/api/v1/machines", headers=hdr("guess4")).status_code == 429  # one budget for both paths


class _Server:
    """The app under a real uvicorn on a free loopback port, in this process."""

    def __init__(self, app):
        import uvicorn

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.thread.start()
        until(lambda: self.server.started, "uvicorn started")

    def stop(self):
        self.server.should_exit = True
        self.thread.join(30)
        self.sock.close()


def test_the_pymtconnect_client_parses_the_json_documents(tmp_path, capsys):
    from pymtconnect.mtconnect_client import current, probe, sample
    from pymtconnect.probe_example import parse_probe

    runner = FakeRunner(backlash_um=400.0)  # an ALARM: a Fault condition
    app = _app(tmp_path, runner)
    srv = _Server(app)
    try:
        svc, agent = app.state.service, app.state.mtconnect
        _measure(svc, _axis(svc), agent, 0)
        base = f"{srv.url}/mtconnect"
        header, devices = probe(base)
        assert header.version == "2.4.0.0" and header.buffer_size == agent.buffer.size
        assert [(d.name, d.uuid) for d in devices] == [("vmc-850", agent.devices()[0].uuid)]
        # its full walk of the device tree resolves the axis to its Linear class, with the DataItems
        _, (dev,) = parse_probe(base)
        (linear,) = dev.components
        assert type(linear).__name__ == "Linear" and linear.name == "y"
        types = {(di.category, di.type, di.units) for di in linear.data_items}
        assert {("SAMPLE", "DISPLACEMENT", "MILLIMETER"), ("SAMPLE", "TEMPERATURE", "CELSIUS"),
                ("CONDITION", "DISPLACEMENT", None), ("SAMPLE", "x:BACKLASH_LIMIT", "MILLIMETER")} <= types
        header, events, conditions = current(base)
        first, last, nxt = agent.buffer.bounds()
        assert (header.first_sequence, header.last_sequence, header.next_sequence) == (first, last, nxt)
        by_type = {e.type: e for e in events}
        assert by_type["Availability"].result == "AVAILABLE"
        assert by_type["x:LastCycleStatus"].result == "ok"
        (cond,) = conditions
        assert (cond.state, cond.native_code, cond.type) == ("Fault", "ALARM", "DISPLACEMENT")
        assert cond.condition_id.startswith("alert-") and "ALARM" in cond.result
        header, events, conditions = sample(base, from_seq=1, count=3)
        assert header.next_sequence == 4 and [e.sequence for e in events] == [1]  # 2 and 3 are samples
    finally:
        srv.stop()
    capsys.readouterr()  # the client prints what it fetches


def test_the_json_documents_say_what_the_xml_says(tmp_path, schemas):
    app = _app(tmp_path, FakeRunner(backlash_um=183.4))
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        _measure(svc, _axis(svc), agent, 0)
        xml = schemas.streams_ok(client.get("/mtconnect/current").content)
        js = client.get("/mtconnect/current", headers=JSON).json()["MTConnectStreams"]
        assert js["Header"]["nextSequence"] == _header(xml)["nextSequence"]
        (linear,) = [c for c in js["Streams"]["DeviceStream"][0]["ComponentStream"] if c["component"] == "Linear"]
        (disp,) = linear["Samples"]["Displacement"]
        assert disp["value"] == float(xml.find(".//m:Displacement", NS).text) == pytest.approx(0.1834)
        assert disp["sequence"] == int(xml.find(".//m:Displacement", NS).get("sequence"))
        assert list(linear["Condition"]) == ["Normal"]
        probe = client.get("/mtconnect/probe", headers=JSON).json()["MTConnectDevices"]
        (lin,) = probe["Devices"]["Device"][0]["Components"]["Linear"]
        types = {di["type"] for di in lin["DataItems"]["DataItem"]}
        assert types >= {"DISPLACEMENT", "TEMPERATURE", "x:BACKLASH_LIMIT"}
        xsd = client.get("/mtconnect/schemas/mebm_streams_2.4.xsd")
        assert xsd.status_code == 200 and xsd.content == EXTENSION.read_bytes()


def test_the_mtconnect_table_of_the_configuration():
    st = parse_settings({"mtconnect": {"enabled": False, "require_key": True, "buffer_size": 500, "sender": "cell-3"}})
    assert st.mtconnect == MtconnectSettings(enabled=False, require_key=True, buffer_size=500, sender="cell-3")
    assert parse_settings({}).mtconnect.enabled is True  # on unless turned off, open by default
    with pytest.raises(ConfigError, match="mtconnect.buffer_size"):
        parse_settings({"mtconnect": {"buffer_size": 0}})
    with pytest.raises(ConfigError, match="unknown option"):
        parse_settings({"mtconnect": {"port": 5000}})
    assert parse_settings({"mtconnect": {"shdr_port": 7878}}).mtconnect.shdr_port == 7878
    assert parse_settings({}).mtconnect.shdr_port is None  # the SHDR port is opened only when asked for
    with pytest.raises(ConfigError, match="mtconnect.shdr_port"):
        parse_settings({"mtconnect": {"shdr_port": 70000}})


def test_the_start_banner_prints_the_mtconnect_url(tmp_path):
    from api.cli.serve import banner
    from api.service.service import StartReport

    report = StartReport(database="sqlite:///x", replayed=0, interrupted=0, created_axes=(), demo_keys={},
                         simulators={}, bootstrap_admin=None)  # fmt: skip
    text = banner(make_settings("sqlite:///x", tmp_path), report, "http://127.0.0.1:8000")
    assert "MTConnect agent: http://127.0.0.1:8000/mtconnect/probe" in text and "(open, read-only)" in text
    assert "SHDR" not in text
    shdr = banner(make_settings("sqlite:///x", tmp_path, mtconnect=MtconnectSettings(shdr_port=7878)), report, "u")
    assert "MTConnect SHDR adapter: 127.0.0.1:7878" in shdr
    off = banner(make_settings("sqlite:///x", tmp_path, mtconnect=MtconnectSettings(enabled=False)), report, "u")
    assert "MTConnect: off" in off


class _LineClient:
    """A plain TCP client reading SHDR lines, as an agent's adapter connection does."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=30)
        self.file = self.sock.makefile("rb")

    def until(self, pred) -> list[str]:
        lines = []
        while True:
            line = self.file.readline().decode().rstrip("\n")
            assert line, f"the adapter closed the connection after {lines}"
            lines.append(line)
            if pred(line):
                return lines

    def close(self):
        self.file.close()
        self.sock.close()


def test_the_shdr_adapter_sends_current_values_then_each_change_and_answers_ping(tmp_path):
    runner = FakeRunner(backlash_um=200.0)
    app = _app(tmp_path, runner, mtconnect=MtconnectSettings(shdr_port=0))
    with TestClient(app):
        svc, agent = app.state.service, app.state.mtconnect
        axis_id = _axis(svc)
        client = _LineClient(agent.shdr.port)
        try:
            first = client.until(lambda line: f"|a{axis_id}_backlash_cond|" in line)
            fields = {line.split("|")[1]: line.split("|")[2:] for line in first}
            assert fields[f"a{axis_id}_backlash"] == ["UNAVAILABLE"] and fields["m1_avail"] == ["AVAILABLE"]
            assert fields[f"a{axis_id}_backlash_cond"] == ["unavailable", "", "", "", ""]
            client.sock.sendall(b"* PING\n")
            assert client.until(lambda line: line.startswith("* PONG")) == ["* PONG 10000"]
            runner.backlash_um = 400.0
            _measure(svc, axis_id, agent, 0)
            new = client.until(lambda line: f"|a{axis_id}_backlash_cond|" in line)
            fields = {line.split("|")[1]: line.split("|")[2:] for line in new}
            assert fields[f"a{axis_id}_backlash"] == ["0.4"]
            level, code, severity, qualifier, message = fields[f"a{axis_id}_backlash_cond"]
            assert (level, code, severity, qualifier) == ("fault", "BACKLASH", "ALARM", "HIGH") and "ALARM" in message
            assert agent.shdr.clients == 1
        finally:
            client.close()


def test_the_validators_catch_what_the_schemas_forbid(tmp_path, schemas):
    """The checks above are not vacuous: a micrometre unit, a Header without its
    deviceModelChangeTime and a Fault without conditionId are refused."""
    import xmlschema

    runner = FakeRunner(backlash_um=400.0)
    app = _app(tmp_path, runner)
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        _measure(svc, _axis(svc), agent, 0)
        probe = client.get("/mtconnect/probe").content
        cur = client.get("/mtconnect/current").content
    schemas.devices_ok(probe)
    schemas.streams_ok(cur)
    with pytest.raises(xmlschema.XMLSchemaValidationError, match="MICROMETER"):
        schemas.devices_ok(probe.replace(b'units="MILLIMETER"', b'units="MICROMETER"', 1))
    assert not schemas.streams.validate(etree.fromstring(cur.replace(b' deviceModelChangeTime="', b' x="', 1)))
    assert b"conditionId=" in cur
    assert not schemas.streams.validate(etree.fromstring(cur.replace(b" conditionId=", b" x=", 1)))


def test_tasks_changed_through_the_api_change_the_device_model_at_once(tmp_path, schemas):
    app = _app(tmp_path, FakeRunner(backlash_um=200.0))
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        axis_id = _axis(svc)
        _measure(svc, axis_id, agent, 0)
        with session_scope(svc.factory) as s:
            admin = config_repo.create_key(s, "admin-mtc", "admin")[1]
        before = schemas.devices_ok(client.get("/mtconnect/probe").content)
        changed_at = before.find("d:Header", NS).get("deviceModelChangeTime")
        tasks = [{"name": "line 30deg", "profile": "line", "feed_mm_min": 1000, "tolerance_um": 20, "angle_deg": 30},
                 {"name": "circle R50", "profile": "circle", "feed_mm_min": 500, "tolerance_um": 30, "radius_mm": 50}]
        r = client.put(f"/api/v1/axes/{axis_id}/tasks", json={"tasks": tasks}, headers=hdr(admin))
        assert r.status_code == 200, r.text

        def tbe_names(doc):
            return [di.get("name") for di in doc.iter("{%s}DataItem" % NS["d"])
                    if di.get("type") == "x:TRANSIENT_BACKLASH_ERROR"]  # fmt: skip

        def probed():
            return tbe_names(etree.fromstring(client.get("/mtconnect/probe").content))

        until(lambda: probed() == ["line 30deg", "circle R50"], "the new tasks in the probe")
        after = schemas.devices_ok(client.get("/mtconnect/probe").content)
        assert after.find("d:Header", NS).get("deviceModelChangeTime") > changed_at
        cur = schemas.streams_ok(client.get("/mtconnect/current").content)
        tbe = {el.get("name"): el.text for el in cur.iterfind(".//x:TransientBacklashError", NS)}
        assert set(tbe) == {"line 30deg", "circle R50"}  # the old task's DataItem is gone from current
        assert all(float(v) > 0 for v in tbe.values())  # TBE of the new tasks from the stored measurement


def test_a_failure_text_names_no_controller_address_while_rest_keeps_it(tmp_path, schemas):
    runner = FakeRunner()
    runner.fail = "ConnectionError: cannot connect to 127.0.0.1:1 (connection refused)"
    app = _app(tmp_path, runner)
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        axis_id = _axis(svc)
        _measure(svc, axis_id, agent, 0)
        doc = schemas.streams_ok(client.get("/mtconnect/current").content)
        cond = doc.find(".//m:Condition", NS)
        text = "".join(cond.itertext())
        assert "cannot connect to the controller (connection refused)" in text, text
        assert "127.0.0.1" not in client.get("/mtconnect/current").text
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, "mes", "read")[1]
        body = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(key)).json()
        assert "127.0.0.1:1" in body["message"]  # behind a key, the technician's whole text


@contextlib.contextmanager
def _circle_plane(tmp_path):
    """A service whose machine has the x-y plane of the circular-test REST tests, a fake
    runner's 150 µm play: (client, service, agent, axes by name, read and operate keys)."""
    from dataclasses import replace

    from tests.api.rest.test_circles import circle_axis

    settings = make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path)
    app = create_app(replace(settings, axes=(circle_axis("x"), circle_axis("y"))), runner=FakeRunner(150.0))
    with TestClient(app) as client:
        svc, agent = app.state.service, app.state.mtconnect
        with session_scope(svc.factory) as s:
            axes = {a.name: a for a in config_repo.list_axes(s)}
            keys = {r: config_repo.create_key(s, f"{r}-mtc", r)[1] for r in ("read", "operate")}
        yield client, svc, agent, axes, keys


def test_a_circular_test_is_beside_the_tbe_in_probe_current_and_sample(tmp_path, schemas):
    from tests.api.rest.test_circles import circle_body

    with _circle_plane(tmp_path) as (client, svc, agent, axes, keys):
        y = axes["y"].id
        cur = schemas.streams_ok(client.get("/mtconnect/current").content)
        assert {el.text for el in cur.iterfind(".//x:CircularDeviation", NS)} == {"UNAVAILABLE"}  # no test yet
        _measure(svc, y, agent, 0)  # b̄ of y, for the agreement
        seen = agent.subscription.delivered
        r = client.post(f"/api/v1/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 150.0)),
                        headers=hdr(keys["operate"]))
        assert r.status_code == 201, r.text
        until(lambda: agent.subscription.pending == 0 and agent.subscription.delivered > seen, "the test's events")
        ct = client.get(f"/api/v1/axes/{y}/status", headers=hdr(keys["read"])).json()["circular_test"]

        probe = schemas.devices_ok(client.get("/mtconnect/probe").content)
        linear = probe.find(f".//d:Linear[@id='a{y}']", NS)
        types = {di.get("id"): di.get("type") for di in linear.iter("{%s}DataItem" % NS["d"])}
        assert types[f"a{y}_circle_g"] == "x:CIRCULAR_DEVIATION" and types[f"a{y}_circle_spike"] == "x:REVERSAL_SPIKE"
        assert types[f"a{y}_circle_agreement"] == "x:CIRCLE_AGREEMENT"

        for doc in (schemas.streams_ok(client.get("/mtconnect/current").content),
                    schemas.streams_ok(client.get("/mtconnect/sample", params={"from": 1, "count": 1000}).content)):
            stream = doc.find(f".//m:ComponentStream[@componentId='a{y}']", NS)
            g = stream.findall("m:Samples/x:CircularDeviation", NS)[-1]
            assert float(g.text) == pytest.approx(ct["circular_deviation_um"] / 1000, abs=1e-7)
            assert g.get("timestamp").startswith(ct["measured_at"][:19])  # the test's time
            assert float(stream.findall("m:Samples/x:CircularHysteresis", NS)[-1].text) == pytest.approx(
                ct["hysteresis_um"] / 1000, abs=1e-7)
            assert float(stream.findall("m:Samples/x:ReversalSpike", NS)[-1].text) == pytest.approx(
                ct["spike_um"] / 1000, abs=1e-7)
            u = {el.get("name"): el.text for el in stream.iterfind("m:Samples/x:CircleUncertainty", NS)}
            assert float(u["reversal_spike_uncertainty"]) == pytest.approx(ct["spike_uncertainty_um"] / 1000, abs=1e-7)
            assert set(u) == {"circular_deviation_uncertainty", "circular_hysteresis_uncertainty",
                              "reversal_spike_uncertainty"}
            assert stream.findall("m:Events/x:CircleAgreement", NS)[-1].text == ct["agreement"] is not None
        js = client.get("/mtconnect/current", headers=JSON).json()
        comps = js["MTConnectStreams"]["Streams"]["DeviceStream"][0]["ComponentStream"]
        (ys,) = [c for c in comps if c.get("componentId") == f"a{y}"]
        assert ys["Samples"]["x:ReversalSpike"][0]["value"] == pytest.approx(ct["spike_um"] / 1000, abs=1e-7)


def test_an_alert_a_circular_test_raises_is_the_axis_condition(tmp_path, schemas):
    """The round trip's b̄ leaves the axis within its task; a circular test with 300 µm of
    play on y at the task's radius and feed raises the alert: the axis' condition is the
    test's, with the alert's id, as an MES reading conditions alone must see it."""
    from tests.api.rest.test_circles import circle_body

    with _circle_plane(tmp_path) as (client, svc, agent, axes, keys):
        y = axes["y"].id
        _measure(svc, y, agent, 0)
        status = client.get(f"/api/v1/axes/{y}/status", headers=hdr(keys["read"])).json()
        assert status["state"] not in ("WARNING", "ALARM"), status["state"]  # the premise
        seen = agent.subscription.delivered
        r = client.post(f"/api/v1/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 300.0)),
                        headers=hdr(keys["operate"]))
        assert r.status_code == 201, r.text
        until(lambda: agent.subscription.pending == 0 and agent.subscription.delivered > seen, "the test's events")
        status = client.get(f"/api/v1/axes/{y}/status", headers=hdr(keys["read"])).json()
        ct = status["circular_test"]
        assert ct["state"] == "ALARM" and status["active_alert_id"] is not None, status
        doc = schemas.streams_ok(client.get("/mtconnect/current").content)
        stream = doc.find(f".//m:ComponentStream[@componentId='a{y}']", NS)
        (cond,) = list(stream.find("m:Condition", NS))
        assert cond.tag == "{%s}Fault" % NS["m"], cond.tag
        assert cond.get("conditionId") == f"alert-{status['active_alert_id']}"
        assert f"circular test {ct['id']}" in cond.text

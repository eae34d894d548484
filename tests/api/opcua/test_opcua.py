"""The OPC UA server, checked with a real asyncua client over TCP on loopback.

One service with its OPC UA server (port 0) per module: asyncua servers take seconds
to start. The tests of this module share it and run in the order written (the value
seen before a measurement, then after). SQLite: the server only reads the status."""

from __future__ import annotations

import asyncio
import logging
import socket
import time
import uuid
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID
from fastapi.testclient import TestClient

from api.cli.serve import opcua_line
from api.opcua import OpcuaServer
from api.opcua.nodes import UNECE_URI, unece_unit_id
from api.rest import create_app
from api.service.config.loading import load_settings, parse_settings
from api.service.config.settings import DEFAULT_OPCUA_ENDPOINT, ConfigError, OpcuaSettings
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.waiting import until
from tests.api.rest.test_prognosis import bulk_history

LOOPBACK = "opc.tcp://127.0.0.1:0/mebm/"
CLIENT_URI = "urn:mebm:test-client"  # a client certificate's URI must be the client's ApplicationUri


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("opcua")
    runner = FakeRunner(backlash_um=200.0)
    settings = make_settings(f"sqlite:///{tmp}/db.sqlite3", tmp, opcua=OpcuaSettings(enabled=True, endpoint=LOOPBACK))
    app = create_app(settings, runner=runner)
    with TestClient(app) as client:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            read = config_repo.create_key(s, f"read-{uuid.uuid4().hex[:6]}", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        yield {"client": client, "app": app, "svc": svc, "runner": runner, "read": read, "axis_id": axis_id,
               "ua": app.state.opcua}


def _measure(env):
    before = env["ua"].updates
    env["svc"].scheduler.request(env["axis_id"], "manual")
    assert env["svc"].scheduler.idle(30)
    until(lambda: env["ua"].updates > before, "the OPC UA update")


async def mebm_namespace(c: Client) -> int:
    """The index of the installation's namespace (``urn:mebm:<instance>``)."""
    uris = await c.get_namespace_array()
    (idx,) = [i for i, u in enumerate(uris) if u.startswith("urn:mebm:") and u != "urn:mebm:server"]
    return idx


async def _browse_to_axis(c: Client):
    """From Objects, by browsing (not by node id), to the axis object."""
    idx = await mebm_namespace(c)
    node = c.nodes.objects
    for name in ("Machines", "vmc-850", "y"):
        children = {(await ch.read_browse_name()).Name: ch for ch in await node.get_children()}
        assert name in children, f"{name} not among {sorted(children)}"
        node = children[name]
    return idx, node


async def _read_axis(endpoint: str) -> dict:
    async with Client(endpoint, timeout=10) as c:
        idx, axis = await _browse_to_axis(c)
        out = {}
        for name in ("BacklashMean", "BacklashMeanUncertainty", "BacklashLimit", "State", "Message"):
            dv = await (await axis.get_child(f"{idx}:{name}")).read_data_value(raise_on_bad_status=False)
            out[name] = dv.Value.Value if dv.StatusCode.is_good() else dv.StatusCode.name
        mean = await axis.get_child(f"{idx}:BacklashMean")
        out["eu"] = await (await mean.get_child("0:EngineeringUnits")).read_value()
        out["type"] = (await mean.read_type_definition())
        tbe = await axis.get_child(f"{idx}:TBE")
        out["tbe"] = {}
        for var in await tbe.get_children():
            dv = await var.read_data_value(raise_on_bad_status=False)
            out["tbe"][(await var.read_browse_name()).Name] = dv.Value.Value if dv.StatusCode.is_good() else None
        prognoses = await c.nodes.objects.get_child([f"{idx}:Machines", f"{idx}:vmc-850", f"{idx}:Notification",
                                                     f"{idx}:Prognoses"])
        out["prognoses"] = {}
        for entry in await prognoses.get_children():
            out["prognoses"][(await entry.read_browse_name()).Name] = {
                n: await (await entry.get_child(f"{idx}:{n}")).read_value() for n in ("PredictedTime", "Source")}
        return out


class _Changes:
    def __init__(self):
        self.values = []

    def datachange_notification(self, node, val, data):  # asyncua's subscription handler
        self.values.append(val)


async def _subscribe_while_measuring(env) -> list:
    async with Client(env["ua"].endpoint, timeout=10) as c:
        idx, axis = await _browse_to_axis(c)
        changes = _Changes()
        sub = await c.create_subscription(50, changes)
        await sub.subscribe_data_change(await axis.get_child(f"{idx}:BacklashMean"))
        await asyncio.to_thread(_measure, env)
        end = time.monotonic() + 30
        while not any(isinstance(v, float) for v in changes.values) and time.monotonic() < end:
            await asyncio.sleep(0.05)
        await sub.delete()
        return [v for v in changes.values if v is not None]


def test_a_client_browses_to_backlash_mean_and_sees_it_change_after_a_measurement(env):
    ep = env["ua"].endpoint
    assert env["ua"].running and not ep.endswith(":0/mebm/")
    before = asyncio.run(_read_axis(ep))
    assert before["BacklashMean"] == "BadWaitingForInitialData" and before["State"] == "UNKNOWN"
    eu = before["eu"]
    assert (eu.NamespaceUri, eu.UnitId, eu.DisplayName.Text) == (UNECE_URI, unece_unit_id("4H"), "µm")
    assert before["type"] == ua.NodeId(ua.ObjectIds.AnalogItemType)

    seen = asyncio.run(_subscribe_while_measuring(env))  # a data change notification...
    assert seen == [pytest.approx(200.0, abs=2.0)]  # the one value of the one measurement (before: no value)
    after = asyncio.run(_read_axis(ep))  # ...and the values read afterwards
    rest = env["client"].get(f"/api/v1/axes/{env['axis_id']}/status", headers=hdr(env["read"])).json()
    assert after["BacklashMean"] == pytest.approx(200.0, abs=2.0)
    assert after["BacklashMean"] == pytest.approx(rest["backlash_mean_um"])
    assert after["BacklashLimit"] == pytest.approx(rest["backlash_limit_um"])
    assert (after["State"], after["Message"]) == (rest["state"], rest["message"]) and rest["state"] == "OK"
    assert after["tbe"] == pytest.approx({t["name"]: t["tbe_um"] for t in rest["tasks"]}) and after["tbe"]
    assert after["prognoses"] == {}  # below the limit and no prognosis: nothing predicted

    env["runner"].backlash_um = 400.0  # past the limit: an alert, and its date in Prognoses
    _measure(env)
    alarm = asyncio.run(_read_axis(ep))
    rest = env["client"].get(f"/api/v1/axes/{env['axis_id']}/status", headers=hdr(env["read"])).json()
    alerts = env["client"].get("/api/v1/alerts?state=active", headers=hdr(env["read"])).json()["items"]
    (alert,) = [a for a in alerts if a["id"] == rest["active_alert_id"]]
    assert alarm["BacklashMean"] == pytest.approx(rest["backlash_mean_um"]) and alarm["State"] == "ALARM"
    (entry,) = alarm["prognoses"].values()
    assert entry["Source"] == "limit passed" and rest["prognosis"]["limit_date"] is None  # two cycles: no fit yet
    raised_at = datetime.fromisoformat(alert["raised_at"].replace("Z", "+00:00"))
    assert abs(entry["PredictedTime"].replace(tzinfo=timezone.utc) - raised_at) < timedelta(milliseconds=1)


def test_a_write_is_refused_and_every_variable_is_read_only(env, caplog):
    caplog.set_level(logging.INFO, logger="asyncua.server")

    async def go():
        async with Client(env["ua"].endpoint, timeout=10) as c:
            idx, axis = await _browse_to_axis(c)
            mean = await axis.get_child(f"{idx}:BacklashMean")
            before = (await mean.read_data_value(raise_on_bad_status=False)).Value  # none yet, if run alone
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await mean.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
            levels = []
            for var in await axis.get_children(nodeclassmask=ua.NodeClass.Variable):
                levels.append((await var.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value)
                levels.append((await var.read_attribute(ua.AttributeIds.UserAccessLevel)).Value.Value)
            return before, (await mean.read_data_value(raise_on_bad_status=False)).Value, refused.value, levels

    before, after, refused, levels = asyncio.run(go())
    assert isinstance(refused, ua.uaerrors.BadUserAccessDenied)
    assert after == before
    # a client refused by design is told so and logged at INFO, not as an error of the server
    server_lines = [r for r in caplog.records if r.name.startswith("asyncua.server")]
    assert any("BadUserAccessDenied" in r.getMessage() and r.levelno == logging.INFO for r in server_lines)
    assert not [r.getMessage() for r in server_lines if r.levelno >= logging.WARNING and "Denied" in r.getMessage()]
    assert levels and set(levels) == {ua.AccessLevel.CurrentRead.mask}


def _certificate(tmp_path, name: str, uri: str, use) -> tuple[Path, Path]:
    key, cert = tmp_path / f"{name}-key.pem", tmp_path / f"{name}-cert.der"
    asyncio.run(setup_self_signed_certificate(key, cert, uri, "127.0.0.1", [use], {"commonName": name}))
    return cert, key


async def _connect(endpoint: str, user=None, password=None, cert=None, key=None) -> str:
    """The axis' State read in a session, or the name of the status code that refused it."""
    c = Client(endpoint, timeout=10)
    c.application_uri = CLIENT_URI
    if cert is not None:
        await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    if user is not None:
        c.set_user(user)
        c.set_password(password)
    try:
        await c.connect()
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    except ua.UaError as exc:  # no endpoint of the requested security
        return f"UaError: {exc}"
    try:
        idx = await mebm_namespace(c)
        _, axis = await _browse_to_axis(c)
        return await (await axis.get_child(f"{idx}:State")).read_value()
    finally:
        await c.disconnect()


async def _policies(endpoint: str) -> set:
    endpoints = await Client(endpoint, timeout=10).connect_and_get_server_endpoints()
    return {(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode.name) for e in endpoints}


STATES = ("OK", "WARNING", "ALARM", "UNKNOWN")


def test_with_a_username_anonymous_and_wrong_passwords_are_refused(env, tmp_path):
    cert, key = _certificate(tmp_path, "server", "urn:mebm:server", ExtendedKeyUsageOID.SERVER_AUTH)
    client_cert, client_key = _certificate(tmp_path, "client", CLIENT_URI, ExtendedKeyUsageOID.CLIENT_AUTH)
    settings = OpcuaSettings(enabled=True, endpoint=LOOPBACK, anonymous=False, username="mes", password="s3cret",
                             certificate=cert, private_key=key)
    srv = OpcuaServer(env["svc"], settings)
    assert srv.start(), srv.error
    try:
        anonymous = asyncio.run(_connect(srv.endpoint))
        wrong = asyncio.run(_connect(srv.endpoint, "mes", "nope"))
        plain = asyncio.run(_connect(srv.endpoint, "mes", "s3cret"))  # the password encrypted with the server's certificate
        secure = asyncio.run(_connect(srv.endpoint, "mes", "s3cret", client_cert, client_key))
        offered = asyncio.run(_policies(srv.endpoint))
    finally:
        srv.close()
    assert anonymous == "BadIdentityTokenRejected"
    assert wrong == "BadUserAccessDenied"
    assert plain in STATES and secure == plain
    assert offered == {("None", "None_"), ("Basic256Sha256", "Sign"), ("Basic256Sha256", "SignAndEncrypt")}


def test_with_trusted_client_certificates_only_their_holders_get_in(env, tmp_path):
    cert, key = _certificate(tmp_path, "server", "urn:mebm:server", ExtendedKeyUsageOID.SERVER_AUTH)
    good_cert, good_key = _certificate(tmp_path, "mes", CLIENT_URI, ExtendedKeyUsageOID.CLIENT_AUTH)
    bad_cert, bad_key = _certificate(tmp_path, "stranger", CLIENT_URI, ExtendedKeyUsageOID.CLIENT_AUTH)
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    (trusted / "mes.der").write_bytes(good_cert.read_bytes())
    settings = OpcuaSettings(enabled=True, endpoint=LOOPBACK, anonymous=False, certificate=cert, private_key=key,
                             trusted_certificates=trusted)
    srv = OpcuaServer(env["svc"], settings)
    assert srv.start(), srv.error
    try:
        holder = asyncio.run(_connect(srv.endpoint, cert=good_cert, key=good_key))
        stranger = asyncio.run(_connect(srv.endpoint, cert=bad_cert, key=bad_key))
        unsigned = asyncio.run(_connect(srv.endpoint))
        offered = asyncio.run(_policies(srv.endpoint))
    finally:
        srv.close()
    assert holder in STATES
    assert stranger.startswith("BadCertificate") or stranger == "BadSecurityChecksFailed", stranger
    assert unsigned != holder and unsigned not in STATES
    assert offered == {("Basic256Sha256", "Sign"), ("Basic256Sha256", "SignAndEncrypt")}  # no None channel


def test_a_taken_port_leaves_the_service_measuring_without_opc_ua(env):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        settings = OpcuaSettings(enabled=True, endpoint=f"opc.tcp://127.0.0.1:{port}/mebm/")
        srv = OpcuaServer(env["svc"], settings)
        assert srv.start() is False
        srv.close()
    assert not srv.running and "cannot listen" in srv.error
    line = opcua_line(replace(env["app"].state.service.settings, opcua=settings), srv)
    assert line.startswith(f"OPC UA: NOT running on opc.tcp://127.0.0.1:{port}/mebm/")
    running = opcua_line(env["app"].state.service.settings, env["ua"])
    assert running.startswith(f"OPC UA: {env['ua'].endpoint}  (anonymous read-only; security None;")
    health = env["client"].get("/healthz").json()
    assert health["opcua"] == f"listening on {env['ua'].endpoint}"  # the module's own server is unaffected
    _measure(env)  # and the service still measures and publishes


def _toml(tmp_path, text: str) -> Path:
    p = tmp_path / "mebm.toml"
    p.write_text(text)
    return p


def test_opcua_configuration_is_checked_by_name(tmp_path):
    s = parse_settings({"opcua": {"endpoint": "opc.tcp://0.0.0.0:4841/x/", "username": "mes", "password": "pw"}})
    assert s.opcua.anonymous is False and s.opcua.username == "mes"  # a username turns anonymous off...
    s = parse_settings({"opcua": {"username": "mes", "password": "pw", "anonymous": True}})
    assert s.opcua.anonymous is True  # ...unless said otherwise
    assert load_settings(None, {}).opcua == OpcuaSettings(enabled=True, endpoint=DEFAULT_OPCUA_ENDPOINT)  # make run
    assert load_settings(None, {"MEBM_OPCUA_ENDPOINT": ""}).opcua.enabled is False
    assert load_settings(None, {"MEBM_OPCUA_ENDPOINT": "opc.tcp://127.0.0.1:0/x/"}).opcua.endpoint.endswith(":0/x/")
    with pytest.raises(ConfigError, match="MEBM_OPCUA_PASSWORD"):  # a username without a password
        load_settings(_toml(tmp_path, '[opcua]\nusername = "mes"\n'), {})
    assert load_settings(_toml(tmp_path, '[opcua]\nusername = "mes"\n'), {"MEBM_OPCUA_PASSWORD": "pw"}).opcua.password == "pw"
    for bad, field in (({"endpoint": "http://x/"}, "opcua.endpoint"), ({"password": "pw"}, "password"),
                       ({"anonymous": False}, "anonymous"), ({"certificate": "/nonexistent.pem"}, "certificate"),
                       ({"port": 4840}, "unknown option")):  # fmt: skip
        with pytest.raises(ConfigError, match=field):
            parse_settings({"opcua": bad})


def test_predicted_time_is_the_prognosis_limit_date_once_the_history_supports_one(env):
    """Last in the module: it adds a history of 80 measurements to the shared database."""
    env["runner"].backlash_um, env["runner"].temperature_c = 200.0, 20.0
    bulk_history(env["svc"], env["axis_id"])  # b̄ = 200 + 2 (T - 20) + 0.02 d: wear towards 236 µm at 30 °C
    _measure(env)
    rest = env["client"].get(f"/api/v1/axes/{env['axis_id']}/status", headers=hdr(env["read"])).json()
    assert rest["prognosis"]["identifiable"] is True and rest["prognosis"]["limit_date"] is not None, rest["prognosis"]
    (entry,) = asyncio.run(_read_axis(env["ua"].endpoint))["prognoses"].values()
    assert entry["Source"] == "prognosis"
    limit_date = datetime.fromisoformat(rest["prognosis"]["limit_date"].replace("Z", "+00:00"))
    assert abs(entry["PredictedTime"].replace(tzinfo=timezone.utc) - limit_date) < timedelta(seconds=1)


async def _read_circle(endpoint: str) -> dict:
    async with Client(endpoint, timeout=10) as c:
        idx, axis = await _browse_to_axis(c)
        folder = await axis.get_child(f"{idx}:CircularTest")
        out = {}
        for var in await folder.get_children():
            dv = await var.read_data_value(raise_on_bad_status=False)
            out[(await var.read_browse_name()).Name] = (dv.Value.Value if dv.StatusCode.is_good() else
                                                        dv.StatusCode.name, dv.SourceTimestamp)
        spike = await folder.get_child(f"{idx}:ReversalSpike")
        out["eu"] = await (await spike.get_child("0:EngineeringUnits")).read_value()
        return out


def test_the_newest_circular_test_is_beside_the_tbe(tmp_path):
    from tests.api.rest.test_circles import circle_axis, circle_body

    settings = replace(make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path,
                                     opcua=OpcuaSettings(enabled=True, endpoint=LOOPBACK)),
                       axes=(circle_axis("x"), circle_axis("y")))
    app = create_app(settings, runner=FakeRunner(backlash_um=150.0))
    with TestClient(app) as client:
        svc, server = app.state.service, app.state.opcua
        with session_scope(svc.factory) as s:
            axes = {a.name: a for a in config_repo.list_axes(s)}
            keys = {r: config_repo.create_key(s, f"{r}-ua", r)[1] for r in ("read", "operate")}
        y = axes["y"].id
        before = asyncio.run(_read_circle(server.endpoint))
        assert before["ReversalSpike"][0] == "BadWaitingForInitialData"  # no test yet
        assert before["eu"].DisplayName.Text == "µm"
        svc.scheduler.request(y, "manual")  # b̄ of y, for the agreement
        assert svc.scheduler.idle(30)
        n = server.updates
        r = client.post(f"/api/v1/machines/{axes['y'].machine_id}/circles", json=circle_body((0.0, 150.0)),
                        headers=hdr(keys["operate"]))
        assert r.status_code == 201, r.text
        until(lambda: server.updates >= n + 2, "the OPC UA update of both axes of the plane")
        ct = client.get(f"/api/v1/axes/{y}/status", headers=hdr(keys["read"])).json()["circular_test"]
        after = asyncio.run(_read_circle(server.endpoint))
        assert after["CircularDeviation"][0] == pytest.approx(ct["circular_deviation_um"])
        assert after["CircularDeviationUncertainty"][0] == pytest.approx(ct["circular_deviation_uncertainty_um"])
        assert after["CircularHysteresis"][0] == pytest.approx(ct["hysteresis_um"])
        assert after["ReversalSpike"][0] == pytest.approx(ct["spike_um"]) and ct["spike_um"] > 50.0
        assert after["ReversalSpikeUncertainty"][0] == pytest.approx(ct["spike_uncertainty_um"])
        assert after["Agreement"][0] == ct["agreement"] is not None
        measured = datetime.fromisoformat(ct["measured_at"].replace("Z", "+00:00"))
        assert abs(after["ReversalSpike"][1].replace(tzinfo=timezone.utc) - measured) < timedelta(milliseconds=1)
        assert abs(after["MeasuredAt"][0].replace(tzinfo=timezone.utc) - measured) < timedelta(milliseconds=1)

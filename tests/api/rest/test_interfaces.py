"""The service's events fanned out to MQTT and webhooks, checked with clients we
did not write (mosquitto's broker and mosquitto_sub) and a webhook receiver that verifies
the Standard Webhooks signature by the specification's steps. SQLite only: the
publishers do not touch the database."""

from __future__ import annotations

import base64
import hashlib
import hmac
import http.server
import json
import logging
import shutil
import socket
import subprocess
import threading
import time
import uuid
from dataclasses import replace

import paho.mqtt.client as paho
import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError, MqttSettings, WebhookSettings
from api.service.events import Event, EventHub
from storage.db import config_repo, session_scope, utcnow
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.ports import free_port
from tests.waiting import until

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
needs_mosquitto = pytest.mark.skipif(not (shutil.which("mosquitto_sub") and shutil.which(MOSQUITTO)),
                                     reason="mosquitto and mosquitto-clients are not installed")  # fmt: skip
SECRET = "whsec_" + base64.b64encode(b"0123456789abcdef0123456789abcdef").decode()


class Broker:
    def __init__(self, port: int, tmp_path):
        conf = tmp_path / f"mosquitto-{port}.conf"
        conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        until(lambda: self._listening(port), f"mosquitto on port {port}")

    @staticmethod
    def _listening(port: int) -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", port)) == 0

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


def _sub(port: int, topic: str, count: int) -> list[tuple[str, bytes]]:
    """mosquitto_sub: the first ``count`` messages (retained ones at once), topic and payload."""
    out = subprocess.run(["mosquitto_sub", "-h", "127.0.0.1", "-p", str(port), "-t", topic, "-C", str(count),
                          "-W", "30", "-F", "%t %p"], capture_output=True, timeout=40)  # fmt: skip
    assert out.returncode == 0, out.stderr
    return [(line.split(b" ", 1)[0].decode(), line.split(b" ", 1)[1]) for line in out.stdout.splitlines()]


def _app(tmp_path, runner, **kw):
    return create_app(make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path, **kw), runner=runner)


def _keys_and_axis(svc):
    with session_scope(svc.factory) as s:
        key = config_repo.create_key(s, f"read-{uuid.uuid4().hex[:6]}", "read")[1]
        admin = config_repo.create_key(s, f"admin-{uuid.uuid4().hex[:6]}", "admin")[1]
        return key, admin, config_repo.list_axes(s)[0].id


def _measure(svc, axis_id):
    svc.scheduler.request(axis_id, "manual")
    assert svc.scheduler.idle(30)


@needs_mosquitto
def test_an_mqtt_subscriber_receives_the_retained_status_the_birth_and_each_alert(tmp_path, caplog):
    port, prefix = free_port(), f"t{uuid.uuid4().hex[:8]}"
    broker = Broker(port, tmp_path)
    runner = FakeRunner(backlash_um=200.0)
    try:
        app = _app(tmp_path, runner, mqtt=MqttSettings(url=f"mqtt://127.0.0.1:{port}", topic_prefix=prefix),
                   instance="plant-a")
        with TestClient(app) as client:
            svc = app.state.service
            read, admin, axis_id = _keys_and_axis(svc)
            assert _sub(port, f"{prefix}/plant-a/vmc-850/online", 1) == [(f"{prefix}/plant-a/vmc-850/online", b"online")]
            _measure(svc, axis_id)
            rest = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(read)).json()
            (topic, payload), = until(lambda: _sub(port, f"{prefix}/plant-a/+/+/status", 1), "the retained status")
            assert topic == f"{prefix}/plant-a/vmc-850/y/status"
            body = json.loads(payload)
            assert body["instance"] == "plant-a" and body["axis_id"] == axis_id and body["state"] == rest["state"]
            assert body["backlash_mean_um"] == pytest.approx(rest["backlash_mean_um"])
            # an alert raised: a subscriber listening before it gets it (QoS 1, not retained);
            # paho here, because it says when the broker has acknowledged the subscription
            got, subscribed = [], threading.Event()
            sub = paho.Client(paho.CallbackAPIVersion.VERSION2)
            sub.on_connect = lambda c, *a: c.subscribe(f"{prefix}/plant-a/+/+/alerts", qos=1)
            sub.on_subscribe = lambda *a: subscribed.set()
            sub.on_message = lambda c, u, msg: got.append((msg.topic, msg.payload))
            sub.connect("127.0.0.1", port)
            sub.loop_start()
            try:
                until(subscribed.is_set, "the alert subscription")
                runner.backlash_um = 400.0
                _measure(svc, axis_id)
                until(lambda: got, "the alert message")
            finally:
                sub.loop_stop()
                sub.disconnect()
            ((topic, payload),) = got
            alert = json.loads(payload)
            assert alert["instance"] == "plant-a"
            assert topic == f"{prefix}/plant-a/vmc-850/y/alerts" and alert["active"] is True and alert["tbe_um"] > alert["tolerance_um"]
            # the ALARM opened a work order; acknowledging it (no measurement) republishes the
            # retained status with the order's new state, as REST shows it

            def retained_order_state():
                (_, p), = _sub(port, f"{prefix}/plant-a/vmc-850/y/status", 1)
                return (json.loads(p).get("work_order") or {}).get("state")

            until(lambda: retained_order_state() == "open", "the order in the retained status")
            order_id = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(read)).json()["work_order"]["id"]
            r = client.post(f"/api/v1/maintenance/orders/{order_id}/ack", headers=hdr(admin))
            assert r.status_code == 200, r.text
            until(lambda: retained_order_state() == "acknowledged", "the acknowledged order in the retained status")
            info = client.get("/api/v1/interfaces", headers=hdr(read)).json()
            assert info["mqtt"]["connected"] == {"vmc-850": True} and info["instance"] == "plant-a"
            assert info["mqtt"]["topics"] == f"{prefix}/plant-a/<machine>/<axis>/status|alerts|maintenance"
            assert info["event_consumers"]["mqtt"]["failed"] == 0
            caplog.set_level(logging.INFO, logger="mebm.mqtt")
        # the service's own stop is a clean disconnect, not a lost connection (no WARNING
        # "lost ... retrying"), and the retained birth says offline
        mine = [r for r in caplog.records if r.name == "mebm.mqtt"]
        assert not [r for r in mine if r.levelno >= logging.WARNING], [r.getMessage() for r in mine]
        assert any("service stopping" in r.getMessage() for r in mine)
        assert _sub(port, f"{prefix}/plant-a/vmc-850/online", 1) == [(f"{prefix}/plant-a/vmc-850/online", b"offline")]
    finally:
        broker.stop()


@needs_mosquitto
def test_a_broker_outage_loses_no_measurement_and_the_status_is_published_when_it_returns(tmp_path):
    port, prefix = free_port(), f"t{uuid.uuid4().hex[:8]}"
    runner = FakeRunner(backlash_um=180.0)
    app = _app(tmp_path, runner, mqtt=MqttSettings(url=f"mqtt://127.0.0.1:{port}", topic_prefix=prefix),
               instance="plant-a")
    with TestClient(app) as client:
        svc = app.state.service
        read, _, axis_id = _keys_and_axis(svc)
        _measure(svc, axis_id)  # no broker: the cycle is not delayed or failed
        page = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(read)).json()
        assert [m["status"] for m in page["items"]] == ["ok"]
        assert app.state.mqtt.connections() == {"vmc-850": False}
        broker = Broker(port, tmp_path)
        try:
            until(lambda: app.state.mqtt.connections() == {"vmc-850": True}, "the reconnection", 90)
            (topic, payload), = _sub(port, f"{prefix}/plant-a/+/+/status", 1)
            assert topic == f"{prefix}/plant-a/vmc-850/y/status"
            assert json.loads(payload)["backlash_mean_um"] == pytest.approx(180.0, abs=2.0)
        finally:
            broker.stop()


class Receiver(http.server.BaseHTTPRequestHandler):
    """A webhook endpoint that verifies each request as the Standard Webhooks spec says:
    HMAC-SHA256 over "{webhook-id}.{webhook-timestamp}.{body}" with the secret's base64
    key, compared with each "v1,<base64>" in webhook-signature; keeps the timestamp for the
    test to check against the seconds of its own run; answers 500 to the first request it
    ever gets (to make the sender retry), 200 after."""

    received: list = []
    key = base64.b64decode(SECRET.split("_", 1)[1])

    def do_POST(self):  # noqa: N802 - http.server's name
        body = self.rfile.read(int(self.headers["content-length"]))
        msg_id, ts = self.headers["webhook-id"], self.headers["webhook-timestamp"]
        expected = base64.b64encode(hmac.new(self.key, f"{msg_id}.{ts}.".encode() + body, hashlib.sha256).digest())
        sigs = [s.split(",", 1)[1].encode() for s in self.headers["webhook-signature"].split(" ") if s.startswith("v1,")]
        valid = any(hmac.compare_digest(expected, s) for s in sigs)
        first = not Receiver.received
        Receiver.received.append((msg_id, valid, json.loads(body), int(ts)))
        self.send_response(500 if first else 200)
        self.end_headers()

    def log_message(self, *args):
        pass


def test_a_webhook_receiver_verifies_the_signature_of_each_alert_change_after_a_retry(tmp_path):
    Receiver.received = []
    started_s = int(time.time())
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Receiver)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}/hook"
    runner = FakeRunner(backlash_um=400.0)
    try:
        app = _app(tmp_path, runner, webhooks=WebhookSettings(urls=(url,), secret=SECRET))
        with TestClient(app) as client:
            svc = app.state.service
            _, admin, axis_id = _keys_and_axis(svc)
            _measure(svc, axis_id)  # raises the alert
            runner.backlash_um = 150.0
            _measure(svc, axis_id)  # clears it
            until(lambda: len(Receiver.received) >= 4, "four webhook requests")
            log = client.get("/api/v1/webhooks/deliveries", headers=hdr(admin)).json()
            ended_s = int(time.time())
    finally:
        server.shutdown()
    # each request is stamped with the second it was sent in: one of this test's
    assert all(started_s <= r[3] <= ended_s for r in Receiver.received), [r[3] for r in Receiver.received]
    # the ALARM also opened a work order: its step is delivered the same way
    (order,) = [r for r in Receiver.received if r[2]["type"].startswith("work_order.")]
    assert order[1] and order[2]["type"] == "work_order.open" and order[2]["data"]["kind"] == "corrective"
    # every message names the installation that sent it, as the MQTT payloads do
    assert {r[2]["data"]["instance"] for r in Receiver.received} == {svc.instance}
    log = [d for d in log if d["event_type"].startswith("alert.")]
    (id1, ok1, doc1, _), (id1b, ok1b, _, _), (id2, ok2, doc2, _) = [r for r in Receiver.received if r[2]["type"].startswith("alert.")]
    assert ok1 and ok1b and ok2  # every signature verifies
    assert id1 == id1b != id2  # the retry keeps its webhook-id
    assert doc1["type"] == "alert.raised" and doc2["type"] == "alert.cleared"
    assert doc1["data"]["axis"] == "y" and doc1["data"]["tbe_um"] > doc1["data"]["tolerance_um"]
    assert [(d["attempt"], d["status"], d["delivered"]) for d in reversed(log)] == [(1, 500, False), (2, 200, True),
                                                                                   (1, 200, True)]  # fmt: skip


class Accept(http.server.BaseHTTPRequestHandler):
    """A webhook endpoint that takes everything (200) and keeps (webhook-id, type)."""

    received: list = []

    def do_POST(self):  # noqa: N802 - http.server's name
        body = json.loads(self.rfile.read(int(self.headers["content-length"])))
        Accept.received.append((self.headers["webhook-id"], body["type"]))
        self.send_response(200)
        self.end_headers()

    def log_message(self, *args):
        pass


def _serve_later(port: int) -> http.server.ThreadingHTTPServer:
    Accept.received = []
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Accept)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _messages(client, admin, state=None) -> dict:
    q = "" if state is None else f"?state={state}"
    return client.get(f"/api/v1/webhooks/messages{q}", headers=hdr(admin)).json()


def test_webhook_messages_pending_when_the_service_stops_are_sent_after_the_restart(tmp_path):
    port = free_port()  # nothing listens there yet: the receiver is down
    hooks = WebhookSettings(urls=(f"http://127.0.0.1:{port}/hook",), secret=SECRET, max_attempts=20)
    runner = FakeRunner(backlash_um=400.0)
    app = _app(tmp_path, runner, webhooks=hooks)
    with TestClient(app) as client:
        svc = app.state.service
        _, admin, axis_id = _keys_and_axis(svc)
        _measure(svc, axis_id)  # raises the alert and opens a work order: two messages
        until(lambda: _messages(client, admin)["counts"]["pending"] == 2
               and _messages(client, admin)["items"][-1]["attempts"] >= 1, "a refused first attempt")
        pending = _messages(client, admin, "pending")["items"]
        assert [m["type"] for m in pending] == ["work_order.open", "alert.raised"]  # newest first
        assert pending[0]["attempts"] == 0  # held back behind the alert: the receiver gets them in order
        assert "refused" in pending[1]["last_error"].lower()
    server = _serve_later(port)  # the receiver comes back while the service is down
    try:
        app = _app(tmp_path, runner, webhooks=hooks)
        with TestClient(app) as client:
            until(lambda: len(Accept.received) == 2, "the two messages after the restart", 60)
            until(lambda: _messages(client, admin)["counts"] == {"pending": 0, "delivered": 2, "failed": 0},
                   "both messages marked delivered")
    finally:
        server.shutdown()
    assert Accept.received == [(m["webhook_id"], m["type"]) for m in reversed(pending)]  # same ids, in order


def test_a_webhook_message_that_used_every_attempt_is_kept_and_sent_again_when_an_admin_asks(tmp_path):
    port = free_port()
    hooks = WebhookSettings(urls=(f"http://127.0.0.1:{port}/hook",), secret=SECRET, max_attempts=2)
    runner = FakeRunner(backlash_um=400.0)
    app = _app(tmp_path, runner, webhooks=hooks)
    with TestClient(app) as client:
        svc = app.state.service
        read, admin, axis_id = _keys_and_axis(svc)
        _measure(svc, axis_id)
        until(lambda: _messages(client, admin)["counts"]["failed"] == 2, "both messages failed", 60)
        failed = _messages(client, admin, "failed")["items"]
        assert [m["attempts"] for m in failed] == [2, 2]
        hw = client.get("/api/v1/interfaces", headers=hdr(read)).json()["webhooks"]
        assert hw["given_up"] == 2 and hw["failed_attempts"] == 4 and hw["delivered"] == 0
        assert client.post("/api/v1/webhooks/messages/retry", headers=hdr(read)).status_code == 403
        server = _serve_later(port)
        try:
            assert client.post("/api/v1/webhooks/messages/retry", headers=hdr(admin)).json() == {"requeued": 2}
            until(lambda: _messages(client, admin)["counts"]["delivered"] == 2, "the re-queued messages", 30)
        finally:
            server.shutdown()
        assert Accept.received == [(m["webhook_id"], m["type"]) for m in reversed(failed)]
        assert client.get("/api/v1/webhooks/messages?state=lost", headers=hdr(admin)).status_code == 422


def test_webhook_messages_wait_in_memory_while_the_database_is_unreachable_and_are_stored_after(tmp_path):
    from types import SimpleNamespace

    from api.webhooks import WebhookSender
    from storage.db import make_engine, make_session_factory, upgrade, webhooks_repo
    from storage.db.records import AlertRecord

    down = make_engine(f"postgresql+psycopg://nobody@127.0.0.1:{free_port()}/none")  # a refused connection
    up = make_engine(f"sqlite:///{tmp_path}/db.sqlite3")
    upgrade(up)
    port = free_port()
    server = _serve_later(port)
    svc = SimpleNamespace(events=EventHub(), factory=make_session_factory(down), instance="plant-a")
    sender = WebhookSender(svc, WebhookSettings(urls=(f"http://127.0.0.1:{port}/hook",), secret=SECRET))
    try:
        alert = AlertRecord(id=7, axis_id=1, kind="tbe", raised_at=utcnow(), cleared_at=None, acknowledged_at=None,
                            acknowledged_by=None, raised_by_measurement_id=1, cleared_by_measurement_id=None,
                            task_name="circle", tbe_um=50.0, tolerance_um=45.0, backlash_um=300.0,
                            backlash_limit_um=200.0, message="ALARM")
        svc.events.publish(Event("alert_changed", 1, "m", "y", utcnow(), alert=alert))
        until(lambda: sender.unstored == 1, "the message held in memory")
        time.sleep(0.5)
        assert Accept.received == [] and sender.unstored == 1  # nothing sent, nothing lost
        svc.factory = make_session_factory(up)  # the database answers again
        until(lambda: len(Accept.received) == 1, "the message sent once stored", 30)
        assert Accept.received[0][1] == "alert.raised" and sender.unstored == 0
        def delivered():
            with session_scope(svc.factory) as s:
                return webhooks_repo.counts(s)["delivered"] == 1

        until(delivered, "the message marked delivered")
    finally:
        sender.close()
        svc.events.close()
        server.shutdown()
        down.dispose()
        up.dispose()


def test_a_slow_consumer_never_delays_a_cycle_and_a_full_queue_drops_its_oldest(tmp_path):
    hub = EventHub()
    gate, busy, seen = threading.Event(), threading.Event(), []
    sub = hub.subscribe("slow", lambda ev: (busy.set(), gate.wait(30), seen.append(ev.axis_id)), maxsize=2)
    fast = hub.subscribe("fast", lambda ev: seen.append(-ev.axis_id))
    hub.publish(Event("measurement_stored", 1, "m", "y", utcnow()))
    until(busy.is_set, "the slow consumer taking event 1")
    for i in range(2, 6):
        hub.publish(Event("measurement_stored", i, "m", "y", utcnow()))  # returns at once
    until(lambda: sorted(x for x in seen if x < 0) == [-5, -4, -3, -2, -1], "the fast consumer's five events")
    gate.set()
    until(lambda: len([x for x in seen if x > 0]) == 3, "the slow consumer's events")
    assert [x for x in seen if x > 0] == [1, 4, 5]  # 1 was being handled; 2 and 3 dropped for 4 and 5
    assert sub.dropped == 2 and fast.dropped == 0
    hub.close()


def test_a_cycle_completes_while_an_interface_is_stuck(tmp_path):
    runner = FakeRunner()
    app = _app(tmp_path, runner)
    gate = threading.Event()
    with TestClient(app) as client:
        svc = app.state.service
        read, _, axis_id = _keys_and_axis(svc)
        svc.events.subscribe("stuck", lambda ev: gate.wait(60))
        _measure(svc, axis_id)
        _measure(svc, axis_id)
        page = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(read)).json()
        assert [m["status"] for m in page["items"]] == ["ok", "ok"]
        gate.set()


@pytest.mark.parametrize("doc, field", [
    ({"mqtt": {"url": "http://broker"}}, "mqtt.url"),
    ({"mqtt": {"topic_prefix": "a/#"}}, "mqtt.topic_prefix"),
    ({"webhooks": {"urls": ["http://mes/hook"]}}, "webhooks.secret must be set"),
    ({"webhooks": {"urls": ["ftp://mes/hook"], "secret": SECRET}}, "is not an http(s) URL"),
    ({"webhooks": {"urls": ["http://mes/hook"], "secret": "whsec_c2hvcnQ="}}, "use at least 16"),
    ({"mqtt": {"broker": "x"}}, "broker"),
])
def test_bad_interface_settings_are_refused_naming_the_field(doc, field):
    with pytest.raises(ConfigError, match=field.replace("(", r"\(").replace(")", r"\)")):
        parse_settings(doc)


def test_make_run_defaults_publish_to_a_local_broker_and_the_environment_turns_it_off():
    from api.service.config.loading import load_settings

    assert load_settings(None, {}).mqtt.url == "mqtt://127.0.0.1:1883"
    assert load_settings(None, {"MEBM_MQTT_URL": ""}).mqtt.url is None
    assert replace(load_settings(None, {}), webhooks=WebhookSettings()).webhooks.urls == ()


def test_the_start_banner_says_whether_mqtt_and_webhooks_are_on_without_the_broker_password(tmp_path):
    from api.cli.serve import banner
    from api.service.service import StartReport

    report = StartReport(database="sqlite:///x", replayed=0, interrupted=0, created_axes=(), demo_keys={},
                         simulators={}, bootstrap_admin=None)  # fmt: skip
    on = make_settings("sqlite:///x", tmp_path, mqtt=MqttSettings(url="mqtt://mes:s3cret@broker:1884"), instance="plant-a",
                       webhooks=WebhookSettings(urls=("http://mes/hook",), secret=SECRET))  # fmt: skip
    text = banner(on, report, "http://127.0.0.1:1")
    assert "MQTT: mqtt://mes:***@broker:1884, topics mebm/plant-a/<machine>/<axis>/status|alerts" in text
    assert "s3cret" not in text and "webhooks: 1 receiver(s)" in text
    off = banner(make_settings("sqlite:///x", tmp_path), report, "http://127.0.0.1:1")
    assert "MQTT: off" in off and "webhooks: off" in off


@needs_mosquitto
def test_a_circular_test_refreshes_the_retained_status_and_its_alert_names_the_test(tmp_path):
    from tests.api.rest.test_circles import circle_axis, circle_body

    port, prefix = free_port(), f"t{uuid.uuid4().hex[:8]}"
    broker = Broker(port, tmp_path)
    try:
        settings = make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path, instance="plant-a",
                                 mqtt=MqttSettings(url=f"mqtt://127.0.0.1:{port}", topic_prefix=prefix))
        app = create_app(replace(settings, axes=(circle_axis("x"), circle_axis("y"))), runner=FakeRunner(150.0))
        with TestClient(app) as client:
            svc = app.state.service
            with session_scope(svc.factory) as s:
                machine_id = config_repo.list_axes(s)[0].machine_id
                operate = config_repo.create_key(s, "op-mqtt", "operate")[1]
            assert _sub(port, f"{prefix}/plant-a/vmc-850/online", 1) == [(f"{prefix}/plant-a/vmc-850/online", b"online")]
            got, subscribed = [], threading.Event()
            sub = paho.Client(paho.CallbackAPIVersion.VERSION2)
            sub.on_connect = lambda c, *a: c.subscribe(f"{prefix}/plant-a/+/+/alerts", qos=1)
            sub.on_subscribe = lambda *a: subscribed.set()
            sub.on_message = lambda c, u, msg: got.append((msg.topic, msg.payload))
            sub.connect("127.0.0.1", port)
            sub.loop_start()
            try:
                until(subscribed.is_set, "the alert subscription")
                r = client.post(f"/api/v1/machines/{machine_id}/circles", json=circle_body((0.0, 300.0)),
                                headers=hdr(operate))
                assert r.status_code == 201, r.text
                until(lambda: got, "the alert message")
            finally:
                sub.loop_stop()
                sub.disconnect()
            test_id = r.json()["id"]
            ((topic, payload),) = got
            alert = json.loads(payload)
            assert topic == f"{prefix}/plant-a/vmc-850/y/alerts" and alert["active"] is True
            assert alert["raised_by_circular_test_id"] == test_id and alert["tbe_um"] > alert["tolerance_um"]

            def retained(axis):
                (_, p), = _sub(port, f"{prefix}/plant-a/vmc-850/{axis}/status", 1)
                return (json.loads(p).get("circular_test") or {}).get("id")

            until(lambda: retained("y") == test_id and retained("x") == test_id, "the test in both retained statuses")
    finally:
        broker.stop()

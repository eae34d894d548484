"""Two installations with a machine of one name on one broker and one MES: each has a name
of its own (drawn once and kept in its data folder), which goes into its MQTT topics and
payloads, its MTConnect device uuids and its OPC UA namespace, so nothing of the two mixes.
Checked on the Mosquitto broker at 127.0.0.1:1883 with a paho subscriber."""

from __future__ import annotations

import json
import socket
import threading
import time
import uuid

import paho.mqtt.client as paho
import pytest
from fastapi.testclient import TestClient

from api.mqtt import client_id
from api.opcua.nodes import namespace_uri
from api.service.config.settings import ConfigError, MqttSettings
from api.service.installation import INSTALLATION_FILE, installation_name
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.waiting import until

BROKER = ("127.0.0.1", 1883)


def _broker_listens() -> bool:
    with socket.socket() as s:
        s.settimeout(1.0)
        return s.connect_ex(BROKER) == 0


needs_broker = pytest.mark.skipif(not _broker_listens(), reason="no MQTT broker on 127.0.0.1:1883")


def test_the_default_name_differs_between_installations_and_is_kept(tmp_path):
    a = installation_name(make_settings("sqlite:///x", tmp_path / "a"))
    b = installation_name(make_settings("sqlite:///x", tmp_path / "b"))
    assert a != b and a.startswith("mebm-") and b.startswith("mebm-")
    assert installation_name(make_settings("sqlite:///x", tmp_path / "a")) == a  # kept across restarts
    assert (tmp_path / "a" / INSTALLATION_FILE).read_text().strip() == a
    assert installation_name(make_settings("sqlite:///x", tmp_path / "a", instance="plant-a")) == "plant-a"
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / INSTALLATION_FILE).write_text("no/slash\n")
    with pytest.raises(ConfigError, match="installation-id"):
        installation_name(make_settings("sqlite:///x", tmp_path / "c"))


def test_client_ids_are_unique_per_installation_and_machine():
    ids = {client_id(i, m) for i in ("plant-a", "plant-b") for m in ("m a", "m_a", "vmc-1")}
    assert len(ids) == 6 and all(len(c) <= 64 for c in ids)


@needs_broker
def test_two_installations_with_one_machine_name_publish_under_topics_of_their_own(tmp_path):
    prefix = f"t{uuid.uuid4().hex[:8]}"
    got: dict[str, bytes] = {}
    subscribed = threading.Event()
    sub = paho.Client(paho.CallbackAPIVersion.VERSION2)
    sub.on_connect = lambda c, *a: c.subscribe(f"{prefix}/#", qos=1)
    sub.on_subscribe = lambda *a: subscribed.set()
    sub.on_message = lambda c, u, msg: got.__setitem__(msg.topic, msg.payload)
    sub.connect(*BROKER)
    sub.loop_start()
    apps = [TestClient(_app(tmp_path / name, prefix)) for name in ("plant-a", "plant-b")]
    try:
        until(subscribed.is_set, "the subscription")
        for c in apps:
            c.__enter__()
        svcs = [c.app.state.service for c in apps]
        assert svcs[0].instance != svcs[1].instance
        for svc in svcs:
            with session_scope(svc.factory) as s:
                svc.scheduler.request(config_repo.list_axes(s)[0].id, "manual")
            assert svc.scheduler.idle(30)
        topics = {svc.instance: f"{prefix}/{svc.instance}/vmc-850/y/status" for svc in svcs}
        until(lambda: all(t in got for t in topics.values()), "both statuses", 30)
        for instance, topic in topics.items():
            assert json.loads(got[topic])["instance"] == instance
        # both connections stay up: no broker drops one for the other's client id
        links = [c.app.state.mqtt._links["vmc-850"] for c in apps]
        assert links[0].client_id != links[1].client_id
        time.sleep(1.5)
        assert all(c.app.state.mqtt.connections() == {"vmc-850": True} for c in apps)
        births = {t: p for t, p in got.items() if t.endswith("/online")}
        assert births == {f"{prefix}/{svc.instance}/vmc-850/online": b"online" for svc in svcs}
        # one MES reading both agents: two devices, not one
        uuids = [c.get("/mtconnect/probe").text.split('uuid="', 1)[1].split('"', 1)[0] for c in apps]
        assert uuids[0] != uuids[1]
        assert namespace_uri(svcs[0].instance) != namespace_uri(svcs[1].instance)
    finally:
        for c in apps:
            c.__exit__(None, None, None)
        for topic in list(got):  # the retained messages of this test leave the shared broker with it
            sub.publish(topic, b"", qos=1, retain=True).wait_for_publish(5)
        sub.loop_stop()
        sub.disconnect()


def _app(data_dir, prefix):
    from api.rest import create_app

    data_dir.mkdir()
    settings = make_settings(f"sqlite:///{data_dir}/db.sqlite3", data_dir,
                             mqtt=MqttSettings(url=f"mqtt://{BROKER[0]}:{BROKER[1]}", topic_prefix=prefix))
    return create_app(settings, runner=FakeRunner(backlash_um=190.0))


@needs_broker
def test_two_stored_machines_that_meet_in_one_topic_are_named_in_the_log(tmp_path, caplog):
    """Machines stored before such names were refused keep their client ids apart and are
    named, so an operator can rename one."""
    import logging

    from types import SimpleNamespace

    from api.mqtt import MqttPublisher
    from api.service.events import EventHub

    service = SimpleNamespace(instance="plant-a", events=EventHub())  # what the publisher uses of the service
    pub = MqttPublisher(service, MqttSettings(url=f"mqtt://{BROKER[0]}:{BROKER[1]}", topic_prefix="t"))
    try:
        caplog.set_level(logging.ERROR, logger="mebm.mqtt")
        a, b = pub.link("m a"), pub.link("m_a")
        assert a.client_id != b.client_id
        until(lambda: pub.connections() == {"m a": True, "m_a": True}, "both connections")
        assert any("'m a' and 'm_a' publish under one topic level 'm_a'" in r.getMessage() for r in caplog.records)
    finally:
        pub.close()

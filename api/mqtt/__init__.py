"""MQTT: the status and the alerts, published to a broker (paho-mqtt 2.x).

Topics, per installation ``I`` (``[service] instance``: api.service.installation), machine
``M`` and axis ``A`` (names with ``/ + #`` or blanks get ``_``; two names that map to one
are refused at creation, storage.db.names):

- ``<prefix>/I/M/A/status``: the status body as ``GET /axes/{id}/status`` serves it, with
  ``instance`` added, **retained**, QoS 1, on each stored measurement and each failed cycle;
- ``<prefix>/I/M/A/alerts``: each alert change (raised, cleared) as JSON, QoS 1;
- ``<prefix>/I/M/A/maintenance``: each work-order step (opened, acknowledged, repaired,
  verified, back to open, cancelled) as JSON, QoS 1, through the same outbox as alerts;
- ``<prefix>/I/M/online``: ``online`` (retained) when the machine's connection is up,
  ``offline`` by the broker's will when it drops.

Every JSON payload names its ``instance``. Two installations on one broker publish under
topics of their own even for machines of one name, and their clients never share an id.

One connection per machine (each with its own will), with a client id unique per
installation, machine and process (:func:`client_id`). paho reconnects with back-off
(1-60 s). While the broker is away, the newest status per axis and up to ``outbox_max``
alert messages wait (the oldest alerts dropped and counted); on every (re)connect the
waiting statuses are published again and the alerts not yet acknowledged are resent
(at least once, as QoS 1 is). Publishing runs on the event hub's own consumer thread:
the broker never delays or fails a cycle.
"""

from __future__ import annotations

import collections
import hashlib
import json
import logging
import os
import queue
import socket
import threading
from urllib.parse import unquote, urlsplit

import paho.mqtt.client as paho

from api.service.config.settings import MqttSettings
from api.service.events import Event, order_document
from storage.db.names import interface_name

log = logging.getLogger("mebm.mqtt")
QOS = 1


def topic_level(name: str) -> str:
    """A machine's or an axis' name as one topic level (two names that map to one are refused
    at creation: storage.db.names)."""
    return interface_name(name)


def client_id(instance: str, machine: str) -> str:
    """The MQTT client id of one machine's connection: readable (instance and machine),
    at most 64 characters, and unique per installation, machine (its exact name) and
    process by its digest: a broker drops the older of two connections of one id."""
    digest = hashlib.sha256(f"{instance}\0{machine}\0{socket.gethostname()}\0{os.getpid()}".encode()).hexdigest()
    return f"mebm-{instance[:24]}-{topic_level(machine)[:20]}-{digest[:12]}"


def with_instance(body: bytes, instance: str) -> bytes:
    """The status body (JSON) with the installation's name added."""
    doc = json.loads(body)
    return json.dumps({"instance": instance, **doc}, separators=(",", ":")).encode() if isinstance(doc, dict) else body


def alert_document(ev: Event) -> dict:
    a = ev.alert
    return {
        "machine": ev.machine, "axis": ev.axis, "axis_id": ev.axis_id, "id": a.id, "kind": a.kind,
        "active": a.active, "raised_at": a.raised_at.isoformat(),
        "cleared_at": a.cleared_at.isoformat() if a.cleared_at else None, "task_name": a.task_name,
        "tbe_um": a.tbe_um, "tolerance_um": a.tolerance_um, "backlash_um": a.backlash_um,
        "backlash_limit_um": a.backlash_limit_um, "message": a.message,
        "raised_by_circular_test_id": a.raised_by_circular_test_id,  # the evidence, when a circular test raised it
    }  # fmt: skip


class _MachineLink:
    """One broker connection for one machine: birth, will, retained statuses, alert outbox."""

    def __init__(self, pub: MqttPublisher, machine: str):
        self.pub = pub
        self.machine = machine
        self.online_topic = f"{pub.base}/{topic_level(machine)}/online"
        self.connected = False
        self.closing = False  # close() asked for the disconnect: not a lost connection
        self.status: dict[str, bytes] = {}  # topic -> the newest status body
        self.outbox: collections.OrderedDict[int, tuple[str, bytes]] = collections.OrderedDict()  # key -> alert
        self.in_flight: dict[int, int] = {}  # paho mid -> outbox key
        self._acks: queue.SimpleQueue[int] = queue.SimpleQueue()
        self._key = 0
        self._lock = threading.Lock()
        self.client_id = client_id(pub.instance, machine)
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=self.client_id, clean_session=True)
        if pub.username is not None:
            c.username_pw_set(pub.username, pub.password)
        if pub.tls:
            c.tls_set()
        c.will_set(self.online_topic, b"offline", qos=QOS, retain=True)
        c.reconnect_delay_set(1, 60)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_publish = self._on_publish
        self.client = c
        c.connect_async(pub.host, pub.port, keepalive=30)
        c.loop_start()

    def _on_connect(self, client, userdata, flags, reason_code, properties):
        if reason_code.is_failure:
            log.warning("MQTT broker %s:%s refused %s: %s", self.pub.host, self.pub.port, self.machine, reason_code)
            return
        with self._lock:
            self.connected = True
            self._drain_acks()
            self.in_flight.clear()
            client.publish(self.online_topic, b"online", qos=QOS, retain=True)
            for topic, body in self.status.items():
                client.publish(topic, body, qos=QOS, retain=True)
            for key, (topic, body) in self.outbox.items():
                self.in_flight[client.publish(topic, body, qos=QOS).mid] = key
        log.info("MQTT connected to %s:%s for machine %s", self.pub.host, self.pub.port, self.machine)

    def _on_disconnect(self, client, userdata, flags, reason_code, properties):
        with self._lock:
            was, self.connected = self.connected, False
        if self.closing:
            log.info("MQTT disconnected from %s:%s for machine %s (service stopping)", self.pub.host, self.pub.port,
                     self.machine)
        elif was:
            log.warning("MQTT connection of machine %s lost (%s): retrying with back-off", self.machine, reason_code)

    def _on_publish(self, client, userdata, mid, reason_code, properties):
        # paho calls this holding its own message lock, which publish() takes too: taking
        # self._lock here could deadlock with a publish under self._lock. Queue the ack.
        self._acks.put(mid)

    def _drain_acks(self) -> None:
        """Drop the acknowledged alerts from the outbox (under self._lock)."""
        while True:
            try:
                mid = self._acks.get_nowait()
            except queue.Empty:
                return
            key = self.in_flight.pop(mid, None)
            if key is not None:
                self.outbox.pop(key, None)
                self.pub.published += 1

    def publish_status(self, topic: str, body: bytes) -> None:
        with self._lock:
            self.status[topic] = body
            if self.connected:
                self.client.publish(topic, body, qos=QOS, retain=True)

    def publish_alert(self, topic: str, body: bytes) -> None:
        with self._lock:
            self._drain_acks()
            if len(self.outbox) >= self.pub.outbox_max:
                self.outbox.popitem(last=False)
                self.pub.dropped += 1
                log.warning("MQTT outbox of machine %s full: oldest alert message dropped", self.machine)
            self._key += 1
            self.outbox[self._key] = (topic, body)
            if self.connected:
                self.in_flight[self.client.publish(topic, body, qos=QOS).mid] = self._key

    def close(self) -> None:
        with self._lock:
            self.closing = True
            if self.connected:
                self.client.publish(self.online_topic, b"offline", qos=QOS, retain=True)
        self.client.disconnect()
        self.client.loop_stop()


class MqttPublisher:
    """Subscribes to the service's events and publishes them (see the module docstring)."""

    def __init__(self, service, settings: MqttSettings):
        u = urlsplit(settings.url)
        self.service = service
        self.host = u.hostname
        self.port = u.port or (8883 if u.scheme == "mqtts" else 1883)
        self.tls = u.scheme == "mqtts"
        self.username = unquote(u.username) if u.username else None
        self.password = unquote(u.password) if u.password else None
        self.prefix = settings.topic_prefix
        self.instance: str = service.instance
        self.base = f"{self.prefix}/{self.instance}"  # every topic of this installation begins so
        self.outbox_max = settings.outbox_max
        self.published = self.dropped = 0
        self._links: dict[str, _MachineLink] = {}
        self._lock = threading.Lock()
        self.subscription = service.events.subscribe("mqtt", self.handle)

    def link(self, machine: str) -> _MachineLink:
        with self._lock:
            if machine not in self._links:
                # machines stored before such names were refused may still meet in one topic: say so, once
                other = next((m for m in self._links if topic_level(m) == topic_level(machine)), None)
                if other is not None:
                    log.error("MQTT: machines %r and %r publish under one topic level %r: rename one of them",
                              other, machine, topic_level(machine))
                self._links[machine] = _MachineLink(self, machine)
            return self._links[machine]

    def handle(self, ev: Event) -> None:
        base = f"{self.base}/{topic_level(ev.machine)}/{topic_level(ev.axis)}"
        if ev.kind in ("measurement_stored", "cycle_failed", "circular_test_stored"):
            body = self.service.status_document(ev.axis_id)
            if body is not None:
                self.link(ev.machine).publish_status(f"{base}/status", with_instance(body, self.instance))
        elif ev.kind == "alert_changed":
            body = json.dumps({"instance": self.instance, **alert_document(ev)}, separators=(",", ":")).encode()
            self.link(ev.machine).publish_alert(f"{base}/alerts", body)
        elif ev.kind == "work_order_changed":
            body = json.dumps({"instance": self.instance, **order_document(ev)}, separators=(",", ":")).encode()
            self.link(ev.machine).publish_alert(f"{base}/maintenance", body)
            status = self.service.status_document(ev.axis_id)  # its work_order changed: the retained one too
            if status is not None:
                self.link(ev.machine).publish_status(f"{base}/status", with_instance(status, self.instance))

    def connected(self, machine: str) -> bool:
        link = self._links.get(machine)
        return bool(link and link.connected)

    def connections(self) -> dict[str, bool]:
        with self._lock:
            return {m: link.connected for m, link in self._links.items()}

    def close(self) -> None:
        self.service.events.unsubscribe(self.subscription)
        with self._lock:
            links, self._links = list(self._links.values()), {}
        for link in links:
            link.close()

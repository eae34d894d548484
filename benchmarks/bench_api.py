"""Load GET /api/v1/axes/{id}/status from N concurrent clients on loopback and print
throughput and latency percentiles. A measurement, not a test.

    .venv/bin/python benchmarks/bench_api.py [--clients 50] [--duration-s 20] [--days 365]
                                             [--database-url URL] [--publishers]

It seeds a fresh database (SQLite in a temporary folder by default) with a year of
daily measurements of the demo axis (curves, TBE, a few alerts), starts
``mebm serve --no-scheduler`` as a subprocess on a free port, and runs the clients
(keep-alive HTTP/1.1 over raw asyncio streams, so the client costs little CPU) in
this process. Every loop is bounded in count and in time.

``--publishers``: the same load with every event interface on and busy. The scheduler
runs, a second axis on the built-in simulated controller is measured every few seconds
(high time scale), and each stored measurement is published: MQTT to the broker at
127.0.0.1:1883, webhooks to a receiver in this process, and the MTConnect and OPC UA
interfaces where the service has them. It prints how many measurements were stored and
delivered during the load, so "publishers on" is seen, not assumed.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from api.service.config.settings import demo_axis  # noqa: E402
from api.service.cycles.runner import analyse  # noqa: E402
from core.criteria import BacklashProfile  # noqa: E402
from core.tbe import decide  # noqa: E402
from storage.db import (  # noqa: E402
    AxisRecord,
    FinishedCycle,
    config_repo,
    make_engine,
    make_session_factory,
    results_repo,
    session_scope,
    upgrade,
)
from tests.demo import demo_axis_toml, demo_machine_toml  # noqa: E402

CONFIG = "[auth]\ndemo_keys = false\n" + demo_machine_toml(
    "bench-vmc", demo_axis_toml(travel_mm=(0, 1000), controller="modbus://127.0.0.1:1", schedule_enabled=False))


PUBLISHERS = """
[simulator]
time_scale = 40
[mqtt]
url = "mqtt://127.0.0.1:1883"
topic_prefix = "{prefix}"
[webhooks]
urls = ["http://127.0.0.1:{hook_port}/hook"]
secret = "whsec_{secret}"
{extra}
""" + demo_machine_toml("bench-sim", demo_axis_toml("x", travel_mm=(0, 300), measure_feed_mm_min=6000,
                                                            schedule_interval_s=3))
# The MTConnect and OPC UA interfaces, on in this run where the service has them (each
# table is only written when the service's configuration knows it).
INTERFACE_TABLES = {"mtconnect": "[mtconnect]\nenabled = true\n",
                    "opcua": "[opcua]\nenabled = true\nendpoint = \"opc.tcp://127.0.0.1:{opcua_port}/mebm/\"\n"}


class Receivers:
    """What the publishers deliver during the load: MQTT status messages (a paho client
    subscribed to the run's own topic prefix) and webhook POSTs (an HTTP receiver)."""

    def __init__(self, prefix: str):
        import http.server
        import threading

        import paho.mqtt.client as mqtt

        self.mqtt_status = 0
        self.webhooks = 0
        outer = self

        class Hook(http.server.BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802 - http.server's name
                self.rfile.read(int(self.headers.get("content-length", 0)))
                outer.webhooks += 1
                self.send_response(204)
                self.end_headers()

            def log_message(self, *_a):
                pass

        self.http = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Hook)
        threading.Thread(target=self.http.serve_forever, daemon=True).start()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)

        def on_message(_c, _u, msg):
            if msg.topic.endswith("/status"):
                outer.mqtt_status += 1

        self.client.on_message = on_message
        self.client.on_connect = lambda c, *_a: c.subscribe(f"{prefix}/#", qos=1)
        self.client.connect("127.0.0.1", 1883)
        self.client.loop_start()

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()
        self.http.shutdown()


def _known_tables() -> set[str]:
    from api.service.config.loading import TABLES

    return set(TABLES)


def synthetic_round_trip(axis: AxisRecord):
    """One analysed round trip over 0..1000 mm (b = 228 µm, 4 µm cyclic lead error)."""
    x = np.arange(-30.0, 1030.0, 0.1)
    cmd = np.concatenate([x, x[::-1]])
    h = 0.228 / 2
    table = np.where(np.arange(cmd.size) < x.size, cmd - h, cmd + h)
    table = table + 0.004 * np.sin(2 * np.pi * table / 16.0)
    t = np.arange(cmd.size) * 0.002
    return analyse(axis, t, cmd / 6.857, table)


def seed(url: str, days: int) -> str:
    engine = make_engine(url)
    upgrade(engine)
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "bench-vmc", "benchmark")
        # the configured controller, not the built-in simulator: its thread would tax the server
        axis = config_repo.create_axis(s, m.id, demo_axis(controller_url="modbus://127.0.0.1:1").settings)
        _, key = config_repo.create_key(s, "bench-read", "read")
    rt0 = synthetic_round_trip(axis)
    t0 = datetime.now(timezone.utc) - timedelta(days=days)
    rng = np.random.default_rng(0)
    for d in range(days):
        temp = 15.0 + 8.0 * np.sin(2 * np.pi * d / 365.0) + rng.normal(0, 0.5)
        b = 220.0 + 2.0 * (temp - 20.0) + rng.normal(0, 1.0)
        bp = rt0.backlash
        shifted = BacklashProfile(bp.position_mm, bp.backlash_um + (b - bp.mean_um), b, bp.min_um + b - bp.mean_um,
                                  bp.max_um + b - bp.mean_um, bp.std_um)
        rt = replace(rt0, backlash=shifted)
        when = t0 + timedelta(days=d)
        fc = FinishedCycle(uuid=str(uuid.uuid4()), axis_id=axis.id, trigger="schedule", status="ok",
                           requested_at=when, started_at=when, finished_at=when + timedelta(seconds=40),
                           temperature_c=float(temp), utility_day=float(d), uncertainty_um=0.0, run_file=None,
                           round_trip=rt, decision=decide(b, axis.tasks))
        with session_scope(factory) as s:
            results_repo.save_finished_cycle(s, fc)
    engine.dispose()
    return key


async def client(host, port, path, key, stop_at, latencies, errors, max_requests):
    reader, writer = await asyncio.open_connection(host, port)
    req = (f"GET {path} HTTP/1.1\r\nHost: {host}\r\nX-API-Key: {key}\r\nConnection: keep-alive\r\n\r\n").encode()
    n = 0
    try:
        while time.monotonic() < stop_at and n < max_requests:
            t = time.perf_counter()
            writer.write(req)
            await writer.drain()
            head = await reader.readuntil(b"\r\n\r\n")
            m = re.search(rb"content-length: (\d+)", head, re.I)
            await reader.readexactly(int(m.group(1)) if m else 0)
            latencies.append(time.perf_counter() - t)
            if not head.startswith(b"HTTP/1.1 200"):
                errors.append(head.split(b"\r\n", 1)[0].decode())
            n += 1
    finally:
        writer.close()


async def load(host, port, path, key, clients, duration_s):
    latencies: list[float] = []
    errors: list[str] = []
    stop_at = time.monotonic() + duration_s
    t0 = time.monotonic()
    await asyncio.wait_for(
        asyncio.gather(*(client(host, port, path, key, stop_at, latencies, errors, 10**6) for _ in range(clients))),
        timeout=duration_s + 30,
    )
    return latencies, errors, time.monotonic() - t0


def _free_port() -> int:
    import socket

    with socket.socket() as so:
        so.bind(("127.0.0.1", 0))
        return so.getsockname()[1]


def _stored(port: int, key: str) -> int:
    """Measurements stored on the simulated axis (id 2) so far."""
    import json
    import urllib.request

    req = urllib.request.Request(f"http://127.0.0.1:{port}/api/v1/axes/2/measurements?limit=1",
                                 headers={"X-API-Key": key})
    with urllib.request.urlopen(req, timeout=10) as r:
        return int(json.loads(r.read())["total"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--duration-s", type=float, default=20.0)
    ap.add_argument("--days", type=int, default=365, help="days of daily history to seed")
    ap.add_argument("--database-url", help="default: SQLite in a temporary folder (a PostgreSQL database "
                                           "must be empty)")
    ap.add_argument("--publishers", action="store_true",
                    help="every event interface on, with a simulated axis measured every 3 s during the load")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mebm-bench-") as tmp:
        url = a.database_url or f"sqlite:///{tmp}/bench.sqlite3"
        t = time.monotonic()
        key = seed(url, a.days)
        print(f"seeded {a.days} daily measurements in {time.monotonic() - t:.1f} s ({url.split('://')[0]})")
        cfg = Path(tmp) / "bench.toml"
        receivers = None
        if a.publishers:
            prefix = f"mebm-bench-{uuid.uuid4().hex[:8]}"
            receivers = Receivers(prefix)
            extra = "".join(table.format(opcua_port=_free_port()) for name, table in INTERFACE_TABLES.items()
                            if name in _known_tables())
            head, machines = CONFIG.split("[[machines]]", 1)
            cfg.write_text(head + PUBLISHERS.format(prefix=prefix, hook_port=receivers.http.server_address[1],
                                                    secret=base64.b64encode(os.urandom(32)).decode(), extra=extra)
                           + "[[machines]]" + machines)
        else:
            cfg.write_text(CONFIG)
        log = open(Path(tmp) / "serve.log", "w+")  # noqa: SIM115
        env = {**os.environ, "MEBM_DATABASE_URL": url}
        proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--config", str(cfg), "--port", "0",
                                 "--data-dir", tmp, *([] if a.publishers else ["--no-scheduler"])], cwd=ROOT,
                                env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            port = None
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and port is None and proc.poll() is None:
                log.seek(0)
                m = re.search(r"mebm service on http://127\.0\.0\.1:(\d+)", log.read())
                port = int(m.group(1)) if m else None
                time.sleep(0.1)
            if port is None:
                log.seek(0)
                print(log.read())
                return 1
            path = "/api/v1/axes/1/status"
            asyncio.run(load("127.0.0.1", port, path, key, 2, 1.0))  # warm up
            before = _stored(port, key) if a.publishers else 0
            seen0 = (receivers.mqtt_status, receivers.webhooks) if receivers else (0, 0)
            lat, errors, wall = asyncio.run(load("127.0.0.1", port, path, key, a.clients, a.duration_s))
            if a.publishers:
                stored = _stored(port, key) - before
                log.seek(0)
                banner = [ln for ln in log.read().splitlines()[:20] if ln.startswith(("MQTT", "webhooks", "MTConnect",
                                                                                      "OPC UA"))]
                print("publishers on:", "; ".join(banner))
                print(f"during the load: {stored} measurement(s) stored on the simulated axis; "
                      f"{receivers.mqtt_status - seen0[0]} MQTT status message(s) and "
                      f"{receivers.webhooks - seen0[1]} webhook POST(s) received")
        finally:
            if receivers is not None:
                receivers.close()
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
    ms = sorted(x * 1e3 for x in lat)
    pct = lambda q: ms[min(int(q * len(ms)), len(ms) - 1)]  # noqa: E731
    print(f"GET {path}: {a.clients} clients, {wall:.1f} s, {len(ms)} requests, {len(errors)} errors")
    print(f"throughput {len(ms) / wall:.0f} req/s; latency p50 {pct(0.50):.1f} ms, p90 {pct(0.90):.1f} ms, "
          f"p99 {pct(0.99):.1f} ms, max {ms[-1]:.1f} ms (mean {statistics.fmean(ms):.1f} ms)")
    print(f"goal p99 < 25 ms: {'met' if pct(0.99) < 25 else 'NOT met'} on {os.cpu_count()} CPU(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

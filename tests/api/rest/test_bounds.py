"""Bounds: one waiting manual measurement (atomic in the database), 429 with
Retry-After beyond it, a per-key trigger rate, throttled and logged failed
authentication, and a request body limit enforced before the body is read."""

from __future__ import annotations

import threading
import uuid

import numpy as np
import pytest

from api.rest.limits import AuthThrottle, TokenBucket
from storage.db import WaitingCycleError, results_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.demo import demo_axis_toml, demo_machine_toml

V1 = "/api/v1"


def test_sixty_concurrent_triggers_leave_at_most_one_waiting_cycle(app_env, runner):
    client, svc, keys, axis_id = app_env
    client.app.state.trigger_limit = TokenBucket(1e6, 1000)  # this test is about the waiting rule only
    runner.gate = threading.Event()  # the first cycle stays running while the others arrive
    go = threading.Barrier(60)
    answers = []

    def post():
        go.wait()
        answers.append(client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["operate"])))

    threads = [threading.Thread(target=post) for _ in range(60)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    try:
        with session_scope(svc.factory) as s:
            _, rows = results_repo.list_measurements(s, axis_id, limit=500)
        queued = [c for c in rows if c.status == "queued"]
        accepted = [r for r in answers if r.status_code == 202]
        refused = [r for r in answers if r.status_code == 429]
        assert len(queued) <= 1
        assert len(accepted) + len(refused) == 60 and len(accepted) == len(rows) <= 2
        assert all(int(r.headers["Retry-After"]) >= 1 for r in refused)
        assert "waiting already" in refused[0].json()["detail"]
    finally:
        runner.gate.set()
        assert svc.scheduler.idle(30)


def test_the_database_refuses_a_second_waiting_manual_cycle_whoever_asks(app_env):
    """Two writers that bypass the service's in-memory queue (as two processes would)."""
    _client, svc, _keys, axis_id = app_env
    go = threading.Barrier(2)
    outcomes = []

    def insert():
        go.wait()
        try:
            with session_scope(svc.factory) as s:
                results_repo.queue_cycle(s, axis_id, str(uuid.uuid4()), "manual")
            outcomes.append("queued")
        except WaitingCycleError:
            outcomes.append("refused")

    threads = [threading.Thread(target=insert) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(outcomes) == ["queued", "refused"]
    with session_scope(svc.factory) as s:  # scheduled cycles are not limited by the rule
        results_repo.queue_cycle(s, axis_id, str(uuid.uuid4()), "schedule")
        results_repo.queue_cycle(s, axis_id, str(uuid.uuid4()), "schedule")


def test_triggers_are_rate_limited_per_key(app_env, runner):
    client, svc, keys, axis_id = app_env
    client.app.state.trigger_limit = TokenBucket(per_minute=1.0, burst=2)
    runner.gate = threading.Event()
    try:
        codes = [client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["operate"])) for _ in range(3)]
        assert codes[2].status_code == 429 and "triggers_per_minute" in codes[2].json()["detail"]
        assert int(codes[2].headers["Retry-After"]) >= 1
        # another key has its own allowance
        other = client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["admin"]))
        assert other.status_code in (202, 429) and "triggers_per_minute" not in other.json().get("detail", "")
    finally:
        runner.gate.set()
        assert svc.scheduler.idle(30)


def test_token_bucket_refills_at_its_rate():
    now = [0.0]
    bucket = TokenBucket(per_minute=6.0, burst=2, clock=lambda: now[0])
    assert bucket.take("k") == 0 and bucket.take("k") == 0
    assert bucket.take("k") == pytest.approx(10.0)
    now[0] = 10.0
    assert bucket.blocked("k") == 0 and bucket.take("k") == 0 and bucket.take("k") > 0


def test_failed_authentication_is_logged_without_the_key_and_throttled(app_env, caplog):
    client, svc, keys, _ = app_env
    client.app.state.auth_throttle = AuthThrottle(per_minute=1.0, burst=5, address_per_minute=1.0, address_burst=50)
    wrong = "wrong-" + "k" * 40
    with caplog.at_level("WARNING", logger="mebm.api"):
        codes = [client.get(f"{V1}/machines", headers=hdr(wrong)).status_code for _ in range(5)]
        throttled = client.get(f"{V1}/machines", headers=hdr(wrong))
        even_good = client.get(f"{V1}/machines", headers=hdr(keys["read"]))
    assert codes == [401] * 5
    assert throttled.status_code == 429 and int(throttled.headers["Retry-After"]) >= 1
    assert even_good.status_code == 200  # a valid key is never refused by the failures' throttle
    failures = [r.getMessage() for r in caplog.records if "failed authentication" in r.getMessage()]
    assert len(failures) == 6 and all("/api/v1/machines" in m for m in failures)
    assert "throttled for" in failures[-1] and "throttled" not in failures[-2]
    assert not any(wrong in r.getMessage() or keys["read"] in r.getMessage() for r in caplog.records)


# `mebm serve` with what a request body meets (its uvicorn protocol, the app's limits); no
# OPC UA server, MQTT client or cycle process, which no request here reaches and whose
# start (seconds of CPU for the OPC UA address space, two spawned processes) the test
# would only sit in
BODY_CONFIG = """
[server]
host = "127.0.0.1"
port = 0
[auth]
demo_keys = false
[opcua]
enabled = false
[mqtt]
url = ""
[scheduler]
cycle_processes = 0
""" + demo_machine_toml("body-test", demo_axis_toml(controller="modbus://127.0.0.1:1", task=False,
                                                                 schedule_enabled=False, schedule_interval_s=3600))


def _peak_rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM:"))


def _send_big_body(url: str, total_bytes: int, *, chunked: bool, limit_bytes: int = 1_000_000) -> bytes:
    """POST ``total_bytes`` without a key, 64 KB at a time, reading the answer as soon
    as the server sends one (so the test's own memory stays small).

    Once the server could have answered (after the headers with Content-Length, after
    ``limit_bytes`` when chunked) the client waits for an answer once, up to 10 s,
    before it sends more: a server that answers and closes while more of the body is
    arriving resets the connection, and the reset discards an answer not yet read."""
    import select
    import socket

    host, port = url.removeprefix("http://").split(":")
    sock = socket.create_connection((host, int(port)), timeout=60)
    head = f"POST /api/v1/machines HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n"
    head += "Transfer-Encoding: chunked\r\n\r\n" if chunked else f"Content-Length: {total_bytes}\r\n\r\n"
    chunk = b"[" + b"0," * 32767 + b"0"  # 64 KB of valid-looking JSON
    sent, answer, waited = 0, b"", False
    try:
        sock.sendall(head.encode())
        while sent < total_bytes:
            could_answer = not chunked or sent > limit_bytes
            timeout_s = 10.0 if could_answer and not waited else 0.0
            waited = waited or could_answer
            if select.select([sock], [], [], timeout_s)[0]:
                break  # the server answered before the body was sent
            piece = f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n" if chunked else chunk
            sock.sendall(piece)
            sent += len(chunk)
        while b"\r\n\r\n" not in answer:
            data = sock.recv(65536)
            if not data:
                break
            answer += data
    except (BrokenPipeError, ConnectionResetError):
        pass
    finally:
        sock.close()
    return answer


@pytest.mark.slow
@pytest.mark.parametrize("chunked", [False, True], ids=["content-length", "chunked"])
def test_a_100_mb_body_without_a_key_is_refused_before_it_is_read(tmp_path, chunked):
    from tests.api.rest.test_kill_restart import Server

    config = tmp_path / "mebm.toml"
    config.write_text(BODY_CONFIG)
    server = Server(tmp_path, config, f"sqlite:///{tmp_path}/mebm.sqlite3")
    try:
        import httpx

        assert httpx.get(f"{server.url}/healthz", timeout=10).status_code in (200, 503)
        before_kb = _peak_rss_kb(server.proc.pid)
        answer = _send_big_body(server.url, 100 * 1024 * 1024, chunked=chunked)
        grown_mb = (_peak_rss_kb(server.proc.pid) - before_kb) / 1024
        assert answer.startswith(b"HTTP/1.1 413"), (answer[:200], server.output()[-2000:])
        assert grown_mb < 50, f"server peak memory grew by {grown_mb:.0f} MB"
        small = httpx.post(f"{server.url}/api/v1/machines", json={"name": "x"}, timeout=10)
        assert small.status_code == 401  # under the limit: the usual answer
    finally:
        server.terminate()


def test_trend_series_are_downsampled_to_the_screen_keeping_every_excursion(tmp_path):
    """100,000 results row by row (within one hour: the rows are read one by one)."""
    from datetime import datetime, timedelta, timezone

    from api.rest import convert
    from storage.db import make_engine, make_session_factory, session_scope, upgrade
    from storage.db import config_repo, results_repo
    from tests.storage.db import factories as f
    from tests.storage.db.test_rollup import CYCLE_OFFSET, bulk_load_results

    n = 100_000
    engine = make_engine(f"sqlite:///{tmp_path}/t.sqlite3")
    upgrade(engine)
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        axis_id = config_repo.create_axis(s, config_repo.create_machine(s, "m", "").id, f.settings()).id
    b = np.full(n, 200.0) + np.sin(np.arange(n) / 500.0)
    b[77_777] = 262.0  # the one measurement that raised an alert
    temps = 20.0 + (b - 200.0) / 2.0
    bulk_load_results(engine, axis_id, np.arange(n), temps, b, step=timedelta(milliseconds=30))
    with session_scope(factory) as s:
        out = convert.trend(axis_id, results_repo.trend(s, axis_id, max_points=2000))
    engine.dispose()
    assert out.points <= 2000 and out.points_total == n and len(out.series.measured_at) == out.points
    assert 77_778 + CYCLE_OFFSET in out.series.measurement_id and max(out.series.backlash_mean_um) == 262.0
    assert out.correlation["backlash_mean_um"]["temperature_c"] == pytest.approx(1.0)  # from all points
    assert out.thermal_model is not None and out.thermal_model.n == n


def test_the_trend_endpoint_takes_max_points(app_env):
    client, svc, keys, axis_id = app_env
    for _ in range(12):
        svc.scheduler.request(axis_id, "schedule")
        assert svc.scheduler.idle(30)
    full = client.get(f"{V1}/axes/{axis_id}/trend", headers=hdr(keys["read"])).json()
    thin = client.get(f"{V1}/axes/{axis_id}/trend", params={"max_points": 10}, headers=hdr(keys["read"])).json()
    assert full["points"] == full["points_total"] == 12
    assert thin["points"] <= 10 and thin["points_total"] == 12
    assert client.get(f"{V1}/axes/{axis_id}/plots/backlash_trend.png", headers=hdr(keys["read"])).status_code == 200

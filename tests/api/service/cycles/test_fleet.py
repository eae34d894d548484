"""Several workers on one PostgreSQL database: leases, takeover, pinning,
manual triggers, and SQLite's one worker per file.

In-process workers (two ``Service`` objects on one database, an injected runner that
records how many cycles of each axis run at once) for the rules; real ``mebm serve``
processes where a worker must die by SIGKILL or a second process must be refused.
Leases are short here (3 s, a tick of 0.5 s; 10 s where real simulated cycles of seconds
run) so takeovers take seconds, not 30 s.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import replace
from datetime import datetime, timedelta, timezone
from pathlib import Path

import httpx
import pytest
from sqlalchemy import select

from api.service.config.loading import load_settings
from api.service.config.settings import AxisConfig, ConfigError, Settings, WorkerSettings
from api.service.cycles.leases import fair_share, latest_due
from api.service.cycles.runner import CycleOutcome
from api.service.service import Service
from storage.db import (
    AxisRecord,
    Schedule,
    WaitingCycleError,
    leases,
    make_engine,
    make_session_factory,
    session_scope,
    upgrade,
)
from storage.db.leases import WorkerConflictError
from storage.db.models import AxisLease, Cycle
from tests.api.rest.conftest import FakeRunner
from tests.api.rest.test_kill_restart import Server
from tests.demo import demo_axis_toml
from tests.waiting import poll
from tests.storage.db import factories as f
from tests.storage.db.backends import make_database, truncate_all

LEASE = WorkerSettings(lease_s=3.0, tick_s=0.5)
ROOT = Path(__file__).resolve().parents[4]


class SharedRunner(FakeRunner):
    """One runner for every in-process worker: counts the cycles of each axis running at
    once (fleet-wide) and who ran what."""

    def __init__(self, hold_s: float = 0.15):
        super().__init__()
        self.hold_s = hold_s
        self.lock = threading.Lock()
        self.now: Counter = Counter()
        self.peak: Counter = Counter()
        self.runs: Counter = Counter()

    def __call__(self, axis, url) -> CycleOutcome:
        with self.lock:
            self.now[axis.id] += 1
            self.peak[axis.id] = max(self.peak[axis.id], self.now[axis.id])
            self.runs[axis.id] += 1
        try:
            if self.gate is not None:
                self.gate.wait(60.0)
            time.sleep(self.hold_s)  # a cycle takes a while: time for another worker to try the same axis
            return CycleOutcome.failed("test runner: no controller", temperature_c=20.0)
        finally:
            with self.lock:
                self.now[axis.id] -= 1


def fleet_settings(url: str, data_dir: Path, axes: list[tuple[str, str]], *, interval_s: float | None = 1.0,
                   worker: WorkerSettings = LEASE, **kw) -> Settings:
    machines = tuple(dict.fromkeys(m for m, _ in axes))
    schedule = Schedule(interval_s=interval_s) if interval_s else Schedule(enabled=False, interval_s=3600.0)
    cfg = tuple(AxisConfig(m, f.settings(spec=replace(f.AXIS, name=a), schedule=schedule)) for m, a in axes)
    return Settings(data_dir=data_dir, database_url=url, machines=tuple((m, "") for m in machines), axes=cfg,
                    demo_keys=False, worker=worker, **kw)


@pytest.fixture(scope="module")
def pg_url(tmp_path_factory):
    """A PostgreSQL database of its own (a fleet needs PostgreSQL; under CI=true an
    unreachable server fails the test, see tests/storage/db/backends.py)."""
    url, handle = make_database("postgresql", tmp_path_factory.mktemp("pg"))
    eng = make_engine(url)
    upgrade(eng)
    eng.dispose()
    yield url
    handle.drop()


@pytest.fixture
def pg(pg_url):
    eng = make_engine(pg_url)
    truncate_all(eng)
    yield pg_url, make_session_factory(eng)
    eng.dispose()


def start(settings: Settings, runner) -> Service:
    svc = Service(settings, runner=runner)
    svc.start()
    return svc


def cycles(factory) -> list[Cycle]:
    with session_scope(factory) as s:
        return list(s.scalars(select(Cycle).order_by(Cycle.id)))


def test_two_workers_never_run_one_axis_at_once(pg, tmp_path):
    url, factory = pg
    axes = [(f"m{i // 4}", f"a{i % 4}") for i in range(12)]
    runner = SharedRunner()
    one = start(fleet_settings(url, tmp_path / "one", axes, worker=replace(LEASE, name="one")), runner)
    two = start(fleet_settings(url, tmp_path / "two", axes, worker=replace(LEASE, name="two")), runner)
    try:
        ids = sorted(one.executor._axes)
        assert len(ids) == 12
        # manual triggers through both workers on top of the 1 s schedules
        for i, axis_id in enumerate(ids):
            try:
                (one if i % 2 else two).trigger(axis_id, "test")
            except WaitingCycleError:
                pass  # one waits already: refused atomically, fleet-wide

        def done():
            per_axis = Counter(c.axis_id for c in cycles(factory) if c.status in ("ok", "failed"))
            return all(per_axis[a] >= 3 for a in ids)

        assert poll(done, timeout_s=120), Counter(c.axis_id for c in cycles(factory))
        with session_scope(factory) as s:
            assert leases.overlapping_cycles(s) == []
            workers = {w.name: w for w in leases.list_workers(s)}
        assert max(runner.peak.values()) == 1, runner.peak  # the runner never saw an axis twice at once
        ran_by = Counter(c.worker for c in cycles(factory) if c.status in ("ok", "failed"))
        assert set(ran_by) == {workers["one"].id, workers["two"].id}, ran_by  # both workers did work
        assert all(c.due_at is not None for c in cycles(factory) if c.trigger == "schedule")
    finally:
        one.stop()
        two.stop()


def test_pinned_worker_never_touches_other_axes(pg, tmp_path):
    url, factory = pg
    axes = [("site-a-1", "x"), ("site-a-1", "y"), ("site-b-1", "x"), ("site-b-1", "y")]
    runner = SharedRunner(hold_s=0.05)
    pinned = start(fleet_settings(url, tmp_path / "a", axes, worker=replace(LEASE, name="a", axes=("site-a-*/*",))),
                   runner)
    anyone = start(fleet_settings(url, tmp_path / "any", axes, worker=replace(LEASE, name="any")), runner)
    try:
        site_a = {a.id for a in pinned.executor._axes.values() if a.machine_name.startswith("site-a")}
        site_b = set(pinned.executor._axes) - site_a
        seen_by_pinned: set[int] = set()

        def watched():
            seen_by_pinned.update(pinned.scheduler.held)
            per_axis = Counter(c.axis_id for c in cycles(factory) if c.status == "failed")
            return all(per_axis[a] >= 3 for a in site_a | site_b)

        # a manual trigger of a site-b axis through the pinned worker's API: the other worker runs it
        b_axis = min(site_b)
        queued = pinned.trigger(b_axis, "operator")
        assert poll(watched, timeout_s=120)
        assert seen_by_pinned <= site_a and seen_by_pinned, seen_by_pinned
        rows = cycles(factory)
        assert {c.axis_id for c in rows if c.worker == pinned.scheduler.id} <= site_a
        assert {c.axis_id for c in rows if c.worker == pinned.scheduler.id}  # it did run its own axes
        manual = next(c for c in rows if c.uuid == queued.uuid)
        assert manual.status == "failed" and manual.worker == anyone.scheduler.id
        with session_scope(factory) as s:
            owners = dict(s.execute(select(AxisLease.axis_id, AxisLease.owner)).all())
        assert all(owners[a] != pinned.scheduler.id for a in site_b)
    finally:
        pinned.stop()
        anyone.stop()


def two_workers(url, tmp_path, axes, runner):
    """Workers "one" and "two" on the same axes, without a schedule (cycles only when asked)."""
    return tuple(start(fleet_settings(url, tmp_path / name, axes, interval_s=None, worker=replace(LEASE, name=name)),
                       runner) for name in ("one", "two"))


def test_manual_trigger_through_either_worker_runs_once(pg, tmp_path):
    url, factory = pg
    axes = [("m", "x"), ("m", "y"), ("m", "z")]
    runner = SharedRunner(hold_s=0.3)
    one, two = two_workers(url, tmp_path, axes, runner)
    try:
        ids = sorted(one.executor._axes)
        # settled: every axis held and the shares balanced (2 and 1), so no lease moves while the
        # triggers run (the first worker up claims all three and hands one over)
        assert poll(lambda: len(one.scheduler.held | two.scheduler.held) == 3
                    and sorted(map(len, (one.scheduler.held, two.scheduler.held))) == [1, 2], timeout_s=30)
        sent = {}
        status = lambda uuid: next(c for c in cycles(factory) if c.uuid == uuid).status  # noqa: E731
        for axis_id in ids:
            runner.gate = threading.Event()  # the first cycle holds the axis until the gate opens
            first = one.trigger(axis_id, "via one")
            assert poll(lambda: status(first.uuid) == "running", timeout_s=60)
            second = two.trigger(axis_id, "via two")  # waits behind it, in the database
            for svc in (one, two):
                with pytest.raises(WaitingCycleError):  # fleet-wide: at most one waits
                    svc.trigger(axis_id, "again")
            runner.gate.set()
            assert poll(lambda: status(second.uuid) == "failed", timeout_s=60)
            sent.update({first.uuid: axis_id, second.uuid: axis_id})
        rows = [c for c in cycles(factory) if c.trigger == "manual"]
        assert sorted(c.uuid for c in rows) == sorted(sent)  # no other manual cycle appeared
        assert all(c.status == "failed" and c.started_at is not None for c in rows)
        assert runner.runs == Counter({a: 2 for a in ids})  # each trigger measured exactly once
        owner = {a: c.worker for c in rows for a in [c.axis_id]}
        for c in rows:
            assert c.worker == owner[c.axis_id]  # run by the axis' owner whichever worker took the trigger
    finally:
        one.stop()
        two.stop()


SIM_CONFIG = """
[server]
host = "127.0.0.1"
port = 0
[auth]
demo_keys = false
bootstrap_admin_key = "fleet-test-admin-key-0123456789abcdef"
[opcua]
enabled = false
[mqtt]
url = ""
[mtconnect]
enabled = false
[worker]
lease_s = 10
tick_s = 0.5
[simulator]
time_scale = 4
temperature_amplitude_c = 0
[[machines]]
name = "vmc"
"""
# a 200 mm travel: a round trip of 8 s of machine time, 2 s at the simulator's time scale, so
# the takeover's cycles before and after the kill are short; each still runs for seconds.
# The lease (10 s) keeps the fleet's condition for "never two cycles of an axis at once"
# (docs/fleet.md, Limits: the lease outlasts the longest cycle plus the longest pause of a
# live worker) on a host busy enough to stretch a cycle and delay heartbeats by seconds.
SIM_AXIS = demo_axis_toml("{name}", travel_mm=(0, 200), task=False, measure_feed_mm_min=3000, schedule_interval_s=1)


@pytest.mark.slow
def test_sigkilled_worker_is_taken_over_and_its_cycle_interrupted(pg, tmp_path):
    url, factory = pg
    config = tmp_path / "fleet.toml"
    config.write_text(SIM_CONFIG + "".join(SIM_AXIS.format(name=n) for n in ("x", "y")))
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = Server(tmp_path / "a", config, url)  # alone at first: it takes both axes
    b = None
    try:
        with session_scope(factory) as s:
            a_id = next(w.id for w in leases.list_workers(s) if w.live)

        def a_running():
            return [c for c in cycles(factory) if c.status == "running" and c.worker == a_id]

        assert poll(lambda: [c for c in cycles(factory) if c.status == "ok"], timeout_s=90), a.output()
        b = Server(tmp_path / "b", config, url)
        running = poll(a_running, timeout_s=90, interval_s=0.02)
        assert running, a.output()
        left = running[0]
        a.kill()
        killed_at = datetime.now(timezone.utc)
        assert next(c for c in cycles(factory) if c.uuid == left.uuid).status == "running"  # what a crash leaves

        def taken():
            c = next(c for c in cycles(factory) if c.uuid == left.uuid)
            return c if c.status == "interrupted" else None

        closed = poll(taken, timeout_s=60)
        assert closed is not None, b.output()
        assert "stopped renewing its lease" in closed.failure_reason
        with session_scope(factory) as s:
            b_id = next(w.id for w in leases.list_workers(s) if w.live)
        # both axes measured by the survivor after the kill, never two cycles of an axis at once
        assert poll(lambda: {c.axis_id for c in cycles(factory)
                             if c.worker == b_id and c.status == "ok" and c.started_at > killed_at} == {1, 2},
                    timeout_s=90), b.output()
        with session_scope(factory) as s:
            overlaps = leases.overlapping_cycles(s)
        assert overlaps == [], "\n".join(
            [f"{c.uuid} axis {c.axis_id} {c.status} by {c.worker} {c.started_at} .. {c.finished_at}: {c.failure_reason}"
             for c in cycles(factory)] + [a.output(), b.output()])
        hdr = {"X-API-Key": "fleet-test-admin-key-0123456789abcdef"}
        workers = httpx.get(f"{b.url}/api/v1/workers", headers=hdr, timeout=10).json()
        live = [w for w in workers if w["live"]]
        assert len(live) == 1 and live[0]["this_process"] and {x["id"] for x in live[0]["axes"]} == {1, 2}
        assert live[0]["takeovers"] >= 1
        metrics = httpx.get(f"{b.url}/metrics", headers=hdr, timeout=10).text
        assert 'mebm_worker_leases_held{worker="' in metrics and "mebm_lease_takeovers_total" in metrics
        assert "mebm_cycle_lateness_p95_seconds" in metrics
    finally:
        a.kill()
        if b is not None:
            b.terminate()


@pytest.mark.slow
def test_second_worker_on_sqlite_refuses(tmp_path):
    settings = Settings(data_dir=tmp_path, demo_keys=False, machines=(("m", ""),),
                        axes=(AxisConfig("m", f.settings(schedule=Schedule(interval_s=3600.0))),))
    first = start(settings, FakeRunner())
    try:
        config = tmp_path / "mebm.toml"
        config.write_text('[opcua]\nenabled = false\n[mqtt]\nurl = ""\n[server]\nport = 0\n')
        env = {k: v for k, v in os.environ.items() if not k.startswith("MEBM_")}
        proc = subprocess.run([sys.executable, "-m", "api.cli", "serve", "--config", str(config),
                               "--data-dir", str(tmp_path)], cwd=ROOT, env=env, capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode != 0
        assert f"another mebm worker (pid {os.getpid()}" in proc.stderr, proc.stderr
        assert "SQLite takes one worker" in proc.stderr and "--no-scheduler" in proc.stderr
        assert "mebm service on" not in proc.stdout
        # an API-only process on the same file is fine
        with pytest.raises(WorkerConflictError):
            Service(settings, runner=FakeRunner()).start()
        api_only = start(replace(settings, scheduler_enabled=False), FakeRunner())
        api_only.stop()
    finally:
        first.stop()
    again = start(settings, FakeRunner())  # the lock goes with the worker
    again.stop()


def test_due_times_coalesce_and_shares_split():
    spec = replace(f.AXIS, name="x")
    rec = AxisRecord(id=1, machine_id=1, machine_name="m", settings=f.settings(spec=spec,
                     schedule=Schedule(interval_s=60.0)))
    t0 = datetime(2026, 1, 1, 12, 0, tzinfo=timezone.utc)
    assert latest_due(rec, t0, t0 + timedelta(seconds=30)) == t0 + timedelta(seconds=60)
    assert latest_due(rec, t0, t0 + timedelta(seconds=610)) == t0 + timedelta(seconds=600)  # once, the latest
    assert latest_due(rec, t0, t0 + timedelta(seconds=610), catch_up=False) == t0 + timedelta(seconds=670)
    assert latest_due(rec, None, t0) == t0 + timedelta(seconds=60)  # a real controller: one period first
    cron = replace(rec, settings=replace(rec.settings, schedule=Schedule(cron="0 * * * *")))
    assert latest_due(cron, t0, t0 + timedelta(hours=5, minutes=5)) == t0 + timedelta(hours=5)
    axes = [replace(rec, id=i, machine_name="a" if i < 2 else "b") for i in range(6)]
    live = [("p", ("a/*",)), ("q", None), ("r", None)]
    assert fair_share("p", live, axes) == 1  # 2 axes shared with q and r
    assert fair_share("q", live, axes) + fair_share("r", live, axes) >= 6 - 1


def test_worker_settings_are_checked(tmp_path):
    cfg = tmp_path / "w.toml"
    cfg.write_text('[worker]\nname = "site-a"\naxes = ["site-a-*/*"]\nlease_s = 20\n')
    w = load_settings(cfg, env={}).worker
    assert (w.name, w.axes, w.lease_s, w.period_s) == ("site-a", ("site-a-*/*",), 20.0, 2.0)
    assert load_settings(cfg, env={"MEBM_WORKER_AXES": "vmc-1/x, vmc-2/*"}).worker.axes == ("vmc-1/x", "vmc-2/*")
    for bad, word in (('axes = ["vmc-1"]', "machine/axis"), ("lease_s = 0", "lease_s"),
                      ("lease_s = 3\ntick_s = 2", "tick_s"), ("lease = 3", "unknown")):
        cfg.write_text(f"[worker]\n{bad}\n")
        with pytest.raises(ConfigError, match=word):
            load_settings(cfg, env={})


def test_api_replica_follows_what_other_processes_store(pg, tmp_path):
    """``serve --no-scheduler`` beside a worker: a measurement the worker stores shows in
    the replica's status once its cache is older than ``status_max_age_s``, an alert at
    once, and a key revoked through the worker stops working on the replica once the
    replica's key cache is older than its time to live."""
    from fastapi.testclient import TestClient

    from api.rest import create_app
    from storage.db import config_repo

    url, factory = pg
    axes = [("m", "x")]
    runner = FakeRunner(backlash_um=200.0)
    worker_app = create_app(fleet_settings(url, tmp_path / "w", axes, interval_s=None,
                                           worker=replace(LEASE, name="worker")), runner=runner)
    replica_app = create_app(replace(fleet_settings(url, tmp_path / "r", axes, interval_s=None),
                                     scheduler_enabled=False, status_max_age_s=0.5), runner=runner)
    with TestClient(worker_app) as w, TestClient(replica_app) as r:
        with session_scope(factory) as s:
            _, admin = config_repo.create_key(s, "admin", "admin")
            _, reader = config_repo.create_key(s, "reader", "read")
            axis_id = config_repo.list_axes(s)[0].id
        hdr = {"X-API-Key": admin}
        assert r.get("/api/v1/workers", headers=hdr).json()[0]["name"] == "worker"  # a replica is no worker
        assert r.get(f"/api/v1/axes/{axis_id}/status", headers=hdr).json()["measurement_id"] is None
        # a manual trigger through the replica: stored, run by the worker that holds the axis
        assert r.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr).status_code == 202
        assert poll(lambda: r.get(f"/api/v1/axes/{axis_id}/status", headers=hdr).json()["measurement_id"],
                    timeout_s=60)
        assert runner.calls == 1
        runner.backlash_um = 400.0  # past the task's limit: the worker raises an alert
        assert w.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr).status_code == 202
        assert poll(lambda: r.get("/api/v1/alerts?state=active", headers=hdr).json()["total"] == 1, timeout_s=60)
        assert poll(lambda: r.get(f"/api/v1/axes/{axis_id}/status", headers=hdr).json()["state"] == "ALARM",
                    timeout_s=60)
        assert r.get("/api/v1/machines", headers={"X-API-Key": reader}).status_code == 200  # cached on the replica
        key_id = next(k["id"] for k in w.get("/api/v1/keys", headers=hdr).json() if k["name"] == "reader")
        assert w.delete(f"/api/v1/keys/{key_id}", headers=hdr).status_code == 200
        assert poll(lambda: r.get("/api/v1/machines", headers={"X-API-Key": reader}).status_code == 401,
                    timeout_s=30)


class CuttableProxy:
    """A TCP proxy to PostgreSQL whose link can be cut: while cut, bytes are held (as a
    network does while TCP retransmits), new connections wait; healing lets them through."""

    def __init__(self, target=("127.0.0.1", 5432)):
        import socket

        self.target = target
        self.open = threading.Event()
        self.open.set()
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self._closed = False
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        import socket

        while not self._closed:
            try:
                client, _ = self.sock.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(self.target)
            except OSError:
                client.close()
                continue
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src, dst):
        import socket

        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                self.open.wait()
                dst.sendall(data)
        except OSError:
            pass
        finally:
            # shutdown first: close() alone does not end the other pump's recv() on the same
            # socket (Linux keeps it open while a thread is blocked in it), so the FIN that the
            # server sent (e.g. ending an idle-in-transaction session while the link was cut)
            # never reached the worker, whose query then waited forever after the heal
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                try:
                    s.close()
                except OSError:
                    pass

    def close(self):
        self._closed = True
        self.open.set()
        self.sock.close()


def test_worker_cut_from_the_database_loses_its_axes_and_nothing_overlaps(pg, tmp_path):
    url, factory = pg
    proxy = CuttableProxy()
    host, rest = url.split("@", 1)
    via_proxy = f"{host}@127.0.0.1:{proxy.port}/{rest.split('/', 1)[1]}"
    axes = [("m", "a0"), ("m", "a1"), ("m", "a2"), ("m", "a3")]
    runner = SharedRunner(hold_s=0.3)
    cut = start(fleet_settings(via_proxy, tmp_path / "cut", axes, worker=replace(LEASE, name="cut")), runner)
    other = None
    try:
        ids = set(cut.executor._axes)
        with cut.engine.connect() as c:  # a session cut mid-transaction ends, and frees its locks, before its lease
            assert c.exec_driver_sql("SHOW idle_in_transaction_session_timeout").scalar_one() == "2s"
        assert poll(lambda: cut.scheduler.held == ids, timeout_s=30)  # alone: it holds every axis
        other = start(fleet_settings(url, tmp_path / "other", axes, worker=replace(LEASE, name="other")), runner)
        assert poll(lambda: any(c.status == "running" and c.worker == cut.scheduler.id for c in cycles(factory)),
                    timeout_s=60, interval_s=0.01)
        proxy.open.clear()  # the network between "cut" and the database goes down
        assert poll(lambda: other.scheduler.held == ids, timeout_s=60)  # lease_s + tick_s, here 3.5 s
        with session_scope(factory) as s:
            workers = {w.name: w for w in leases.list_workers(s)}
        assert not workers["cut"].live and workers["other"].takeovers >= 1
        assert poll(lambda: {c.axis_id for c in cycles(factory) if c.worker == other.scheduler.id
                             and c.status == "failed"} == ids, timeout_s=60)
        proxy.open.set()  # healed: "cut" finds its leases gone and drops the axes
        assert poll(lambda: workers_live(factory) == {"cut", "other"}, timeout_s=60)
        # "cut" drops the axes whose leases it lost before its heartbeat's commit makes it live
        assert not cut.scheduler.held & other.scheduler.held
        with session_scope(factory) as s:
            assert leases.overlapping_cycles(s) == []
        assert max(runner.peak.values()) == 1
    finally:
        proxy.open.set()
        if other is not None:
            other.stop()
        cut.stop()
        proxy.close()


def workers_live(factory) -> set[str]:
    with session_scope(factory) as s:
        return {w.name for w in leases.list_workers(s) if w.live}


def test_repair_verification_through_any_worker_runs_on_the_owner_and_survives_a_takeover(pg, tmp_path):
    """The maintenance loop on a fleet: a repair recorded through a worker that does not hold the axis
    queues its verification in the database; the owner runs it. A takeover cancels the old
    owner's scheduled cycles but keeps a waiting verification, like a manual trigger."""
    url, factory = pg
    axes = [("m", "x")]
    runner = SharedRunner(hold_s=0.1)
    one, two = two_workers(url, tmp_path, axes, runner)
    try:
        (axis_id,) = one.executor._axes
        assert poll(lambda: len(one.scheduler.held | two.scheduler.held) == 1, timeout_s=30)
        owner, other = (one, two) if axis_id in one.scheduler.held else (two, one)
        rec = other.scheduler.request(axis_id, "verification", "repair 1")
        assert rec is not None and rec.trigger == "verification"
        row = lambda: next(c for c in cycles(factory) if c.uuid == rec.uuid)  # noqa: E731
        assert poll(lambda: row().status == "failed", timeout_s=60)  # the test runner fails every cycle
        assert row().worker == owner.scheduler.id and row().requested_by == "repair 1"
        assert runner.runs[axis_id] == 1
    finally:
        one.stop()
        two.stop()
    with session_scope(factory) as s:  # a verification and a scheduled cycle wait; another worker takes over
        leases.register_worker(s, "w-old", "old", "host", 1, None, 3.0)
        leases.register_worker(s, "w-new", "new", "host", 2, None, 3.0)
        verification = leases.queue_scheduled(s, axis_id, "u-verify", "verification", datetime.now(timezone.utc), "w-old")
        scheduled = leases.queue_scheduled(s, axis_id, "u-sched", "schedule", datetime.now(timezone.utc), "w-old")
        assert leases.take_over(s, "w-new", axis_id, "w-old") == 1
    with session_scope(factory) as s:
        state = {c.uuid: c.status for c in s.scalars(select(Cycle).where(Cycle.uuid.in_(["u-verify", "u-sched"])))}
    assert state == {verification.uuid: "queued", scheduled.uuid: "cancelled"}
    with session_scope(factory) as s:  # and a clean stop keeps it too
        assert leases.stop_worker(s, "w-old") == 0
        assert s.scalar(select(Cycle.status).where(Cycle.uuid == "u-verify")) == "queued"

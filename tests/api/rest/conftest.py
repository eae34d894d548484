"""Fixtures of the REST suite: an app on SQLite and PostgreSQL with an injected cycle
runner (a synthetic round trip of a settable backlash), and one key per role."""

from __future__ import annotations

import socket
import threading
from dataclasses import replace
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.settings import AxisConfig, LimitSettings, Settings
from api.service.cycles.runner import CycleOutcome, analyse
from storage.db import Schedule, config_repo, session_scope
from tests.storage.db import factories as f
from tests.waiting import poll
from tests.storage.db.backends import db_url, engine  # noqa: F401 - fixtures


class FakeRunner:
    """Stands in for the controller: a round trip through a play of ``backlash_um``,
    sampled every ``step_mm`` of the command (``factories.trace``; a coarser step is fewer
    samples, for a test that diagnoses the stored runs)."""

    def __init__(self, backlash_um: float = 200.0, temperature_c: float = 20.0, step_mm: float = 0.05):
        self.backlash_um = backlash_um
        self.temperature_c = temperature_c
        self.step_mm = step_mm
        self.fail: str | None = None
        self.calls = 0
        self.gate: threading.Event | None = None  # set to hold a cycle "running"...
        self.gate_timeout_s = 10.0  # ...at most this long
        self.running = threading.Event()

    def __call__(self, axis, url) -> CycleOutcome:
        self.calls += 1
        self.running.set()
        if self.gate is not None:
            self.gate.wait(self.gate_timeout_s)
        self.running.clear()
        if self.fail:
            return CycleOutcome.failed(self.fail, temperature_c=self.temperature_c)
        t, m, x = f.trace(self.backlash_um, step_mm=self.step_mm)
        return CycleOutcome(ok=True, time_s=t, motor_rev=m, table_mm=x, temperature_c=self.temperature_c,
                            uncertainty_um=0.8, round_trip=analyse(axis, t, m, x), feed_mm_min=1000.0)


def make_settings(url: str, data_dir: Path, **kw) -> Settings:
    axis = AxisConfig("vmc-850", f.settings(controller_url="modbus://127.0.0.1:1",
                                            schedule=Schedule(interval_s=3600.0)))
    # the gap diagnosis' worker at the tests' own priority: at the default nice +10 the
    # other tests running beside it would starve it (its niceness is tested in test_gap_jobs)
    base = Settings(data_dir=data_dir, database_url=url, machines=(("vmc-850", "test"),), axes=(axis,),
                    catch_up_missed=False, demo_keys=False, limits=LimitSettings(gap_diagnosis_nice=0))
    return replace(base, **kw)


@pytest.fixture
def runner():
    return FakeRunner()


@pytest.fixture
def app_env(engine, db_url, tmp_path, runner):  # noqa: F811 - engine truncates the tables
    app = create_app(make_settings(db_url, tmp_path), runner=runner)
    with TestClient(app) as client:
        svc = app.state.service
        keys = {}
        with session_scope(svc.factory) as s:
            for role in ("read", "operate", "admin"):
                keys[role] = config_repo.create_key(s, f"test-{role}", role)[1]
            axis_id = config_repo.list_axes(s)[0].id
        yield client, svc, keys, axis_id


@pytest.fixture
def client(app_env):
    return app_env[0]


def hdr(key: str) -> dict:
    return {"X-API-Key": key}


class ServedApp:
    """The app under uvicorn, configured as ``mebm serve`` configures it, on a free port."""

    def __init__(self, tmp_path, **settings_kw):
        import uvicorn

        from api.cli.serve import uvicorn_config

        settings = make_settings(f"sqlite:///{tmp_path}/mebm.sqlite3", tmp_path, **settings_kw)
        self.app = create_app(settings, runner=FakeRunner())
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.server = uvicorn.Server(uvicorn_config(self.app, replace(settings, log_level="warning")))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.thread.start()
        assert poll(lambda: self.server.started, 60.0), "the server did not start"

    def close(self):
        self.server.should_exit = True
        self.thread.join(30)
        self.sock.close()

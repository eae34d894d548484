"""Killing ``mebm serve`` (SIGKILL) in the middle of a cycle and starting it again loses
no stored result, leaves no cycle "running" and the database passes an integrity
check. A real uvicorn server in a subprocess, the built-in simulated controller,
SQLite and PostgreSQL."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from storage.db import integrity_problems, make_session_factory, results_repo, session_scope
from storage.db.models import Cycle
from tests.demo import demo_axis_toml, demo_machine_toml
from tests.waiting import poll

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[3]
CONFIG = """
[server]
host = "127.0.0.1"
port = 0
[scheduler]
spool_retry_s = 2
[opcua]
enabled = false
[simulator]
time_scale = 5
temperature_amplitude_c = 0
""" + demo_machine_toml("kill-test", demo_axis_toml(measure_feed_mm_min=3000, schedule_interval_s=1))


class Server:
    def __init__(self, data_dir: Path, config: Path, db_url: str):
        env = {**os.environ, "MEBM_DATABASE_URL": db_url, "PYTHONUNBUFFERED": "1"}
        env.pop("MEBM_BOOTSTRAP_ADMIN_KEY", None)
        self.log = open(data_dir / f"serve-{time.monotonic_ns()}.log", "w+")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "api.cli", "serve", "--config", str(config), "--data-dir", str(data_dir)],
            cwd=ROOT, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
        )
        self.url = self._wait_banner()

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def _wait_banner(self, timeout_s: float = 60.0) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            m = re.search(r"mebm service on (http://127\.0\.0\.1:\d+)", self.output())
            if m:
                return m.group(1)
            if self.proc.poll() is not None:
                break
            time.sleep(0.1)
        self.kill()
        raise AssertionError(f"no banner:\n{self.output()}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def terminate(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                return self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.kill()
        return self.proc.returncode


def test_sigkill_mid_cycle_then_restart(engine, db_url, tmp_path):  # noqa: ARG001 - engine empties the DB
    config = tmp_path / "mebm.toml"
    config.write_text(CONFIG)
    factory = make_session_factory(engine)

    def cycles_by_status():
        with session_scope(factory) as s:
            rows = s.query(Cycle.uuid, Cycle.status).all()
        return dict(rows)

    def ok_ids():
        with session_scope(factory) as s:
            return {c.id for c in results_repo.list_measurements(s, 1, status="ok", limit=500)[1]}

    first = Server(tmp_path, config, db_url)
    try:
        key = __import__("json").loads((tmp_path / "demo-keys.json").read_text())["read"]
        assert poll(lambda: len(ok_ids()) >= 1), first.output()
        running = poll(lambda: [u for u, st in cycles_by_status().items() if st == "running"], interval_s=0.02)
        assert running, first.output()
        time.sleep(0.3)  # well inside the cycle (it lasts seconds)
        before = ok_ids()
        first.kill()
    finally:
        first.kill()
    killed = running[0]
    assert cycles_by_status()[killed] == "running"  # what a crash leaves behind

    second = Server(tmp_path, config, db_url)
    try:
        assert "interrupted by the last stop were closed" in second.output()
        st = cycles_by_status()
        assert st[killed] == "interrupted"
        assert before <= ok_ids()  # no stored result lost
        assert integrity_problems(engine) == []
        # the service works again: a new good cycle, served over HTTP
        assert poll(lambda: len(ok_ids() - before) >= 1), second.output()
        r = httpx.get(f"{second.url}/api/v1/axes/1/status", headers={"X-API-Key": key}, timeout=10)
        assert r.status_code == 200 and r.json()["measurement_id"] is not None
        assert httpx.get(f"{second.url}/healthz", timeout=10).json()["database"] == "ok"
    finally:
        code = second.terminate()
    assert code in (0, -signal.SIGTERM), second.output()  # uvicorn re-raises SIGTERM after a clean shutdown
    assert integrity_problems(engine) == []

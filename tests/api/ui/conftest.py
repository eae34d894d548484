"""Fixtures of the dashboard's browser tests: a real server (uvicorn on port 0, SQLite,
the REST suite's injected cycle runner) and one headless Debian chromium per module.

Without /usr/bin/chromium the browser tests skip with the reason, except under CI=true,
where they fail (.ci/run installs chromium and chromium-driver when it can)."""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
from pathlib import Path

import pytest

from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.waiting import poll

CHROMIUM = os.environ.get("MEBM_TEST_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
# The README's screenshots (docs/screenshots) are taken by the browser tests when asked
# (MEBM_UPDATE_SCREENSHOTS=1 .venv/bin/python -m pytest tests/api/ui); otherwise they go
# to a temporary folder, so a test run leaves the checkout as it found it.
SCREENSHOTS = (Path(__file__).resolve().parents[3] / "docs" / "screenshots"
               if os.environ.get("MEBM_UPDATE_SCREENSHOTS") == "1"
               else Path(tempfile.gettempdir()) / f"mebm-screenshots-{os.getpid()}")


class FakeClock:
    """The dashboard's clock for sign-in links and sessions: now, plus ``offset_s``."""

    def __init__(self):
        self.offset_s = 0.0

    def __call__(self):
        from datetime import timedelta

        from storage.db import utcnow

        return utcnow() + timedelta(seconds=self.offset_s)


class UiServer:
    """The whole app (REST + dashboard) served by uvicorn on a free port, in a thread."""

    def __init__(self, tmp: Path):
        import uvicorn

        from api.rest import create_app

        self.runner = FakeRunner()
        url = f"sqlite:///{tmp}/mebm.sqlite3"
        self.app = create_app(make_settings(url, tmp), runner=self.runner)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(128)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.server = uvicorn.Server(uvicorn.Config(self.app, log_level="warning", access_log=False))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.thread.start()
        assert poll(lambda: self.server.started, 60.0), "the server did not start"
        self.svc = self.app.state.service
        self.clock = FakeClock()
        self.app.state.ui.sessions.clock = self.clock
        self.keys = {}
        with session_scope(self.svc.factory) as s:
            for role in ("read", "operate", "admin"):
                self.keys[role] = config_repo.create_key(s, f"ui-{role}", role)[1]
            self.axis_id = config_repo.list_axes(s)[0].id

    def measure(self, backlash_um: float, axis_id: int | None = None) -> None:
        self.runner.backlash_um = backlash_um
        self.svc.trigger(axis_id or self.axis_id, "test")
        assert self.svc.scheduler.idle(60)

    def add_axis(self, machine: str, name: str) -> int:
        """Another axis (a second machine of the fleet), configured as the first."""
        from dataclasses import replace

        from tests.storage.db import factories as f

        with session_scope(self.svc.factory) as s:
            m = config_repo.find_machine(s, machine) or config_repo.create_machine(s, machine, "")
            a = config_repo.create_axis(s, m.id, f.settings(spec=replace(f.AXIS, name=name),
                                                            controller_url="modbus://127.0.0.1:1"))
            s.commit()
        self.svc.axis_changed(a)
        return a.id

    def link(self, role: str = "read") -> str:
        return f"{self.url}/ui/sign-in/{self.app.state.ui.sessions.issue_link(self.keys[role])}"

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(30)
        self.sock.close()


@pytest.fixture(scope="module")
def ui_server(tmp_path_factory):
    srv = UiServer(tmp_path_factory.mktemp("ui"))
    yield srv
    srv.close()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not (Path(CHROMIUM).is_file() and shutil.which(CHROMIUM)):
        why = f"no chromium at {CHROMIUM} (apt-get install chromium chromium-driver)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(why + "; CI=true requires the browser tests")
        pytest.skip(why)
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"playwright is not installed ({exc})")
        pytest.skip(f"playwright is not installed ({exc})")
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_playwright() as p:
        # a persistent context is how Playwright takes a --user-data-dir: a fresh one per module
        ctx = p.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS,
            viewport={"width": 1280, "height": 800}, chromium_sandbox=False)
        try:
            yield ctx
        finally:
            ctx.close()

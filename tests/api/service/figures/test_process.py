"""Figure renders in a worker process (api/service/figures/process.py): same bytes as on the
caller's thread, another interpreter, and a dead or stuck process is a typed error and
is replaced."""

from __future__ import annotations

import os
import time
from datetime import datetime, timedelta, timezone

import pytest

from api.service.figures import plots
from api.service.figures.process import PlotProcess, RenderCrashed, RenderTimeout


def pid_of_renderer() -> int:
    return os.getpid()


def die() -> bytes:
    os._exit(3)


def sleep_s(s: float) -> bytes:
    time.sleep(s)
    return b"late"


@pytest.fixture
def renderer():
    r = PlotProcess(timeout_s=60.0)
    yield r
    r.close()


def test_a_render_in_the_process_is_byte_identical_and_not_on_this_interpreter(renderer):
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    t = [t0 + timedelta(days=i) for i in range(30)]
    b = [20.0 + 0.1 * i for i in range(30)]
    temp = [20.0 + (i % 5) for i in range(30)]
    args = (t, b, temp)
    kw = dict(limit_um=25.0, title="m axis x")
    here = plots.backlash_trend(*args, **kw)
    there = renderer.draw(plots.backlash_trend, *args, **kw)
    assert there[:8] == b"\x89PNG\r\n\x1a\n"
    assert there == here
    assert renderer.draw(pid_of_renderer) != os.getpid()
    assert renderer.renders == 2


def test_a_process_that_dies_is_a_typed_error_and_is_replaced(renderer):
    first = renderer.draw(pid_of_renderer)
    with pytest.raises(RenderCrashed, match="died twice"):
        renderer.draw(die)
    assert renderer.crashes == 2  # the render was tried once more in a fresh process
    second = renderer.draw(pid_of_renderer)
    assert second not in (first, os.getpid())


def test_a_stuck_render_times_out_and_the_next_one_gets_a_fresh_process():
    r = PlotProcess(timeout_s=60.0)  # room for the spawn on a loaded machine
    try:
        first = r.draw(pid_of_renderer)
        r.timeout_s = 1.0
        with pytest.raises(RenderTimeout, match="longer than 1 s"):
            r.draw(sleep_s, 120.0)
        r.timeout_s = 60.0
        assert not os.path.exists(f"/proc/{first}"), "the stuck process was not ended and reaped"
        second = r.draw(pid_of_renderer)
        assert second != first
    finally:
        r.close()


def test_use_process_false_draws_here():
    assert PlotProcess(use_process=False).draw(pid_of_renderer) == os.getpid()


def test_services_of_one_interpreter_share_the_renderer():
    assert PlotProcess.shared() is PlotProcess.shared()


def test_a_warm_up_spawns_the_process_in_the_background_and_the_first_draw_uses_it(renderer):
    renderer.warm_up()  # returns at once: the spawn and the blank figure happen on a thread
    assert renderer.warmed.wait(60), "the warm-up did not finish"
    assert renderer.warm_pid not in (None, os.getpid())
    assert renderer.draw(pid_of_renderer) == renderer.warm_pid  # the warm process draws it
    assert renderer.renders == 1  # the warm-up is not a client's render
    renderer.warm_up()  # once per renderer
    assert renderer.draw(pid_of_renderer) == renderer.warm_pid


def test_a_service_warms_its_renderer_at_start(tmp_path):
    from api.service.config.settings import Settings
    from api.service.service import Service

    svc = Service(Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/m.sqlite3", demo_keys=False,
                           scheduler_enabled=False))
    svc.start()
    try:
        assert svc.plots.warmed.wait(60) and svc.plots.warm_pid is not None
    finally:
        svc.stop()

"""Figures are drawn once per set of inputs: the REST plot endpoints and the dashboard share
the service's figure cache, keyed by the stored results a figure shows (immutable once
stored) and its parameters. Renders are counted through the service's drawing function."""

from __future__ import annotations

import re
import threading

import pytest

from api.service.figures.cache import FigureCache
from tests.api.rest.conftest import hdr
from tests.waiting import poll

V1 = "/api/v1"


@pytest.fixture
def drawn(app_env, monkeypatch):
    """The names of the figure functions the service drew, in order."""
    _, svc, _, _ = app_env
    calls = []
    real = svc.plots.draw

    def counting(fn, *args, **kwargs):
        calls.append(fn.__name__)
        return real(fn, *args, **kwargs)

    monkeypatch.setattr(svc.plots, "draw", counting)
    return calls


def _measure(client, svc, keys, axis_id) -> int:
    r = client.post(f"{V1}/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
    assert r.status_code == 202, r.text
    assert svc.scheduler.idle(30)
    return r.json()["measurement"]["id"]


def _png(client, keys, path) -> bytes:
    r = client.get(path, headers=hdr(keys["read"]))
    assert r.status_code == 200 and r.content[:4] == b"\x89PNG", r.text
    return r.content


def test_the_same_plot_of_a_stored_result_is_drawn_once_and_another_result_draws_its_own(app_env, runner, drawn):
    client, svc, keys, axis_id = app_env
    first = _measure(client, svc, keys, axis_id)
    runner.backlash_um += 40.0
    second = _measure(client, svc, keys, axis_id)
    plot = f"{V1}/axes/{axis_id}/plots/backlash_profile.png"
    a = _png(client, keys, f"{plot}?measurement_id={first}")
    assert drawn == ["backlash_profile"]
    assert _png(client, keys, f"{plot}?measurement_id={first}") == a
    assert drawn == ["backlash_profile"]  # the second request: from the cache
    b = _png(client, keys, f"{plot}?measurement_id={second}")
    assert drawn == ["backlash_profile"] * 2 and b != a  # another result: its own figure
    _png(client, keys, plot)  # the newest is the second: drawn already
    assert drawn == ["backlash_profile"] * 2
    lead = f"{V1}/axes/{axis_id}/plots/lead_deviation.png?measurement_id={first}"
    _png(client, keys, lead)
    _png(client, keys, lead + "&direction=negative")  # another parameter: another figure
    _png(client, keys, lead)
    assert drawn == ["backlash_profile"] * 2 + ["lead_deviation"] * 2


def test_a_history_plot_is_drawn_again_only_when_a_result_is_stored_or_its_settings_change(app_env, drawn):
    client, svc, keys, axis_id = app_env
    _measure(client, svc, keys, axis_id)
    trend = f"{V1}/axes/{axis_id}/plots/backlash_trend.png"
    _png(client, keys, trend)
    _png(client, keys, trend)
    assert drawn == ["backlash_trend"]
    _measure(client, svc, keys, axis_id)  # a new result: the history it shows changed
    _png(client, keys, trend)
    _png(client, keys, trend)
    assert drawn == ["backlash_trend"] * 2
    body = {"tasks": [{"name": "finer", "profile": "circle", "radius_mm": 200, "feed_mm_min": 200,
                       "tolerance_um": 20}]}
    assert client.put(f"{V1}/axes/{axis_id}/tasks", json=body, headers=hdr(keys["admin"])).status_code == 200
    _png(client, keys, trend)  # another backlash limit is drawn
    _png(client, keys, f"{V1}/axes/{axis_id}/plots/tbe_vs_backlash.png")
    _png(client, keys, f"{V1}/axes/{axis_id}/plots/tbe_vs_backlash.png")
    assert drawn == ["backlash_trend"] * 3 + ["tbe_vs_backlash"]


def test_the_dashboard_serves_a_figure_the_rest_api_drew(app_env, drawn):
    client, svc, keys, axis_id = app_env
    _measure(client, svc, keys, axis_id)
    _png(client, keys, f"{V1}/axes/{axis_id}/plots/backlash_profile.png")
    form = client.get("/ui/sign-in")
    csrf = re.search(r'name="csrf" value="([^"]+)"', form.text).group(1)
    assert client.post("/ui/sign-in", data={"key": keys["read"], "csrf": csrf}).status_code == 200
    r = client.get(f"/ui/axes/{axis_id}/plots/backlash_profile.png")
    assert r.status_code == 200 and r.content[:4] == b"\x89PNG"
    assert drawn == ["backlash_profile"]  # one cache for both


def test_concurrent_requests_for_one_figure_wait_for_one_drawing():
    cache = FigureCache()
    started, release = threading.Event(), threading.Event()
    renders = []

    def render():
        renders.append(1)
        started.set()
        assert release.wait(10)
        return b"png"

    out = []
    threads = [threading.Thread(target=lambda: out.append(cache.get_or_render(("k",), render))) for _ in range(8)]
    for t in threads:
        t.start()
    assert started.wait(10)
    release.set()
    for t in threads:
        t.join(10)
    assert out == [b"png"] * 8 and renders == [1]
    assert (cache.hits, cache.misses) == (7, 1)


def test_a_failed_drawing_is_not_kept_and_the_next_request_draws_it():
    cache = FigureCache()

    def broken():
        raise RuntimeError("the plot process died")

    with pytest.raises(RuntimeError):
        cache.get_or_render(("k",), broken)
    assert cache.get_or_render(("k",), lambda: b"png") == b"png" and len(cache) == 1


def test_the_figure_cache_keeps_the_most_recently_used_up_to_its_size():
    cache = FigureCache(size=2)
    for k in ("a", "b"):
        cache.get_or_render(k, lambda k=k: k.encode())
    assert cache.get("a") == b"a"  # used: b is now the oldest
    cache.get_or_render("c", lambda: b"c")
    assert len(cache) == 2 and cache.get("b") is None and cache.get("a") == b"a" and cache.get("c") == b"c"


def test_a_cleared_figure_cache_draws_again():
    cache = FigureCache()
    drawn = []
    cache.get_or_render("a", lambda: drawn.append(1) or b"a")
    cache.clear()
    assert len(cache) == 0 and cache.get("a") is None
    assert cache.get_or_render("a", lambda: drawn.append(2) or b"a2") == b"a2" and drawn == [1, 2]


def test_since_values_within_one_step_share_a_cache_entry_and_the_next_step_draws_its_own(app_env, drawn):
    client, svc, keys, axis_id = app_env
    _measure(client, svc, keys, axis_id)
    assert svc.figures.resolution_s == 3600.0  # limits.plot_window_step_s
    plot = f"{V1}/axes/{axis_id}/plots/tbe_history.png?since="
    a = _png(client, keys, plot + "2026-01-05T10:00:00Z")
    for since in ("2026-01-05T10:00:01Z", "2026-01-05T10:59:59.999Z", "2026-01-05T12:30:00%2B02:00"):
        assert _png(client, keys, plot + since) == a
    assert drawn == ["tbe_history"]  # one render for all four
    _png(client, keys, plot + "2026-01-05T11:00:00Z")  # the next step: a figure of its own
    assert drawn == ["tbe_history"] * 2


def test_a_since_is_rounded_down_to_the_cache_resolution():
    from datetime import datetime, timedelta, timezone

    cache = FigureCache(resolution_s=900.0)
    t = datetime(2026, 3, 1, 8, 29, 59, 999000, tzinfo=timezone(timedelta(hours=1)))
    assert cache.snap(t) == datetime(2026, 3, 1, 7, 15, tzinfo=timezone.utc)
    assert cache.snap(datetime(2026, 3, 1, 7, 15)) == datetime(2026, 3, 1, 7, 15, tzinfo=timezone.utc)  # naive: UTC
    assert cache.snap(None) is None
    with pytest.raises(ValueError, match="resolution_s"):
        FigureCache(resolution_s=0)


def test_beyond_the_render_queue_a_plot_is_answered_429_with_retry_after(app_env, monkeypatch):
    from api.service.figures.gate import RenderGate

    client, svc, keys, axis_id = app_env
    monkeypatch.setattr(svc, "render_gate", RenderGate(workers=1, queue=1))
    started, release = threading.Event(), threading.Event()
    real = svc.plots.draw

    def held(fn, *args, **kwargs):
        started.set()
        assert release.wait(30)
        return real(fn, *args, **kwargs)

    monkeypatch.setattr(svc.plots, "draw", held)
    plot = f"{V1}/axes/{axis_id}/plots/tbe_history.png?since="
    answers = []

    def ask(since):
        answers.append(client.get(plot + since, headers=hdr(keys["read"])).status_code)

    first = threading.Thread(target=ask, args=("2026-01-01T00:00:00Z",))
    first.start()
    assert started.wait(30)  # drawing: the one worker is taken
    queued = threading.Thread(target=ask, args=("2026-01-02T00:00:00Z",))
    queued.start()
    assert poll(lambda: svc.render_gate.admitted == 2, 30)  # waiting: the one queue place is taken
    r = client.get(plot + "2026-01-03T00:00:00Z", headers=hdr(keys["read"]))
    assert r.status_code == 429, r.text
    assert int(r.headers["Retry-After"]) >= 1
    assert "limits.plot_queue" in r.json()["detail"]
    assert client.get("/healthz").status_code == 200  # answered while every render place is taken
    form = client.get("/ui/sign-in")
    csrf = re.search(r'name="csrf" value="([^"]+)"', form.text).group(1)
    assert client.post("/ui/sign-in", data={"key": keys["read"], "csrf": csrf}).status_code == 200
    ui = client.get(f"/ui/axes/{axis_id}/plots/backlash_trend.png")  # the dashboard's figures: the same gate
    assert ui.status_code == 429 and int(ui.headers["Retry-After"]) >= 1, ui.text
    release.set()
    first.join(30)
    queued.join(30)
    assert sorted(answers) == [200, 200] and svc.render_gate.admitted == 0 and svc.render_gate.refused == 2


def test_the_render_bounds_are_limits_settings_with_bounds():
    from api.service.config.loading import parse_settings
    from api.service.config.settings import ConfigError

    lim = parse_settings({"limits": {"plot_renders": 3, "plot_queue": 0, "plot_window_step_s": 60}}).limits
    assert (lim.plot_renders, lim.plot_queue, lim.plot_window_step_s) == (3, 0, 60.0)
    for key, bad in (("plot_renders", 0), ("plot_renders", 17), ("plot_queue", -1), ("plot_queue", 1001),
                     ("plot_window_step_s", 0.5), ("plot_window_step_s", 86401)):
        with pytest.raises(ConfigError, match=key):
            parse_settings({"limits": {key: bad}})

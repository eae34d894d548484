"""Server-side render time of every dashboard page and figure, with a year of daily
history on 10 axes. A measurement, not a test: prints medians (goal: pages < 200 ms).

    .venv/bin/python benchmarks/bench_ui.py [--axes 10] [--days 365] [--repeats 7]

Seeds SQLite in a temporary folder (bench_api's synthetic round trip, shifted per day
with a seasonal temperature), builds the app in this process (scheduler off) and times
each GET through Starlette's TestClient after signing in with a one-time link: server
side only (routing, session, queries, templates, PNG encoding), no network, no browser.
"Warm" is with the status cache (and, for figures, the figure cache) filled: a page
polled every few seconds, a figure viewed again; "cold" drops both before every call
(the first view after a measurement).
"""

from __future__ import annotations

import argparse
import re
import statistics
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
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_api import synthetic_round_trip  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from api.rest import create_app  # noqa: E402
from api.service.config.settings import Settings, demo_axis  # noqa: E402
from core.criteria import BacklashProfile  # noqa: E402
from core.tbe import decide  # noqa: E402
from storage.db import (  # noqa: E402
    FinishedCycle, config_repo, make_engine, make_session_factory, results_repo, session_scope, upgrade)


def seed(url: str, n_axes: int, days: int) -> tuple[str, list[int]]:
    engine = make_engine(url)
    upgrade(engine)
    factory = make_session_factory(engine)
    demo = demo_axis(controller_url="modbus://127.0.0.1:1")
    ids = []
    with session_scope(factory) as s:
        for i in range(n_axes):
            m = config_repo.find_machine(s, f"vmc-{i // 3 + 1}") or config_repo.create_machine(s, f"vmc-{i // 3 + 1}")
            st = replace(demo.settings, spec=replace(demo.settings.spec, name="xyz"[i % 3]))
            ids.append(config_repo.create_axis(s, m.id, st).id)
        s.commit()
        _, key = config_repo.create_key(s, "bench-admin", "admin")  # admin: the configuration pages too
        axis = config_repo.get_axis(s, ids[0])
    rt0 = synthetic_round_trip(axis)
    t0 = datetime.now(timezone.utc) - timedelta(days=days)
    rng = np.random.default_rng(0)
    for axis_id in ids:
        wear_um = rng.uniform(-40.0, 15.0)
        with session_scope(factory) as s:
            for d in range(days):
                temp = 15.0 + 8.0 * np.sin(2 * np.pi * d / 365.0) + rng.normal(0, 0.5)
                b = 200.0 + wear_um + 0.05 * d + 2.0 * (temp - 20.0) + rng.normal(0, 1.0)
                bp = rt0.backlash
                shifted = BacklashProfile(bp.position_mm, bp.backlash_um + (b - bp.mean_um), b,
                                          bp.min_um + b - bp.mean_um, bp.max_um + b - bp.mean_um, bp.std_um)
                when = t0 + timedelta(days=d)
                results_repo.save_finished_cycle(s, FinishedCycle(
                    uuid=str(uuid.uuid4()), axis_id=axis_id, trigger="schedule", status="ok", requested_at=when,
                    started_at=when, finished_at=when + timedelta(seconds=40), temperature_c=float(temp),
                    utility_day=float(d), uncertainty_um=0.0, run_file=None,
                    round_trip=replace(rt0, backlash=shifted), decision=decide(b, axis.tasks)))
    engine.dispose()
    return key, ids


def median_ms(client: TestClient, path: str, repeats: int, before=None) -> tuple[float, int]:
    if before:
        before()
    r = client.get(path)  # warm-up (and the status code to report)
    times = []
    for _ in range(repeats):
        if before:
            before()
        t = time.perf_counter()
        client.get(path)
        times.append(time.perf_counter() - t)
    return 1000 * statistics.median(times), r.status_code


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--axes", type=int, default=10)
    ap.add_argument("--days", type=int, default=365)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mebm-bench-ui-") as tmp:
        url = f"sqlite:///{tmp}/bench.sqlite3"
        t = time.monotonic()
        key, ids = seed(url, a.axes, a.days)
        print(f"seeded {a.axes} axes x {a.days} daily measurements in {time.monotonic() - t:.1f} s (SQLite)")
        settings = Settings(data_dir=Path(tmp), database_url=url, machines=(), axes=(), demo_keys=False,
                            scheduler_enabled=False, catch_up_missed=False)
        app = create_app(settings)
        with TestClient(app) as client:
            link = app.state.ui.sessions.issue_link(key)
            form = client.get(f"/ui/sign-in/{link}")  # the link's page; its button posts the link
            csrf = re.search(r'name="csrf" value="([^"]+)"', form.text).group(1)
            assert client.post(f"/ui/sign-in/{link}", data={"csrf": csrf}).status_code == 200
            svc = app.state.service
            ax = ids[len(ids) // 2]
            pages = [("fleet page", "/ui/"), ("fleet fragment (polled)", "/ui/fleet.frag"),
                     ("axis page", f"/ui/axes/{ax}?range=1y"), ("axis verdict fragment", f"/ui/axes/{ax}/part/verdict.frag"),
                     ("axis cycles fragment", f"/ui/axes/{ax}/part/cycles.frag"), ("gap page", f"/ui/axes/{ax}/gap"),
                     ("configuration page", "/ui/config"), ("axis configuration page", f"/ui/config/axes/{ax}")]
            figures = [(f"figure {n}", f"/ui/axes/{ax}/plots/{n}.png?range=1y") for n in
                       ("backlash_profile", "lead_deviation", "tbe_vs_backlash", "backlash_trend", "tbe_history",
                        "prognosis")]
            figures.append(("history CSV (all)", f"/ui/axes/{ax}/history.csv?range=all"))
            print(f"median of {a.repeats}, server side, ms        warm    cold (caches dropped)")
            def cold_start():  # no cached status, no cached figure
                svc.status.invalidate()
                svc.figures.clear()

            for label, path in pages + figures:
                warm, code = median_ms(client, path, a.repeats)
                cold, _ = median_ms(client, path, a.repeats, before=cold_start)
                flag = "" if code == 200 else f"  (HTTP {code})"
                print(f"  {label:<36} {warm:7.1f} {cold:7.1f}{flag}")
            # the usual case: one axis was just measured (a saved cycle invalidates its status only)
            one, _ = median_ms(client, "/ui/", a.repeats, before=lambda: svc.status.invalidate(ids[0]))
            print(f"  fleet page, one axis just measured   {one:7.1f}")
            # every request reads its session (and key) from the database: its share of the above
            token, ts = client.cookies.get("mebm_session"), []
            for _ in range(200):
                t0 = time.perf_counter()
                assert app.state.ui.sessions.get(token) is not None
                ts.append(1000 * (time.perf_counter() - t0))
            print(f"  session lookup (per request)        {statistics.median(ts):7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

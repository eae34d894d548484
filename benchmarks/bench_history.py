"""Cost of /status, /trend and a trend plot with a long history on one axis. A measurement,
not a test.

    .venv/bin/python benchmarks/bench_history.py [--minutes 525600] [--repeat 5]

Seeds a fresh SQLite database with one result per minute (default: a year, 525,600)
by bulk insert (cycles, results, positive/negative lead criteria, one task's TBE; no
curves, which /trend and the plots timed here do not read) and builds the hourly trend rollups, then calls each endpoint in process
(Starlette's TestClient) ``--repeat`` times and prints the median and the worst time,
and the size of the /trend answer. The timings start once the service's start-up has
warmed its plot process up (it prints how long that took); the first of each is the
first after start.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fastapi.testclient import TestClient  # noqa: E402
from sqlalchemy import func, insert, select  # noqa: E402

from api.rest import create_app  # noqa: E402
from api.service.config.settings import Settings, demo_axis  # noqa: E402
from storage.db import config_repo, make_engine, make_session_factory, rollup, session_scope, upgrade  # noqa: E402
from storage.db.models import Cycle, LeadCriteriaRow, Result, TbeRow  # noqa: E402


def seed(url: str, minutes: int) -> tuple[int, str]:
    engine = make_engine(url)
    upgrade(engine)
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "bench-vmc", "benchmark")
        axis = config_repo.create_axis(s, m.id, demo_axis(controller_url="modbus://127.0.0.1:1").settings)
        _, key = config_repo.create_key(s, "bench-read", "read")
    rng = np.random.default_rng(0)
    t0 = datetime.now(timezone.utc) - timedelta(minutes=minutes)
    batch = 20000
    for start in range(0, minutes, batch):
        n = min(batch, minutes - start)
        i = np.arange(start, start + n)
        temp = 20.0 + 6.0 * np.sin(2 * np.pi * i / 1440.0) + rng.normal(0, 0.3, n)
        b = 220.0 + 2.0 * (temp - 20.0) + i / minutes * 30.0 + rng.normal(0, 1.0, n)
        when = [t0 + timedelta(minutes=int(k)) for k in i]
        cycles = [dict(id=int(k) + 1, uuid=str(uuid.uuid4()), axis_id=axis.id, trigger="schedule", status="ok",
                       requested_at=w, started_at=w, finished_at=w, temperature_c=float(tc), utility_day=float(k) / 1440)
                  for k, w, tc in zip(i, when, temp)]
        results = [dict(id=int(k) + 1, cycle_id=int(k) + 1, axis_id=axis.id, measured_at=w, temperature_c=float(tc),
                        utility_day=float(k) / 1440, backlash_mean_um=float(bb), backlash_min_um=float(bb) - 5,
                        backlash_max_um=float(bb) + 5, backlash_std_um=2.0, useful_travel_start_mm=0.0,
                        useful_travel_end_mm=1000.0, n_samples=12000, peak_speed_mm_min=3000.0, uncertainty_um=0.8,
                        state="OK")
                   for k, w, tc, bb in zip(i, when, temp, b)]
        lead = [dict(result_id=int(k) + 1, direction=d, e_p_um=10.0, e_p_um_per_1000mm=8.0, v_u_um=12.0, v_300_um=6.0,
                     v_2pi_um=3.0, n_strokes=1) for k in i for d in ("positive", "negative")]
        tbe = [dict(result_id=int(k) + 1, task_name="circle R200 F200", profile="circle", radius_mm=200.0,
                    feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0, tbe_um=0.19 * float(bb), state="OK")
               for k, bb in zip(i, b)]  # fmt: skip
        with engine.begin() as c:
            c.execute(insert(Cycle), cycles)
            c.execute(insert(Result), results)
            c.execute(insert(LeadCriteriaRow), lead)
            c.execute(insert(TbeRow), tbe)
    with session_scope(factory) as s:
        rollup.rebuild(s, axis.id)  # a bulk load bypasses the per-result refresh
    engine.dispose()
    return axis.id, key


def after_new_results(svc, axis_id: int, repeat: int) -> tuple[float, float]:
    """The status recomputation a stored cycle pays (``StatusCache.prepare``, inside the
    transaction that stores it), each time after one more result, as cycles add them."""
    times = []
    last = None
    with session_scope(svc.factory) as s:
        last = s.scalar(select(func.max(Result.id)))
    for k in range(repeat):
        w = datetime.now(timezone.utc)
        n = last + 1 + k
        with session_scope(svc.factory) as s:
            s.execute(insert(Cycle), [dict(id=n, uuid=str(uuid.uuid4()), axis_id=axis_id, trigger="schedule", status="ok",
                                           requested_at=w, started_at=w, finished_at=w, temperature_c=21.0)])
            s.execute(insert(Result), [dict(id=n, cycle_id=n, axis_id=axis_id, measured_at=w, temperature_c=21.0,
                                            utility_day=366.0, backlash_mean_um=260.0, backlash_min_um=255.0,
                                            backlash_max_um=265.0, backlash_std_um=2.0, useful_travel_start_mm=0.0,
                                            useful_travel_end_mm=1000.0, n_samples=12000, peak_speed_mm_min=3000.0,
                                            uncertainty_um=0.8, state="OK")])
            s.execute(insert(LeadCriteriaRow), [dict(result_id=n, direction=d, e_p_um=10.0, e_p_um_per_1000mm=8.0,
                                                     v_u_um=12.0, v_300_um=6.0, v_2pi_um=3.0, n_strokes=1)
                                                for d in ("positive", "negative")])
            rollup.refresh(s, axis_id, w)
            t = time.perf_counter()
            publish = svc.status.prepare(s, axis_id)
            times.append(time.perf_counter() - t)
        publish()
    return statistics.median(times) * 1e3, max(times) * 1e3


def timed(client, path, key, repeat):
    times, size = [], 0
    for _ in range(repeat):
        t = time.perf_counter()
        r = client.get(path, headers={"X-API-Key": key})
        times.append(time.perf_counter() - t)
        assert r.status_code == 200, (path, r.status_code, r.text[:300])
        size = len(r.content)
    return statistics.median(times) * 1e3, max(times) * 1e3, size


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=int, default=525_600, help="results to seed, one per minute")
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mebm-bench-history-") as tmp:
        url = f"sqlite:///{tmp}/bench.sqlite3"
        t = time.monotonic()
        axis_id, key = seed(url, a.minutes)
        print(f"seeded {a.minutes} one-minute results in {time.monotonic() - t:.1f} s")
        settings = Settings(data_dir=Path(tmp), database_url=url, demo_keys=False, scheduler_enabled=False)
        t_start = time.monotonic()
        with TestClient(create_app(settings)) as client:
            # the service warms its plot process up at start (spawn, matplotlib, fonts: ~1.5 s on
            # a thread); a client asking within that time waits for it. Timed once it is done:
            plots = client.app.state.service.plots
            if plots.warmed.wait(60):
                print(f"plot process warmed up {time.monotonic() - t_start:.1f} s after the start began")
            for name, path in (("status (first)", f"/api/v1/axes/{axis_id}/status"),
                               ("status", f"/api/v1/axes/{axis_id}/status"),
                               ("trend", f"/api/v1/axes/{axis_id}/trend"),
                               ("plot backlash_trend", f"/api/v1/axes/{axis_id}/plots/backlash_trend.png"),
                               ("plot tbe_history", f"/api/v1/axes/{axis_id}/plots/tbe_history.png")):
                med, worst, size = timed(client, path, key, 1 if name.endswith("(first)") else a.repeat)
                print(f"{name:<22} median {med:8.1f} ms  max {worst:8.1f} ms  body {size / 1e3:8.1f} kB")
            med, worst = after_new_results(client.app.state.service, axis_id, a.repeat)
            print(f"{'status, new result':<22} median {med:8.1f} ms  max {worst:8.1f} ms  "
                  "(recomputed in the storing transaction, one new result each time)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

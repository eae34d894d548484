"""A fleet under load: N ``mebm serve`` workers on one PostgreSQL database,
M axes on short schedules, one worker killed with SIGKILL part-way.

Run:
    nice -n 5 .venv/bin/python benchmarks/bench_fleet.py --database-url postgresql://postgres@127.0.0.1:5432/test \\
        --workers 3 --axes 30 --minutes 3 --kill-one-at 60

``--database-url`` names a server (and a database on it to connect to): the benchmark
creates a database of its own there, ``mebm_fleet_<random>``, and drops it at the end
(``--keep`` keeps it). Each worker is a real ``mebm serve`` process (``--no``-nothing:
scheduler, REST API, leases). The axes' controllers are the built-in simulated Modbus
controller (``controller = "sim"``: a pymodbus server per axis inside the worker that
measures it, at ``--time-scale``), so M controllers do not cost M processes.

Everything is read from the database at the end:
- cycles C: cycles that started (any final state);
- overlapping O: pairs of cycles of one axis whose [start, end] intersect (SQL self-join);
- missed M: axes without a good measurement that started after the kill (after the start
  without a kill);
- takeover_s X: for the axes the killed worker held, the longest time from the kill to the
  first cycle another worker started on one of them;
- lateness_p95_s Y: 95th percentile of start minus due time of the scheduled cycles.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
import uuid
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
from sqlalchemy import create_engine, select, text

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from storage.db import leases, make_engine, make_session_factory, session_scope, upgrade  # noqa: E402
from storage.db.models import Cycle  # noqa: E402
from tests.demo import demo_axis_toml  # noqa: E402


def config(axes: int, interval_s: float, lease_s: float, time_scale: float, travel_mm: float) -> str:
    out = ["[server]", 'host = "127.0.0.1"', "port = 0", "[auth]", "demo_keys = false", "[opcua]",
           "enabled = false", "[mqtt]", 'url = ""', "[mtconnect]", "enabled = false", "[logging]",
           'level = "warning"', "[worker]", f"lease_s = {lease_s}", "[simulator]", f"time_scale = {time_scale}",
           "temperature_amplitude_c = 2"]
    per = 5
    for m in range((axes + per - 1) // per):
        out += ["[[machines]]", f'name = "cell-{m:02d}"']
        for a in range(min(per, axes - m * per)):
            out.append(demo_axis_toml(f"a{a}", travel_mm=(0, travel_mm), measure_feed_mm_min=3000,
                                          schedule_interval_s=interval_s))
    return "\n".join(out) + "\n"


class Worker:
    def __init__(self, name: str, cfg: Path, data_dir: Path, url: str):
        data_dir.mkdir(parents=True, exist_ok=True)
        self.name = name
        self.log = open(data_dir / "serve.log", "w+")  # noqa: SIM115
        env = {**{k: v for k, v in os.environ.items() if not k.startswith("MEBM_")}, "MEBM_DATABASE_URL": url,
               "MEBM_WORKER_NAME": name, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--config", str(cfg),
                                      "--data-dir", str(data_dir)], cwd=ROOT, env=env, stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def wait_banner(self, timeout_s: float = 180.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if re.search(r"mebm service on http://", self.output()):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.2)
        raise SystemExit(f"worker {self.name} did not start:\n{self.output()[-3000:]}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def terminate(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.kill()
            print(f"{self.name}: no clean stop within 60 s, killed:\n{self.output()[-1500:]}")
        self.stop_s = time.monotonic() - t0


def create_database(server_url: str) -> tuple[str, object]:
    url = server_url.replace("postgresql://", "postgresql+psycopg://", 1)
    admin = create_engine(url, isolation_level="AUTOCOMMIT")
    name = f"mebm_fleet_{uuid.uuid4().hex[:10]}"
    with admin.connect() as c:
        c.execute(text(f'CREATE DATABASE "{name}"'))
    return url.rsplit("/", 1)[0] + "/" + name, (admin, name)


def drop_database(handle) -> None:
    admin, name = handle
    with admin.connect() as c:
        c.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--database-url", required=True, help="a PostgreSQL server (a database on it to connect to)")
    ap.add_argument("--workers", type=int, default=3)
    ap.add_argument("--axes", type=int, default=30)
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--kill-one-at", type=float, default=None, help="seconds after the start: SIGKILL one worker")
    ap.add_argument("--interval-s", type=float, default=20.0, help="every axis' schedule")
    ap.add_argument("--lease-s", type=float, default=30.0)
    ap.add_argument("--time-scale", type=float, default=20.0, help="the simulated controllers' speed-up")
    ap.add_argument("--travel-mm", type=float, default=300.0)
    ap.add_argument("--keep", action="store_true", help="keep the database")
    a = ap.parse_args()
    if a.workers < 1 or a.axes < 1 or a.minutes <= 0:
        ap.error("--workers, --axes and --minutes must be positive")
    if a.kill_one_at is not None and (a.workers < 2 or not 0 < a.kill_one_at < a.minutes * 60):
        ap.error("--kill-one-at needs two workers or more and must fall within the run")
    url, handle = create_database(a.database_url)
    eng = make_engine(url)
    upgrade(eng)  # once, before the workers start
    factory = make_session_factory(eng)
    workers: list[Worker] = []
    try:
        with TemporaryDirectory(prefix="bench-fleet-") as tmp:
            cfg = Path(tmp) / "fleet.toml"
            cfg.write_text(config(a.axes, a.interval_s, a.lease_s, a.time_scale, a.travel_mm))
            workers = [Worker(f"w{i}", cfg, Path(tmp) / f"w{i}", url) for i in range(a.workers)]
            for w in workers:
                w.wait_banner()
            t0 = time.monotonic()
            start_at = datetime.now(timezone.utc)
            print(f"{a.workers} workers up, {a.axes} axes every {a.interval_s:g} s, lease {a.lease_s:g} s, "
                  f"simulators at x{a.time_scale:g}; running {a.minutes:g} min", flush=True)
            killed_at, victim_axes, victim_id = None, set(), None
            end = t0 + a.minutes * 60
            while time.monotonic() < end:
                if a.kill_one_at is not None and killed_at is None and time.monotonic() - t0 >= a.kill_one_at:
                    victim = workers[0]
                    with session_scope(factory) as s:
                        info = next(w for w in leases.list_workers(s) if w.name == victim.name and w.live)
                    victim_id, victim_axes = info.id, set(info.held)
                    victim.kill()
                    killed_at = datetime.now(timezone.utc)
                    print(f"t={time.monotonic() - t0:.0f} s: SIGKILL {victim.name} (held {len(victim_axes)} axes)",
                          flush=True)
                time.sleep(0.2)
            for w in workers:  # all at once: a worker stopping first must not hand its axes to the others
                if w.proc.poll() is None:
                    w.proc.send_signal(signal.SIGTERM)
            for w in workers:
                w.terminate()
            print("stop: " + ", ".join(f"{w.name} {getattr(w, 'stop_s', 0):.1f} s" for w in workers[1 if killed_at else 0:]))
            with session_scope(factory) as s:
                rows = list(s.scalars(select(Cycle).where(Cycle.started_at.is_not(None))))
                overlapping = leases.overlapping_cycles(s)
                late = [v for _, v in leases.lateness(s, start_at)]
                names = {w.id: w.name for w in leases.list_workers(s, include_stopped_s=1e9)}
                n_axes = s.execute(text("SELECT count(*) FROM axes")).scalar_one()
            since = killed_at or start_at
            measured = {c.axis_id for c in rows if c.status == "ok" and c.started_at >= since}
            missed = n_axes - len(measured)
            takeover = float("nan")
            if killed_at is not None and victim_axes:
                firsts = []
                for axis_id in victim_axes:
                    after = [c.started_at for c in rows if c.axis_id == axis_id and c.worker != victim_id
                             and c.started_at >= killed_at]
                    firsts.append((min(after) - killed_at).total_seconds() if after else float("inf"))
                takeover = max(firsts)
            by_status = Counter(c.status for c in rows)
            by_worker = Counter(names.get(c.worker, "?") for c in rows)
            print("cycles by status: " + ", ".join(f"{k} {v}" for k, v in sorted(by_status.items())))
            print("cycles by worker: " + ", ".join(f"{k} {v}" for k, v in sorted(by_worker.items())))
            if late:
                print(f"lateness: median {np.median(late):.2f} s, p95 {np.percentile(late, 95):.2f} s, "
                      f"max {max(late):.2f} s over {len(late)} scheduled cycles")
            for w in workers:
                errors = [ln for ln in w.output().splitlines() if " ERROR " in ln or "Traceback" in ln]
                if errors:
                    print(f"{w.name}: {len(errors)} error line(s), first: {errors[0][:200]}")
            p95 = float(np.percentile(late, 95)) if late else float("nan")
            print(f"fleet: cycles {len(rows)}, overlapping {len(overlapping)}, missed {missed}, "
                  f"takeover_s {takeover:.1f}, lateness_p95_s {p95:.1f}", flush=True)
    finally:
        for w in workers:
            w.kill()
        eng.dispose()
        if not a.keep:
            drop_database(handle)
        else:
            print(f"database kept: {url}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Sixty read-key clients ask for history figures, each from a different time, while
/healthz is polled: prints the health latency's median and p99 and how the figure
requests were answered. A measurement, not a test (tests/api/rest/test_plot_cache.py
checks the mechanism: the render queue's bound answers 429 with Retry-After, and a
``since`` within one step of the figure cache shares its entry).

    .venv/bin/python benchmarks/bench_plot_storm.py [--clients 60] [--requests 120] [--repeats 3]

Each repeat starts a real ``mebm serve`` (its own process: the demo machine on the
built-in simulated controller, SQLite in a temporary folder) on a free loopback port,
waits for the demo's first measurement, creates one read key per client through the API
and lets the clients ask ``GET /api/v1/axes/1/plots/tbe_history.png?since=...`` with a
``since`` in a different hour each (every one a render of its own: the worst case for
the figure cache), ``--requests`` in all. Meanwhile /healthz is asked every 20 ms by a
process of its own (so the storm's client does not delay its timing). Bounded: a fixed number of requests, each with a 120 s time-out,
and the service is stopped at the end. Goal: /healthz p99 < 100 ms, every figure
request answered 200 or 429.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import secrets
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
MEBM = Path(sys.executable).with_name("mebm")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(tmp: Path, admin: str) -> tuple[subprocess.Popen, str, Path]:
    port = _free_port()
    log = tmp / "serve.log"
    env = {**os.environ, "MEBM_BOOTSTRAP_ADMIN_KEY": admin}
    proc = subprocess.Popen([str(MEBM), "serve", "--host", "127.0.0.1", "--port", str(port),
                             "--data-dir", str(tmp / "data")], cwd=tmp, env=env,
                            stdout=log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)
    return proc, f"http://127.0.0.1:{port}", log


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


async def _ready(c: httpx.AsyncClient, admin: str, limit_s: float = 120.0) -> None:
    """The service answers and the demo axis has its first good measurement."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        try:
            r = await c.get("/api/v1/axes/1/measurements?status=ok&limit=1", headers={"X-API-Key": admin})
            if r.status_code == 200 and r.json()["items"]:
                return
        except httpx.TransportError:
            pass
        await asyncio.sleep(0.5)
    raise SystemExit(f"the service had no good measurement within {limit_s:g} s")


def _poll_health(url: str, started, stop, out) -> None:
    """In a process of its own: /healthz every 20 ms from ``started`` until ``stop``; the
    latencies (ms) go to ``out``."""
    ms = []
    with httpx.Client(base_url=url, timeout=120) as c:
        for _ in range(20):  # the connection warm, as a load balancer's is
            c.get("/healthz")
        started.set()
        while not stop.is_set():
            t = time.perf_counter()
            c.get("/healthz")
            ms.append((time.perf_counter() - t) * 1e3)
            time.sleep(0.02)
    out.put(ms)


async def _storm(url: str, admin: str, clients: int, requests: int) -> tuple[list[float], dict[int, int], float]:
    limits = httpx.Limits(max_connections=clients + 10, max_keepalive_connections=clients + 10)
    async with httpx.AsyncClient(base_url=url, timeout=120, limits=limits) as c:
        await _ready(c, admin)
        keys = []
        for i in range(clients):
            r = await c.post("/api/v1/keys", json={"name": f"storm-{i}", "role": "read"},
                             headers={"X-API-Key": admin})
            r.raise_for_status()
            keys.append(r.json()["key"])
        ctx = multiprocessing.get_context("spawn")
        started, stop, out = ctx.Event(), ctx.Event(), ctx.Queue()
        poller = ctx.Process(target=_poll_health, args=(url, started, stop, out), daemon=True)
        poller.start()
        if not started.wait(60):
            raise SystemExit("the /healthz poller did not start")
        start = datetime.now(timezone.utc).replace(minute=0, second=0, microsecond=0) - timedelta(days=30)
        codes: list[int] = []

        async def client(i: int) -> None:
            for j in range(i, requests, clients):  # request j: a since in an hour of its own
                since = (start + timedelta(hours=j, minutes=(7 * j) % 60, seconds=j % 60)).isoformat()
                r = await c.get("/api/v1/axes/1/plots/tbe_history.png", params={"since": since},
                                headers={"X-API-Key": keys[i]})
                codes.append(r.status_code)

        t0 = time.perf_counter()
        await asyncio.gather(*[client(i) for i in range(clients)])
        took_s = time.perf_counter() - t0
        stop.set()
        health_ms = out.get(timeout=60)
        poller.join(30)
    return health_ms, {code: codes.count(code) for code in sorted(set(codes))}, took_s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=60)
    ap.add_argument("--requests", type=int, default=120)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    p50s, p99s, all_answered = [], [], True
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            admin = "mebm_" + secrets.token_urlsafe(32)
            proc, url, log = _serve(Path(tmp), admin)
            try:
                health, by_code, took_s = asyncio.run(_storm(url, admin, args.clients, args.requests))
            except BaseException:
                print(log.read_text(errors="replace")[-3000:], file=sys.stderr)
                raise
            finally:
                _stop(proc)
        q = statistics.quantiles(health, n=100) if len(health) >= 2 else health * 99
        p50s.append(statistics.median(health))
        p99s.append(q[98])
        all_answered &= sum(by_code.values()) == args.requests and set(by_code) <= {200, 429}
        print(f"repeat {i + 1}: {args.requests} figure requests from {args.clients} read keys answered {by_code} "
              f"in {took_s:.1f} s; /healthz asked {len(health)} times: p50 {p50s[-1]:.1f} ms, p99 {p99s[-1]:.1f} ms, "
              f"max {max(health):.1f} ms", flush=True)  # fmt: skip
    print(f"/healthz during the plot storm, median of {args.repeats} repeats: p50 {statistics.median(p50s):.1f} ms, "
          f"p99 {statistics.median(p99s):.1f} ms (goal < 100 ms); every figure request answered 200 or 429: "
          f"{'yes' if all_answered else 'NO'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Sixty clients wait for one gap diagnosis while /healthz is polled: prints the health
latency's median, p95 and maximum. A measurement, not a test (the suite's
tests/api/rest/test_gap_bounds.py checks the mechanism: waiting gap requests hold no worker
thread).

    .venv/bin/python benchmarks/bench_gap_requests.py [--clients 60] [--repeats 3]

Each repeat serves a fresh app under uvicorn on a free port (SQLite in a temporary
folder, the simulated controller), stores the runs of a small generated dataset as the
demo axis' history, and starts ``--clients`` concurrent ``GET /api/v1/axes/{id}/gap``
requests: the first queues the diagnosis, every one waits on it (each answered once the
diagnosis is done, or with 202 and its job at the wait's end). While they wait, /healthz
is asked every 20 ms; its latency is what the goal bounds (< 200 ms).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402

from storage.db import config_repo, session_scope  # noqa: E402
from tests.api.rest.conftest import ServedApp, hdr  # noqa: E402
from tests.api.rest.test_gap import store_case  # noqa: E402


async def _load(url: str, key: str, axis_id: int, clients: int) -> tuple[list[float], list[int], float]:
    limits = httpx.Limits(max_connections=clients + 10, max_keepalive_connections=clients + 10)
    async with httpx.AsyncClient(base_url=url, timeout=600, limits=limits) as c:
        for _ in range(20):  # the connection and the endpoint warm, as on a running service
            await c.get("/healthz")
        t0 = time.perf_counter()
        waiting = [asyncio.create_task(c.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(key))) for _ in range(clients)]
        health_ms: list[float] = []
        while not all(w.done() for w in waiting) and time.perf_counter() - t0 < 600:
            t = time.perf_counter()
            await c.get("/healthz")
            health_ms.append((time.perf_counter() - t) * 1e3)
            await asyncio.sleep(0.02)
        answers = await asyncio.gather(*waiting)
        return health_ms, [a.status_code for a in answers], time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    medians, p95s, maxima = [], [], []
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            served = ServedApp(Path(tmp))
            try:
                svc = served.app.state.service
                with session_scope(svc.factory) as s:
                    key = config_repo.create_key(s, "bench", "read")[1]
                    axis_id = config_repo.list_axes(s)[0].id
                store_case(svc, axis_id, "cyclic_error", seed=11)
                health, codes, took_s = asyncio.run(_load(served.url, key, axis_id, args.clients))
            finally:
                served.close()
        q = statistics.quantiles(health, n=20) if len(health) >= 2 else health * 19
        medians.append(statistics.median(health))
        p95s.append(q[18])
        maxima.append(max(health))
        by_code = {c: codes.count(c) for c in sorted(set(codes))}
        print(f"repeat {i + 1}: {args.clients} gap requests answered {by_code} in {took_s:.1f} s; /healthz asked "
              f"{len(health)} times: median {medians[-1]:.1f} ms, p95 {p95s[-1]:.1f} ms, max {maxima[-1]:.1f} ms",
              flush=True)  # fmt: skip
    print(f"/healthz under {args.clients} waiting gap requests, median of {args.repeats} repeats: median "
          f"{statistics.median(medians):.1f} ms, p95 {statistics.median(p95s):.1f} ms, max "
          f"{statistics.median(maxima):.1f} ms (goal < 200 ms)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

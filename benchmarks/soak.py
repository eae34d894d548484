"""Soak: ``mebm serve`` for M minutes on a high time scale with several simulated axes and
bounded concurrent clients, with faults injected; then every cycle is accounted for.
A measurement, not a test.

    .venv/bin/python benchmarks/soak.py --minutes 30 [--axes 3] [--interval-s 2]

Clients (one thread each, so the load is bounded): status polls (read key), trend,
plots, gap, and manual triggers (operate key; 429 answers are expected and counted).
Faults, each for ``--fault-s`` seconds, spread over the run:

- a locked database (another connection holds ``BEGIN EXCLUSIVE``): cycles are spooled
  and stored when the lock goes;
- a data folder that refuses files (``datasets`` and ``unfiled`` replaced by regular
  files: as root, chmod would not stop the service): raw runs are lost and each such
  cycle must say so (``raw_run_lost``);
- a full disk: the data folder (database, spool, raw runs) is a size-limited tmpfs in a
  private mount namespace (the script re-runs itself under ``unshare -m``; root, or
  ``--no-full-disk`` to skip), filled to the last byte by a filler file: database
  writes, spool files and raw runs all fail with ENOSPC until the filler goes.

At the end the server is stopped and the database and folders are checked: every cycle
in a final state, no run in another axis' folder, every ok cycle's run in its folder or
the cycle marked ``raw_run_lost``. Last line::

    soak: cycles C, accounted A, mixed X, lost L (each marked), rss_max_mb R, status_p99_ms P
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from storage.db import config_repo, make_engine, make_session_factory, session_scope, upgrade  # noqa: E402
from tests.demo import demo_axis_toml  # noqa: E402


TIME_SCALE = 40  # the built-in simulator's
EXTERNAL_TIME_SCALE = 10  # a controller process keeps its trace in a ring of at most 10906 samples: 1.1 s at 10x


def config(controllers: list[str], interval_s: float) -> str:
    head = (f'[auth]\ndemo_keys = false\n[scheduler]\nspool_retry_s = 2\n[simulator]\ntime_scale = {TIME_SCALE}\n'
            '[limits]\ntriggers_per_minute = 30\ntrigger_burst = 5\n'
            '[retention]\nkeep_last_runs = 50\nmax_runs = 400\ninterval_s = 60\n'
            '[[machines]]\nname = "soak-vmc"\n')
    return head + "".join(demo_axis_toml(n, travel_mm=(0, 300), controller=c, measure_feed_mm_min=6000,
                                         schedule_interval_s=interval_s)
                          for n, c in zip("xyzuvw", controllers))


def start_controllers(n: int, run_s: float) -> tuple[list[subprocess.Popen], list[str]]:
    """``n`` simulated Modbus controllers, each its own process (as real controllers are
    their own devices): ``mebm sim-controller modbus`` on a free port at the soak's time scale."""
    procs, urls = [], []
    for _ in range(n):
        p = subprocess.Popen([sys.executable, "-m", "api.cli", "sim-controller", "modbus", "--port", "0",
                              "--time-scale", str(EXTERNAL_TIME_SCALE), "--ring-records", "10906",
                              "--duration-s", f"{run_s:.0f}"], cwd=ROOT,
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
        procs.append(p)
        line = p.stdout.readline()  # "... on modbus://127.0.0.1:PORT ..." once it listens
        m = re.search(r"modbus://127\.0\.0\.1:\d+", line)
        if m is None:
            for q in procs:
                q.kill()
            raise SystemExit(f"soak: a simulated controller did not start: {line!r}")
        urls.append(m.group(0).replace("modbus://", "sim://", 1))  # sim://: mebm starts the round trips
    return procs, urls


def rss_mb(pid: int) -> float:
    """Resident memory of the service and its child processes (the gap diagnosis worker)."""
    total = 0.0
    for p in [pid, *_children(pid)]:
        try:
            with open(f"/proc/{p}/status") as fh:
                total += next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:")) / 1024
        except (OSError, StopIteration):
            if p == pid:
                raise
    return total


def _children(pid: int) -> list[int]:
    out = []
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for k in kids:
        out += [int(k), *_children(int(k))]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--axes", type=int, default=3)
    ap.add_argument("--interval-s", type=float, default=2.0)
    ap.add_argument("--fault-s", type=float, default=15.0)
    ap.add_argument("--keep", action="store_true", help="keep the data folder (printed) for a look afterwards")
    ap.add_argument("--no-full-disk", action="store_true", help="skip the full-disk fault (needs root for unshare -m)")
    ap.add_argument("--disk-mb", type=int, default=2048, help="size of the data folder's tmpfs (full-disk fault)")
    ap.add_argument("--controllers", choices=("inprocess", "external"), default="inprocess",
                    help="the service's built-in simulator threads at 40x (default, the demo's set-up), or "
                         "simulated controllers as processes of their own at 10x (as real ones are devices of "
                         "their own; at 40x their 10906-sample trace ring lasts 0.27 s and most cycles lose "
                         "samples)")
    a = ap.parse_args()
    full_disk = not a.no_full_disk
    if full_disk and os.environ.get("MEBM_SOAK_NS") != "1":
        if shutil.which("unshare") is None:
            print("soak: unshare not found: run with --no-full-disk", file=sys.stderr)
            return 2
        os.execvpe("unshare", ["unshare", "-m", "--propagation", "private", sys.executable, *sys.argv],
                   {**os.environ, "MEBM_SOAK_NS": "1"})  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="mebm-soak-"))
    if full_disk:
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={a.disk_mb}m,mode=0700", "tmpfs", str(tmp)], check=True)
    url = f"sqlite:///{tmp}/soak.sqlite3"
    eng = make_engine(url)
    upgrade(eng)
    with session_scope(make_session_factory(eng)) as s:
        read = config_repo.create_key(s, "soak-read", "read")[1]
        operate = config_repo.create_key(s, "soak-operate", "operate")[1]
    eng.dispose()
    sims: list[subprocess.Popen] = []
    if a.controllers == "external":
        sims, urls = start_controllers(a.axes, a.minutes * 60 + 600)
    else:
        urls = ["sim"] * a.axes
    print(f"controllers: {a.controllers} ({', '.join(urls)})", flush=True)
    (tmp / "soak.toml").write_text(config(urls, a.interval_s))
    log = open(tmp / "serve.log", "w+")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--config", str(tmp / "soak.toml"),
                             "--port", "0", "--data-dir", str(tmp)], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                            env={**os.environ, "MEBM_DATABASE_URL": url}, start_new_session=True)
    base = None
    deadline = time.monotonic() + 60
    while base is None and time.monotonic() < deadline and proc.poll() is None:
        log.seek(0)
        m = re.search(r"mebm service on (http://127\.0\.0\.1:\d+)", log.read())
        base = m.group(1) if m else None
        time.sleep(0.2)
    if base is None:
        log.seek(0)
        print(log.read()[-3000:])
        return 1
    stop = threading.Event()
    status_ms: list[float] = []
    status_at: list[float] = []  # when each status answer came (monotonic), for the p99 by minute
    answers: dict[str, int] = {}
    rss: list[float] = []
    lock = threading.Lock()

    def count(kind: str, code: int) -> None:
        with lock:
            answers[f"{kind} {code}"] = answers.get(f"{kind} {code}", 0) + 1

    def poll(kind: str, paths, key: str, pause_s: float, method: str = "GET") -> None:
        with httpx.Client(base_url=base, headers={"X-API-Key": key}, timeout=60) as c:
            i = 0
            while not stop.is_set():
                path = paths[i % len(paths)]
                i += 1
                t = time.perf_counter()
                try:
                    r = c.request(method, path)
                    code = r.status_code
                except httpx.HTTPError:
                    code = 0
                if kind == "status":
                    with lock:
                        status_ms.append((time.perf_counter() - t) * 1e3)
                        status_at.append(time.monotonic())
                count(kind, code)
                stop.wait(pause_s)

    ids = range(1, a.axes + 1)
    clients = [
        ("status", [f"/api/v1/axes/{i}/status" for i in ids], read, 0.01, "GET"),
        ("status", [f"/api/v1/axes/{i}/status" for i in ids], read, 0.01, "GET"),
        ("trend", [f"/api/v1/axes/{i}/trend" for i in ids], read, 0.5, "GET"),
        ("plot", [f"/api/v1/axes/{i}/plots/backlash_trend.png" for i in ids], read, 1.0, "GET"),
        ("gap", [f"/api/v1/axes/{i}/gap?runs=4" for i in ids], read, 5.0, "GET"),
        ("trigger", [f"/api/v1/axes/{i}/measurements" for i in ids], operate, 1.0, "POST"),
    ]
    threads = [threading.Thread(target=poll, args=c, daemon=True) for c in clients]
    for t in threads:
        t.start()

    def sample_rss() -> None:
        while not stop.is_set():
            try:
                rss.append(rss_mb(proc.pid))
            except (OSError, StopIteration):
                pass
            stop.wait(1.0)

    threading.Thread(target=sample_rss, daemon=True).start()
    total_s = a.minutes * 60
    t0 = time.monotonic()
    faults = [(total_s * 0.25, "locked database"), (total_s * 0.5, "data folder refuses files")]
    if full_disk:
        faults.append((total_s * 0.75, "full disk"))
    for at_s, what in faults:
        while time.monotonic() - t0 < at_s and proc.poll() is None:
            time.sleep(0.5)
        print(f"{time.monotonic() - t0:7.0f} s: {what} for {a.fault_s:.0f} s", flush=True)
        if what == "full disk":
            filler = tmp / "filler"
            with open(filler, "wb", buffering=0) as fh:
                st = os.statvfs(tmp)
                with contextlib.suppress(OSError):  # most of it at once (may be refused near the limit)
                    os.posix_fallocate(fh.fileno(), 0, max(st.f_bavail - 256, 0) * st.f_frsize)
                fh.seek(0, os.SEEK_END)
                with contextlib.suppress(OSError):
                    while True:  # then to the last block
                        fh.write(b"\0" * 65536)
                with contextlib.suppress(OSError):
                    while True:
                        fh.write(b"\0" * 512)
            print(f"{time.monotonic() - t0:7.0f} s: disk full ({os.statvfs(tmp).f_bavail} blocks free)", flush=True)
            time.sleep(a.fault_s)
            filler.unlink()
        elif what == "locked database":
            con = sqlite3.connect(tmp / "soak.sqlite3", timeout=30, isolation_level=None)
            con.execute("BEGIN EXCLUSIVE")
            time.sleep(a.fault_s)
            con.execute("ROLLBACK")
            con.close()
        else:
            moved = []
            for name in ("datasets", "unfiled"):
                p = tmp / name
                if p.exists():
                    p.rename(tmp / f"{name}.aside")
                    moved.append(name)
                p.write_text("a file where a folder should be")
            time.sleep(a.fault_s)
            for name in ("datasets", "unfiled"):
                (tmp / name).unlink()
                if name in moved:
                    (tmp / f"{name}.aside").rename(tmp / name)
    while time.monotonic() - t0 < total_s and proc.poll() is None:
        time.sleep(0.5)
    stop.set()
    for t in threads:
        t.join(70)
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
    for sim in sims:
        sim.kill()
    try:
        return report(tmp, url, status_ms, answers, rss, [t - t0 for t in status_at])
    finally:
        if a.keep:
            print(f"data folder kept: {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


def report(tmp: Path, url: str, status_ms, answers, rss, status_t_s=()) -> int:
    con = sqlite3.connect(tmp / "soak.sqlite3")
    cycles = con.execute("SELECT id, uuid, axis_id, status, run_file, raw_run_lost FROM cycles").fetchall()
    outcomes = con.execute("SELECT status, substr(coalesce(failure_reason, ''), 1, 60), count(*) FROM cycles "
                           "GROUP BY 1, 2 ORDER BY 3 DESC").fetchall()
    axes = dict(con.execute("SELECT id, machine_id FROM axes").fetchall())
    con.close()
    final = {"ok", "failed", "interrupted", "cancelled"}
    in_folder: dict[str, tuple[int, str]] = {}  # cycle uuid -> (axis id of the folder, file)
    mixed = 0
    for folder in (tmp / "datasets").glob("machine-*_axis-*"):
        m = re.fullmatch(r"machine-(\d+)_axis-(\d+)(_rejected)?(@.*)?", folder.name)
        if not m or not (folder / "dataset.json").is_file():
            continue
        for r in json.loads((folder / "dataset.json").read_text())["runs"]:
            if int(r.get("axis_id", m.group(2))) != int(m.group(2)):
                mixed += 1
            in_folder[str(r.get("cycle_uuid"))] = (int(m.group(2)), r["file"])
    accounted = lost = unmarked = retired = 0
    for _id, uuid, axis_id, status, run_file, raw_lost in cycles:
        if status not in final:
            continue
        where = in_folder.get(uuid)
        if where is not None and where[0] != axis_id:
            mixed += 1
            continue
        if status == "ok" and where is None:
            if raw_lost and raw_lost.startswith("deleted by the retention policy"):
                retired += 1
            elif raw_lost:
                lost += 1
            elif (tmp / "unfiled" / f"{uuid}.npz").is_file():
                pass  # kept outside the dataset folder
            else:
                unmarked += 1
                continue
        accounted += 1
    disk = sum(f.stat().st_size for f in (tmp / "datasets").rglob("*") if f.is_file())
    print(f"raw runs on disk: {disk / 1e6:.1f} MB in {sum(1 for _ in (tmp / 'datasets').rglob('*.csv*'))} files "
          "(retention: the newest 50 per axis plain, at most 400 per axis)")
    ms = sorted(status_ms)
    p99 = ms[min(int(0.99 * len(ms)), len(ms) - 1)] if ms else float("nan")
    print("answers:", ", ".join(f"{k}: {v}" for k, v in sorted(answers.items())))
    print(f"raw runs deleted by the retention policy, each marked on its cycle: {retired}")
    print("cycle outcomes:", "; ".join(f"{st}{' (' + why + ')' if why else ''}: {n}" for st, why, n in outcomes[:8]))
    print(f"cycles not in a final state: {sum(1 for c in cycles if c[3] not in final)}; "
          f"ok cycles whose run is neither kept nor marked lost: {unmarked}; axes: {len(axes)}")
    if len(status_t_s) == len(status_ms) and ms:  # where the tail is: each minute's p99 (faults at 1/4, 1/2, 3/4)
        by_min: dict[int, list[float]] = {}
        for t_s, v in zip(status_t_s, status_ms, strict=True):
            by_min.setdefault(int(t_s // 60), []).append(v)
        per = [sorted(v)[min(int(0.99 * len(v)), len(v) - 1)] for _, v in sorted(by_min.items())]
        print("status p99 by minute (ms):", " ".join(f"{v:.0f}" for v in per))
    if len(rss) >= 30:  # bounded: the last third of the run against the first (the workers start late)
        third = len(rss) // 3
        print(f"rss (service and its worker processes): max of the first third {max(rss[:third]):.0f} MB, "
              f"of the middle {max(rss[third:-third]):.0f} MB, of the last third {max(rss[-third:]):.0f} MB")
    print(f"soak: cycles {len(cycles)}, accounted {accounted}, mixed {mixed}, lost {lost} (each marked), "
          f"rss_max_mb {max(rss) if rss else float('nan'):.0f}, status_p99_ms {p99:.1f}")
    return 0 if mixed == 0 and unmarked == 0 else 1


if __name__ == "__main__":
    sys.exit(main())

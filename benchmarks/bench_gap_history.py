"""Time of the gap diagnosis of the demo axis' stored history, in the foreground and
through the service's path. A measurement, not a test.

    .venv/bin/python benchmarks/bench_gap_history.py [--runs 16] [--repeat 1]

Builds the history `make run` stores for the demo axis (api.service.config.settings:
the seed paper's Y axis, 1000 mm of travel, round trips at 3000 mm/min and 500 mm/s²,
sampled at 400 Hz, on the service's demo twin: its encoders, lead error, cyclic error and
thermal growth, the backlash following the simulated shop temperature and the chain's
wear by utility day), ``--runs`` round trips a minute apart, written as the service's
cycle writes them (time and the two encoders, the conditions in the run's fields;
storage.dataset.append_runs). Then times

* ``direct``: ``core.gap.diagnose`` of the folder in this process, and
* ``service``: the same runs through ``api.service.gap_jobs.GapJobs``, as the dashboard's
  gap page asks for them (a fresh ``spawn``-ed worker process at nice +10, which
  compiles the model kernels once, then the diagnosis),

and prints each time, the ratio, the named effect of both (which must be the same), the
CPU and the load average before and after. The page's expected time
(``job.expected_s``) is printed beside the measured one.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.measurement import default_program  # noqa: E402
from api.service.config.settings import DEMO_MACHINE, DEMO_SIMULATOR, demo_axis  # noqa: E402
from api.service.demo import DriftingTwin  # noqa: E402
from api.service.gap_jobs import GapJobs, RunPlan, stored_files  # noqa: E402
from core.dataset import MachineSpec, Run, RunSpec  # noqa: E402
from core.gap import diagnose  # noqa: E402
from storage.dataset import append_runs, next_run_name, read_dataset  # noqa: E402
from timing import cpu_name  # noqa: E402

RATE_HZ = 400.0
CYCLE_S = 60.0  # the demo's schedule: one round trip a minute


def build_history(folder: Path, runs: int, seed: int = 1) -> None:
    """``runs`` round trips of the demo axis, a minute apart, stored in ``folder``: the
    service's own demo twin (api.service.demo.DriftingTwin, on a clock that advances a
    cycle per run) running the round trip the service programs."""
    cfg = demo_axis()
    spec, name = cfg.settings.spec, cfg.settings.spec.name
    now = [0.0]
    twin = DriftingTwin(spec, DEMO_SIMULATOR, clock=lambda: now[0], seed=seed)
    program = default_program(spec, cfg.settings.measure_feed_mm_min,
                              acceleration_mm_s2=cfg.settings.measure_acceleration_mm_s2)
    for i in range(runs):
        now[0] = i * CYCLE_S
        temp_c = twin.temperature_c
        tr = twin.round_trip(program, RATE_HZ)
        # as the service's cycle stores a round trip: time and the two encoders, no
        # command column (the diagnosis rebuilds the program), the conditions in the spec
        run = RunSpec(file=next_run_name(folder, f"rt_{name}"), kind="round_trip", axes=(name,),
                      feed_mm_min=program.feed_mm_min, temperature_c=temp_c, utility_day=twin.wear.utility_days(),
                      acceleration_mm_s2=program.acceleration_mm_s2,
                      extra={"measured_at": f"2026-01-01T00:{i:02d}:00+00:00", "temperature_measured": True})
        cols = {"time_s": tr.time_s, f"{name}_motor_rev": tr.motor_rev, f"{name}_table_mm": tr.table_mm}
        append_runs(folder, MachineSpec(DEMO_MACHINE, {name: spec}), [Run(run, cols)])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    print(f"CPU: {cpu_name()} ({os.cpu_count()} cores); load average before: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "demo"
        t0 = time.perf_counter()
        build_history(folder, a.runs)
        files = stored_files(folder) or ()
        size_mb = sum((folder / f).stat().st_size for f in files) / 1e6
        print(f"history: {len(files)} round trips, {size_mb:.1f} MB, built in {time.perf_counter() - t0:.0f} s")
        direct_s, service_s, answers = [], [], set()
        for _ in range(a.repeat):
            t0 = time.perf_counter()
            rep = diagnose(read_dataset(folder))
            direct_s.append(time.perf_counter() - t0)
            d = rep.to_dict()
            answers.add(("direct", d["effect"]))
            print(f"direct:  {direct_s[-1]:6.1f} s -> {d['effect']} ({d['gap_before_um']:.2f} -> {d['gap_after_um']:.2f} µm)")
            jobs = GapJobs(abandon_s=3600.0)
            try:
                t0 = time.perf_counter()
                job = jobs.start(("bench",), folder, len(files), plan=RunPlan(tuple(files), len(files)))
                out = job.future.result(timeout=3600)
                service_s.append(time.perf_counter() - t0)
            finally:
                jobs.close()
            answers.add(("service", out["effect"]))
            print(f"service: {service_s[-1]:6.1f} s -> {out['effect']} ({out['gap_before_um']:.2f} -> "
                  f"{out['gap_after_um']:.2f} µm); the page expected {job.expected_s:.0f} s")
        dm, sm = statistics.median(direct_s), statistics.median(service_s)
        same = len({e for _, e in answers}) == 1
        print(f"median: direct {dm:.1f} s, service {sm:.1f} s (ratio {sm / dm:.2f}); "
              f"same answer: {'yes' if same else 'NO'}; goal service <= 90 s: {'met' if sm <= 90 else 'not met'}")
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())

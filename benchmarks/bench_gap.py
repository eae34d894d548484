"""Benchmark: diagnosis time of a full-size dataset (8 round trips of ~30,000 samples + 6 circles).

Generates one dataset per label with the benchmark generator (core.gap_benchmark,
default CaseSize: 4 round trips per axis at 1 kHz over ~30 s, 6 circles at 500 Hz),
diagnoses each and prints the wall time, samples and result; then the median.
Goal: a median of at most 20 s and a maximum of at most 60 s per dataset on the quiet
2-core machine. The scoring benchmark (confusion matrix, fraction correct) is
``mebm gap benchmark --cases 48``.

    .venv/bin/python benchmarks/bench_gap.py [--seed S] [--plant twin|independent|forms] [--labels none,thermal,...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.gap import GapSettings, diagnose  # noqa: E402
from core.gap_benchmark import LABELS, CaseSize, make_plant_case  # noqa: E402
from timing import cpu_name  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--labels", default=",".join(LABELS))
    ap.add_argument("--plant", choices=("twin", "independent", "forms"), default="twin")
    args = ap.parse_args()
    diagnose(make_plant_case(args.plant, (), np.random.default_rng(0), CaseSize(), True)[0])  # numba warm-up
    times = []
    for label in args.labels.split(","):
        labs = tuple(x for x in label.split("+") if x != "none")
        ds, _ = make_plant_case(args.plant, labs, np.random.default_rng(args.seed), CaseSize(), True)
        n_rt = sum(r.spec.kind == "round_trip" for r in ds.runs)
        n_ct = len(ds.runs) - n_rt
        rt_samples = [len(r) for r in ds.runs if r.spec.kind == "round_trip"]
        t0 = time.perf_counter()
        rep = diagnose(ds, GapSettings(keep_curves=False))
        dt = time.perf_counter() - t0
        times.append(dt)
        print(f"{label:17s} {n_rt} round trips (median {int(np.median(rt_samples))} samples) + {n_ct} circles: "
              f"{dt:5.1f} s -> {rep.effect} ({rep.gap_before_um:.2f} -> {rep.gap_after_um:.2f} µm)", flush=True)  # fmt: skip
    med, top = statistics.median(times), max(times)
    met = "met" if med <= 20.0 and top <= 60.0 else "NOT met"
    print(f"plant {args.plant}: median diagnosis time: {med:.1f} s, max {top:.1f} s (goal median <= 20 s, "
          f"max <= 60 s: {met}; {cpu_name()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()

"""Benchmark: analyse a 1,000,000-sample round trip.

Prints the median wall time of `analyze_round_trip` over repeats and its ratio to
one `numpy.interp` over the same number of samples (a floor for any O(n) pass).
Goal: under 0.3 s on the 2-core machine and under 15x that baseline, with
the interpolation onto the grid and the outlier rejection on: the trace
carries 20 glitches of 5 mm on the motor and table encoders.

    .venv/bin/python benchmarks/bench_core.py [--samples N] [--repeats R]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.criteria import analyze_round_trip  # noqa: E402
from core.dataset import AxisSpec  # noqa: E402
from tests.core.criteria.synth import round_trip  # noqa: E402
from timing import median_s  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()

    travel_mm, feed = 1000.0, 1000.0
    duration_s = 2 * (travel_mm + 10) / (feed / 60) + 2 * 0.5 + 2 * feed / 60 / 500
    rate_hz = args.samples / duration_s
    s = round_trip(
        start_mm=-5.0, end_mm=travel_mm + 5.0, feed_mm_min=feed, rate_hz=rate_hz,
        backlash_um=lambda u: 236 + 8 * np.sin(2 * np.pi * u / 700),
        lead_error_um=lambda u: 5 * np.sin(2 * np.pi * u / 16) + 10 * np.sin(2 * np.pi * u / 300) - 0.018 * u,
        table_noise_um=0.3, motor_noise_um=0.3, rng=np.random.default_rng(0),
    )
    axis = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, travel_mm))
    n = s.time_s.size
    glitches = np.random.default_rng(1).choice(np.arange(1000, n - 1000), size=20, replace=False)
    s.table_mm[glitches[:10]] += 5.0
    s.motor_rev[glitches[10:]] -= 5.0 / axis.transmission_mm_per_rev

    def analyse():
        return analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, axis)

    xp = np.sort(s.motor_rev)
    t_analyse = median_s(analyse, args.repeats)
    t_interp = median_s(lambda: np.interp(s.motor_rev, xp, s.table_mm), args.repeats)
    r = analyse()
    print(f"samples                     {n:,}")
    print(f"analyze_round_trip median   {t_analyse * 1e3:8.1f} ms  (goal < 300 ms)")
    print(f"numpy.interp median         {t_interp * 1e3:8.1f} ms")
    print(f"ratio                       {t_analyse / t_interp:8.1f} x  (goal < 15 x)")
    print(f"result                      b̄ = {r.backlash.mean_um:.2f} µm, v_u = {r.strokes['positive'].v_u_um:.2f} µm, "
          f"{r.outliers_removed} outliers removed")


if __name__ == "__main__":
    main()

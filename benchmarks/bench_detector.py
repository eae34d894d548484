"""Speed of the passive round-trip detector: medians over repeats, as multiples of real time.

Run: .venv/bin/python benchmarks/bench_detector.py [--repeats N]

Case: 60 s of rest (encoder noise within the rest band), then a 500 mm round trip at
3000 mm/min and rest again, at 1 kHz (82,500 samples), fed in blocks of 100 samples as a
polling driver would; once from the positions alone, once with a running flag. Passive
mode listens for up to ``start_timeout_s`` (600 s by default) while the controller
streams, so the detector must cost a small fraction of real time. Target: >= 100x real
time in both modes (under 1 % of one core at 1 kHz).
"""

from __future__ import annotations

import argparse

import numpy as np

from timing import median_s

from acquisition.driver.round_trip_detector import DetectorSettings, RoundTripDetector

RATE_HZ = 1000.0
BLOCK = 100


def stream():
    rng = np.random.default_rng(0)
    x = np.concatenate([np.zeros(60_000), np.linspace(0, 500, 10_000), np.full(500, 500.0),
                        np.linspace(500, 0, 10_000), np.zeros(2_000)])
    x = x + rng.uniform(-0.001, 0.001, x.size)
    t = np.arange(x.size) / RATE_HZ
    running = (t >= 60.0) & (t < 80.5)
    return t, x / 6.857, x, running


def detect(t, m, x, running, use_flag: bool):
    det = RoundTripDetector(DetectorSettings(min_stroke_mm=400.0, max_duration_s=60.0), use_flag=use_flag)
    for i in range(0, t.size, BLOCK):
        found = det.feed(t[i:i + BLOCK], m[i:i + BLOCK], x[i:i + BLOCK], running[i:i + BLOCK])
        if found is not None:
            return found
    raise AssertionError("the benchmark's round trip was not found")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    t, m, x, running = stream()
    machine_s = t[-1]
    print(f"median of {args.repeats} runs after one warm-up; {t.size} samples = {machine_s:.1f} s at 1 kHz, "
          f"blocks of {BLOCK}")
    print(f"{'mode':12s} {'wall ms':>9s} {'x real time':>12s} {'samples/s':>12s}  target")
    for name, flag in (("positions", False), ("flag", True)):
        wall = median_s(lambda: detect(t, m, x, running, flag), args.repeats)  # noqa: B023
        ratio = machine_s / wall
        print(f"{name:12s} {wall * 1e3:9.1f} {ratio:12.0f} {t.size / wall:12.0f}  >= 100x "
              + ("ok" if ratio >= 100 else "MISSED"))


if __name__ == "__main__":
    main()

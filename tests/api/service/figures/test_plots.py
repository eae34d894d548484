"""The plots hold no global lock: renders from many threads at once give exactly the
bytes of the same renders made one at a time (a shared matplotlib cache misused across
threads would show as different or broken images, or as an exception)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timedelta, timezone

import numpy as np

from api.service.figures import plots
from core.tbe import MachiningTask


def _renders():
    x = np.linspace(0.0, 500.0, 2001)
    b = 230.0 + 5.0 * np.sin(x / 40.0)
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    days = [t0 + timedelta(hours=6 * i) for i in range(400)]
    task = MachiningTask(name="circle", profile="circle", radius_mm=200.0, feed_mm_min=200.0, tolerance_um=45.0,
                         gain_per_s=10.0)
    return [
        lambda: plots.backlash_profile(x, b, -b / 2, b / 2, mean_um=230.0, limit_um=236.0, title="m / y"),
        lambda: plots.tbe_vs_backlash([task], [236.0], backlash_um=230.0, title="m / y", backlash_uncertainty_um=2.0),
        lambda: plots.backlash_trend(days, list(230 + np.cos(np.arange(400) / 9.0)), [20.0 + i % 7 for i in range(400)],
                                     limit_um=236.0, title="m / y"),
        lambda: plots.tbe_history({"circle": (days, list(40 + np.sin(np.arange(400) / 5.0) * 6), [45.0] * 400)},
                                  title="m / y"),
        lambda: plots.empty("m / y", "no good measurement yet"),
    ]


def test_concurrent_renders_equal_serial_renders():
    renders = _renders()
    serial = [r() for r in renders]
    assert all(png.startswith(b"\x89PNG") and len(png) > 5000 for png in serial)
    jobs = [i % len(renders) for i in range(40)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        parallel = list(pool.map(lambda i: renders[i](), jobs))
    for i, png in zip(jobs, parallel):
        assert png == serial[i], f"render {i} differs when made beside others"


def test_a_name_with_dollars_is_drawn_as_written_not_as_mathtext():
    name = r"$\frac{$"  # mathtext refuses it: the figure would not be drawn
    task = MachiningTask(name=name, profile="circle", radius_mm=200.0, feed_mm_min=200.0, tolerance_um=45.0,
                         gain_per_s=10.0)
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    days = [t0 + timedelta(hours=i) for i in range(5)]
    for png in (plots.tbe_vs_backlash([task], [236.0], backlash_um=230.0, title=f"{name} / y"),
                plots.tbe_history({name: (days, [40.0, 41.0, 42.0, 41.0, 40.0], [45.0] * 5)}, title=f"{name} / y"),
                plots.empty(name, f"no good measurement of {name} yet")):
        assert png.startswith(b"\x89PNG\r\n\x1a\n")

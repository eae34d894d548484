"""A year of one axis under condition-based maintenance, and the figure of its history
with the repairs marked (docs/maintenance-history.png).

The demo axis (the seed paper's Y axis and its circle task, tolerance 45 µm) measured
once a day (06:00 UTC); its backlash follows the simulator's model: b̄ = b_0 + γ·(utility days
since the last repair) + β·(T - 20 °C) + noise, the shop temperature swinging over the
year and the weather. Each measurement is judged by the service's decision rule
(core.tbe.decide, guarded); an ALARM opens a corrective order, the repair (a preload
adjustment) follows two days later and restores b_0. The summary (core.maintenance) is
printed against a fixed 90-day plan.

    .venv/bin/python benchmarks/maintenance_year.py [--out docs/maintenance-history.png]
"""

from __future__ import annotations

import argparse
import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from api.service.config.settings import DEMO_TASK
from api.service.figures.plots import backlash_trend
from core.maintenance import summarise_axis
from core.tbe import State, decide

B0_UM, GAMMA_UM_PER_DAY, BETA_UM_PER_K, NOISE_UM, U_UM = 196.0, 0.32, 2.0, 1.0, 2.0
REPAIR_DELAY_DAYS = 2.0


def year(seed: int = 7):
    rng = np.random.default_rng(seed)
    start = datetime(2026, 1, 1, tzinfo=timezone.utc)
    t, b, temp, repairs, orders = [], [], [], [], []
    last_repair_day, pending = 0.0, None
    for k in range(365):
        day = k + 0.25
        if pending is not None and day >= pending + REPAIR_DELAY_DAYS:
            repairs.append(start + timedelta(days=pending + REPAIR_DELAY_DAYS))
            orders[-1] = (orders[-1][0], orders[-1][1], (start + timedelta(days=day)).timestamp())
            last_repair_day, pending = pending + REPAIR_DELAY_DAYS, None
        temperature = 21.0 + 4.0 * math.sin(2 * math.pi * (day - 110) / 365.0) + rng.normal(0.0, 1.0)
        backlash = (B0_UM + GAMMA_UM_PER_DAY * (day - last_repair_day) + BETA_UM_PER_K * (temperature - 20.0)
                    + rng.normal(0.0, NOISE_UM))
        when = start + timedelta(days=day)
        t.append(when)
        b.append(backlash)
        temp.append(temperature)
        d = decide(max(backlash, 0.0), [DEMO_TASK], backlash_uncertainty_um=U_UM, rule="guarded")
        if d.state is State.ALARM and pending is None:
            pending = day
            orders.append(("corrective", when.timestamp(), None))
    return start, t, b, temp, repairs, orders


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/maintenance-history.png"))
    ap.add_argument("--fixed-interval-days", type=float, default=90.0)
    a = ap.parse_args()
    start, t, b, temp, repairs, orders = year()
    limit = DEMO_TASK.backlash_limit_um()
    png = backlash_trend(t, b, temp, limit_um=limit, title="demo-vmc axis y, a simulated year",
                         repairs=[(r, "preload_adjusted") for r in repairs])
    a.out.write_bytes(png)
    end = start + timedelta(days=365)
    s = summarise_axis(1, start.timestamp(), end.timestamp(), called_repairs_s=[r.timestamp() for r in repairs],
                       other_repairs=0, orders=orders, fixed_interval_days=a.fixed_interval_days)
    d = s.to_dict()
    print(f"wrote {a.out} ({len(png)} bytes): {len(t)} measurements, {d['repairs_called_by_error']} repairs called "
          f"by the error (intervals {d['intervals_days']} days), ALARM -> verified {d['alarm_to_verified_mean_days']} "
          f"days on average; a fixed {a.fixed_interval_days:g}-day plan: {d['fixed_interval_repairs']} repairs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

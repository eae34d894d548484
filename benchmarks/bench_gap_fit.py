"""Benchmark: one train cost of each round-trip form, the unit every round-trip fit repeats.

A fit of a candidate's round-trip form evaluates its train cost (the model simulated over
each train round trip, scored as the fit scores it: rt.train_rss) some tens to hundreds
of times per start, so the time of one evaluation sets most of a diagnosis' round-trip
time. Times, on one axis of a full-size independent-plant dataset (3 train round trips
of ~30,000 samples), the nominal play, the friction lost-motion form, the friction chain
(three starts per run) and the compliance form; prints the median per evaluation and its
ratio to the nominal play's.

    .venv/bin/python benchmarks/bench_gap_fit.py [--seed S] [--repeats N]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.gap import prepare_runs  # noqa: E402
from core.gap import roundtrip as rt  # noqa: E402
from core.gap.candidates import compliance_stage, compose, friction_chain_stage, friction_stage  # noqa: E402
from core.gap_benchmark import CaseSize, make_plant_case  # noqa: E402
from timing import median_s  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    ds, _ = make_plant_case("independent", ("friction",), np.random.default_rng(args.seed), CaseSize(), True)
    rts, _ = prepare_runs(ds)
    axis = min(r.axis for r in rts)
    runs = [r for r in rts if r.axis == axis and r.split == "train"]
    b_um = rt.estimate_backlash_um(runs)
    gain = ds.machine.axes[axis].position_gain_per_s
    forms = {"nominal play": (), "friction lost motion": (friction_stage(),),
             "friction chain": (friction_chain_stage(),), "compliance": (compliance_stage(gain),)}  # fmt: skip
    print(f"axis {axis}: {len(runs)} train round trips, median {int(np.median([r.t_s.size for r in runs]))} samples")
    base = None
    for name, stages in forms.items():
        model = compose(stages, b_um, {})
        theta = model.x0
        rss = rt.train_rss(model, theta, runs, model.envelope)
        t = median_s(lambda m=model, th=theta: rt.train_rss(m, th, runs, m.envelope), args.repeats)
        base = base or t
        print(f"{name:22s} {t * 1e3:7.2f} ms per train cost ({t / base:5.1f}x the nominal play), "
              f"train RSS {rss:.6g} um^2")  # fmt: skip


if __name__ == "__main__":
    main()

"""``mebm demo``: the core end to end on the seed paper's example, no hardware needed.

The digital twin plays the paper's Y axis (Table 1: k_a 6.857 mm/rev, 16 mm lead,
K = 10 1/s) with the backlash measured on June 7th (239.5 µm), a cyclic lead error
and encoder noise. The round trip is analysed like a measured one, the backlash
mapped to the TBE of the circle task (R = 200 mm at 200 mm/min, 45 µm tolerance)
and the maintenance verdict given.
"""

from __future__ import annotations

import argparse

import numpy as np

from api.cli.output import print_json, print_table
from core.criteria import analyze_round_trip, criterion_label
from core.sim import AxisModel, CyclicError, Effects, Encoders, round_trip, simulate
from core.tbe import MachiningTask, decide
from storage.dataset import append_runs, next_run_name
from core.dataset import MachineSpec

PAPER_TASK = MachiningTask(
    "ring R200 @200 mm/min", profile="circle", radius_mm=200.0, feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="analyse a simulated round trip of the paper's Y axis and give the verdict")
    p.add_argument("--backlash-um", type=float, default=239.5, help="backlash of the simulated axis (µm)")
    p.add_argument("--travel-mm", type=float, default=400.0, help="useful travel measured (mm)")
    p.add_argument("--feed-mm-min", type=float, default=2000.0)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", help="also write the simulated run to this dataset folder")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    axis = AxisModel(
        name="y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0, position_gain_per_s=10.0,
        backlash_um=a.backlash_um,
        effects=Effects(cyclic_error=CyclicError.of((16.0, 4.0, 0.0), (300.0, 6.0, 60.0))),
        encoders=Encoders(motor_noise_um=0.2, table_noise_um=0.3),
    )
    overtravel_mm = 5.0
    program = round_trip(-overtravel_mm, a.travel_mm + overtravel_mm, a.feed_mm_min, dwell_s=0.5)
    trace = simulate({"y": axis}, program, rate_hz=1000.0, rng=np.random.default_rng(a.seed))
    spec = axis.to_axis_spec((0.0, a.travel_mm))
    result = analyze_round_trip(trace.time_s, trace.motor_rev["y"], trace.table_mm["y"], spec)
    decision = decide(result.backlash.mean_um, [PAPER_TASK])
    if a.out:
        name = next_run_name(a.out, "rt_y")
        append_runs(a.out, MachineSpec("demo-vmc", {"y": spec}), [trace.to_run(name)])
    target = decision.repair_target
    if a.json:
        print_json({
            "simulated_backlash_um": a.backlash_um,
            "round_trip": result.to_dict(),
            "decision": {
                "state": decision.state.value,
                "binding_task": decision.binding_task,
                "backlash_limit_um": decision.backlash_limit_um,
                "restore_below_um": target.restore_below_um if target is not None else None,
                "restore_below_explanation": target.explanation if target is not None else None,
                "tasks": [{"task": x.task.name, "tbe_um": x.tbe_um, "tolerance_um": x.task.tolerance_um,
                           "state": x.state.value} for x in decision.assessments],
            },
        })
        return 0
    pos = result.strokes["positive"]
    print(f"Simulated round trip of the paper's Y axis over {a.travel_mm:g} mm at {a.feed_mm_min:g} mm/min "
          f"({result.n_samples} samples), backlash set to {a.backlash_um:g} µm.")
    print()
    print_table(
        ["quantity", "value"],
        [["mean backlash b̄ (µm)", result.backlash.mean_um],
         ["backlash min..max (µm)", f"{result.backlash.min_um:.2f}..{result.backlash.max_um:.2f}"],
         [f"{criterion_label('e_p')} (µm/1000 mm)", pos.e_p_um_per_1000mm],
         [f"{criterion_label('v_u')} (µm)", pos.v_u_um], [f"{criterion_label('v_300')} (µm)", pos.v_300_um],
         [f"{criterion_label('v_2pi')} (µm)", pos.v_2pi_um]],
    )
    print()
    for x in decision.assessments:
        print(f"task {x.task.name}: TBE {x.tbe_um:.2f} µm (Eq. 8) against {x.task.tolerance_um:g} µm permitted")
    print(decision.message())
    return 0

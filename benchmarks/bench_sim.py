"""Speed of the simulator (core.sim): medians over repeats, as multiples of real time.

Run: .venv/bin/python benchmarks/bench_sim.py [--repeats N]

Cases: a 600 mm round trip of the Y axis at 1000 mm/min (about 76 s of machine
time, 1 kHz samples) on the nominal model and with every effect on (LuGre friction
on a compliant chain, thermal, backlash profile, cyclic error, servo dynamics,
sampling skew, encoder noise); and a 30,000-sample round trip, the call the gap
diagnosis repeats while fitting. The first call of each case compiles the numba
kernels and is not timed. Targets: nominal >= 1000x real time, all effects >= 100x.
"""

from __future__ import annotations

import argparse

import numpy as np

from timing import median_s

from core.sim import (
    AxisModel,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Encoders,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    round_trip,
    simulate,
)

ALL_EFFECTS = Effects(
    friction=Friction(
        coulomb_n=300.0, static_n=380.0, stribeck_velocity_mm_s=2.0, viscous_n_s_per_mm=2.0, model="lugre"
    ),
    compliance=Compliance(stiffness_n_per_um=200.0, table_mass_kg=500.0),
    thermal=Thermal(lead_error_um_per_m=-20.0, lead_growth_ppm_per_k=1.3, backlash_um_per_k=3.0),
    backlash_profile=BacklashProfile((0.0, 300.0, 600.0), (90.0, 120.0, 100.0)),
    cyclic_error=CyclicError.of((16.0, 3.0, 0.0), (6.857, 1.0, 45.0)),
    servo_dynamics=ServoDynamics(velocity_lag_s=0.003, dead_time_s=0.0005),
    sampling_skew=SamplingSkew(table_delay_s=0.0005),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    prog = round_trip(-5.0, 605.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=1.0)
    short = round_trip(-5.0, 225.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=1.0)  # ~30 s, 30k samples
    enc = Encoders(motor_counts_per_rev=2**20, table_resolution_um=0.05, motor_noise_um=0.1, table_noise_um=0.1)
    cases = [
        ("600 mm round trip, nominal", {"y": AxisModel(backlash_um=100.0)}, prog, 1000.0),
        ("600 mm round trip, all effects", {"y": AxisModel(backlash_um=100.0, effects=ALL_EFFECTS, encoders=enc)},
         prog, 100.0),
        ("30k-sample round trip, nominal", {"y": AxisModel(backlash_um=100.0)}, short, None),
        ("30k-sample round trip, all effects",
         {"y": AxisModel(backlash_um=100.0, effects=ALL_EFFECTS, encoders=enc)}, short, None),
    ]  # fmt: skip
    print(f"median of {args.repeats} runs after one warm-up call (numba compile excluded)")
    print(
        f"{'case':36s} {'samples':>8s} {'machine s':>10s} {'wall ms':>9s} {'x real time':>12s} {'step µs':>8s}  target"
    )
    for name, axes, program, target in cases:
        trace = simulate(axes, program, rng=np.random.default_rng(0))
        wall = median_s(lambda: simulate(axes, program, rng=np.random.default_rng(0)), args.repeats)  # noqa: B023
        machine_s = program.duration_s
        ratio = machine_s / wall
        step_us = trace.step_s["y"] * 1e6
        verdict = "" if target is None else (f">= {target:.0f}x " + ("ok" if ratio >= target else "MISSED"))
        print(
            f"{name:36s} {trace.time_s.size:8d} {machine_s:10.1f} {wall * 1e3:9.1f} {ratio:12.0f} "
            f"{step_us:8.1f}  {verdict}"
        )


if __name__ == "__main__":
    main()

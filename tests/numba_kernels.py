"""Compile the numba kernels once, before the workers of a parallel run start.

numba keeps what it compiles in the ``__pycache__`` folders beside the sources
(``cache=True``), so only the first process to call a kernel compiles it. On a fresh
clone the suite's workers start together, and each would compile every kernel it meets
before any of them had written the cache. ``compile_kernels`` calls each kernel through
the product's own code, so with the argument types it is called with: the twin's
simulation of round trips and circles with every effect, a gap diagnosis of them (every
family's forms and contour refits), and a small case of each independent plant.
"""

from __future__ import annotations

import numpy as np


def compile_kernels() -> None:
    from core.dataset import Dataset, MachineSpec
    from core.gap import GapSettings, diagnose
    from core.gap_benchmark import SMALL, benchmark_case
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
        circle,
        round_trip,
        simulate,
    )

    rng = np.random.default_rng(0)
    fx = Effects(thermal=Thermal(lead_growth_ppm_per_k=8.0, backlash_um_per_k=3.0),
                 backlash_profile=BacklashProfile((0.0, 100.0), (50.0, 60.0)),
                 cyclic_error=CyclicError.of((16.0, 4.0, 30.0)), sampling_skew=SamplingSkew(0.001),
                 servo_dynamics=ServoDynamics(velocity_lag_s=0.004, dead_time_s=0.001),
                 friction=Friction(coulomb_n=2500.0, model="lugre", bristle_stiffness_n_per_um=125.0),
                 compliance=Compliance(stiffness_n_per_um=60.0, table_mass_kg=1500.0, damping_ratio=0.3))  # fmt: skip
    axes = {a: AxisModel(name=a, transmission_mm_per_rev=6.857, backlash_um=60.0, effects=fx,
                         encoders=Encoders(table_noise_um=0.2, motor_noise_um=0.2)) for a in "xy"}  # fmt: skip
    stribeck = Effects(friction=Friction(coulomb_n=2500.0, static_n=3000.0, stribeck_velocity_mm_s=2.0))
    simulate({"y": AxisModel(name="y", effects=stribeck)}, round_trip(10.0, 11.0, 1200.0, 800.0, 0.1, axis="y"),
             rate_hz=500.0, rng=rng)  # fmt: skip
    runs = []
    for i, feed in enumerate((1200.0, 2000.0, 3000.0)):
        tr = simulate({"y": axes["y"]}, round_trip(10.0, 14.0, feed, 1500.0, 0.1, axis="y"), temperature_c=20.0 + i,
                      rate_hz=500.0, rng=rng)  # fmt: skip
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == 2 else "train"))
    for i, feed in enumerate((1200.0, 2000.0)):
        tr = simulate(axes, circle(3.0, (100.0, 100.0), feed, ("ccw", "cw")[i]), rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"c_{i}.csv", split="test" if i == 1 else "train"))
    machine = MachineSpec("warm", {a: m.to_axis_spec((0.0, 200.0)) for a, m in axes.items()})
    diagnose(Dataset(machine, tuple(runs)), GapSettings(keep_curves=False, second_effect=False), workers=1)
    for plant in ("independent", "forms"):
        benchmark_case(plant, 1, 0, 0, SMALL)

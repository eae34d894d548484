"""Benchmark: the gap diagnosis' answers under other BLAS and numba kernels.

A diagnosis' fits end in last digits that move with the BLAS kernel OpenBLAS picks for
the CPU (``OPENBLAS_CORETYPE``) and with numba's target (``NUMBA_CPU_NAME``); the
decision must not. This script diagnoses the benchmark's datasets (one per label and
plant, as ``benchmarks/bench_gap.py`` makes them) in a fresh process per kernel setting
and compares: the named effects must be the same under every setting, and the figures
(gap before and after, noise floor) the same to two significant digits.

    .venv/bin/python benchmarks/bench_gap_kernels.py [--plants twin,independent,forms]
        [--settings default,Prescott,Haswell,SkylakeX,generic] [--jobs 2] [--seed 7] [--labels none,thermal,...]

``default`` is the machine's own environment; ``Prescott``, ``Haswell`` and ``SkylakeX``
set ``OPENBLAS_CORETYPE``; ``generic`` sets ``NUMBA_CPU_NAME=generic`` (numba compiles
its kernels for a generic x86-64 once, then keeps them in its cache). A kernel the CPU
cannot run (``SkylakeX`` needs AVX-512) is left out, and the script says so. Each worker
prints the BLAS kernel it ran (threadpoolctl). Exit status 1 when an effect differs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SETTINGS = {
    "default": {},
    "Prescott": {"OPENBLAS_CORETYPE": "Prescott"},
    "Haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "SkylakeX": {"OPENBLAS_CORETYPE": "SkylakeX"},
    "generic": {"NUMBA_CPU_NAME": "generic"},
}
# the instruction sets an OpenBLAS kernel needs (/proc/cpuinfo flags): forced onto a CPU
# without them, OpenBLAS dies of an illegal instruction (SkylakeX's AVX-512 on an AMD
# EPYC before Zen 4)
CORETYPE_NEEDS = {"Haswell": frozenset({"avx2", "fma"}), "SkylakeX": frozenset({"avx512f"})}


def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (/proc/cpuinfo; empty where it cannot be read)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return frozenset()
    return frozenset(next((ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith("flags")), []))


def runnable(setting: str, flags: frozenset[str]) -> bool:
    """Whether this CPU can run ``setting`` (a setting name of SETTINGS or an OpenBLAS core type)."""
    coretype = SETTINGS.get(setting, {"OPENBLAS_CORETYPE": setting}).get("OPENBLAS_CORETYPE")
    return CORETYPE_NEEDS.get(coretype, frozenset()) <= flags


def sig2(x: float) -> str:
    """``x`` to two significant digits, as the comparison reads it."""
    return f"{float(x):.2g}"


def worker(plant: str, seed: int, labels: list[str]) -> None:
    """Diagnose each label's dataset of ``plant`` and print one JSON line per dataset."""
    import numpy as np
    from threadpoolctl import threadpool_info

    from core.gap import GapSettings, diagnose
    from core.gap_benchmark import CaseSize, make_plant_case

    blas = [f"{i.get('internal_api')} {i.get('architecture')}" for i in threadpool_info() if i.get("user_api") == "blas"]
    print(json.dumps({"blas": blas}), flush=True)
    for label in labels:
        labs = tuple(x for x in label.split("+") if x != "none")
        ds, _ = make_plant_case(plant, labs, np.random.default_rng(seed), CaseSize(), True)
        t0 = time.perf_counter()
        rep = diagnose(ds, GapSettings(keep_curves=False))
        print(json.dumps({"plant": plant, "label": label, "effects": list(rep.effects) or ["none"],
                          "gap_before_um": rep.gap_before_um, "gap_after_um": rep.gap_after_um,
                          "noise_floor_um": rep.noise_floor_um, "seconds": time.perf_counter() - t0}),
              flush=True)  # fmt: skip


def run_setting(name: str, plant: str, seed: int, labels: list[str]) -> tuple[str, str, list[dict], list[str]]:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NUMBA_CPU_NAME")}
    env.update(SETTINGS[name])
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--plant", plant, "--seed", str(seed),
           "--labels", ",".join(labels)]  # fmt: skip
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"worker {name}/{plant} failed:\n{out.stderr[-3000:]}")
    rows, blas = [], []
    for line in out.stdout.splitlines():
        d = json.loads(line)
        if "blas" in d:
            blas = d["blas"]
        else:
            rows.append(d)
    return name, plant, rows, blas


def main() -> None:
    from core.gap_benchmark import LABELS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default="twin,independent,forms")
    ap.add_argument("--settings", default="default,Prescott,Haswell,SkylakeX,generic")
    ap.add_argument("--labels", default=",".join(LABELS))
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=2, help="worker processes at once")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--plant", help=argparse.SUPPRESS)
    args = ap.parse_args()
    labels = args.labels.split(",")
    if args.worker:
        worker(args.plant, args.seed, labels)
        return
    settings = args.settings.split(",")
    unknown = [s for s in settings if s not in SETTINGS]
    if unknown:
        raise SystemExit(f"unknown setting(s) {unknown}: choose from {sorted(SETTINGS)}")
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), platform.processor())  # fmt: skip
    flags = cpu_flags()
    for s in [s for s in settings if not runnable(s, flags)]:
        need = ", ".join(sorted(CORETYPE_NEEDS[SETTINGS[s]["OPENBLAS_CORETYPE"]] - flags))
        print(f"setting {s} left out: this CPU lacks {need}, which its BLAS kernel needs")
    settings = [s for s in settings if runnable(s, flags)]
    print(f"CPU: {cpu}; seed {args.seed}; settings {', '.join(settings)}")
    jobs = [(s, p) for p in args.plants.split(",") for s in settings]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max(1, args.jobs)) as ex:
        results = list(ex.map(lambda j: run_setting(j[0], j[1], args.seed, labels), jobs))
    wall = time.perf_counter() - t0
    for name, plant, _, blas in results:
        if plant == jobs[0][1]:
            print(f"  {name:9s} BLAS: {', '.join(blas) or '?'}")
    by = {(n, p): {r["label"]: r for r in rows} for n, p, rows, _ in results}
    same_effects = same_figures = total = 0
    for plant in args.plants.split(","):
        print(f"plant {plant}:")
        for label in labels:
            rows = [by[(s, plant)][label] for s in settings]
            effects = {"+".join(r["effects"]) for r in rows}
            figures = {(sig2(r["gap_before_um"]), sig2(r["gap_after_um"]), sig2(r["noise_floor_um"])) for r in rows}
            total += 1
            same_effects += len(effects) == 1
            same_figures += len(figures) == 1
            cells = "  ".join(f"{s}: {'+'.join(r['effects'])} {r['gap_before_um']:.3g}->{r['gap_after_um']:.3g}"
                              for s, r in zip(settings, rows))  # fmt: skip
            flag = "" if len(effects) == 1 else "   <- EFFECTS DIFFER"
            flag += "" if len(figures) == 1 else "   (figures differ at two digits)"
            print(f"  {label:17s} {cells}{flag}")
    print(f"identical effects: {same_effects}/{total}; identical figures to two significant digits: "
          f"{same_figures}/{total}; {len(jobs)} worker runs in {wall:.0f} s")
    if same_effects != total:
        sys.exit(1)


if __name__ == "__main__":
    main()

"""The same data gives the same diagnosis under another BLAS kernel: a few small cases
diagnosed in a fresh process per ``OPENBLAS_CORETYPE`` (OpenBLAS picks its kernel when it
loads; a kernel this CPU cannot run, SkylakeX's AVX-512 on an AMD EPYC before Zen 4, is left out),
their named effects compared. The benchmark's full-size datasets, and numba's
generic target, are compared by ``benchmarks/bench_gap_kernels.py``."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
_spec = importlib.util.spec_from_file_location("bench_gap_kernels", ROOT / "benchmarks" / "bench_gap_kernels.py")
kernels_bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(kernels_bench)
# the kernels compared: those of Prescott, Haswell and SkylakeX this CPU can run
CORETYPES = tuple(ct for ct in ("Prescott", "Haswell", "SkylakeX")
                  if kernels_bench.runnable(ct, kernels_bench.cpu_flags()))

# the independent plant's two-mass chain (x round trips) on the draw after the plant-form
# tests' seed, and its Karnopp friction chain: the chain forms, whose fits are the most
# sensitive to the last bits of their numerics. One thread each (the answer does not depend
# on it): the suite's other workers share the machine
CASES = """
import json, sys
import numpy as np
from core.dataset import Dataset
from core.gap import GapSettings, diagnose
from core.plant_independent import SMALL_PLANT, make_plant_case
from threadpoolctl import threadpool_info

def x_round_trips(ds):
    return Dataset(ds.machine, tuple(r for r in ds.runs if r.spec.axes == ("x",)))

out = {"blas": [i.get("architecture") for i in threadpool_info() if i.get("user_api") == "blas"]}
chain = make_plant_case(("compliance",), np.random.default_rng([32, len("compliance")]), SMALL_PLANT)
rep = diagnose(x_round_trips(chain.dataset), GapSettings(keep_curves=False, second_effect=False), workers=1)
out["two_mass_chain"] = [rep.effect, rep.gap_before_um, rep.gap_after_um]
karnopp = make_plant_case(("friction",), np.random.default_rng([31, len("friction")]), SMALL_PLANT)
rep = diagnose(karnopp.dataset, GapSettings(keep_curves=False, second_effect=False), workers=1)
out["karnopp_chain"] = [rep.effect, rep.gap_before_um, rep.gap_after_um]
print(json.dumps(out))
"""


def _diagnose_under(coretype: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    env["OPENBLAS_CORETYPE"] = coretype
    out = subprocess.run([sys.executable, "-c", CASES], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=600, check=False)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_kernel_the_cpu_cannot_run_is_known_by_its_instruction_set():
    assert kernels_bench.runnable("Prescott", frozenset())
    assert kernels_bench.runnable("generic", frozenset())
    assert not kernels_bench.runnable("SkylakeX", frozenset({"sse2", "avx2", "fma"}))
    assert kernels_bench.runnable("SkylakeX", frozenset({"avx2", "fma", "avx512f"}))
    assert not kernels_bench.runnable("Haswell", frozenset({"avx2"}))


@pytest.mark.skipif(len(CORETYPES) < 2, reason="this CPU runs only one of the BLAS kernels compared")
def test_the_chain_forms_are_named_alike_under_every_blas_kernel():
    runs = {ct: _diagnose_under(ct) for ct in CORETYPES}
    # each process ran one kernel, and each a kernel of its own (OpenBLAS reports Prescott's as Katmai)
    kernels = {ct: set(r["blas"]) for ct, r in runs.items()}
    assert all(len(k) == 1 for k in kernels.values()) and len(set.union(*kernels.values())) == len(CORETYPES), kernels
    for case, effect in (("two_mass_chain", "compliance"), ("karnopp_chain", "friction")):
        named = {ct: r[case][0] for ct, r in runs.items()}
        assert set(named.values()) == {effect}, (case, runs)
        # the gap before is the nominal model's, one parameter per axis: the same to three digits
        before = [r[case][1] for r in runs.values()]
        assert max(before) - min(before) <= 1e-3 * max(before), (case, runs)

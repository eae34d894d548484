"""``mebm gap diagnose DATASET`` and ``mebm gap benchmark``: the sim-to-real gap diagnosis."""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

from api.cli.output import json_safe
from core.errors import InputError
from core.gap import diagnose
from core.gap_benchmark import LABELS, SMALL, CaseSize, run_benchmark
from storage.dataset import read_dataset, write_dataset


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gap", help="where and why the nominal model misses a machine (sim-to-real gap)")
    gsub = p.add_subparsers(dest="gap_command", metavar="GAP_COMMAND")
    gsub.required = True

    d = gsub.add_parser("diagnose", help="diagnose the gap on a dataset's test runs")
    d.add_argument("dataset", help="dataset folder (mebm-dataset/1) with round trips and/or circles/lines")
    d.add_argument("--json", metavar="FILE", help="write the mebm-gap/1 JSON result to FILE ('-' for stdout)")
    d.add_argument("--plots", metavar="DIR", help="write PNG plots of measured vs nominal vs corrected to DIR")
    d.set_defaults(func=run_diagnose)

    b = gsub.add_parser("benchmark", help="diagnose generated datasets whose effect is withheld, and score it")
    b.add_argument("--cases", type=int, default=40, help="number of generated datasets (default 40)")
    b.add_argument("--seed", type=int, default=2024, help="random seed (default 2024)")
    b.add_argument("--json", metavar="FILE", help="write the per-case results and the summary to FILE")
    b.add_argument("--small", action="store_true", help="small, fast datasets (for a smoke test)")
    b.add_argument("--jobs", type=int, default=1, help="cases diagnosed in parallel processes (default 1; the "
                   "per-case time is then measured under that load)")
    b.add_argument("--plant", choices=("twin", "independent", "forms", "both"), default="twin",
                   help="which plant generates the cases: the project's twin, the independent simulator, the "
                        "second independent simulator of other forms (core.plant_forms), or both of the first two "
                        "(default twin)")  # fmt: skip
    b.add_argument("--only", metavar="N[,N...]", help="diagnose only these cases, numbered from 1 as the case lines "
                   "print them, with the same data as in the whole run of --cases and --seed (to look at a case again)")
    b.add_argument("--write-datasets", metavar="DIR", help="also write each case's dataset to "
                   "DIR/<plant>-seed<S>-case<NNN>/ (for `mebm gap diagnose`), with truth.json beside it: the injected "
                   "effects and every parameter the plant drew")  # fmt: skip
    b.set_defaults(func=run_benchmark_cmd)


def _write_json(obj, target: str) -> None:
    text = json.dumps(json_safe(obj), indent=2, ensure_ascii=False) + "\n"
    if target == "-":
        sys.stdout.write(text)
    else:
        Path(target).write_text(text, encoding="utf-8")


def run_diagnose(a: argparse.Namespace) -> int:
    ds = read_dataset(a.dataset)
    for r in ds.runs:
        for axis in r.spec.axes:
            if axis in ds.machine.axes and ds.machine.axes[axis].position_gain_per_s is None:
                raise InputError(f"{a.dataset}: axis {axis!r} has no position_gain_per_s: the nominal model's "
                                 "position loop is proportional with the gain K, so the gap diagnosis needs it; "
                                 f"add the drive's K (1/s) to machine.axes.{axis} in dataset.json, or import "
                                 "into a new folder with --position-gain-per-s")  # fmt: skip
    report = diagnose(ds)
    if a.json != "-":
        print(report.text())
    if a.json:
        _write_json(report.to_dict(), a.json)
    if a.plots:
        files = write_plots(report, Path(a.plots))
        if a.json != "-":
            print(f"\nplots: {', '.join(str(f) for f in files)}")
    return 0


def write_plots(report, folder: Path) -> list[Path]:
    """PNGs of the test residuals: nominal vs corrected by the diagnosed effect
    (along the travel for round trips, versus angle for circles); the dashboard's gap
    page draws the same figure (api.service.figures.plots.gap_residual)."""
    from api.service.figures.plots import gap_residual

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for c in [*report.curves.get("round_trip", []), *report.curves.get("contour", [])]:
        path = folder / f"gap_{Path(c['file']).stem}.png"
        path.write_bytes(gap_residual(c, report.effect))
        out.append(path)
    return out


def _only(text: str | None, n_cases: int) -> list[int] | None:
    """``--only`` as 0-based indexes (it counts from 1, as the case lines do)."""
    if text is None:
        return None
    try:
        nums = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise InputError(f"--only (={text!r}) must be case numbers separated by commas, e.g. 15,21") from None
    if not nums or not all(1 <= n <= n_cases for n in nums):
        raise InputError(f"--only (={text!r}) must name cases 1..{n_cases} (--cases)")
    return [n - 1 for n in nums]


def _keep_dataset(root: Path, plant: str, seed: int, n_cases: int, i: int, labs: tuple[str, ...], ds, truth: dict) -> None:
    """``--write-datasets``: case ``i``'s dataset and the plant's truth, written where the
    benchmark generated them (a module-level function: it goes to the worker processes)."""
    folder = write_dataset(root / f"{plant}-seed{seed}-case{i + 1:03d}", ds)
    _write_json({"plant": plant, "seed": seed, "cases": n_cases, "case": i + 1, "labels": list(labs), "truth": truth},
                str(folder / "truth.json"))  # fmt: skip


def run_benchmark_cmd(a: argparse.Namespace) -> int:
    if a.cases < 1:
        raise InputError(f"--cases (={a.cases}) must be >= 1")
    only = _only(a.only, a.cases)
    size = SMALL if a.small else CaseSize()
    plants = ("twin", "independent") if a.plant == "both" else (a.plant,)
    results = []
    for plant in plants:
        def progress(c, plant=plant):
            got = "+".join(c.diagnosed_effects) or c.diagnosed
            print(f"{plant} case {c.index + 1:3d}/{a.cases}: {c.label:34s} -> {got:34s} gap {c.gap_before_um:7.2f} -> "
                  f"{c.gap_after_um:6.2f} µm (noise {c.noise_floor_um:.2f}) {c.seconds:5.1f} s"
                  f"{'' if c.split_given else ' [no split field]'}", flush=True)  # fmt: skip

        keep = (functools.partial(_keep_dataset, Path(a.write_datasets), plant, a.seed, a.cases)
                if a.write_datasets else None)  # fmt: skip
        res = run_benchmark(a.cases, a.seed, size, progress=progress, plant=plant, jobs=a.jobs, only=only,
                            keep_dataset=keep)  # fmt: skip
        print()
        if only is not None:
            print(f"only cases {', '.join(str(i + 1) for i in only)} of the {a.cases} drawn from seed {a.seed}: "
                  "the figures below are of these alone")  # fmt: skip
        print(format_summary(res))
        print()
        results.append(res)
    if a.json:
        _write_json(results[0].to_dict() if len(results) == 1 else {r.plant: r.to_dict() for r in results}, a.json)
    return 0


def format_summary(res) -> str:
    short = {"none": "none", "thermal": "therm", "backlash_profile": "b_prof", "cyclic_error": "cyclic",
             "friction": "fric", "compliance": "compl", "servo_dynamics": "servo", "sampling_skew": "skew"}  # fmt: skip
    conf = res.confusion()
    lines = [f"plant {res.plant}: confusion matrix (rows: injected, the diagnosed one for a mixed case it names; "
             f"columns: diagnosed), {len(res.cases)} cases, seed {res.seed}:"]  # fmt: skip
    head = "".ljust(17) + "".join(short[p].rjust(8) for p in LABELS)
    lines.append(head)
    for t in LABELS:
        lines.append(t.ljust(17) + "".join(str(conf[t][p]).rjust(8) for p in LABELS))
    n_ok = sum(c.correct for c in res.cases)
    lines.append("")
    lines.append(f"named correctly: {n_ok}/{len(res.cases)} = {res.fraction_correct * 100:.1f} % "
                 "(a mixed case counts when either effect is named)")  # fmt: skip
    n_none = sum(not c.labels for c in res.cases)
    lines.append(f"none cases diagnosed as an effect: {res.false_effects_on_none} of {n_none}")
    hit, n = res.none_within_2x_noise
    lines.append(f"none cases with gap_before within 2x the noise floor: {hit} of {n}")
    rec, m = res.second_effect_recall
    lines.append(f"second effect recall on the mixed cases: {rec} of {m}")
    lines.append(f"median gap_after/gap_before on the effect cases: {res.median_ratio_effect_cases:.3f}")
    hidden = res.hidden_effect_cases()
    n_vis = len(res.cases) - len(hidden)
    lines.append(f"effect cases whose gap_before is within 2x the noise floor (the effect did not show): {len(hidden)}"
                 + (f"; named correctly without them: {sum(c.correct for c in res.cases if c not in hidden)}/{n_vis}"
                    f" = {res.fraction_correct_visible() * 100:.1f} %" if hidden else ""))  # fmt: skip
    close, wrong, there = res.close_alternative_cases
    lines.append(f"answers with a candidate not told apart from them: {close}; of them wrong: {wrong}, "
                 f"with an injected effect among those candidates: {there}")  # fmt: skip
    for c in res.errors:
        lines.append(f"case {c.index + 1} ({c.label}): the diagnosis raised {c.axis}")
    lines.append(f"diagnoses that raised: {len(res.errors)} (scored as wrong)")
    lines.append(f"median diagnosis time per dataset: {res.median_seconds:.1f} s")
    return "\n".join(lines)

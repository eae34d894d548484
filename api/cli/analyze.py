"""``mebm analyze DATASET``: backlash and lead criteria of every round-trip run."""

from __future__ import annotations

import argparse
import sys

from api.cli.instruments import add_options, instruments_of
from api.cli.output import print_json, print_table
from core.criteria import CRITERION_NAMES, CRITERION_SYMBOLS, RoundTripSettings, analyze_round_trip
from core.criteria.lost_motion import clearance_from_feeds
from core.criteria.roundtrip import TBE_NEEDS_POSITION_GAIN
from core.criteria.uncertainty import inputs_of_spec
from core.errors import MebmError, TraceError
from storage.dataset import read_dataset


class AnalysisFailed(TraceError):
    """Some runs of a dataset could not be analysed (each was reported on stderr)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="backlash b(x) and ISO 3408-3 lead criteria of a dataset's round trips")
    p.add_argument("dataset", help="dataset folder (mebm-dataset/1)")
    p.add_argument("--json", action="store_true", help="print a JSON list, one object per run and axis")
    p.add_argument("--curves", action="store_true", help="with --json: include b(x) and the lead curves")
    p.add_argument(
        "--useful-travel-mm", nargs=2, type=float, metavar=("START", "END"),
        help="useful travel (table coordinates); default: the axis' travel_mm",
    )
    p.add_argument("--grid-step-mm", type=float, default=None,
                   help="resolution of b(x) and the lead curves (mm); default: chosen from the axis and reported")
    add_options(p)
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    ds = read_dataset(a.dataset)
    settings = RoundTripSettings(grid_step_mm=a.grid_step_mm)
    instruments = instruments_of(a)
    results, failures, skipped = [], [], []
    for r in ds.runs:
        if r.spec.kind != "round_trip":
            skipped.append(r.spec.file)
            continue
        for axis_name in r.spec.axes:
            axis = ds.machine.axes[axis_name]
            try:
                # a run measured with separate (unlatched) reads states its skew x speed, a polled one its clock;
                # a run states its instruments (options override them)
                res = analyze_round_trip(
                    r.time_s, r.motor_rev(axis_name), r.table_mm(axis_name), axis,
                    useful_travel_mm=tuple(a.useful_travel_mm) if a.useful_travel_mm else None,
                    settings=settings, uncertainty=inputs_of_spec(r.spec, instruments),
                )
            except MebmError as exc:
                failures.append(f"{r.spec.file} (axis {axis_name}): {exc}")
                continue
            measured = r.spec.temperature_measured
            results.append({
                "file": r.spec.file,
                "feed_mm_min": r.spec.feed_mm_min,
                "temperature_c": r.spec.temperature_c if measured else None,
                **({} if measured else {"temperature_measured": False}),
                **({} if axis.position_gain_per_s is not None else {"needs_position_gain": {"tbe": (
                    f"{TBE_NEEDS_POSITION_GAIN}: give the axis' position_gain_per_s (machine.axes.{axis_name} "
                    "in dataset.json)")}}),
                **({"utility_day": r.spec.utility_day} if r.spec.utility_day is not None else {}),
                **res.to_dict(curves=a.curves),
            })
    clearances = _dataset_clearance(results)
    if a.json:
        print_json(results)
    elif results:
        print_table(
            ["run", "axis", "b̄ (µm)", "U(b̄) (µm)", "b min (µm)", "b max (µm)", "B̄ (µm)", "B (µm)", "e_p (µm)",
             "e_p (µm/1000mm)", "v_u (µm)", "v_300 (µm)", "v_2π (µm)", "outliers"],
            [[x["file"], x["axis"], x["backlash_mean_um"], x["backlash_mean_uncertainty_um"], x["backlash_min_um"],
              x["backlash_max_um"], x["reversal_mean_um"], x["reversal_max_um"], x["e_p_um"], x["e_p_um_per_1000mm"],
              x["v_u_um"], x["v_300_um"], x["v_2pi_um"], x["outliers_removed"]] for x in results],
        )
        for axis_name, c in clearances.items():
            if c.clearance_um is not None:
                u = f" ± {c.clearance_uncertainty_um:.2f} µm (k = 2)" if c.clearance_uncertainty_um is not None else " µm"
                print(f"axis {axis_name}: feed-independent lost motion {c.clearance_um:.2f}{u} from {len(c.feeds_mm_min)} runs at "
                      f"{min(c.feeds_mm_min):.0f}..{max(c.feeds_mm_min):.0f} mm/min, "
                      f"{c.slope_um_per_m_min:+.2f} µm per m/min: the clearance plus the Coulomb wind-up")
            else:
                print(f"axis {axis_name}: clearance not separated: {c.reason}")
        for axis_name in dict.fromkeys(x["axis"] for x in results if "needs_position_gain" in x):
            print(f"axis {axis_name}: {_tbe_reason(results, axis_name)}")
        unrecorded = [x["file"] for x in results if x.get("temperature_measured") is False]
        if unrecorded:
            print(f"temperature not recorded for {', '.join(dict.fromkeys(unrecorded))}: b̄ is not normalised to "
                  "20 °C, and the uncertainty budget takes the thermometer's tolerance at 20 °C")
        print("B̄, B: ISO 230-2 reversal values (lost motion); the TBE uses the total lost motion b̄")
        print("; ".join(f"{CRITERION_SYMBOLS[k]}: {name}" for k, name in CRITERION_NAMES.items()) + " (ISO 3408-3)")
        print("lead criteria of the positive stroke; --json gives both directions, the GUM budgets and "
              "U for each criterion; U: expanded uncertainty, k = 2")
    if skipped and not a.json:
        print(f"skipped {len(skipped)} run(s) that are not round trips: {', '.join(skipped)}")
    for f in failures:
        print(f"mebm analyze: error: {f}", file=sys.stderr)
    if failures:
        return 1
    if not results:
        raise AnalysisFailed(f"dataset {a.dataset} has no round-trip run to analyse")
    return 0


def _tbe_reason(results: list[dict], axis_name: str) -> str:
    """The reason an axis' TBE is not computed, as its first result states it."""
    return next(x["needs_position_gain"]["tbe"] for x in results
                if x["axis"] == axis_name and "needs_position_gain" in x)  # fmt: skip


def _dataset_clearance(results: list[dict]) -> dict:
    """Per axis, the lost motion's feed-independent part over the dataset's runs (their
    feeds and temperatures: core.criteria.lost_motion.clearance_from_feeds), added to
    each run's ``lost_motion`` as ``clearance_dataset``."""
    out = {}
    for axis_name in dict.fromkeys(x["axis"] for x in results):
        rows = [x for x in results if x["axis"] == axis_name and "lost_motion" in x]
        if not rows:
            continue
        temps = [x.get("temperature_c") for x in rows]
        c = clearance_from_feeds(
            [x["peak_speed_mm_min"] for x in rows], [x["reversal_mean_um"] for x in rows],
            [max(x.get("backlash_mean_uncertainty_um", 0.0) / 2.0, 0.01) for x in rows], source="dataset",
            temperature_c=None if any(t is None for t in temps) else temps)
        out[axis_name] = c
        for x in rows:
            x["lost_motion"]["clearance_dataset"] = c.to_dict()
    return out

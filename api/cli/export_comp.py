"""``mebm export-comp DATASET --run FILE --format linuxcnc|beckhoff|csv``: a measured
round trip as the controller's bidirectional compensation table (docs/compensation.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from api.cli.instruments import add_options, instruments_of
from api.service.compensation import COMP_TYPES, FORMATS, export, load_round_trip
from core.compensation import LOOP_ENCODERS
from core.criteria import analyze_round_trip
from core.criteria.uncertainty import inputs_of_spec
from core.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-comp",
                       help="a round trip as the controller's compensation table (LinuxCNC, Beckhoff/ISG, CSV)")
    p.add_argument("dataset", help="dataset folder (mebm-dataset/1)")
    p.add_argument("--run", required=True, metavar="FILE", help="the round-trip run (its CSV file name)")
    p.add_argument("--format", required=True, choices=FORMATS, help="table format")
    p.add_argument("--comp-type", type=int, choices=COMP_TYPES, default=1,
                   help="LinuxCNC COMP_FILE_TYPE: 0 actual positions, 1 trims (nominal - actual); default 1")
    p.add_argument("--step-mm", type=float, default=5.0,
                   help="spacing of the table's points (mm), coarsened to the format's point limit; default 5")
    p.add_argument("--joint", type=int, default=None, metavar="N",
                   help="LinuxCNC joint number (named in the comment) or ISG logical axis number (kopf.log_achs_nr)")
    p.add_argument("--axis", default=None, help="axis of the run (needed only if the run moves several)")
    p.add_argument("--useful-travel-mm", nargs=2, type=float, metavar=("START", "END"),
                   help="travel the table spans (table coordinates); default: the axis' travel_mm")
    p.add_argument("--reference-mm", type=float, default=None,
                   help="position where the midline of the two directions is zero (e.g. the reference point); "
                        "default: median midline zero")
    p.add_argument("--loop-encoder", choices=LOOP_ENCODERS, default=None,
                   help="encoder that closes the axis' position loop; default: the dataset axis' loop_encoder, "
                        "else motor")
    p.add_argument("--out", default=None, metavar="FILE", help="write the table here (default: standard output)")
    add_options(p)
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    folder = Path(a.dataset)
    axis, r = load_round_trip(folder, a.run, a.axis)
    loop = a.loop_encoder or str(axis.extra.get("loop_encoder", "motor"))
    result = analyze_round_trip(
        r.time_s, r.motor_rev(axis.name), r.table_mm(axis.name), axis,
        useful_travel_mm=tuple(a.useful_travel_mm) if a.useful_travel_mm else None,
        uncertainty=inputs_of_spec(r.spec, instruments_of(a)),
    )
    ex = export(result, a.format, step_mm=a.step_mm, comp_type=a.comp_type, joint=a.joint,
                loop_encoder=loop, reference_mm=a.reference_mm, source=f"{folder.name}/{a.run}",
                temperature_c=r.spec.temperature_c)
    if a.out is None:
        sys.stdout.write(ex.text)
        return 0
    try:
        Path(a.out).write_text(ex.text, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"--out {a.out}: cannot write the table ({exc.strerror or exc})") from exc
    t = ex.table
    print(f"wrote {a.out}: {a.format} table of axis {t.axis}, {t.n_points} points, step {t.step_mm:g} mm"
          + (f" (coarsened from {t.requested_step_mm:g} mm)" if t.coarsened else "")
          + f", mean backlash {t.backlash_mean_um:.1f} um")
    return 0

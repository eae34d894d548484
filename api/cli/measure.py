"""``mebm measure``: one measurement cycle against a controller; writes the run as a dataset.

A failed cycle (connection refused or dropped, timeout, exception code, lost samples,
EMCY, encoder fault, axis busy) prints its reason on one line and exits non-zero;
nothing is written, so no partial result is ever stored as a measurement.
"""

from __future__ import annotations

import argparse
import logging
import re
from pathlib import Path

from api.cli.instruments import add_options, instruments_of
from api.cli.output import print_json
from core.criteria.uncertainty import Instruments
from core.dataset import AxisSpec, MachineSpec
from core.errors import InputError, MebmError


class CycleFailed(MebmError):
    """The measurement cycle failed; the message is the technician's reason."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("measure", help="measure an axis' backlash and lead criteria on the machine")
    p.add_argument("--controller", required=True, metavar="URL",
                   help="modbus://HOST:PORT[?mode=trace|latched|separate|profile=P.toml], "
                        "modbus+rtu:///dev/DEVICE?baudrate=N[&parity=E&profile=P.toml], sim://HOST:PORT "
                        "(mebm sim-controller), canopen://INTERFACE/CHANNEL?node=N[&rate_hz=250] or "
                        "linuxcnc://HOST:PORT?joint=N&motor_pin=PIN&scale_pin=PIN")
    p.add_argument("--trigger", choices=("active", "passive"), default=None,
                   help="who starts the round trip: active (mebm commands it) or passive (the CNC runs it, mebm "
                        "records). Default: active for a simulator (sim://, canopen://virtual/...), else passive")
    p.add_argument("--start-timeout-s", type=float, default=None,
                   help="passive: how long to wait for the CNC to start the round trip (default 600)")
    p.add_argument("--axis", default="y", help="axis name (default y)")
    p.add_argument("--travel-mm", nargs="+", type=float, required=True, metavar="MM",
                   help="useful travel: START END, or a LENGTH from 0")
    p.add_argument("--feed-mm-min", type=float, required=True, help="programmed feed (mm/min)")
    p.add_argument("--out", required=True, help="dataset folder to append the run to (created if absent)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--acceleration-mm-s2", type=float, default=500.0)
    p.add_argument("--dwell-s", type=float, default=0.2, help="dwell at the ends (s)")
    p.add_argument("--overtravel-mm", type=float, default=None,
                   help="travel beyond the useful travel at each end (default: enough for the reversal transient)")
    p.add_argument("--timeout-s", type=float, default=2.0, help="timeout of every exchange and of connecting")
    p.add_argument("--retries", type=int, default=2, help="retries after a transient fault")
    p.add_argument("--machine-id", default="machine")
    p.add_argument("--transmission-mm-per-rev", type=float, default=6.857, help="k_a (mm/rev)")
    p.add_argument("--screw-lead-mm", type=float, default=16.0)
    p.add_argument("--position-gain-per-s", type=float, default=10.0)
    p.add_argument("--task", action="append", default=[], metavar="circle:radius_mm=R,feed_mm_min=F,tolerance_um=T",
                   help="a machining task for the decision (circle or line:angle_deg=A,...); repeatable")
    add_options(p)
    p.set_defaults(func=run)


def _travel(values: list[float]) -> tuple[float, float]:
    if len(values) == 1:
        return (0.0, values[0]) if values[0] > 0 else (values[0], 0.0)
    if len(values) == 2:
        return (values[0], values[1])
    raise InputError(f"--travel-mm takes START END or LENGTH, got {values}")


def parse_task(text: str, i: int, gain: float):
    from core.tbe import MachiningTask

    profile, _, rest = text.partition(":")
    kw = {"name": f"{profile}_{i}", "profile": profile.strip(), "gain_per_s": gain}
    for item in filter(None, rest.split(",")):
        key, eq, val = item.partition("=")
        if not eq or key.strip() not in ("name", "radius_mm", "angle_deg", "feed_mm_min", "tolerance_um", "gain_per_s"):
            raise InputError(f"--task {text!r}: {item!r} must be key=value with key one of name, radius_mm, "
                             "angle_deg, feed_mm_min, tolerance_um, gain_per_s")
        kw[key.strip()] = val if key.strip() == "name" else float(val)
    return MachiningTask(**kw)


def run(a: argparse.Namespace) -> int:
    from acquisition.measurement import default_program, run_cycle
    from acquisition.url import driver_from_url
    from storage.dataset import append_runs, next_run_name

    for name in ("pymodbus", "canopen", "can"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    axis_name = a.axis.lower()
    if not re.fullmatch(r"[a-z][a-z0-9]*", axis_name):
        raise InputError(f"--axis (={a.axis!r}) must be a name like x, y, z")
    start, end = _travel(a.travel_mm)
    axis = AxisSpec(axis_name, a.transmission_mm_per_rev, a.screw_lead_mm, a.position_gain_per_s, (start, end))
    tasks = [parse_task(t, i, a.position_gain_per_s) for i, t in enumerate(a.task)]
    extra = {} if a.trigger is None else {"trigger": a.trigger}
    if a.start_timeout_s is not None:
        extra["passive"] = {"start_timeout_s": a.start_timeout_s}
    driver = driver_from_url(a.controller, timeout_s=a.timeout_s, retries=a.retries, **extra)
    program = default_program(axis, a.feed_mm_min, acceleration_mm_s2=a.acceleration_mm_s2, dwell_s=a.dwell_s,
                              overtravel_mm=a.overtravel_mm)
    instruments = instruments_of(a)
    result = run_cycle(driver, axis, program, tasks=tasks, useful_travel_mm=(start, end), instruments=instruments)
    if not result.ok:
        if a.json:
            print_json(result.to_dict())
        raise CycleFailed(f"{result.reason_code}: {result.reason}")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    file = next_run_name(out, f"rt_{axis_name}")
    append_runs(out, MachineSpec(a.machine_id, {axis_name: axis}),
                [result.to_run(file, instruments=instruments or Instruments())])
    doc = {**result.to_dict(), "dataset": str(out), "file": file}
    if a.json:
        print_json(doc)
        return 0
    r = doc["result"]
    acq = doc["acquisition"]
    print(f"measured axis {axis_name} on {result.controller}: {acq['samples']} samples "
          f"({acq['mode']}, {'latched' if acq['latched'] else 'UNLATCHED'}, {acq['lost_samples']} lost, "
          f"{acq['trigger']})")
    if acq["trigger"] == "passive":
        p = result.program
        print(f"  round trip run by the CNC: {p.start_mm:.3f} -> {p.end_mm:.3f} mm at {p.feed_mm_min:.0f} mm/min")
    unc = f" ± {result.result.backlash_mean_uncertainty_um:.2f} (k = 2)" if result.result.budgets else ""
    print(f"  mean backlash b̄ = {r['backlash_mean_um']:.2f} µm{unc} (min {r['backlash_min_um']:.2f}, "
          f"max {r['backlash_max_um']:.2f})")
    print(f"  e_p = {r['e_p_um']:.2f} µm, v_u = {r['v_u_um']:.2f} µm, v_300 = {r['v_300_um']:.2f} µm, "
          f"v_2π = {r['v_2pi_um']:.2f} µm (positive stroke)")
    if "decision" in doc:
        print(f"  {doc['decision']['message']}")
    print(f"  written to {out / file}")
    return 0

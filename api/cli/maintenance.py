"""``mebm maintenance orders|show|ack|cancel|repair|verify|summary``: the maintenance loop
through a running service's REST API.

The service must run (it queues the verification measurement of a repair). The key is
``--key``, else ``MEBM_API_KEY``, else the demo's operate key kept in
``<data dir>/demo-keys.json`` (``--data-dir``, default ``data``): reading needs a read
key, acknowledging, cancelling and recording repairs an operate key.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import urllib.error
import urllib.request
from pathlib import Path

from api.cli.output import print_json, print_table
from core.errors import InputError
from core.maintenance import REPAIR_KINDS


class ServiceError(InputError):
    """The service answered with an error (its status and detail) or not at all."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("maintenance", help="work orders, repairs and the maintenance summary of a running service")
    ms = p.add_subparsers(dest="maintenance_command", metavar="ACTION")
    ms.required = True

    def common(q):
        q.add_argument("--url", default=os.environ.get("MEBM_URL", "http://127.0.0.1:8000"),
                       help="the service (default $MEBM_URL or http://127.0.0.1:8000)")
        q.add_argument("--key", help="API key (default $MEBM_API_KEY, else the demo's operate key)")
        q.add_argument("--data-dir", type=Path, default=Path("data"), help="where demo-keys.json is (default data)")
        q.add_argument("--json", action="store_true", help="print JSON")

    o = ms.add_parser("orders", help="list work orders")
    o.add_argument("--state", default="active", help="active (default), closed, all, or one state")
    o.add_argument("--axis", type=int, help="only this axis id")
    common(o)
    o.set_defaults(func=_orders)
    sh = ms.add_parser("show", help="one order with its transitions, repairs and verification")
    sh.add_argument("order", type=int)
    sh.add_argument("--wait-s", type=float, default=0.0,
                    help="wait up to this long for the order to be closed (verified or cancelled)")
    common(sh)
    sh.set_defaults(func=_show)
    for name, helptext in (("ack", "acknowledge an order"), ("cancel", "cancel an order (a reason is required)")):
        q = ms.add_parser(name, help=helptext)
        q.add_argument("order", type=int)
        q.add_argument("--note", default="", help="note (the reason, to cancel)")
        common(q)
        q.set_defaults(func=_step, action=name)
    r = ms.add_parser("repair", help="record a repair: the axis' order becomes repaired, a verification is queued")
    r.add_argument("--axis", type=int, required=True, help="axis id")
    r.add_argument("--kind", required=True, choices=REPAIR_KINDS)
    r.add_argument("--note", default="", help="what was done")
    r.add_argument("--performed-at", help="when (ISO 8601; default now)")
    r.add_argument("--compensation-measurement", type=int,
                   help="compensation_loaded: the measurement whose table was loaded (default: the newest)")
    r.add_argument("--compensation-file", help="compensation_loaded: the table's file name")
    r.add_argument("--wait-s", type=float, default=0.0,
                   help="wait up to this long for the verification and print the order's verdict")
    common(r)
    r.set_defaults(func=_repair)
    v = ms.add_parser("verify", help="queue a repaired order's verification measurement again")
    v.add_argument("order", type=int)
    common(v)
    v.set_defaults(func=_verify)
    s = ms.add_parser("summary", help="repairs called by the error against a fixed interval, per axis and fleet")
    s.add_argument("--fixed-interval-days", type=float, help="the fixed plan (default: the service's setting)")
    s.add_argument("--since", help="from (ISO 8601)")
    s.add_argument("--csv", action="store_true", help="print the CSV")
    common(s)
    s.set_defaults(func=_summary)


def _key(a) -> str:
    key = a.key or os.environ.get("MEBM_API_KEY")
    if key:
        return key
    path = a.data_dir / "demo-keys.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))["operate"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"no API key: give --key or MEBM_API_KEY ({path} has no demo operate key: {exc})") from exc


def _call(a, method: str, path: str, body: dict | None = None, *, raw: bool = False):
    url = a.url.rstrip("/") + "/api/v1" + path
    data = json.dumps(body).encode() if body is not None else None
    req = urllib.request.Request(url, data=data, method=method, headers={
        "X-API-Key": _key(a), "Accept": "application/json", **({"Content-Type": "application/json"} if data else {})})
    try:
        with urllib.request.urlopen(req, timeout=30) as resp:  # noqa: S310 - the user's service URL
            text = resp.read().decode()
    except urllib.error.HTTPError as exc:
        try:
            detail = json.loads(exc.read().decode()).get("detail")
        except ValueError:
            detail = exc.reason
        raise ServiceError(f"{method} {path}: HTTP {exc.code}: {detail}") from exc
    except (urllib.error.URLError, OSError) as exc:
        raise ServiceError(f"no service at {a.url}: {getattr(exc, 'reason', exc)}; start one (make run, mebm serve) "
                           f"or name where it runs with --url URL or the MEBM_URL environment variable") from exc
    return text if raw else json.loads(text)


def _print_order(o: dict) -> None:
    print(f"order {o['id']} on axis {o['axis_id']}: {o['state']} ({o['kind']}), opened {o['opened_at']}")
    print(f"  {o['recommendation']}")
    for t in o["transitions"]:
        print(f"  {t['at'][:19]}  {t['from'] or '-':>12} -> {t['to']:<12} by {t['by']}"
              + (f": {t['note']}" if t["note"] else ""))
    for r in o["repairs"]:
        print(f"  repair {r['id']}: {r['kind']} at {r['performed_at'][:19]} by {r['recorded_by']}"
              + (f" ({r['note']})" if r["note"] else ""))
    if o.get("verification"):
        print(f"  verification (measurement {o['verification_measurement_id']}): {o['verification']['message']}")


def _orders(a) -> int:
    q = f"/maintenance/orders?state={a.state}" + (f"&axis_id={a.axis}" if a.axis else "")
    page = _call(a, "GET", q)
    if a.json:
        print_json(page)
        return 0
    print_table(["id", "axis", "state", "kind", "opened", "binding task", "b̄ µm", "restore below µm"],
                [[o["id"], o["axis_id"], o["state"], o["kind"], o["opened_at"][:19], o["binding_task"] or "",
                  o["backlash_um"] if o["backlash_um"] is not None else "", o["restore_below_um"] or ""]
                 for o in page["items"]])
    return 0


def _wait_closed(a, order_id: int, wait_s: float) -> dict:
    deadline = time.monotonic() + wait_s
    o = _call(a, "GET", f"/maintenance/orders/{order_id}")
    while time.monotonic() < deadline and o["state"] == "repaired":
        time.sleep(1.0)
        o = _call(a, "GET", f"/maintenance/orders/{order_id}")
    return o


def _show(a) -> int:
    o = _wait_closed(a, a.order, a.wait_s) if a.wait_s > 0 else _call(a, "GET", f"/maintenance/orders/{a.order}")
    print_json(o) if a.json else _print_order(o)
    return 0


def _step(a) -> int:
    o = _call(a, "POST", f"/maintenance/orders/{a.order}/{a.action}", {"note": a.note})
    print_json(o) if a.json else _print_order(o)
    return 0


def _repair(a) -> int:
    body = {"kind": a.kind, "note": a.note}
    if a.performed_at:
        body["performed_at"] = a.performed_at
    if a.compensation_measurement is not None:
        body["compensation_measurement_id"] = a.compensation_measurement
    if a.compensation_file:
        body["compensation_file"] = a.compensation_file
    out = _call(a, "POST", f"/axes/{a.axis}/repairs", body)
    order = out["order"]
    if order is not None and a.wait_s > 0:
        order = _wait_closed(a, order["id"], a.wait_s)
    if a.json:
        print_json({**out, "order": order})
        return 0
    r = out["repair"]
    print(f"repair {r['id']} recorded on axis {r['axis_id']}: {r['kind']} by {r['recorded_by']}")
    if order is None:
        print("  no work order was active on the axis: nothing to verify")
    else:
        _print_order(order)
    return 0 if order is None or order["state"] != "repaired" or a.wait_s == 0 else 3


def _verify(a) -> int:
    o = _call(a, "POST", f"/maintenance/orders/{a.order}/verify")
    print_json(o) if a.json else _print_order(o)
    return 0


def _or_blank(v) -> object:
    return "" if v is None else v


def _summary(a) -> int:
    q = []
    if a.fixed_interval_days:
        q.append(f"fixed_interval_days={a.fixed_interval_days}")
    if a.since:
        q.append(f"since={a.since}")
    if a.csv:
        q.append("format=csv")
    path = "/maintenance/summary" + ("?" + "&".join(q) if q else "")
    if a.csv:
        print(_call(a, "GET", path, raw=True), end="")
        return 0
    d = _call(a, "GET", path)
    if a.json:
        print_json(d)
        return 0
    rows = [[f"{x['machine']}/{x['axis']}", x["history_days"], x["repairs_called_by_error"], x["interval_mean_days"] or "",
             x["alarm_to_verified_mean_days"] or "", x["fixed_interval_repairs"], _or_blank(x["repairs_saved"])]
            for x in d["axes"]]
    f = d["fleet"]
    rows.append(["fleet", "", f["repairs_called_by_error"], f["interval_mean_days"] or "",
                 f["alarm_to_verified_mean_days"] or "", f["fixed_interval_repairs"], _or_blank(f["repairs_saved"])])
    print_table(["axis", "days", "called", "interval d", "ALARM->verified d", "fixed plan", "saved"], rows)
    for x in d["axes"]:
        if x.get("repairs_saved_note"):
            print(f"saved, {x['machine']}/{x['axis']}: {x['repairs_saved_note']}")
    if f.get("repairs_saved_note"):
        print(f"saved, fleet: {f['repairs_saved_note']}")
    return 0

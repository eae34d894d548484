"""Shared output helpers: JSON with unit-suffixed keys, short unit tables."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence


def json_safe(obj):
    """``obj`` with every infinite or NaN float as None (JSON has no infinity), in nested
    dicts, lists and tuples too."""
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def print_json(obj) -> None:
    """JSON to stdout; inf/NaN become null (JSON has no infinity)."""
    json.dump(json_safe(obj), sys.stdout, indent=2, ensure_ascii=False)
    sys.stdout.write("\n")


def print_table(headers: Sequence[str], rows: Sequence[Sequence]) -> None:
    cells = [[str(h) for h in headers]] + [[_fmt(v) for v in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    for r in cells:  # first column (names) left-aligned, values right-aligned
        print("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))).rstrip())


def _fmt(v) -> str:
    if v is None:  # a value not computed (a criterion whose input is not known)
        return "–"
    if isinstance(v, float):
        if math.isinf(v):
            return "none"
        return f"{v:.2f}"
    return str(v)

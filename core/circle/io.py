"""A circular test as a JSON document (``circles/<name>.json`` in a dataset folder, the
``circular_tests`` table's samples).

Core reads and writes no files, so :func:`to_json` returns the JSON-ready ``dict`` and
:func:`from_json` takes the parsed one; the caller does ``json.dumps``/``json.loads``.
The layout (units in the keys)::

    {
      "format": "mebm.circular_test", "version": 1,
      "radius_mm": 50.0, "feed_mm_min": 1000.0, "plane": ["x", "y"],
      "temperature_c": 20.5, "utility_day": 118.0, "source": "measured: linuxcnc://...",
      "instrument": {"kind": "encoders", "resolution_um": 0.1, "accuracy_um": 0.6, "name": "linear scales"},
      "passes": [
        {"direction": "ccw", "angle_deg": [0.0, 0.1, ...], "radial_um": [0.4, 0.5, ...]},
        {"direction": "cw",  "angle_deg": [...], "radial_um": [...]}
      ]
    }

``temperature_c``, ``utility_day`` and ``source`` may be null or absent; keys other than
these are ignored (a stored document may carry the figures beside the samples).
"""

from __future__ import annotations

from collections.abc import Mapping

from core.circle.test import CirclePass, CircularTest, Instrument
from core.errors import InputError

FORMAT = "mebm.circular_test"
VERSION = 1


def to_json(test: CircularTest) -> dict:
    """``test`` as a JSON-ready dict in the layout above (floats as written)."""
    if not isinstance(test, CircularTest):
        raise InputError(f"to_json needs a CircularTest, got {type(test).__name__}")
    ins = test.instrument
    return {
        "format": FORMAT,
        "version": VERSION,
        "radius_mm": test.radius_mm,
        "feed_mm_min": test.feed_mm_min,
        "plane": list(test.plane),
        "temperature_c": test.temperature_c,
        "utility_day": test.utility_day,
        "source": test.source,
        "instrument": {"kind": ins.kind, "resolution_um": ins.resolution_um, "accuracy_um": ins.accuracy_um,
                       "name": ins.name},
        "passes": [{"direction": p.direction, "angle_deg": p.angle_deg.tolist(), "radial_um": p.radial_um.tolist()}
                   for p in test.passes],
    }


def _need(doc: Mapping, key: str, where: str = ""):
    if key not in doc:
        raise InputError(f"circular test document: {where}{key!r} is missing")
    return doc[key]


def from_json(doc: Mapping) -> CircularTest:
    """The :class:`CircularTest` of a parsed document in the layout above."""
    if not isinstance(doc, Mapping):
        raise InputError(f"a circular test document must be a JSON object, got {type(doc).__name__}")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        raise InputError(f"circular test document: format (={fmt!r}) must be {FORMAT!r}")
    version = doc.get("version", VERSION)
    if version != VERSION:
        raise InputError(f"circular test document: version (={version!r}) is not one this mebm reads ({VERSION})")
    ins = _need(doc, "instrument")
    if not isinstance(ins, Mapping):
        raise InputError("circular test document: 'instrument' must be an object (kind, resolution_um, ...)")
    instrument = Instrument(kind=_need(ins, "kind", "instrument."), resolution_um=_need(ins, "resolution_um",
                            "instrument."), accuracy_um=ins.get("accuracy_um", 0.0), name=ins.get("name") or "")
    raw = _need(doc, "passes")
    if not isinstance(raw, list):
        raise InputError("circular test document: 'passes' must be a list of {direction, angle_deg, radial_um}")
    passes = []
    for i, p in enumerate(raw):
        if not isinstance(p, Mapping):
            raise InputError(f"circular test document: passes[{i}] must be an object")
        where = f"passes[{i}]."
        passes.append(CirclePass(direction=_need(p, "direction", where), angle_deg=_need(p, "angle_deg", where),
                                 radial_um=_need(p, "radial_um", where)))
    plane = _need(doc, "plane")
    return CircularTest(
        radius_mm=_need(doc, "radius_mm"), feed_mm_min=_need(doc, "feed_mm_min"),
        plane=tuple(plane) if isinstance(plane, list) else plane, passes=tuple(passes), instrument=instrument,
        temperature_c=doc.get("temperature_c"), utility_day=doc.get("utility_day"), source=doc.get("source") or "")

import json

import numpy as np
import pytest

from core.circle import Instrument, analyze, from_json, to_json
from core.errors import InputError
from tests.core.circle.helpers import drawn_test


def _test():
    t = drawn_test(20.0, instrument=Instrument("ballbar", 0.1, 0.4, name="QC20-W 100 mm"), ellipse_um=3.0,
                   extra=lambda th: np.random.default_rng(0).normal(0, 0.2, th.size), n=720)
    return t


def test_a_circular_test_survives_json_text_exactly():
    t = _test()
    back = from_json(json.loads(json.dumps(to_json(t))))
    assert back == t
    assert analyze(back).to_dict() == analyze(t).to_dict()


def test_the_layout_has_units_in_its_keys():
    doc = to_json(_test())
    assert doc["format"] == "mebm.circular_test" and doc["version"] == 1
    assert {"radius_mm", "feed_mm_min", "plane", "instrument", "passes"} <= set(doc)
    assert set(doc["instrument"]) == {"kind", "resolution_um", "accuracy_um", "name"}
    assert set(doc["passes"][0]) == {"direction", "angle_deg", "radial_um"}


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.pop("passes"), "'passes' is missing"),
    (lambda d: d["instrument"].pop("kind"), "instrument.'kind'"),
    (lambda d: d.update(format="ballbar"), "format"),
    (lambda d: d.update(version=9), "version"),
    (lambda d: d["passes"][0].update(radial_um=[1.0, "x"]), "radial_um"),
    (lambda d: d["passes"].__setitem__(1, d["passes"][0]), "repeated"),
    (lambda d: d.update(radius_mm="fifty"), "radius_mm"),
])
def test_malformed_documents_are_refused_naming_the_field(edit, match):
    doc = to_json(_test())
    edit(doc)
    with pytest.raises(InputError, match=match):
        from_json(doc)

"""Each effect in the independent plant's forms (core.plant_independent: feed-forward and a
feedback delay, Karnopp or Dahl friction on a compliant chain, a two-mass chain, growth
about a moving bearing, several wear bumps, a gear period, a drifting skew) is named and
its gap at least halved, on small datasets: the runs of one axis where the form shows
there (its round trips, and the circles for servo dynamics).

The two forms the diagnosis is known to miss on these draws (wear bumps the short train
strokes never crossed, a two-mass chain near the noise floor) are checked to stay missed by
``benchmarks/bench_gap_scenarios.py`` (``..._is_a_known_miss``): the day one is named, it
says so.
"""

import numpy as np
import pytest

from core.dataset import Dataset
from core.gap import GapSettings, diagnose
from core.plant_independent import SMALL_PLANT, make_plant_case

SEED = 31  # the decision's parameters were set on this seed too (docs/gap-diagnosis.md §5)


def _x_axis(ds: Dataset) -> Dataset:
    """The runs that move x: its round trips and the circles (one axis shows a form)."""
    return Dataset(ds.machine, tuple(r for r in ds.runs if "x" in r.spec.axes and (len(r.spec.axes) == 1 or
                                                                                  r.spec.kind == "circle")))


def _x_round_trips(ds: Dataset) -> Dataset:
    return Dataset(ds.machine, tuple(r for r in ds.runs if r.spec.axes == ("x",)))


# what each form is diagnosed on: one axis where it shows there (circles only where round
# trips cannot see the form); this friction draw shows on both axes together (on x alone
# no fit cuts its 6 µm gap by the 25 % the decision needs: a Karnopp chain, §8)
RUNS = {"servo_dynamics": _x_axis, "sampling_skew": _x_round_trips, "thermal": _x_round_trips,
        "cyclic_error": _x_round_trips, "friction": lambda ds: ds}


@pytest.mark.parametrize("effect", ["servo_dynamics", "sampling_skew", "thermal", "cyclic_error", "friction"])
def test_an_independent_plant_form_is_named_and_its_gap_halved(effect):
    case = make_plant_case((effect,), np.random.default_rng([SEED, len(effect)]), SMALL_PLANT)
    rep = diagnose(RUNS[effect](case.dataset), GapSettings(keep_curves=False, second_effect=False))
    assert rep.effect == effect, rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    # the candidates the test runs do not tell apart from the answer, as the report's own candidates say
    singles = {c.effect: c.gap_after_um for c in rep.candidates}
    rivals = sorted((e for e, g in singles.items() if e not in (effect, "none") and g <= 0.75 * rep.gap_before_um
                     and singles[effect] > 0.75 * g), key=singles.get)  # fmt: skip
    assert [e for e, _ in rep.close_alternatives] == rivals, rep.text()
    assert [a["effect"] for a in rep.to_dict()["close_alternatives"]] == rivals
    if effect == "friction":  # this draw is Karnopp stick-slip: its slowest train stroke rattles
        found = rep.where.details["rattle"]
        assert [(f["file"], f["axis"]) for f in found] == [("rt_x_00.csv", "x")], found
        assert 40.0 < found[0]["frequency_hz"] < 80.0
        assert rep.to_dict()["observations"] == list(rep.observations) and "Observed: The table rattles" in rep.text()


def test_an_independent_plant_two_mass_chain_is_named_compliance():
    """The plant's chain (a table mass behind a spring-damper, the loop closed on the table
    scale; the x round trips) on the draw after the test seed's, whose gap is near its
    floor: compliance is named and cuts the gap by the 25 % the decision needs, but not by
    half. Its form, a mass behind the nut driven by the recorded motor, follows the
    chain's first mode and not the cycle the closed loop keeps going
    (docs/gap-diagnosis.md, known limits)."""
    case = make_plant_case(("compliance",), np.random.default_rng([SEED + 1, len("compliance")]), SMALL_PLANT)
    rep = diagnose(_x_round_trips(case.dataset), GapSettings(keep_curves=False, second_effect=False))
    assert rep.gap_before_um > 3.0 * rep.noise_floor_um, rep.text()  # the premise: the chain shows
    assert rep.effect == "compliance", rep.text()
    assert rep.gap_after_um <= 0.75 * rep.gap_before_um, rep.text()


def test_an_independent_plant_without_effect_is_none_at_the_noise_floor():
    case = make_plant_case((), np.random.default_rng([SEED, 0]), SMALL_PLANT)
    rep = diagnose(_x_round_trips(case.dataset), GapSettings(keep_curves=False))
    assert rep.effect == "none", rep.text()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um, rep.text()
    assert rep.where.details["rattle"] == [] and rep.observations == () and "Observed:" not in rep.text()

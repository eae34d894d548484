from functools import lru_cache

import pytest

from core.circle import analyze, decide_circle
from core.circle.simulate import simulated_test
from core.errors import InputError
from core.tbe import MachiningTask, State, decide, state_of
from core.tbe.formulas import tbe_circle_um

# the seed paper's example (Section 5): R 200 mm at 200 mm/min, K 10/s, roundness 45 µm
RING = MachiningTask("ring", profile="circle", radius_mm=200, feed_mm_min=200, gain_per_s=10, tolerance_um=45)


@lru_cache(maxsize=None)
def _paper(b_um):
    return b_um, analyze(simulated_test(radius_mm=200.0, feed_mm_min=200.0, gain_per_s=10.0, backlash_um=b_um,
                                        directions=("ccw",)))


@pytest.fixture(params=[236.0, 240.1])
def paper_circle(request):
    return _paper(request.param)


def test_the_paper_example_measured_directly_matches_the_decision_from_the_backlash(paper_circle):
    b, f = paper_circle
    d = decide_circle(f, [RING], axis="y")
    from_backlash = decide(b, [RING])
    assert d.task == "ring" and d.judged_tasks == ("ring",)
    # 236.0 µm is the limit (TBE 45.00 µm): the guarded rule cannot say OK or ALARM;
    # 240.1 µm (July 13th) gives 45.55 µm: an ALARM both ways
    assert d.state is from_backlash.state
    assert d.error_um == pytest.approx(float(tbe_circle_um(b, 200, 200, 10)), abs=d.uncertainty_um + 0.002 * 45)
    assert d.state is (State.WARNING if b == 236.0 else State.ALARM)
    assert d.circular_deviation_um >= d.error_um - d.uncertainty_um
    assert "ring" in d.message() and "guarded" in d.message()


def test_a_test_at_another_radius_or_feed_judges_no_task(paper_circle):
    _, f = paper_circle
    other_r = MachiningTask("bore", profile="circle", radius_mm=210, feed_mm_min=200, gain_per_s=10, tolerance_um=45)
    other_f = MachiningTask("fast", profile="circle", radius_mm=200, feed_mm_min=300, gain_per_s=10, tolerance_um=45)
    line = MachiningTask("line", profile="line", angle_deg=30, feed_mm_min=200, gain_per_s=10, tolerance_um=45)
    assert decide_circle(f, [other_r, other_f, line], axis="x") is None
    near = MachiningTask("near", profile="circle", radius_mm=201, feed_mm_min=199, gain_per_s=10, tolerance_um=45)
    assert decide_circle(f, [other_r, near], axis="x").task == "near"
    assert decide_circle(f, [near], axis="x", radius_tolerance_rel=0.001) is None


def test_the_guard_band_and_the_simple_rule_follow_state_of():
    _, f = _paper(236.0)
    simple = decide_circle(f, [RING], axis="y", rule="simple")
    assert simple.state is State.WARNING and simple.reason == "above the warning threshold"
    tight = MachiningTask("tight", profile="circle", radius_mm=200, feed_mm_min=200, gain_per_s=10, tolerance_um=40,
                          decision_rule="simple")
    d = decide_circle(f, [RING, tight], axis="y")
    assert d.task == "tight" and d.state is State.ALARM and d.rule == "simple"
    assert set(d.judged_tasks) == {"ring", "tight"}
    loose = MachiningTask("loose", profile="circle", radius_mm=200, feed_mm_min=200, gain_per_s=10, tolerance_um=60)
    ok = decide_circle(f, [loose], axis="x")
    assert ok.state is State.OK
    assert (ok.state, ok.reason) == state_of(ok.error_um, ok.uncertainty_um, 60.0, 54.0, "guarded")


def test_alarm_needs_the_error_above_the_tolerance_by_more_than_its_uncertainty():
    f = analyze(simulated_test(radius_mm=50.0, feed_mm_min=2000.0, gain_per_s=10.0, backlash_um=100.0,
                               noise_um=0.3, seed=1))
    x = max(f.spikes_of("x"), key=lambda s: s.height_um)
    assert x.height_uncertainty_um > 0.5
    task = MachiningTask("t", profile="circle", radius_mm=50, feed_mm_min=2000, gain_per_s=10,
                         tolerance_um=x.height_um - x.height_uncertainty_um / 2)
    guarded = decide_circle(f, [task], axis="x")
    simple = decide_circle(f, [task], axis="x", rule="simple")
    assert simple.state is State.ALARM
    assert guarded.state is State.WARNING and guarded.reason == "within uncertainty of the limit"
    d = guarded.to_dict()
    assert d["state"] == "WARNING" and d["uncertainty_um"] > 0 and d["tolerance_um"] == task.tolerance_um


def test_bad_requests_are_refused(paper_circle):
    _, f = paper_circle
    with pytest.raises(InputError, match="rule"):
        decide_circle(f, [RING], axis="y", rule="lenient")
    with pytest.raises(InputError, match="does not reverse"):
        decide_circle(f, [RING], axis="z")
    with pytest.raises(InputError, match="warning_fraction"):
        decide_circle(f, [RING], axis="y", warning_fraction=0.0)
    with pytest.raises(InputError, match="radius_tolerance_rel"):
        decide_circle(f, [RING], axis="y", radius_tolerance_rel=-0.1)
    with pytest.raises(InputError, match="rule"):
        state_of(1.0, 0.1, 2.0, 1.8, "lenient")

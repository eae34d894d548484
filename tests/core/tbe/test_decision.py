import math

import pytest

from core.errors import InputError
from core.tbe import MachiningTask, State, decide, tbe_line_um

RING = MachiningTask("ring", profile="circle", radius_mm=200, feed_mm_min=200, gain_per_s=10, tolerance_um=45)


def test_paper_example_june_and_july_are_alarms_with_limit_236():
    # Section 5.3: b̄ 239.5 µm (June 7th) and 240.1 µm (July 13th) exceed the 45 µm threshold
    for b in (239.5, 240.1):
        d = decide(b, [RING])
        assert d.state is State.ALARM
        assert d.binding_task == "ring"
        assert d.backlash_limit_um == pytest.approx(236.0, abs=0.1)
        assert "restore the chain to a backlash below 236.0" in d.message()


def test_states_follow_tolerance_and_warning_margin():
    assert decide(200.0, [RING]).state is State.OK  # 39.99 µm < 0.9 * 45
    assert decide(230.0, [RING]).state is State.WARNING  # 44.18 µm
    assert decide(230.0, [RING], warning_fraction=0.99).state is State.OK


def test_binding_task_is_highest_utilisation_and_limit_the_smallest():
    line = MachiningTask("chamfer", profile="line", angle_deg=45, feed_mm_min=200, gain_per_s=10, tolerance_um=150)
    tight = MachiningTask("bore", profile="circle", radius_mm=25, feed_mm_min=1000, gain_per_s=10, tolerance_um=20)
    d = decide(150.0, [RING, line, tight])
    by_name = {a.task.name: a for a in d.assessments}
    assert d.binding_task == max(by_name.values(), key=lambda a: a.tbe_um / a.task.tolerance_um).task.name
    assert d.backlash_limit_um == min(a.backlash_limit_um for a in d.assessments)
    # the TBE at the limit equals the binding task's tolerance
    binding = by_name[d.binding_task]
    assert float(binding.task.tbe_um(binding.backlash_limit_um)) == pytest.approx(binding.task.tolerance_um, rel=1e-6)


def test_task_that_never_reaches_tolerance_has_infinite_limit():
    loose = MachiningTask("loose", profile="circle", radius_mm=10, feed_mm_min=100, gain_per_s=10, tolerance_um=5000)
    d = decide(100.0, [loose])
    assert math.isinf(d.backlash_limit_um)
    assert "no task limits" in d.message()


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(profile="circle", feed_mm_min=200, gain_per_s=10, tolerance_um=45),  # no radius
        dict(profile="line", feed_mm_min=200, gain_per_s=10, tolerance_um=45),  # no angle
        dict(profile="ellipse", radius_mm=1, feed_mm_min=200, gain_per_s=10, tolerance_um=45),
        dict(profile="circle", radius_mm=200, feed_mm_min=0, gain_per_s=10, tolerance_um=45),
        dict(profile="circle", radius_mm=200, feed_mm_min=200, gain_per_s=10, tolerance_um=-1),
        dict(profile="line", angle_deg=95, feed_mm_min=200, gain_per_s=10, tolerance_um=45),
    ],
)
def test_bad_tasks_are_rejected_with_the_field_named(kwargs):
    with pytest.raises(InputError, match="task 't'"):
        MachiningTask("t", **kwargs)


def test_decide_rejects_bad_arguments():
    with pytest.raises(InputError):
        decide(float("nan"), [RING])
    with pytest.raises(InputError):
        decide(-1.0, [RING])
    with pytest.raises(InputError, match="at least one"):
        decide(100.0, [])
    with pytest.raises(InputError, match="unique"):
        decide(100.0, [RING, RING])


@pytest.mark.parametrize("call", [
    lambda: tbe_line_um("x", 30, 1000, 30),
    lambda: tbe_line_um(100, 30, None, 30),
    lambda: decide(None, [MachiningTask("c", "circle", 200, 10, 45, radius_mm=200)]),
    lambda: MachiningTask("c", "circle", "1000", 10, 45, radius_mm=200),
    lambda: MachiningTask("c", "circle", 1000, 10, 45, radius_mm=None),
])
def test_non_numbers_are_typed_input_errors(call):
    # once bare TypeError/ValueError from float(); a string is never stored as a feed
    with pytest.raises(InputError, match="must be a number|needs radius_mm"):
        call()

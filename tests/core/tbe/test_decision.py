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
        assert "restore the backlash below 212.4 µm (below the warning level, 90 % of the largest permissible backlash 236.0 µm" in d.message()


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


# ---- decision rules ----

from scipy.optimize import brentq  # noqa: E402

from core.tbe.decision import WITHIN_UNCERTAINTY  # noqa: E402

U_B = 4.0  # expanded uncertainty of the backlash, µm


def _edge(f):
    """The backlash where f changes sign, to 1e-9 µm."""
    return brentq(f, 150.0, 260.0, xtol=1e-10)


def test_guarded_rule_flips_exactly_at_the_guard_bands():
    tol, warn = RING.tolerance_um, 0.9 * RING.tolerance_um

    def tbe_and_u(b):
        return float(RING.tbe_um(b)), RING.tbe_uncertainty_um(b, U_B)

    alarm_edge = _edge(lambda b: tbe_and_u(b)[0] - tbe_and_u(b)[1] - tol)
    ok_edge = _edge(lambda b: tbe_and_u(b)[0] + tbe_and_u(b)[1] - warn)
    eps = 1e-6
    states = {b: decide(b, [RING], backlash_uncertainty_um=U_B) for b in
              (ok_edge - eps, ok_edge + eps, alarm_edge - eps, alarm_edge + eps)}
    assert states[ok_edge - eps].state is State.OK
    assert states[ok_edge + eps].state is State.WARNING
    assert states[alarm_edge - eps].state is State.WARNING
    assert states[alarm_edge + eps].state is State.ALARM
    # just past the tolerance but not by the uncertainty: a warning that says why
    just_over = _edge(lambda b: float(RING.tbe_um(b)) - tol) + 0.1
    d = decide(just_over, [RING], backlash_uncertainty_um=U_B)
    assert d.state is State.WARNING and d.assessments[0].reason == WITHIN_UNCERTAINTY
    assert "guarded decision rule: within uncertainty of the limit" in d.message()
    assert decide(just_over, [RING], backlash_uncertainty_um=U_B, rule="simple").state is State.ALARM


def test_simple_rule_ignores_the_uncertainty_and_is_today_s_behaviour():
    for b in (200.0, 230.0, 239.5):
        assert decide(b, [RING], backlash_uncertainty_um=U_B, rule="simple").state is decide(b, [RING]).state


def test_task_rule_overrides_the_axis_rule_and_rules_are_validated():
    from dataclasses import replace

    simple_ring = replace(RING, decision_rule="simple")
    d = decide(236.5, [simple_ring], backlash_uncertainty_um=U_B, rule="guarded")
    assert d.assessments[0].rule == "simple" and d.state is State.ALARM
    with pytest.raises(InputError, match="decision_rule"):
        decide(200.0, [RING], rule="lenient")
    with pytest.raises(InputError, match="decision_rule"):
        replace(RING, decision_rule="strict")


def test_tbe_uncertainty_is_the_derivative_times_the_backlash_uncertainty():
    b = 200.0
    slope = (float(RING.tbe_um(b + 1e-3)) - float(RING.tbe_um(b - 1e-3))) / 2e-3
    assert RING.tbe_uncertainty_um(b, 2.0) == pytest.approx(abs(slope) * 2.0, rel=1e-3)
    assert RING.tbe_uncertainty_um(b, 0.0) == 0.0
    d = decide(b, [RING], backlash_uncertainty_um=2.0)
    assert d.assessments[0].tbe_uncertainty_um == pytest.approx(abs(slope) * 2.0, rel=1e-3)


def test_backlash_limit_uncertainty_follows_the_gain_uncertainty():
    from dataclasses import replace

    a = decide(200.0, [RING]).assessments[0]
    assert a.backlash_limit_uncertainty_um > 0
    exact = replace(RING, gain_rel_uncertainty=0.0)
    assert decide(200.0, [exact]).assessments[0].backlash_limit_uncertainty_um == 0.0
    lo = replace(RING, gain_per_s=10 * 0.99).backlash_limit_um()
    hi = replace(RING, gain_per_s=10 * 1.01).backlash_limit_um()
    assert a.backlash_limit_uncertainty_um == pytest.approx(
        2 * max(abs(lo - a.backlash_limit_um), abs(hi - a.backlash_limit_um)) / 3**0.5)

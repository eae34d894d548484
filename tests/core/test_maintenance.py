"""core.maintenance: the work order's state machine (every step, allowed or refused),
the verification of a repair, and the managers' counts on a generated year."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from core.errors import InputError
from core.maintenance import (
    ORDER_STATES,
    TRANSITIONS,
    Figures,
    TransitionError,
    fixed_interval_count,
    fleet_totals,
    next_state,
    restore_target_um,
    summarise_axis,
    verify_repair,
    verify_repair_by_circle,
)
from core.tbe import MachiningTask, backlash_limit_um

CIRCLE = MachiningTask("circle R200", "circle", feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0, radius_mm=200.0)

ALLOWED = {
    ("open", "acknowledge"): "acknowledged",
    ("open", "repair"): "repaired",
    ("acknowledged", "repair"): "repaired",
    ("repaired", "repair"): "repaired",
    ("repaired", "verify_pass"): "verified",
    ("repaired", "verify_fail"): "open",
    ("open", "cancel"): "cancelled",
    ("acknowledged", "cancel"): "cancelled",
    ("repaired", "cancel"): "cancelled",
}


@pytest.mark.parametrize("state,action", list(itertools.product(ORDER_STATES, TRANSITIONS)))
def test_every_step_is_allowed_or_refused_with_a_clear_error(state, action):
    if (state, action) in ALLOWED:
        assert next_state(state, action) == ALLOWED[(state, action)]
    else:
        with pytest.raises(TransitionError) as err:
            next_state(state, action, order_id=7)
        msg = str(err.value)
        assert "order 7" in msg and repr(state) in msg and "allowed from" in msg
        assert err.value.order_state == state and err.value.action == action


def test_final_states_allow_nothing_and_bad_names_are_named():
    for final in ("verified", "cancelled"):
        with pytest.raises(TransitionError, match="nothing, it is final"):
            next_state(final, "cancel")
    with pytest.raises(InputError, match="order state"):
        next_state("closed", "cancel")
    with pytest.raises(InputError, match="action"):
        next_state("open", "close")


def _fig(mid: int, b: float, u: float = 2.0) -> Figures:
    from core.tbe import decide

    d = decide(b, [CIRCLE], backlash_uncertainty_um=u)
    a = d.assessments[0]
    return Figures(mid, b, u, {"e_p_um_per_1000mm": -25.0, "v_u_um": 3.0, "v_300_um": 4.0, "v_2pi_um": 1.0},
                   ({"task": a.task.name, "tbe_um": a.tbe_um, "tbe_uncertainty_um": a.tbe_uncertainty_um,
                     "tolerance_um": 45.0, "state": a.state.value},))


def test_a_repair_that_restores_the_backlash_is_verified_and_one_that_does_not_is_not():
    limit = backlash_limit_um(CIRCLE.tolerance_um, feed_mm_min=CIRCLE.feed_mm_min, gain_per_s=CIRCLE.gain_per_s,
                              radius_mm=CIRCLE.radius_mm)
    before = _fig(1, limit + 20.0)
    good = verify_repair(before, _fig(2, limit * 0.6), [CIRCLE], rule="guarded", warning_fraction=0.9)
    assert good.passed and good.tasks_after[0]["state"] == "OK"
    ch = good.changes["backlash_mean_um"]
    assert ch["change"] == pytest.approx(limit * 0.6 - limit - 20.0, abs=1e-3)
    assert ch["uncertainty"] == pytest.approx(np.hypot(2.0, 2.0), abs=1e-3) and ch["significant"] is True
    assert "tbe_um[circle R200]" in good.changes and "v_u_um" in good.changes
    assert good.message.startswith("verified against the measured backlash")
    bad = verify_repair(before, _fig(3, limit * 0.97), [CIRCLE], rule="guarded", warning_fraction=0.9)
    assert not bad.passed and "not verified" in bad.message and "circle R200" in bad.message
    assert bad.to_dict()["before"]["measurement_id"] == 1 and bad.to_dict()["after"]["measurement_id"] == 3


def test_a_loaded_compensation_is_judged_on_the_compensated_error():
    limit = backlash_limit_um(CIRCLE.tolerance_um, feed_mm_min=CIRCLE.feed_mm_min, gain_per_s=CIRCLE.gain_per_s,
                              radius_mm=CIRCLE.radius_mm)
    worn = _fig(1, limit + 30.0)
    same = _fig(2, limit + 31.0)  # the mechanics are unchanged by a controller's table
    plain = verify_repair(worn, same, [CIRCLE], rule="guarded", warning_fraction=0.9)
    comp = verify_repair(worn, same, [CIRCLE], rule="guarded", warning_fraction=0.9,
                         compensated_backlash_um=limit + 30.0, compensated_uncertainty_um=2.0,
                         compensation_source="table of measurement 1")
    assert not plain.passed and comp.passed
    assert comp.against.startswith("compensated error: residual backlash") and "measurement 1" in comp.against
    off = verify_repair(worn, same, [CIRCLE], rule="guarded", warning_fraction=0.9, compensated_backlash_um=limit * 0.1)
    assert not off.passed  # a table for far less play leaves the residual in ALARM


def test_no_task_no_verification():
    with pytest.raises(InputError, match="no machining task"):
        verify_repair(_fig(1, 100.0), _fig(2, 90.0), [], rule="simple", warning_fraction=0.9)


def test_restore_target():
    assert restore_target_um(236.0, 0.9) == pytest.approx(212.4)
    assert restore_target_um(float("inf"), 0.9) is None and restore_target_um(None, 0.9) is None


def test_summary_counts_on_a_generated_year_with_known_repairs():
    """A year in which the error called 3 repairs (the wear of that axis needs one about
    every 120 days), against a 30-day fixed plan: 12 planned repairs, 9 saved."""
    day = 86400.0
    start = 1_767_225_600.0  # 2026-01-01
    rng = np.random.default_rng(4)
    repair_days = np.array([118.0, 241.0, 359.0])
    opened = repair_days - rng.uniform(1.0, 3.0, 3)
    verified = repair_days + 0.05
    orders = [("corrective", start + o * day, start + v * day) for o, v in zip(opened, verified)]
    orders.append(("condition_based", start + 364.0 * day, None))  # open at the end of the year
    s = summarise_axis(1, start, start + 365.0 * day, called_repairs_s=list(start + repair_days * day),
                       other_repairs=1, orders=orders, fixed_interval_days=30.0)
    d = s.to_dict()
    assert d["repairs_called_by_error"] == 3 and d["repairs_other"] == 1
    assert d["orders_opened"] == 4 and d["orders_verified"] == 3
    assert d["orders_corrective"] == 3 and d["orders_condition_based"] == 1
    assert d["intervals_days"] == pytest.approx([118.0, 123.0, 118.0])
    assert d["alarm_to_verified_days"] == pytest.approx(list(verified - opened), abs=1e-3)
    assert d["fixed_interval_repairs"] == 12 and d["repairs_saved"] == 9
    other = summarise_axis(2, start, start + 365.0 * day, called_repairs_s=[start + 200 * day], other_repairs=0,
                           orders=[("corrective", start + 199 * day, start + 200.5 * day)], fixed_interval_days=30.0)
    fleet = fleet_totals([s, other])
    assert fleet["repairs_called_by_error"] == 4 and fleet["fixed_interval_repairs"] == 24
    assert fleet["repairs_saved"] == 20 and fleet["orders_verified"] == 4
    assert fleet["alarm_to_verified_max_days"] == pytest.approx(max(1.5, float((verified - opened).max())), abs=1e-3)


def test_fixed_interval_count_edges():
    assert fixed_interval_count(90.0, 90.0) == 1 and fixed_interval_count(89.9, 90.0) == 0
    with pytest.raises(InputError, match="fixed_interval_days"):
        fixed_interval_count(10.0, 0.0)


def test_a_history_shorter_than_one_fixed_plan_period_has_nothing_to_compare():
    start = 1_767_225_600.0
    fresh = summarise_axis(1, start, start, called_repairs_s=[start], other_repairs=0,
                           orders=[("corrective", start, start)], fixed_interval_days=90.0)
    d = fresh.to_dict()
    assert d["repairs_called_by_error"] == 1 and d["fixed_interval_repairs"] == 0
    assert d["repairs_saved"] is None
    assert d["repairs_saved_note"] == ("nothing to compare yet: 0.0 days of history, the comparison with the fixed "
                                       "plan needs at least 90 (one period of it)")
    fleet = fleet_totals([fresh])
    assert fleet["repairs_saved"] is None
    assert fleet["repairs_saved_note"] == ("nothing to compare yet: no axis has a history of one fixed-plan "
                                           "period (90 days)")
    year = summarise_axis(2, start - 365 * 86400.0, start, called_repairs_s=[], other_repairs=0, orders=[],
                          fixed_interval_days=90.0)
    assert year.to_dict()["repairs_saved_note"] is None
    both = fleet_totals([fresh, year])
    assert both["repairs_saved"] == 4
    assert both["repairs_saved_note"] == ("over 1 of 2 axes: the others have less than one fixed-plan "
                                          "period (90 days) of history")


def _circle_decision(play_um: float, task: MachiningTask):
    from core.circle import analyze
    from core.circle.decision import decide_circle
    from core.circle.simulate import simulated_test

    test = simulated_test(radius_mm=task.radius_mm, feed_mm_min=task.feed_mm_min, gain_per_s=task.gain_per_s,
                          backlash_um=(0.0, play_um), noise_um=0.2, resolution_um=0.1, rate_hz=100.0, seed=3)
    return decide_circle(analyze(test), [task], axis="y", warning_fraction=0.9, rule="guarded")


def test_a_circular_test_after_the_repair_verifies_it_on_the_measured_error():
    task = MachiningTask("circle R50", "circle", feed_mm_min=1000.0, gain_per_s=10.0, tolerance_um=100.0,
                         radius_mm=50.0)
    before = Figures(1, 300.0, 2.0, {}, ({"task": "circle R50", "tbe_um": 164.8, "tbe_uncertainty_um": 1.1,
                                          "tolerance_um": 100.0, "state": "ALARM"},))
    good = verify_repair_by_circle(before, _circle_decision(20.0, task), circular_test_id=7, radius_mm=50.0,
                                   feed_mm_min=1000.0)
    assert good["passed"] is True and good["tasks_after"][0]["state"] == "OK"
    assert good["after"]["circular_test_id"] == 7 and good["after"]["tasks"][0]["tbe_uncertainty_um"] > 0
    ch = good["changes"]["tbe_um[circle R50]"]
    assert ch["before"] == 164.8 and ch["change"] < -100.0 and ch["significant"] is True
    assert good["against"].startswith("circular test 7 (R 50 mm, F 1000 mm/min)") and good["message"].startswith(
        "verified")
    # a spike between the warning level (90 µm) and the tolerance: not OK, the order goes back to open
    warn = _circle_decision(150.0, task)
    assert 90.0 < warn.error_um < 100.0
    bad = verify_repair_by_circle(None, warn, circular_test_id=8, radius_mm=50.0, feed_mm_min=1000.0)
    assert bad["passed"] is False and "not verified" in bad["message"] and "WARNING" in bad["message"]
    assert bad["before"] is None and bad["changes"] == {}

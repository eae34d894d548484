"""Candidates the test runs do not tell apart from the answer (core.gap.diagnose.close_rivals):
the report names them beside the answer, in its text and in the JSON's `close_alternatives`."""

from __future__ import annotations

import importlib

import pytest

from core.gap.report import Candidate, GapReport, Where

dg = importlib.import_module("core.gap.diagnose")  # the module (core.gap.diagnose is also the function)


def _fits(**gaps):
    return {e: dg.Fitted((e,), gap_after_um=g) for e, g in gaps.items()}


def test_a_rival_cuts_the_gap_itself_and_the_answer_does_not_cut_its_gap_by_another_quarter():
    # gap before 20 µm; the answer friction leaves 10
    fits = _fits(friction=10.0, compliance=12.0, cyclic_error=11.5, thermal=14.0, servo_dynamics=16.0,
                 sampling_skew=11.0, backlash_profile=9.0)
    named = ["friction", "sampling_skew"]  # an answer with a second effect: neither is its own rival
    out = dg.close_rivals(fits, named, fits["friction"], 20.0, 0.25)
    # compliance: 12 <= 15 (cuts 25 %) and 10 > 0.75 * 12 = 9; cyclic error likewise; thermal: 10 <= 10.5,
    # the answer cuts its gap by 25 %; servo: 16 > 15, no 25 % cut of its own; a candidate better than the
    # answer by test gap (ranked below it by its parameters' penalty) is a rival too
    assert [f.effects[0] for f in out] == ["backlash_profile", "cyclic_error", "compliance"]


def test_no_rivals_for_a_none_answer_or_a_clear_one():
    fits = _fits(friction=10.0, compliance=12.0)
    assert dg.close_rivals(fits, [], None, 20.0, 0.25) == []
    fits = _fits(servo_dynamics=0.4, friction=60.0, compliance=55.0)
    assert dg.close_rivals(fits, ["servo_dynamics"], fits["servo_dynamics"], 80.0, 0.25) == []


def _report(alternatives):
    cands = (Candidate("friction", 10.0, {}, 5, 10.5), Candidate("none", 20.0, {}, 0, 20.0),
             Candidate("compliance", 12.0, {}, 4, 12.5))
    return GapReport("m1", "friction", Where("round_trip", None, None, None, None, "on the round trips"), 20.0, 10.0,
                     0.3, ("a.csv",), ("b.csv",), "given", cands, {"x": 50.0}, {}, {}, 100, "friction cuts it",
                     {"min_reduction": 0.25}, effects=("friction",), close_alternatives=alternatives)


def test_the_report_says_what_it_does_not_tell_apart():
    rep = _report((("compliance", 12.0004),))
    assert rep.to_dict()["close_alternatives"] == [{"effect": "compliance", "gap_after_um": pytest.approx(12.0)}]
    line = next(li for li in rep.text().splitlines() if li.startswith("Not told apart"))
    assert "compliance (12.00 µm) also cut the test gap by 25 % or more" in line
    assert "friction alone (10.00 µm) does not cut theirs by another 25 %" in line
    quiet = _report(())
    assert quiet.to_dict()["close_alternatives"] == [] and "Not told apart" not in quiet.text()

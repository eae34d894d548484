"""Two together (core/gap/diagnose.py): where no single candidate explains the gap, the
pairs are searched beyond the two best single candidates, and a pair is named only where
each of its effects is needed. The end-to-end case (thermal growth and a sampling skew
that each alone worsen the test gap, on a full-size twin dataset) is a scenario of
``benchmarks/bench_gap_scenarios.py``."""

from __future__ import annotations

import importlib

from core.gap.candidates import EFFECTS

dg = importlib.import_module("core.gap.diagnose")  # the module (core.gap.diagnose is also the function)

GAP_BEFORE_UM = 10.0


def _single(effect: str, gap_um: float, took_axis: bool = True):
    """A fitted single candidate; ``took_axis``: its fit took an axis (a parameter left its
    nominal value), which puts it in the pairs even where its test gap grew."""
    return dg.Fitted((effect,), rt_fits={"x": object()} if took_axis else {}, gap_after_um=gap_um)


def _ranked(fits):
    return sorted(fits.values(), key=lambda f: f.gap_after_um)


def _fits():
    # the shape of the full-size case: two candidates that each alone extrapolate badly
    # (thermal worsens the gap sevenfold, the skew doubles it) rank last
    gaps = {"friction": 8.5, "servo_dynamics": 8.8, "compliance": 9.6, "cyclic_error": 9.9,
            "backlash_profile": 12.0, "sampling_skew": 20.0, "thermal": 70.0}  # fmt: skip
    assert set(gaps) == set(EFFECTS)
    return {e: _single(e, g) for e, g in gaps.items()}


def test_the_two_worst_single_candidates_are_tried_together():
    fits = _fits()
    jobs = dg.pair_jobs(_ranked(fits), fits, GAP_BEFORE_UM)
    pairs = [frozenset(effects) for effects, _ in jobs]
    assert frozenset(("thermal", "sampling_skew")) in pairs
    # every pair of candidates that took something, once; the two best singles' pair twice,
    # each of them the base once
    assert set(pairs) == {frozenset((a, b)) for i, a in enumerate(EFFECTS) for b in EFFECTS[i + 1:]}
    assert [p for p in pairs if pairs.count(p) > 1] == [frozenset(("friction", "servo_dynamics"))] * 2
    # a pair beyond the two best singles is fitted on the better of its two
    ((effects, base),) = [(e, b) for e, b in jobs if frozenset(e) == {"thermal", "sampling_skew"}]
    assert effects == ("sampling_skew", "thermal") and base is fits["sampling_skew"]
    # the two best singles are bases with every other candidate on top
    assert [e for e, b in jobs[: 2 * (len(EFFECTS) - 1)]] == [
        (b, e2) for b in ("friction", "servo_dynamics") for e2 in EFFECTS if e2 != b]


def test_a_candidate_that_took_nothing_is_in_no_pair():
    fits = _fits()
    fits["cyclic_error"] = _single("cyclic_error", GAP_BEFORE_UM, took_axis=False)
    jobs = dg.pair_jobs(_ranked(fits), fits, GAP_BEFORE_UM)
    assert jobs and not any("cyclic_error" in effects for effects, _ in jobs)
    # a cut below TOOK_FRACTION of the gap before counts as taking something, without an axis
    fits["cyclic_error"] = _single("cyclic_error", 0.9 * GAP_BEFORE_UM, took_axis=False)
    assert any("cyclic_error" in e for e, _ in dg.pair_jobs(_ranked(fits), fits, GAP_BEFORE_UM))


def test_a_pair_is_named_only_where_each_of_its_effects_is_needed():
    fits = _fits()

    def pair(a, b, gap_um):
        return dg.Fitted((a, b), gap_after_um=gap_um)

    # cuts the gap before by 25 %, but its second effect does not cut its base's gap by 25 %
    assert dg.joint_pair([pair("friction", "compliance", 7.0)], fits, GAP_BEFORE_UM, 0.25) is None
    # cuts its base's gap by 25 %, but not the gap before
    assert dg.joint_pair([pair("sampling_skew", "thermal", 8.0)], fits, GAP_BEFORE_UM, 0.25) is None
    both = pair("sampling_skew", "thermal", 0.5)
    assert dg.joint_pair([pair("friction", "compliance", 7.0), both], fits, GAP_BEFORE_UM, 0.25) is both
    # the first of the ranked pairs that passes
    other = pair("friction", "thermal", 0.4)
    assert dg.joint_pair([other, both], fits, GAP_BEFORE_UM, 0.25) is other

"""The compliance form's fit starts from several backlash values: a table that floats
across the backlash when braking makes the nominal fit take the clearance for smaller
than it is (22 µm where the compliance fit finds 101 µm, independent plant seed 9401
case 33)."""

import numpy as np

from core.gap.candidates import compliance_stage, friction_stage, stage_starts

NOMINAL_B_UM = 60.0  # what a nominal fit takes for the clearance


def test_the_compliance_starts_span_larger_backlash_values():
    st = compliance_stage()
    starts = stage_starts((st,), np.array([NOMINAL_B_UM]))
    assert len(starts) == len(st.starts) * len(st.backlash_factors) == 48
    assert sorted({float(s[0]) for s in starts}) == [NOMINAL_B_UM, 2 * NOMINAL_B_UM, 4 * NOMINAL_B_UM]


def test_other_stages_keep_one_backlash_start():
    st = friction_stage()
    starts = stage_starts((st,), np.array([NOMINAL_B_UM]))
    assert len(starts) == len(st.starts)
    assert {float(s[0]) for s in starts} == {NOMINAL_B_UM}

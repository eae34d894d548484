import pytest

from core.errors import InputError
from core.tbe import repair_target, stored_repair_target


def test_the_target_is_the_warning_level_in_backlash_and_says_so():
    t = repair_target(236.0, 0.9)
    assert t.restore_below_um == pytest.approx(212.4)
    assert t.explanation == ("below the warning level, 90 % of the largest permissible backlash 236.0 µm, "
                             "so that the repaired axis does not warn again at once")
    assert t.sentence().startswith("restore the backlash below 212.4 µm (below the warning level")


def test_no_limit_no_target_and_bad_fractions_are_refused():
    assert repair_target(float("inf"), 0.9) is None and repair_target(None, 0.9) is None
    with pytest.raises(InputError, match="warning_fraction"):
        repair_target(236.0, 1.5)


def test_a_stored_order_explains_its_target_as_when_it_was_opened():
    assert stored_repair_target(212.4, 236.0).explanation == repair_target(236.0, 0.9).explanation
    assert stored_repair_target(None, 236.0) is None and stored_repair_target(212.4, None) is None

import numpy as np
import pytest

from core.errors import InputError
from core.kinematics import motor_rev_for_travel, nominal_travel_mm, transmission_mm_per_rev


def test_table_1_transmission_ratio():
    # 16 mm lead through gears 24/31 and 31/56
    assert transmission_mm_per_rev(16.0, (24, 31, 31, 56)) == pytest.approx(6.857, abs=5e-4)


def test_direct_drive_is_the_lead():
    assert transmission_mm_per_rev(10.0) == 10.0


def test_conversions_are_inverse():
    rev = np.array([-3.0, 0.0, 12.5])
    assert motor_rev_for_travel(nominal_travel_mm(rev, 6.857), 6.857) == pytest.approx(rev)


@pytest.mark.parametrize("teeth", [(24, 31, 31), (24, 0), (24, -31)])
def test_bad_gear_trains_are_rejected(teeth):
    with pytest.raises(InputError):
        transmission_mm_per_rev(16.0, teeth)

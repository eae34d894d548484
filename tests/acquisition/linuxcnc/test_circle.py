"""The paper's closed loop on a real controller: LinuxCNC's pid closed on the linear scale
(full-closed), P only, on the simulated machine with a 120 µm backlash in X and Y. mebm
measures b̄ on a round trip of X; LinuxCNC then runs a G3 half circle through two
quadrant transitions (X reverses at 0°, Y at 90°), recorded by the sampler of both axes.
The radial error's bump after each transition is the transient backlash error: it must
agree with Eq. 8 evaluated at mebm's b̄ within 10 %. One LinuxCNC start for the module.
"""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.cycle import run_cycle
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import SimSettings
from acquisition.url import driver_from_url
from core.tbe.formulas import circle_steady_lag_um, tbe_circle_um
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, PROGRAM, running_sim

RADIUS_MM, FEED_MM_MIN = 50.0, 2000.0
K_PER_S = AXIS.position_gain_per_s


def half_circle_gcode(radius_mm: float, feed_mm_min: float) -> str:
    """G3 (counter-clockwise) from -45° to 135° about the origin, after a move to its start."""
    c = radius_mm / np.sqrt(2.0)
    return (f"G21 G90 G17 G61 G54\nG1 X{c:.4f} Y{-c:.4f} F{feed_mm_min:g}\nG4 P0.5\n"
            f"G3 X{-c:.4f} Y{c:.4f} I{-c:.4f} J{c:.4f} F{feed_mm_min:g}\nG4 P0.3\nM2\n")


@pytest.fixture(scope="module")
def measured():
    with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="full", p_gain_per_s=K_PER_S)) as sim:
        cycle = run_cycle(driver_from_url(sim.url + "&trigger=active", timeout_s=2.0), AXIS, PROGRAM)
        program = sim.run_dir / "circle.ngc"
        program.write_text(half_circle_gcode(RADIUS_MM, FEED_MM_MIN))
        program.chmod(0o644)
        yield cycle, record_contour("127.0.0.1", sim.settings.port, str(program))


def test_mebm_measures_the_chain_s_backlash_full_closed(measured):
    cycle, _ = measured
    assert cycle.ok, cycle.reason
    assert abs(cycle.result.backlash_mean_um - BACKLASH_UM) <= 1.0, cycle.result.backlash_mean_um


def test_the_circle_s_quadrant_bumps_agree_with_eq_8_at_mebm_s_backlash(measured):
    cycle, rec = measured
    assert cycle.ok, cycle.reason
    tbe_um = float(tbe_circle_um(cycle.result.backlash_mean_um, RADIUS_MM, FEED_MM_MIN, K_PER_S))
    (x, y), (xc, yc) = rec.table_mm, rec.command_mm
    on_arc = np.abs(np.hypot(xc, yc) - RADIUS_MM) < 1e-3
    angle_deg = np.degrees(np.arctan2(yc, xc))
    # Eq. 8 is the deviation from the circle the loop traces without backlash, R cos φ
    radial_um = np.hypot(x, y) * 1e3 - (RADIUS_MM * 1e3 - circle_steady_lag_um(RADIUS_MM, FEED_MM_MIN, K_PER_S))
    between = on_arc & (((angle_deg > -30) & (angle_deg < -5)) | ((angle_deg > 50) & (angle_deg < 85)))
    assert abs(np.median(radial_um[between])) < 0.05 * tbe_um  # away from the transitions: R cos φ
    for quadrant_deg in (0.0, 90.0):  # X reverses at 0°, Y at 90°
        after = on_arc & (angle_deg >= quadrant_deg) & (angle_deg < quadrant_deg + 40.0)
        bump_um = float(radial_um[after].max())
        assert bump_um == pytest.approx(tbe_um, rel=0.10), (quadrant_deg, bump_um, tbe_um)

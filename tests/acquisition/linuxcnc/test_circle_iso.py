"""A circular test (ISO 230-4) measured by mebm from LinuxCNC's own scales, on the simulated
machine full-closed, P only (K = P = 30/s), 1 µm scales and the rig's 120 µm backlash in X
and Y. mebm measures b̄ on a round trip of X (as test_circle.py does), then runs a full
circle G3 and G2 (R 20 mm, 2000 mm/min) and records both axes.

Asserts: every reversal spike within 5 % of Eq. 8 at mebm's b̄, and compare_with_backlash
agrees for both axes (|E_n| <= 1). With FF1 = 1 (velocity feed-forward) the circle grows by
the P loop's steady lag R (1 - cos φ), which FF1 removes, while the spikes, a transient
of the P term alone, still agree with Eq. 8: the two loops disagree on the loop itself
(the undisturbed circle against the one Eq. 8's P loop traces), and the result says the
drive feeds forward. With a slow drive (a 10 ms velocity loop,
servo dynamics Eq. 8 does not model) the spikes are larger than Eq. 8 predicts and the
verdict says so and where to look. E-stop and machine off before the circle, a
circle the operator aborts and samples the sampler drops are typed errors (mebm aborts the
circle it started then). One LinuxCNC start for the module: the
tuning is changed in HAL between the circles, as a technician would.
"""

from __future__ import annotations

import math
import os
import signal
import time
from pathlib import Path

import pytest

from acquisition.circle import CircleProgram, measure_circle
from acquisition.errors import IncompleteCircleError, LostSamplesError
from acquisition.linuxcnc import hal
from acquisition.linuxcnc.errors import EstopError, MachineOffError
from acquisition.linuxcnc.sim import SimSettings
from acquisition.measurement import run_cycle
from acquisition.url import driver_from_url
from core.circle import analyze, compare_with_backlash
from core.tbe.formulas import circle_steady_lag_um, tbe_circle_um
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, PROGRAM, in_thread, running_sim
from tests.waiting import until

RADIUS_MM, FEED_MM_MIN = 20.0, 2000.0
K_PER_S = AXIS.position_gain_per_s
CIRCLE = CircleProgram(RADIUS_MM, FEED_MM_MIN)
SERVO_PERIOD_S = 1e-3


@pytest.fixture(scope="module")
def sim():
    settings = SimSettings(backlash_um=BACKLASH_UM, loop="full", p_gain_per_s=K_PER_S, scale_resolution_um=1.0)
    with running_sim(settings) as s:
        yield s


@pytest.fixture
def powered(sim):
    sim.power_on()
    return sim


def circle_url(sim) -> str:
    return f"linuxcnc://127.0.0.1:{sim.settings.port}?sampler=2"


def measure(sim):
    return measure_circle(circle_url(sim), CIRCLE, resolution_um=1.0)


def tuned(sim, **pins):
    """Measure with HAL pins of both axes set (``FF1=1``, ``gain=...`` of the drive), then restore them."""
    names = {"FF1": "{a}-pid.FF1", "gain": "{a}-drive.gain"}
    before = {}
    for key, value in pins.items():
        for a in "xy":
            pin = names[key].format(a=a)
            before[pin] = hal.getp(pin)
            hal.setp(pin, str(value))
    try:
        return measure(sim)
    finally:
        for pin, value in before.items():
            hal.setp(pin, value)


@pytest.fixture(scope="module")
def p_only(sim):
    sim.power_on()
    cycle = run_cycle(driver_from_url(sim.url + "&trigger=active", timeout_s=5.0), AXIS, PROGRAM)
    assert cycle.ok, cycle.reason
    test = measure(sim)
    return cycle.result, test, analyze(test)


@pytest.fixture(scope="module")
def ff1(sim, p_only):
    sim.power_on()
    return analyze(tuned(sim, FF1=1.0))


@pytest.fixture(scope="module")
def slow_drive(sim, p_only):
    sim.power_on()
    tau_s = 0.010
    return analyze(tuned(sim, gain=SERVO_PERIOD_S / (tau_s + SERVO_PERIOD_S)))


def test_the_test_holds_360_degrees_of_both_directions_from_the_scales(p_only):
    _, test, _ = p_only
    assert test.directions == ("ccw", "cw")
    assert test.instrument.kind == "encoders" and test.instrument.resolution_um == 1.0
    assert test.source.startswith("measured: linuxcnc://")
    for p in test.passes:
        swept = abs(p.unwrapped_deg[-1] - p.unwrapped_deg[0])
        assert 358.0 < swept < 360.0, (p.direction, swept)  # one servo period's step short of a full turn
        assert p.angle_deg.size > 3000  # every servo period of the arc (1 kHz, 3.8 s)


def test_p_only_every_reversal_spike_is_eq_8_at_mebm_s_backlash_within_5_percent(p_only):
    result, _, figures = p_only
    assert abs(result.backlash_mean_um - BACKLASH_UM) <= 1.0, result.backlash_mean_um
    tbe_um = float(tbe_circle_um(result.backlash_mean_um, RADIUS_MM, FEED_MM_MIN, K_PER_S))
    assert len(figures.spikes) == 8  # four quadrant points, two directions
    for s in figures.spikes:
        assert s.height_um == pytest.approx(tbe_um, rel=0.05), (s, tbe_um)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_p_only_the_spikes_agree_with_eq_8(p_only, axis):
    result, _, figures = p_only
    ag = compare_with_backlash(figures, axis=axis, backlash_um=result.backlash_mean_um,
                               backlash_uncertainty_um=result.backlash_mean_uncertainty_um, gain_per_s=K_PER_S)
    assert ag.agree and abs(ag.normalised_error) <= 1.0 and ag.verdict == "agree", ag.sentence()
    assert ag.loop.verdict == "agree", ag.sentence()  # away from the reversals: the paper's P loop


def test_ff1_grows_the_circle_by_the_lag_it_removes_and_leaves_the_spikes_to_eq_8(p_only, ff1):
    result, _, p_figures = p_only
    lag_um = circle_steady_lag_um(RADIUS_MM, FEED_MM_MIN, K_PER_S)
    grown_um = ff1.mean_radius_deviation_um - p_figures.mean_radius_deviation_um
    assert grown_um == pytest.approx(lag_um, rel=0.10), (grown_um, lag_um)
    for axis in "xy":
        ag = compare_with_backlash(ff1, axis=axis, backlash_um=result.backlash_mean_um,
                                   backlash_uncertainty_um=result.backlash_mean_uncertainty_um, gain_per_s=K_PER_S)
        assert ag.agree, ag.sentence()
        # the loop is not Eq. 8's, and the result says so: the circle is R, not R cos φ
        assert ag.loop.verdict == "larger" and ag.loop.normalised_error > 3.0, ag.sentence()
        assert ag.loop.measured_um - ag.loop.predicted_um == pytest.approx(lag_um, rel=0.10)
        assert "feeds the commanded velocity forward" in ag.sentence()


@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_slow_drive_makes_the_spikes_larger_than_eq_8_and_the_verdict_says_where_to_look(p_only, slow_drive, axis):
    result, _, _ = p_only
    ag = compare_with_backlash(slow_drive, axis=axis, backlash_um=result.backlash_mean_um,
                               backlash_uncertainty_um=result.backlash_mean_uncertainty_um, gain_per_s=K_PER_S)
    assert not ag.agree and ag.normalised_error > 1.0 and ag.verdict == "larger", ag.sentence()
    assert "servo" in ag.meaning and "gap diagnosis" in ag.meaning


def test_estop_before_the_circle_is_a_typed_error_and_nothing_moves(powered):
    powered.rsh("set estop on")
    before = powered.rsh("get abs_act_pos")
    with pytest.raises(EstopError, match="E-STOP"):
        measure(powered)
    assert powered.rsh("get abs_act_pos") == before
    assert powered.rsh("get estop") == ["ESTOP ON"]  # mebm left it as it was


def test_machine_off_before_the_circle_is_a_typed_error(powered):
    powered.rsh("set machine off")
    with pytest.raises(MachineOffError, match="OFF"):
        measure(powered)


def test_a_circle_the_operator_aborts_does_not_close_and_says_so(powered):
    thread, out = in_thread(measure, powered)
    # watched in HAL: a linuxcncrsh session of the operator's would take control from mebm's
    def off_centre_mm():
        return math.hypot(float(hal.getp("joint.0.pos-cmd")), float(hal.getp("joint.1.pos-cmd")))

    until(lambda: "error" in out or off_centre_mm() < 0.01, "the axes at the circle's centre")
    until(lambda: "error" in out or off_centre_mm() > RADIUS_MM - 0.01, "the axes out at the circle's radius")
    assert "error" not in out, out
    time.sleep(0.8)  # the dwell at the start, then into the arc
    powered.rsh("set abort")
    thread.join(60.0)
    assert not thread.is_alive()
    err = out.get("error")
    assert isinstance(err, IncompleteCircleError), out
    assert err.reason_code == "incomplete_circle" and "does not close" in str(err)


def halsampler_of(channel: int) -> int | None:
    """The pid of the halsampler this process started for FIFO ``channel``, if one runs."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
            ppid = int(next(ln for ln in (d / "status").read_text().splitlines() if ln.startswith("PPid:")).split()[1])
        except (OSError, StopIteration, ValueError):
            continue
        if ppid == os.getpid() and any(c.endswith(b"halsampler") for c in cmd) and str(channel).encode() in cmd:
            return int(d.name)
    return None


def test_samples_the_sampler_drops_fail_the_circle_and_mebm_aborts_it(powered):
    # FIFO 3 of the simulated machine (both axes, six pins) holds a quarter of a second:
    # halsampler held still for longer overruns it, as a busy host would
    url = f"linuxcnc://127.0.0.1:{powered.settings.port}?sampler=3"
    thread, out = in_thread(measure_circle, url, CIRCLE, resolution_um=1.0)
    pid = until(lambda: "error" in out or halsampler_of(3), "halsampler reading FIFO 3")
    assert "error" not in out, out
    time.sleep(1.0)  # the circle's program under way
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(0.6)
    finally:
        os.kill(pid, signal.SIGCONT)
    thread.join(60.0)
    assert not thread.is_alive()
    err = out.get("error")
    assert isinstance(err, LostSamplesError) and err.lost_samples >= 1, out
    assert "abort sent" in str(err)
    until(lambda: powered.rsh("get program_status") == ["PROGRAM_STATUS IDLE"], "the circle stopped")

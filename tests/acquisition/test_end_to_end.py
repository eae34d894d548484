"""End to end on loopback with the digital twin: the measured criteria match the twin's own trace.

Done criterion of the acquisition issue: b̄ within 1 µm and the lead criteria within
1.5 µm of the analysis of the twin's noiseless trace, through Modbus TCP and CANopen.
"""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.canopen.driver import CanopenDriver
from acquisition.measurement import default_program, run_cycle
from acquisition.modbus.driver import ModbusDriver
from acquisition.sim.axis import SimAxis
from acquisition.sim.canopen.drive import SimCanopenDrive
from acquisition.sim.modbus.server import SimModbusController
from acquisition.sim.twin import CoreSimTwin
from core.criteria import analyze_round_trip
from core.dataset import AxisSpec
from core.sim import AxisModel, Effects, parse_effect
from tests.acquisition.conftest import RING_MAX

AXIS = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))
LEAD_KEYS = ("e_p_um", "v_u_um", "v_300_um", "v_2pi_um")


def _twin() -> CoreSimTwin:
    cat, eff = parse_effect("cyclic_error:periods_mm=16/6.857,amplitudes_um=3/1.5")
    model = AxisModel("y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0, position_gain_per_s=10.0,
                      backlash_um=120.0, effects=Effects(**{cat: eff}))
    twin = CoreSimTwin(model, rng=np.random.default_rng(1))
    twin.warm_up()
    return twin


def _reference(program, rate_hz):
    """What the analysis gets from the twin's own trace of the same (first) round trip."""
    tr = _twin().round_trip(program, rate_hz)
    return analyze_round_trip(tr.time_s, tr.motor_rev, tr.table_mm, AXIS, useful_travel_mm=AXIS.travel_mm).to_dict()


def _compare(measured, reference):
    assert measured["backlash_mean_um"] == pytest.approx(reference["backlash_mean_um"], abs=1.0)
    assert abs(measured["backlash_mean_um"] - 120.0) < 2.0
    for key in LEAD_KEYS:
        assert measured[key] == pytest.approx(reference[key], abs=1.5), key
    for direction in ("positive", "negative"):
        for key in LEAD_KEYS:
            m, r = measured["strokes"][direction][key], reference["strokes"][direction][key]
            assert m == pytest.approx(r, abs=1.5), (direction, key)


@pytest.mark.slow
def test_modbus_measures_what_the_twin_simulates():
    program = default_program(AXIS, 1000.0)
    with SimModbusController(SimAxis(_twin(), servo_rate_hz=1000.0, time_scale=10.0, ring_records=RING_MAX)) as sim:
        r = run_cycle(ModbusDriver("127.0.0.1", sim.port, timeout_s=1.0), AXIS, program, useful_travel_mm=AXIS.travel_mm)
    assert r.ok, r.reason
    assert r.trace.lost_samples == 0 and r.trace.latched
    _compare(r.result.to_dict(), _reference(program, 1000.0))


@pytest.mark.slow
def test_canopen_measures_what_the_twin_simulates():
    program = default_program(AXIS, 1000.0)
    with SimCanopenDrive(_twin(), node_id=3, channel="mebm-e2e", servo_rate_hz=1000.0):
        driver = CanopenDriver("mebm-e2e", 3, sync_rate_hz=250.0, time_scale=5.0, timeout_s=1.0)
        r = run_cycle(driver, AXIS, program, useful_travel_mm=AXIS.travel_mm)
    assert r.ok, r.reason
    assert r.trace.lost_samples == 0 and r.trace.mode == "sync"
    _compare(r.result.to_dict(), _reference(program, 1000.0))

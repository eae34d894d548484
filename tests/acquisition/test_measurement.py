"""The cycle: validation of acquired traces, results as dataset runs, use from threads and asyncio."""

from __future__ import annotations

import asyncio
import concurrent.futures
import dataclasses

import numpy as np
import pytest

from acquisition.measurement import default_program, run_cycle, run_cycle_async, validate_trace
from acquisition.errors import IncompleteTraceError
from acquisition.types import AcquiredTrace, RoundTripProgram
from core.dataset import validate_columns, validate_run_spec, MachineSpec
from core.errors import MebmError
from core.tbe import MachiningTask
from tests.acquisition.conftest import AXIS, PROGRAM, modbus_peer


def _trace(x: np.ndarray, **kw) -> AcquiredTrace:
    n = x.size
    base = dict(protocol="t", mode="trace", time_s=np.arange(n) / 1000.0, counter=np.arange(n),
                motor_rev=x / 6.857, table_mm=x, temperature_c=20.0, latched=True, skew_uncertainty_um=0.0,
                lost_samples=0, servo_rate_hz=1000.0, program=PROGRAM)
    base.update(kw)
    return AcquiredTrace(**base)


def _round_trip_x(lo=-2.0, hi=22.0, n=2000):
    half = np.linspace(lo, hi, n // 2)
    return np.concatenate([half, half[::-1]])


def test_validate_accepts_a_whole_round_trip():
    validate_trace(_trace(_round_trip_x()), PROGRAM, AXIS, (0.0, 20.0))


def test_validate_rejects_a_cut_short_return_stroke():
    x = _round_trip_x()[:1400]  # the return stroke stops half way
    with pytest.raises(IncompleteTraceError, match="return stroke"):
        validate_trace(_trace(x), PROGRAM, AXIS, (0.0, 20.0))


def test_validate_rejects_nan_and_undeclared_gaps():
    x = _round_trip_x()
    bad = x.copy()
    bad[500] = np.nan
    with pytest.raises(IncompleteTraceError, match="NaN"):
        validate_trace(_trace(bad), PROGRAM, AXIS, (0.0, 20.0))
    counter = np.arange(x.size)
    counter[1000:] += 3
    with pytest.raises(IncompleteTraceError, match="missing"):
        validate_trace(_trace(x, counter=counter), PROGRAM, AXIS, (0.0, 20.0))


def test_default_program_overtravels_the_useful_travel():
    p = default_program(AXIS, 1000.0)
    assert p.start_mm < AXIS.travel_mm[0] and p.end_mm > AXIS.travel_mm[1]
    assert p.feed_mm_min == 1000.0


def test_ok_cycle_gives_a_valid_dataset_run_and_a_decision():
    task = MachiningTask("circle", "circle", feed_mm_min=1000.0, gain_per_s=30.0, tolerance_um=20.0, radius_mm=50.0)
    with modbus_peer() as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM, tasks=[task], useful_travel_mm=(0.0, 20.0))
    assert r.ok, r.reason
    run = r.to_run("rt_y_00.csv")
    validate_run_spec(run.spec, MachineSpec("m", {"y": AXIS}))
    validate_columns(run.spec, run.columns)
    assert run.spec.extra["acquisition_mode"] == "trace" and run.spec.extra["lost_samples"] == 0
    d = r.to_dict()
    assert d["status"] == "ok" and d["decision"]["binding_task"] == "circle"
    assert d["result"]["backlash_mean_um"] == pytest.approx(120.0, abs=1.0)


def test_failed_cycle_has_no_result_and_no_run():
    with modbus_peer(faults=["stuck:at=0.3"]) as peer:
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
    assert not r.ok and r.result is None and "result" not in r.to_dict()
    with pytest.raises(MebmError, match="never stored"):
        r.to_run("x.csv")


def test_usable_from_worker_threads_and_from_an_event_loop():
    with modbus_peer() as peer:
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            r = pool.submit(run_cycle, peer.driver(), AXIS, PROGRAM).result(timeout=60)
        assert r.ok, r.reason

        async def in_loop():
            return await run_cycle_async(peer.driver(), AXIS, PROGRAM)

        r = asyncio.run(in_loop())
        assert r.ok, r.reason
        # the blocking form refuses to run inside a loop rather than deadlock it
        async def wrong():
            return run_cycle(peer.driver(), AXIS, PROGRAM)

        r = asyncio.run(wrong())
        assert not r.ok and "acquire_async" in r.reason


def test_program_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        PROGRAM.feed_mm_min = 5.0  # type: ignore[misc]
    assert isinstance(PROGRAM, RoundTripProgram)


def test_one_glitch_is_dropped_online_and_in_the_analysis():
    # EncoderMonitor and the analysis share one outlier rule; one glitch is no fault
    with modbus_peer(faults=["glitch:at=0.3,mm=5"]) as peer:
        r = run_cycle(peer.driver(timeout_s=3.0), AXIS, PROGRAM)  # a cold twin starts slowly
        assert r.ok, r.reason
        assert r.result.outliers_removed == 1
        assert abs(r.result.backlash_mean_um - 120.0) < 1.0


def test_many_glitches_are_an_encoder_fault_online():
    with modbus_peer(faults=["glitch:at=0.1,mm=5,n=60"]) as peer:
        r = run_cycle(peer.driver(timeout_s=3.0), AXIS, PROGRAM)  # a cold twin starts slowly
        assert not r.ok and r.reason_code == "encoder_fault", r.reason
        assert "glitch samples" in r.reason and "max_fraction 1 %" in r.reason


def test_encoder_monitor_judges_a_glitch_on_a_block_edge_with_the_next_block():
    from acquisition.driver.base import EncoderMonitor

    mon = EncoderMonitor(PROGRAM, 6.857, 500.0, jump_margin_mm=0.05, stuck_travel_mm=1.0)
    x = -2.0 + np.arange(600) * (1000.0 / 60.0 / 500.0)  # 1000 mm/min at 500 Hz
    table = x.copy()
    table[299] += 5.0  # the last sample of the first block
    c = np.arange(600)
    mon.check(c[:300], x[:300] / 6.857, table[:300])
    mon.check(c[300:], x[300:] / 6.857, table[300:])
    mon.finish()
    assert (mon.outliers, mon.seen) == (1, 600)

"""A cycle whose polled trace has a hole is run again by the service, and the stored run
says so (``repeated_after``) and carries the bounds it was analysed with, so that a
re-analysis of the file (``inputs_of_run``) states the same uncertainty."""

from __future__ import annotations

import pytest

from acquisition.sim.axis import SimAxis
from acquisition.sim.faults import parse_fault
from acquisition.sim.modbus.server import SimModbusController
from acquisition.sim.twin import KinematicTwin
from core.criteria.uncertainty import inputs_of_run
from storage.dataset import read_dataset
from tests.api.service.cycles.test_passive_cycles import passive_service, run_one
from tests.storage.db.backends import make_database

FEED_MM_MIN = 240.0


@pytest.fixture
def slow_once():
    # Separate reads (no latch, no trace buffer): replies slowed by 1.2 s for 0.3 s of the
    # first round trip leave a stretch of travel without samples; the second is clean.
    # The axis measures at FEED_MM_MIN (4 mm/s), so the injected pause leaves a hole of
    # about 5 mm, while a pause of the host during the repeat must last 0.5 s to leave one
    # over max_gap_mm (2 mm): a busy machine's scheduling pauses of 0.1-0.25 s leave the
    # repeat clean.
    axis = SimAxis(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), servo_rate_hz=500.0,
                   faults=[parse_fault("slow:at=0.3,s=1.2,for=0.3")])
    sim = SimModbusController(axis)
    sim.start_in_thread()
    yield sim
    sim.stop_thread()


def test_a_hole_is_measured_again_and_the_stored_run_says_so(tmp_path, slow_once):
    # The repeat and the bounds live in acquisition and the dataset file: one backend.
    url, _ = make_database("sqlite", tmp_path)
    svc = passive_service(url, tmp_path, f"modbus://127.0.0.1:{slow_once.port}?mode=separate&trigger=active",
                          measure_feed_mm_min=FEED_MM_MIN)
    try:
        cycles = run_one(svc)
        assert [c.status for c in cycles] == ["ok"], cycles[0].failure_reason
        assert slow_once.axis.cycles_started == 2
        run = read_dataset(svc.executor.dataset_folder(svc.test_axis)).runs[0]
        assert "no samples between" in run.spec.extra["repeated_after"]
        assert run.spec.extra["skew_uncertainty_um"] > 0 and run.spec.extra["clock_uncertainty_s"] >= 0
        assert inputs_of_run(run.spec.extra).sampling_bound_um == run.spec.extra["skew_uncertainty_um"]
    finally:
        svc.stop()

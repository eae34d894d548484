"""Passive cycles through the service: the scheduler's cycle listens on a controller the
CNC drives. No round trip within the time-out: a failed cycle "no_round_trip" a
technician can act on, and nothing stored as a measurement. A round trip started by
another process: stored, and its run says ``trigger: passive``."""

from __future__ import annotations

import time
from dataclasses import replace

import pytest
from sqlalchemy import func, select

from acquisition.sim.axis import SimAxis
from acquisition.sim.modbus.server import SimModbusController
from acquisition.sim.twin import KinematicTwin
from api.service.config.loading import parse_settings
from api.service.config.settings import AxisConfig, ConfigError
from api.service.cycles.runner import DriverRunner
from api.service.service import Service
from core.dataset import AxisSpec
from storage.dataset import read_dataset
from storage.db import Schedule, config_repo, results_repo, session_scope
from storage.db.models import Curve, Result
from tests.acquisition.test_passive import PROGRAM, start_cnc
from tests.api.rest.conftest import make_settings
from tests.demo import demo_axis_toml, demo_machine_toml
from tests.storage.db import factories as f
from tests.storage.db.backends import db_url, engine  # noqa: F401 - fixtures

AXIS = AxisSpec("y", 6.857, 16.0, 30.0, (0.0, 20.0))


@pytest.fixture
def controller():
    sim = SimModbusController(SimAxis(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0),
                                      servo_rate_hz=500.0, time_scale=3.0, ring_records=10906))
    sim.start_in_thread()
    yield sim
    sim.stop_thread()


def passive_service(db_url, tmp_path, url, **axis_settings):  # noqa: F811 - db_url is a fixture's value here
    axis = AxisConfig("vmc-850", f.settings(spec=AXIS, controller_url=url, schedule=Schedule(interval_s=3600.0),
                                            tasks=(), **axis_settings))
    svc = Service(replace(make_settings(db_url, tmp_path), axes=(axis,)), runner=DriverRunner(timeout_s=1.0))
    svc.start()
    with session_scope(svc.factory) as s:
        svc.test_axis = config_repo.list_axes(s)[0]
    return svc


def run_one(svc, timeout_s=90.0):
    svc.scheduler.request(svc.test_axis.id, "manual")
    assert svc.scheduler.idle(timeout_s), "the cycle did not finish"
    time.sleep(0.1)
    with session_scope(svc.factory) as s:
        return results_repo.list_measurements(s, svc.test_axis.id, limit=10)[1]


def test_no_round_trip_within_the_time_out_is_a_recorded_failure_and_nothing_is_stored(
        engine, db_url, tmp_path, controller):  # noqa: F811
    svc = passive_service(db_url, tmp_path, f"modbus://127.0.0.1:{controller.port}?start_timeout_s=1.5")
    try:
        cycles = run_one(svc)
        assert len(cycles) == 1
        c = cycles[0]
        assert c.status == "failed"
        assert c.failure_reason.startswith("no_round_trip: no round trip seen within 1.5 s")
        assert c.run_file is None and c.backlash_mean_um is None
        with session_scope(svc.factory) as s:
            assert s.scalar(select(func.count()).select_from(Result)) == 0
            assert s.scalar(select(func.count()).select_from(Curve)) == 0
        assert not (tmp_path / "datasets").exists() or not any((tmp_path / "datasets").rglob("*.csv"))
        assert controller.axis.cycles_started == 0  # and the axis never moved
    finally:
        svc.stop()


def test_a_round_trip_started_by_the_cnc_is_stored_as_passive(engine, db_url, tmp_path, controller):  # noqa: F811
    svc = passive_service(db_url, tmp_path, f"modbus://127.0.0.1:{controller.port}?start_timeout_s=60")
    cnc = start_cnc(controller.port, 1.0, PROGRAM)
    try:
        cycles = run_one(svc)
        cnc.communicate(timeout=60)
        assert [c.status for c in cycles] == ["ok"], cycles[0].failure_reason
        assert cycles[0].backlash_mean_um == pytest.approx(120.0, abs=1.5)
        folder = svc.executor.dataset_folder(svc.test_axis)
        run = read_dataset(folder).runs[0]
        assert run.spec.extra["trigger"] == "passive"
        assert run.spec.feed_mm_min == pytest.approx(PROGRAM.feed_mm_min, rel=0.02)  # observed, not configured
        assert controller.axis.cycles_started == 1
    finally:
        svc.stop()


def _config(axis_extra: str, controller: str = "modbus://10.0.4.21:502") -> str:
    return demo_machine_toml("vmc", demo_axis_toml(travel_mm=(0.0, 500.0), controller=controller, task=False)) \
        + axis_extra + "\n"


def _axis_url(text: str) -> str:
    import tomllib

    return parse_settings(tomllib.loads(text)).axes[0].settings.controller_url


def test_the_configuration_puts_trigger_and_detection_settings_in_the_controller_url():
    assert _axis_url(_config("")) == "modbus://10.0.4.21:502"  # passive by default, nothing to add
    url = _axis_url(_config('trigger = "passive"\npassive = { start_timeout_s = 900, running_flag = false }'))
    assert url == "modbus://10.0.4.21:502?trigger=passive&start_timeout_s=900.0&running_flag=0"
    assert _axis_url(_config('trigger = "active"')) == "modbus://10.0.4.21:502?trigger=active"
    assert _axis_url(_config("", "sim")) == "sim"


@pytest.mark.parametrize("extra, controller, what", [
    ('trigger = "sometimes"', "modbus://h:502", "trigger"),
    ('trigger = "passive"', "sim", "built-in simulator"),
    ('passive = { start_timeout_s = 5 }', "sim", "built-in simulator"),
    ('trigger = "active"\npassive = { start_timeout_s = 5 }', "modbus://h:502", "trigger = 'passive' only"),
    ('passive = { start_timeout = 5 }', "modbus://h:502", "unknown option"),
    ('passive = { rest_s = -1.0 }', "modbus://h:502", "rest_s"),
    ('passive = { min_stroke_mm = 1.0 }', "modbus://h:502", "min_stroke_mm"),
    ('trigger = "active"', "modbus://h:502?trigger=passive", "contradicts"),
    ('trigger = "passive"', "canopen://socketcan/can0?node=5&mode=active-cia402", "contradicts"),
])
def test_bad_trigger_configuration_is_refused_when_it_loads(extra, controller, what):
    import tomllib

    with pytest.raises(ConfigError, match=what):
        parse_settings(tomllib.loads(_config(extra, controller)))

"""Compensation on a real controller, semi-closed (LinuxCNC's pid on the motor encoder),
through mebm's maintenance loop: the service measures the axis (b̄ 120 µm: ALARM, a work
order), ``mebm export-comp --format linuxcnc --comp-type 1`` writes the table from the
stored run, LinuxCNC is restarted with it as the joint's COMP_FILE, the repair
``compensation_loaded`` is recorded and the service's verification measurement runs on
the restarted LinuxCNC.

Asserts: the lost motion at the reversal (table minus commanded position, at rest after
the outward stroke and after the return) falls by at least 80 %; the mechanical play the
encoders see is unchanged (b̄ before = after), so the order is verified against the
compensated error, with before and after. LinuxCNC starts twice: the restart with the
table is the point.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from acquisition.measurement import run_cycle
from acquisition.linuxcnc.closed_loop import reversal_lost_motion_um
from acquisition.linuxcnc.sim import MOTOR_PIN, SCALE_PIN, SimSettings
from acquisition.types import RoundTripProgram
from acquisition.url import driver_from_url
from api.rest import create_app
from api.service.config.settings import AxisConfig, Settings
from core.tbe import MachiningTask
from storage.db import Schedule, config_repo, session_scope
from storage.db.records import AxisSettings
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, running_sim

ROOT = Path(__file__).resolve().parents[3]
V1 = "/api/v1"
URL = f"linuxcnc://127.0.0.1:{SimSettings().port}?joint=0&motor_pin={MOTOR_PIN}&scale_pin={SCALE_PIN}&trigger=active"
#: Long dwells: the loop settles (exp(-K dwell) < 1e-4) before the rest is read.
PROGRAM = RoundTripProgram(-1.5, 13.5, 1200.0, acceleration_mm_s2=500.0, dwell_s=0.3)
TASK = MachiningTask("finish circle", "circle", feed_mm_min=2000.0, gain_per_s=AXIS.position_gain_per_s,
                     tolerance_um=20.0, radius_mm=50.0)


def lost_motion(sim) -> tuple[float, float]:
    """(b̄, lost motion at the reversal) of one round trip mebm commands, in µm."""
    drv = driver_from_url(URL, timeout_s=5.0)
    r = run_cycle(drv, AXIS, PROGRAM)
    assert r.ok, r.reason
    return r.result.backlash_mean_um, reversal_lost_motion_um(r.trace.table_mm, drv.last_command_mm, PROGRAM)


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("comp")
    axis = AxisConfig("linuxcnc-sim", AxisSettings(spec=AXIS, controller_url=URL, measure_feed_mm_min=1200.0,
                                                   schedule=Schedule(interval_s=86400.0), tasks=(TASK,)))
    settings = Settings(data_dir=tmp / "data", database_url=f"sqlite:///{tmp}/mebm.sqlite3",
                        machines=(("linuxcnc-sim", "LinuxCNC 2.9, simulated machine"),), axes=(axis,),
                        catch_up_missed=False, demo_keys=False)
    out = {}
    app = create_app(settings)
    with TestClient(app) as client:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            keys = {role: config_repo.create_key(s, f"test-{role}", role)[1] for role in ("read", "operate")}
            axis_id = config_repo.list_axes(s)[0].id
        hdr = {role: {"X-API-Key": key} for role, key in keys.items()}
        with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="semi")) as sim:
            svc.trigger(axis_id, "test")
            assert svc.scheduler.idle(120)
            out["b_before_um"], out["lost_before_um"] = lost_motion(sim)
        orders = client.get(f"{V1}/maintenance/orders?state=active", headers=hdr["read"]).json()["items"]
        assert len(orders) == 1, orders
        order = orders[0]
        (run,) = sorted((settings.data_dir / "datasets").glob("*/rt_*.csv"))
        table = tmp / "comp_x.txt"
        proc = subprocess.run([sys.executable, "-m", "api.cli", "export-comp", str(run.parent), "--run", run.name,
                               "--format", "linuxcnc", "--comp-type", "1", "--joint", "0", "--out", str(table)],
                              capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert proc.returncode == 0, proc.stderr
        with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="semi", comp_file=str(table))) as sim:
            assert "COMP_FILE = " in (sim.run_dir / "mebm_sim.ini").read_text()
            out["b_after_um"], out["lost_after_um"] = lost_motion(sim)
            body = {"kind": "compensation_loaded", "note": "mebm export-comp table as COMP_FILE",
                    "compensation_measurement_id": order["opened_by_measurement_id"], "compensation_file": table.name}
            r = client.post(f"{V1}/axes/{axis_id}/repairs", json=body, headers=hdr["operate"])
            assert r.status_code == 201, r.text
            assert svc.scheduler.idle(120)  # the verification measurement, on the compensated LinuxCNC
        out["order"] = client.get(f"{V1}/maintenance/orders/{order['id']}", headers=hdr["read"]).json()
        out["opened"] = order
        out["table"] = table
    return out


def test_before_the_table_the_service_alarms_and_the_reversal_loses_the_backlash(loop):
    assert abs(loop["b_before_um"] - BACKLASH_UM) <= 1.0
    assert loop["lost_before_um"] == pytest.approx(BACKLASH_UM, abs=2.0)
    assert loop["opened"]["kind"] == "corrective" and loop["opened"]["binding_task"] == "finish circle"


def test_the_exported_table_loaded_as_comp_file_cuts_the_lost_motion_by_80_percent(loop):
    assert loop["table"].read_text().split("\n", 1)[0].split()[1:] == ["0.0600000", "-0.0600000"]  # ±b/2 trims
    assert loop["lost_after_um"] <= 0.2 * loop["lost_before_um"], (loop["lost_before_um"], loop["lost_after_um"])
    # the play between motor and table is mechanical: the encoders still see it
    assert abs(loop["b_after_um"] - BACKLASH_UM) <= 1.0


def test_the_maintenance_loop_records_the_compensation_verified_with_before_and_after(loop):
    done = loop["order"]
    assert done["state"] == "verified", done.get("verification")
    assert done["verified_against"].startswith("compensated error: residual backlash")
    assert loop["table"].name in done["verified_against"]
    v = done["verification"]
    assert v["before"]["backlash_mean_um"] == pytest.approx(BACKLASH_UM, abs=1.0)
    assert v["after"]["backlash_mean_um"] == pytest.approx(BACKLASH_UM, abs=1.0)

"""The simulators' wear and repair: the backlash grows at the configured rate
per utility day, the Modbus register / CANopen object (and `mebm sim-controller repair`)
restore it, and a measurement through the real drivers sees both."""

from __future__ import annotations

import canopen
import pytest
from pymodbus.client import ModbusTcpClient

from acquisition.canopen import objects as co
from acquisition.measurement import run_cycle
from acquisition.sim import wear as sw
from acquisition.sim.canopen import wear as canopen_wear
from acquisition.sim.modbus import wear as modbus_wear
from acquisition.sim.twin import KinematicTwin
from api.cli.main import main
from core.errors import InputError
from tests.acquisition.conftest import AXIS, PROGRAM, canopen_peer, modbus_peer
from tests.clock import ManualClock


def _twin(clock):
    return sw.WearingTwin(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), sw.Wear(8.0, 2.0, clock=clock))


def test_wear_grows_per_utility_day_and_a_repair_restores_it():
    clock = ManualClock()
    w = sw.Wear(8.0, 2.0, clock=clock)  # 8 µm a day, 2 utility days a second
    clock.t = 3.0
    assert w.utility_days() == pytest.approx(6.0) and w.extra_um() == pytest.approx(48.0)
    w.repair()
    assert w.extra_um() == 0.0 and w.repairs == 1
    clock.t = 3.5
    assert w.extra_um() == pytest.approx(8.0)
    with pytest.raises(InputError, match="wear_um_per_day"):
        sw.Wear(-1.0)
    with pytest.raises(InputError, match="utility_days_per_s"):
        sw.Wear(1.0, 0.0)


def test_modbus_register_and_cli_repair_what_the_driver_measures(capsys):
    clock = ManualClock()
    twin = _twin(clock)
    with modbus_peer(twin=twin) as peer:
        r0 = run_cycle(peer.driver(), AXIS, PROGRAM)
        clock.t = 2.5  # 5 utility days: +40 µm
        r1 = run_cycle(peer.driver(), AXIS, PROGRAM)
        port = peer.driver().port
        c = ModbusTcpClient("127.0.0.1", port=port)
        assert c.connect()
        try:
            regs = c.read_holding_registers(modbus_wear.REPAIR_REG, count=modbus_wear.WEAR_WORDS).registers
            assert ((regs[2] << 16) | regs[3]) == 4000 and regs[1] == 0
            assert c.write_register(modbus_wear.REPAIR_REG, 1).isError()  # not the magic value: refused
            assert c.write_register(modbus_wear.REPAIRS_REG, sw.REPAIR_MAGIC).isError()  # a read-only word
        finally:
            c.close()
        assert main(["sim-controller", "repair", f"modbus://127.0.0.1:{port}"]) == 0
        assert "wear 40.00 µm removed (repair 1)" in capsys.readouterr().out
        r2 = run_cycle(peer.driver(), AXIS, PROGRAM)
    assert r0.ok and r1.ok and r2.ok, (r0.reason, r1.reason, r2.reason)
    b0, b1, b2 = (r.result.backlash_mean_um for r in (r0, r1, r2))
    assert b0 == pytest.approx(120.0, abs=2.0)
    assert b1 - b0 == pytest.approx(40.0, abs=2.0)
    assert b2 == pytest.approx(b0, abs=2.0) and twin.wear.repairs == 1


def test_cli_repair_names_a_bad_address():
    assert main(["sim-controller", "repair", "http://127.0.0.1:1"]) != 0


def test_canopen_objects_report_and_repair_the_wear():
    clock = ManualClock()
    twin = _twin(clock)
    with canopen_peer(twin=twin) as peer:
        drive = peer.axis.on_fault.__self__
        clock.t = 1.0
        net = canopen.Network()
        net.connect(interface="virtual", channel=drive.channel)
        try:
            od = co.object_dictionary(5)
            canopen_wear.add_objects(od)
            node = canopen.RemoteNode(5, od)
            net.add_node(node)
            assert node.sdo[canopen_wear.WEAR_OBJECT].raw == 1600  # 2 days x 8 µm, in 0.01 µm
            with pytest.raises(canopen.SdoAbortedError):
                node.sdo[canopen_wear.REPAIR_OBJECT].raw = 7
            node.sdo[canopen_wear.REPAIR_OBJECT].raw = sw.REPAIR_MAGIC
            assert node.sdo[canopen_wear.REPAIRS_OBJECT].raw == 1 and node.sdo[canopen_wear.WEAR_OBJECT].raw == 0
        finally:
            net.disconnect()
        r = run_cycle(peer.driver(), AXIS, PROGRAM)
    assert r.ok, r.reason
    assert r.result.backlash_mean_um == pytest.approx(120.0, abs=2.0)

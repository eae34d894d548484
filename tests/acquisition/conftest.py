"""Simulated peers for the driver tests: each yields a driver factory and the simulated axis."""

from __future__ import annotations

import contextlib
import itertools
import logging

import numpy as np
import pytest

from acquisition.canopen.driver import CanopenDriver
from acquisition.modbus.driver import ModbusDriver
from acquisition.sim.axis import SimAxis
from acquisition.sim.canopen.drive import SimCanopenDrive
from acquisition.sim.faults import parse_fault
from acquisition.sim.modbus.server import SimModbusController
from acquisition.sim.twin import KinematicTwin
from acquisition.types import RoundTripProgram
from core.dataset import AxisSpec
from tests.host_lock import host_lock

for _name in ("pymodbus", "canopen", "can"):
    logging.getLogger(_name).setLevel(logging.CRITICAL)

AXIS = AxisSpec("y", 6.857, 16.0, 30.0, (0.0, 20.0))
PROGRAM = RoundTripProgram(-2.0, 22.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=0.1)
_channels = itertools.count()
# The largest trace ring the register map allows (2.2 s at 5 kHz of simulated servo): the
# simulated axis runs on wall time, so a stall of this host (GIL, a busy machine) must not
# overrun it in tests that are about something else. Overruns are tested with a tiny ring.
RING_MAX = 10906


def realtime_rig():
    """The network-namespace rigs run what stands for hardware (the simulated drive, the
    CNC master) at real-time priority, mebm as it would run; two rigs at once on a 2-core
    host starve each other's replies out of the synchronous window. Rigs take turns (each
    rig bounds its own run)."""
    return host_lock("realtime-rig")


class Peer:
    """A simulated controller and how to reach it."""

    def __init__(self, kind, sim_axis, make_driver, recover):
        self.kind, self.axis, self._make = kind, sim_axis, make_driver
        self.recover = recover  # ends every injected fault now

    def driver(self, **kw):
        kw.setdefault("timeout_s", 0.5)
        kw.setdefault("retries", 2)
        return self._make(**kw)


@contextlib.contextmanager
def modbus_peer(faults=(), twin=None, *, time_scale=10.0, servo_rate_hz=500.0, mode="trace", ring_records=RING_MAX):
    twin = twin or KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0)
    axis = SimAxis(twin, servo_rate_hz=servo_rate_hz, time_scale=time_scale, ring_records=ring_records,
                   faults=[parse_fault(f) if isinstance(f, str) else f for f in faults])
    sim = SimModbusController(axis)
    port = sim.start_in_thread()
    peer = Peer("modbus", axis, lambda **kw: ModbusDriver("127.0.0.1", port, mode=kw.pop("mode", mode), **kw),
                sim.recover)
    peer.server = sim  # the SimModbusController (its port; tests may wrap its request handlers)
    try:
        yield peer
    finally:
        sim.stop_thread()


@contextlib.contextmanager
def canopen_peer(faults=(), twin=None, *, time_scale=5.0, sync_rate_hz=200.0, servo_rate_hz=1000.0, **drive_kw):
    """``drive_kw``: reply timing of the simulated drive (reply_delay_s, reply_jitter_s)."""
    twin = twin or KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0)
    channel = f"mebm-test-{next(_channels)}"
    drive_kw.setdefault("rng", np.random.default_rng(next(_channels)))
    drive = SimCanopenDrive(twin, node_id=5, channel=channel, servo_rate_hz=servo_rate_hz,
                            faults=[parse_fault(f) if isinstance(f, str) else f for f in faults], **drive_kw)
    drive.start()
    try:
        yield Peer("canopen", drive.axis, lambda **kw: CanopenDriver(
            channel, kw.pop("node_id", 5), sync_rate_hz=sync_rate_hz, time_scale=time_scale, heartbeat_ms=100, **kw),
            drive.recover)
    finally:
        drive.stop()


PEERS = {"modbus": modbus_peer, "canopen": canopen_peer}


@pytest.fixture(params=sorted(PEERS))
def peer_factory(request):
    """Parametrises a test over both simulated peers: ``with peer_factory(faults=[...]) as peer``."""
    return PEERS[request.param]

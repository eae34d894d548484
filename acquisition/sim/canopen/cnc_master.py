"""A CNC's CANopen master, played by a separate process: NMT master, SYNC producer, and
a round trip commanded in Cyclic Synchronous Position mode (CiA 402, 0x6060 = 8).

What a CNC with CANopen drives does, reduced to one axis: it configures the drive over
SDO (communication cycle period 0x1006, synchronous window 0x1007, heartbeat 0x1017,
mode 8), enables it through the controlword (0x06, 0x07, 0x0F), starts the node (NMT),
then every communication cycle sends SYNC (with the CiA 301 counter byte) and RPDO1
(controlword, target position 0x607A for the next SYNC). The drive answers each SYNC
with TPDO1 (0x6064, 0x60E4 sub 1). mebm in listen-only mode hears all of this and sends
nothing (docs/canopen-objects.md).

    python -m acquisition.sim.canopen.cnc_master --interface udp_multicast --channel 239.74.163.2 \\
        --bus-port 43113 --node 7 --rate-hz 500 --start-mm -2 --end-mm 22 --feed-mm-min 1000
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import can
import canopen
import numpy as np

from acquisition.canopen import objects as co
from acquisition.sim.canopen.cia402 import TrapezoidMove
from acquisition.sim.twin import trapezoid_round_trip
from acquisition.canopen.sync_matcher import sync_counter_byte
from acquisition.types import RoundTripProgram
from core.errors import InputError, require_positive


def csp_trajectory_mm(x0_mm: float, program: RoundTripProgram, rate_hz: float, *, rest_before_s: float = 0.3,
                      rest_after_s: float = 0.3) -> np.ndarray:
    """Commanded table-side position (mm) at each SYNC: rest at ``x0_mm``, a move to the round
    trip's start (if away from it) and a rest there, the round trip (the twin's own NC
    program), rest: as a CNC part program positions, dwells, then runs the round trip."""
    dt = 1.0 / rate_hz
    parts = [np.full(int(round(rest_before_s * rate_hz)), x0_mm)]
    if abs(program.start_mm - x0_mm) > 1e-6:
        mv = TrapezoidMove(x0_mm, program.start_mm, program.speed_mm_s, program.acceleration_mm_s2,
                   program.acceleration_mm_s2)
        n = int(math.ceil(mv.duration_s / dt)) + 1
        parts.append(np.array([mv.at(i * dt) for i in range(1, n + 1)]))
        parts.append(np.full(int(round(rest_before_s * rate_hz)), program.start_mm))
    parts.append(trapezoid_round_trip(program, rate_hz)[1])
    parts.append(np.full(int(round(rest_after_s * rate_hz)), program.start_mm))
    return np.concatenate(parts)


class CncMaster:
    """NMT master and SYNC producer commanding one drive in CSP (blocking; one round trip per call)."""

    def __init__(self, node_id: int, *, interface: str, channel: str, bus_kwargs: dict | None = None,
                 sync_rate_hz: float = 500.0, time_scale: float = 1.0, window_s: float | None = None,
                 heartbeat_ms: int = 100, transmission_mm_per_rev: float = 6.857, sync_counter: bool = True,
                 sdo_timeout_s: float = 1.0, boot_timeout_s: float = 30.0):
        if not 1 <= int(node_id) <= 127:
            raise InputError(f"node (={node_id}) must be a CANopen node id 1..127")
        self.node_id = int(node_id)
        self.interface, self.channel, self.bus_kwargs = interface, channel, dict(bus_kwargs or {})
        self.sync_rate_hz = require_positive("sync_rate_hz", sync_rate_hz)
        self.time_scale = require_positive("time_scale", time_scale)
        self.period_s = 1.0 / self.sync_rate_hz  # machine time per SYNC (written to 0x1006)
        self.wall_period_s = self.period_s / self.time_scale
        self.window_s = window_s if window_s else 0.5 * self.wall_period_s
        self.heartbeat_ms = int(heartbeat_ms)
        self.k_a = require_positive("transmission_mm_per_rev", transmission_mm_per_rev)
        self.sync_counter = bool(sync_counter)
        self.sdo_timeout_s = sdo_timeout_s
        self.boot_timeout_s = boot_timeout_s
        self.syncs_sent = 0
        self.rpdos_sent = 0
        self.late_syncs = 0  # SYNCs that went out more than half a period late (host stalls)

    def run_round_trip(self, program: RoundTripProgram, *, rest_before_s: float = 0.3,
                       rest_after_s: float = 0.3) -> dict:
        net = canopen.Network()
        net.NOTIFIER_CYCLE = 0.1
        net.connect(interface=self.interface, channel=self.channel, **self.bus_kwargs)
        try:
            node = canopen.RemoteNode(self.node_id, co.object_dictionary(self.node_id))
            net.add_node(node)
            node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout_s
            net.nmt.state = "PRE-OPERATIONAL"  # broadcast: every node, as a master does at start
            sdo = node.sdo
            self._wait_for_node(sdo)
            sdo[co.COMM_CYCLE_PERIOD].raw = int(round(self.period_s * 1e6))
            sdo[co.SYNC_WINDOW].raw = max(1, int(self.window_s * 1e6))
            sdo[co.PRODUCER_HEARTBEAT].raw = self.heartbeat_ms
            sdo[co.MODES_OF_OPERATION].raw = co.MODE_CYCLIC_SYNC_POSITION
            cpr = sdo[co.ENCODER_RESOLUTION][1].raw / max(sdo[co.ENCODER_RESOLUTION][2].raw, 1)
            for cw in (co.CW_SHUTDOWN, co.CW_SWITCH_ON, co.CW_ENABLE_OPERATION):
                sdo[co.CONTROLWORD].raw = cw
            sw = sdo[co.STATUSWORD].raw
            if not sw & co.SW_OPERATION_ENABLED:
                raise RuntimeError(f"drive {self.node_id} not in OPERATION ENABLED (statusword 0x{sw:04X})")
            x0_mm = sdo[co.POSITION_ACTUAL].raw / cpr * self.k_a
            traj = csp_trajectory_mm(x0_mm, program, self.sync_rate_hz, rest_before_s=rest_before_s,
                                     rest_after_s=rest_after_s)
            counts = np.rint(traj / self.k_a * cpr).astype(np.int64)
            net.nmt.state = "OPERATIONAL"
            t0 = time.time()
            self._cycle(net.bus, counts)
            t1 = time.time()
            sdo[co.CONTROLWORD].raw = co.CW_SHUTDOWN  # the axis is left disabled, at rest
            net.nmt.state = "PRE-OPERATIONAL"
            return {"syncs_sent": self.syncs_sent, "rpdos_sent": self.rpdos_sent, "late_syncs": self.late_syncs,
                    "t_start": t0, "t_end": t1, "samples": int(counts.size)}
        finally:
            net.disconnect()

    def _wait_for_node(self, sdo) -> None:
        """Ask the device type until the drive answers (it may still be booting), for ``boot_timeout_s``."""
        end = time.monotonic() + self.boot_timeout_s
        while True:
            try:
                sdo[co.DEVICE_TYPE].raw
                return
            except canopen.SdoCommunicationError:
                if time.monotonic() > end:
                    raise

    def _cycle(self, bus: can.BusABC, counts: np.ndarray) -> None:
        rpdo_id, period = co.rpdo1_cob_id(self.node_id), self.wall_period_s
        min_gap = max(self.window_s, 0.9 * period)

        def rpdo(target: int) -> None:
            bus.send(can.Message(arbitration_id=rpdo_id, is_extended_id=False,
                                 data=co.encode_rpdo1(co.CW_ENABLE_OPERATION, int(target))))
            self.rpdos_sent += 1

        rpdo(counts[0])  # applied on the first SYNC
        next_t = time.perf_counter()
        for i in range(counts.size):
            while True:
                delay = next_t - time.perf_counter()
                if delay <= 0:
                    break
                # no busy wait: the drive's machine time advances one period per SYNC whatever
                # the wall clock, so a SYNC a little late costs nothing but a spinning master
                # would take a core from everyone else
                time.sleep(delay if delay < 0.0015 else delay - 0.0005)
            sent = time.perf_counter()
            if sent - next_t > 0.5 * period:
                self.late_syncs += 1
            self.syncs_sent += 1
            data = [sync_counter_byte(self.syncs_sent)] if self.sync_counter else []
            bus.send(can.Message(arbitration_id=co.SYNC_COB_ID, is_extended_id=False, data=data))
            rpdo(counts[min(i + 1, counts.size - 1)])  # the target of the next SYNC
            next_t = max(next_t + period, sent + min_gap)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m acquisition.sim.canopen.cnc_master", description=__doc__.splitlines()[0])
    p.add_argument("--interface", default="udp_multicast")
    p.add_argument("--channel", default="239.74.163.2")
    p.add_argument("--bus-port", type=int, default=None, help="udp_multicast port")
    p.add_argument("--node", type=int, default=5)
    p.add_argument("--rate-hz", type=float, default=500.0)
    p.add_argument("--time-scale", type=float, default=1.0)
    p.add_argument("--window-ms", type=float, default=None, help="synchronous window written to 0x1007 "
                   "(default half the SYNC period)")
    p.add_argument("--start-mm", type=float, required=True)
    p.add_argument("--end-mm", type=float, required=True)
    p.add_argument("--feed-mm-min", type=float, required=True)
    p.add_argument("--acceleration-mm-s2", type=float, default=500.0)
    p.add_argument("--dwell-s", type=float, default=0.1)
    p.add_argument("--rest-s", type=float, default=0.3)
    p.add_argument("--transmission-mm-per-rev", type=float, default=6.857)
    a = p.parse_args(argv)
    bus_kwargs = {"port": a.bus_port} if a.bus_port else {}
    master = CncMaster(a.node, interface=a.interface, channel=a.channel, bus_kwargs=bus_kwargs,
                       sync_rate_hz=a.rate_hz, time_scale=a.time_scale,
                       window_s=a.window_ms / 1000.0 if a.window_ms else None,
                       transmission_mm_per_rev=a.transmission_mm_per_rev)
    program = RoundTripProgram(a.start_mm, a.end_mm, a.feed_mm_min, acceleration_mm_s2=a.acceleration_mm_s2,
                               dwell_s=a.dwell_s)
    print(json.dumps(master.run_round_trip(program, rest_before_s=a.rest_s, rest_after_s=a.rest_s)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

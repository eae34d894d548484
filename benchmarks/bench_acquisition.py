"""Acquisition throughput of each driver against its simulated peer on loopback.

Run: .venv/bin/python benchmarks/bench_acquisition.py [--repeats N] [--seconds S]

Prints, per driver:
- samples per second sustained and lost samples in a real-time round trip at a 1 kHz
  servo (Modbus: the trace buffer; CANopen: SYNC at 1 kHz on the virtual bus). Goal: 0 lost.
- Modbus only: the driver's maximum sample rate, draining a full trace buffer (the
  controller runs 1000x real time and has latched the whole round trip before the first
  read), against a bare pymodbus read loop of the same size (120 registers = 20 records
  per request) over the same ring. Goal: ratio >= 0.8.
- Modbus register profiles (no trace ring: one poll per sample): the rate the driver's
  poll reaches with a profile read in one request (float32 CDAB holding, ``latched``)
  and in two requests (int32 input registers far apart, ``separate``), against the
  simulated PLC of ``acquisition.sim.modbus.profile_server`` in a thread of this process.

The Modbus controller runs in another process (``mebm sim-controller modbus``), as in
production; the CANopen drive shares the process (python-can's virtual bus is
in-process). Medians over ``--repeats``. A measurement, not a test: nothing fails.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import re
import select
import statistics
import subprocess
import sys
import time
from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from acquisition.modbus import register_map as mm
from acquisition.canopen.driver import CanopenDriver
from acquisition.modbus.driver import ModbusDriver
from acquisition.modbus.polled import ProfileModbusDriver
from acquisition.modbus.profile import load_profile
from acquisition.sim.axis import SimAxis
from acquisition.sim.modbus.profile_server import SimProfileController
from acquisition.sim.canopen.drive import SimCanopenDrive
from acquisition.sim.twin import KinematicTwin
from acquisition.types import RoundTripProgram
from core.dataset import AxisSpec

for _name in ("pymodbus", "canopen", "can"):
    logging.getLogger(_name).setLevel(logging.CRITICAL)

AXIS = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 1000.0))


def program_for(machine_s: float, feed_mm_min: float = 1000.0) -> RoundTripProgram:
    """A round trip lasting about ``machine_s`` seconds of machine time."""
    travel = max(feed_mm_min / 60.0 * (machine_s - 0.4) / 2.0, 2.0)
    return RoundTripProgram(0.0, travel, feed_mm_min, acceleration_mm_s2=2000.0, dwell_s=0.1)


def start_sim(time_scale: float, ring_records: int = 2000) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "api.cli", "sim-controller", "modbus", "--port", "0", "--time-scale", str(time_scale),
         "--servo-rate-hz", "1000", "--ring-records", str(ring_records), "--duration-s", "600"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    if not ready:
        proc.kill()
        raise SystemExit("sim-controller did not start within 60 s")
    port = int(re.search(r":(\d+) ", proc.stdout.readline()).group(1))
    return proc, port


def modbus_real_time(port: int, seconds: float) -> tuple[float, int, int]:
    d = ModbusDriver("127.0.0.1", port, timeout_s=2.0, max_lost_samples=10**9, poll_interval_s=0.005)
    tr = d.acquire(program_for(seconds), AXIS)
    return tr.samples_per_s, tr.lost_samples, len(tr)


def modbus_max_rate(port: int) -> float:
    """Drain rate of a full trace buffer: the controller (1000x real time) has latched the whole
    round trip (9,000 samples in a 10,000-record ring) before the driver's first read."""
    d = ModbusDriver("127.0.0.1", port, timeout_s=2.0)
    tr = d.acquire(program_for(9.0), AXIS)
    assert tr.lost_samples == 0
    return tr.samples_per_s


async def bare_read_loop(port: int, n_reads: int) -> float:
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0, reconnect_delay=0)
    await client.connect()
    words = mm.RECORDS_PER_READ * mm.RECORD_WORDS
    # the controller runs a round trip meanwhile, so it serves the same work as for the driver
    await client.write_registers(mm.COMMAND, [mm.Command.ACKNOWLEDGE])
    await client.write_registers(mm.COMMAND, mm.encode_program(program_for(9.0), mm.Command.START))
    await asyncio.sleep(0.05)  # the round trip is latched (1000x real time): same ring content as the driver reads
    try:
        t0 = time.perf_counter()
        for i in range(n_reads):
            rr = await client.read_holding_registers(mm.RING_BASE + words * (i % 450), count=words)
            assert not rr.isError()
        dt = time.perf_counter() - t0
    finally:
        await client.write_registers(mm.COMMAND, [mm.Command.ABORT])
        client.close()
    return mm.RECORDS_PER_READ * n_reads / dt


PROFILES = Path(__file__).resolve().parents[1] / "examples" / "modbus-profiles"


def profile_poll_rate(name: str, seconds: float = 2.0) -> tuple[float, int]:
    """Polls per second of :meth:`ProfileModbusDriver.poll` for ``seconds`` (and the requests
    per poll) against the simulated PLC serving profile ``name``."""
    profile = load_profile(PROFILES / name)
    axis = SimAxis(KinematicTwin(position_gain_per_s=10.0), servo_rate_hz=1000.0)
    with SimProfileController(axis, profile, program_for(5.0)) as sim:
        d = ProfileModbusDriver("127.0.0.1", sim.port, profile=profile, timeout_s=2.0)

        async def run() -> float:
            await d.connect()
            try:
                n, t0 = 0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    await d.poll()
                    n += 1
                return n / (time.perf_counter() - t0)
            finally:
                await d.close()

        return asyncio.run(run()), len(profile.reads)


def canopen_real_time(seconds: float, sync_hz: float = 1000.0) -> tuple[float, int, int]:
    with SimCanopenDrive(KinematicTwin(position_gain_per_s=10.0), node_id=5, channel="mebm-bench",
                         servo_rate_hz=1000.0):
        d = CanopenDriver("mebm-bench", 5, sync_rate_hz=sync_hz, timeout_s=2.0, max_lost_samples=10**9)
        tr = d.acquire(program_for(seconds), AXIS)
    return tr.samples_per_s, tr.lost_samples, len(tr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=5.0, help="machine time of the real-time round trips")
    a = ap.parse_args()

    rt_proc, rt_port = start_sim(1.0)
    fast_proc, fast_port = start_sim(1000.0, ring_records=10000)
    try:
        rt = [modbus_real_time(rt_port, a.seconds) for _ in range(a.repeats)]
        modbus_max_rate(fast_port)  # warm-up (first connection, first round trip), not counted
        asyncio.run(bare_read_loop(fast_port, 450))
        drv, bare = [], []
        for _ in range(a.repeats):  # interleaved, so both see the same machine load
            drv.append(modbus_max_rate(fast_port))
            bare.append(asyncio.run(bare_read_loop(fast_port, 450)))
    finally:
        for p in (rt_proc, fast_proc):
            p.terminate()
            p.wait(10)
    co = [canopen_real_time(a.seconds) for _ in range(a.repeats)]
    one = [profile_poll_rate("plc-gateway-float32-cdab.toml") for _ in range(a.repeats)]
    two = [profile_poll_rate("drive-int32-input-separate.toml") for _ in range(a.repeats)]

    med = statistics.median
    print(f"acquisition benchmark, medians of {a.repeats} (loopback, 1 kHz servo, {a.seconds:g} s round trips)")
    print(f"{'driver':<34}{'samples/s':>12}{'lost':>8}{'samples':>9}")
    print(f"{'modbus trace buffer, real time':<34}{med(r[0] for r in rt):>12.0f}{max(r[1] for r in rt):>8d}"
          f"{med(r[2] for r in rt):>9.0f}")
    print(f"{'canopen SYNC 1 kHz, virtual bus':<34}{med(r[0] for r in co):>12.0f}{max(r[1] for r in co):>8d}"
          f"{med(r[2] for r in co):>9.0f}")
    d, b = med(drv), med(bare)
    ratio = med(x / y for x, y in zip(drv, bare))  # per interleaved pair: robust to load drifting
    print(f"modbus maximum: driver {d:.0f} samples/s, bare pymodbus loop of 120-register reads {b:.0f} samples/s, "
          f"ratio {ratio:.2f} (median of pairs; goal >= 0.8)")
    print(f"modbus profile, polled: one request per sample (latched) {med(r[0] for r in one):.0f} samples/s; "
          f"positions in two requests (separate, {two[0][1]} reads per poll with the running flag) "
          f"{med(r[0] for r in two):.0f} samples/s")
    print(f"lost samples (worst run): modbus {max(r[1] for r in rt)}, canopen {max(r[1] for r in co)} (goal 0)")


if __name__ == "__main__":
    main()

"""Run inside a private network namespace (``unshare -n``): a simulated CANopen drive in one
process, the CANopen driver in another, on python-can's ``udp_multicast`` over loopback.

Not a test module: ``test_canopen_netns.py`` re-executes it under ``unshare -n`` and
checks the JSON it prints. Nothing here can reach another machine: the namespace has
only its own loopback, with the multicast route on it.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import subprocess
import sys

GROUP = "239.74.163.2"
PORT = 43113  # a private namespace: nothing else is bound here
NODE = 7
FAULTS = ["lost:at=0.3,n=3", "duplicate:at=0.5,n=4"]


def _setup_namespace() -> None:
    for cmd in (["ip", "link", "set", "lo", "up"], ["ip", "route", "add", "224.0.0.0/4", "dev", "lo"]):
        subprocess.run(cmd, check=True, capture_output=True)


def _drive(conn, delay_s: float, jitter_s: float) -> None:
    import numpy as np

    from acquisition.sim.canopen.drive import SimCanopenDrive
    from acquisition.sim.faults import parse_fault
    from acquisition.sim.twin import KinematicTwin
    from tests.acquisition.canopen.priority import hardware_priority

    sched = hardware_priority()  # the drive stands for hardware; the driver runs as mebm would

    for name in ("can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    drive = SimCanopenDrive(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), node_id=NODE,
                            channel=GROUP, interface="udp_multicast", bus_kwargs={"port": PORT},
                            faults=[parse_fault(f) for f in FAULTS], reply_delay_s=delay_s,
                            reply_jitter_s=jitter_s, rng=np.random.default_rng(3))
    dups = []
    real_send = drive._send

    def send(msg):  # count the duplicates actually put on the wire
        if drive._dup_left or dups and dups[-1] is msg:
            dups.append(msg)
        real_send(msg)

    drive._send = send
    with drive:
        conn.send("ready")
        conn.recv()  # the driver is done
        conn.send({"answered": list(drive.answered), "late_discards": drive.late_discards,
                   "tpdos_sent": drive.tpdos_sent, "syncs": drive.syncs, "scheduling": sched})


def main() -> None:
    _setup_namespace()
    from acquisition.canopen.driver import CanopenDriver
    from acquisition.measurement import run_cycle
    from acquisition.types import RoundTripProgram
    from core.dataset import AxisSpec

    for name in ("can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_drive, args=(child, 0.0002, 0.0008), daemon=True)
    proc.start()
    try:
        assert parent.poll(60), "the simulated drive did not start"
        parent.recv()
        # SYNC every 20 ms of wall clock, 10 ms of machine time (time_scale 0.5: the drive runs
        # at half speed); a 4 ms synchronous window (the drive answers within 0.2-1 ms),
        # leaving 14 ms before the next SYNC for this host's scheduling. Frames are
        # stamped on arrival here, as on socketcan: a reply that reached the wire after the
        # next SYNC could only be told from that SYNC's reply by a counter the TPDO does not carry
        driver = CanopenDriver(GROUP, NODE, interface="udp_multicast", bus_kwargs={"port": PORT},
                               sync_rate_hz=100.0, time_scale=0.5, heartbeat_ms=100, timeout_s=2.0,
                               sync_window_s=0.004, max_lost_samples=10**6)
        axis = AxisSpec("y", 6.857, 16.0, 30.0, (0.0, 20.0))
        r = run_cycle(driver, axis, RoundTripProgram(-2.0, 22.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=0.1))
        parent.send("done")
        drive = parent.recv()
    finally:
        proc.join(10)
        if proc.is_alive():
            proc.terminate()
    t = r.trace
    print(json.dumps({
        "ok": r.ok, "reason": r.reason,
        "counter": t.counter.tolist() if t is not None else [],
        "lost_samples": t.lost_samples if t is not None else None,
        "backlash_mean_um": r.result.backlash_mean_um if r.result is not None else None,
        "sync_stats": driver.sync_stats, "frames_too_late": driver.frames_too_late,
        "drive": drive,
    }))


if __name__ == "__main__":
    sys.exit(main())

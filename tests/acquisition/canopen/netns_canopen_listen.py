"""mebm listen-only beside a CNC master, each in its own network namespace (run by
``test_canopen_listen_netns.py`` under ``unshare -n``; not a test module).

The hub (this script, in the private namespace the test made) builds a bridge and
three more namespaces on it, one process each, each with its own address:

    10.77.0.1  the CNC master: NMT master, SYNC producer, CSP commands (acquisition/sim/canopen/cnc_master.py)
    10.77.0.2  the simulated drive: answers each SYNC with its TPDO
    10.77.0.3  mebm, listen-only: measures the round trip

python-can's ``udp_multicast`` carries every CAN frame as one UDP datagram to the group;
the datagram's source address says which namespace sent it. The hub captures every
datagram crossing the bridge (an AF_PACKET socket on it) and counts frames by source.
When mebm is done, its namespace sends one probe frame: the capture must see it, from
mebm's address, so a capture that could not see mebm's frames cannot pass for one
that saw none. Every address here lives in namespaces this run made; nothing leaves.
"""

from __future__ import annotations

import json
import logging
import os
import select
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

from tests.acquisition.canopen.priority import hardware_priority

GROUP = "239.74.163.3"
PORT = 43114
NODE = 7
ADDR = {"master": "10.77.0.1", "drive": "10.77.0.2", "mebm": "10.77.0.3"}
PROBE_ID = 0x6FF
SCRIPT = Path(__file__).resolve()
ROOT = SCRIPT.parents[3]
EDS = ROOT / "examples" / "canopen" / "mebm-sim-drive.eds"
RATE_HZ = 250.0  # SYNC rate of the machine: a 4 ms cycle of machine time
# The master and the drive stand for hardware; on a shared host they run at 0.4 of real time
# (a SYNC every 10 ms of wall clock) with a 4 ms synchronous window, so a reply delayed by
# this host's scheduling is late by 6 ms before it could reach the wire after the next SYNC,
# where no window tells it from that SYNC's reply (the TPDO carries no counter)
TIME_SCALE = 0.4
WINDOW_MS = 4.0
# a reply the drive could not send within its window is discarded (CiA 301): each such SYNC
# is a counted gap in the trace; up to a third of the ~850 samples may go without changing b̄
# by more than a few 0.01 µm
MAX_LOST = 300
PROGRAM = dict(start_mm=-2.0, end_mm=22.0, feed_mm_min=1000.0, acceleration_mm_s2=500.0, dwell_s=0.1)
TWIN = dict(backlash_um=120.0, position_gain_per_s=30.0)


def _run(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, text=True)


def _quiet() -> None:
    for name in ("can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _say(msg) -> None:
    sys.stdout.write(json.dumps(msg) + "\n")
    sys.stdout.flush()


def _wait_line() -> str:
    return sys.stdin.readline().strip()


# -- roles (each in its own namespace) --------------------------------------------------------------
def role_drive() -> None:
    import numpy as np

    from acquisition.sim.canopen.drive import SimCanopenDrive
    from acquisition.sim.twin import KinematicTwin

    sched = hardware_priority()
    drive = SimCanopenDrive(KinematicTwin(**TWIN), node_id=NODE, channel=GROUP, interface="udp_multicast",
                            bus_kwargs={"port": PORT}, reply_delay_s=0.0002, reply_jitter_s=0.0003,
                            rng=np.random.default_rng(5))
    with drive:
        _say("ready")
        _wait_line()  # stop
        _say({"syncs": drive.syncs, "tpdos_sent": drive.tpdos_sent, "late_discards": drive.late_discards,
              "csp_targets": drive.cia402.csp_targets, "scheduling": sched})


def role_master() -> None:
    from acquisition.sim.canopen.cnc_master import CncMaster
    from acquisition.types import RoundTripProgram

    sched = hardware_priority()
    master = CncMaster(NODE, interface="udp_multicast", channel=GROUP, bus_kwargs={"port": PORT},
                       sync_rate_hz=RATE_HZ, time_scale=TIME_SCALE, window_s=WINDOW_MS / 1000.0, sdo_timeout_s=2.0)
    _say("ready")
    _wait_line()  # go
    _say({**master.run_round_trip(RoundTripProgram(**PROGRAM), rest_before_s=0.5, rest_after_s=0.5),
          "scheduling": sched})


def role_mebm() -> None:
    from acquisition.canopen.url import driver_from_canopen_url
    from acquisition.measurement import run_cycle
    from acquisition.types import RoundTripProgram
    from core.dataset import AxisSpec

    url = (f"canopen://udp_multicast/{GROUP}?node={NODE}&mode=listen-only&eds={EDS}&rate_hz={RATE_HZ:g}"
           f"&time_scale={TIME_SCALE:g}&window_ms={WINDOW_MS:g}&port={PORT}&max_lost_samples={MAX_LOST}")
    driver = driver_from_canopen_url(url, timeout_s=20.0)
    _say("ready")
    r = run_cycle(driver, AxisSpec("y", 6.857, 16.0, 30.0, (0.0, 20.0)), RoundTripProgram(**PROGRAM))
    t = r.trace
    _say({"ok": r.ok, "reason": r.reason, "reason_code": r.reason_code,
          "backlash_mean_um": r.result.backlash_mean_um if r.result is not None else None,
          "samples": len(t) if t is not None else 0, "lost_samples": t.lost_samples if t is not None else None,
          "stats": driver.listen_stats, "sends_refused": driver.sends_refused})
    _wait_line()  # probe: this namespace sends one frame, to show the capture sees what it sends
    import can

    with can.Bus(interface="udp_multicast", channel=GROUP, port=PORT) as bus:
        bus.send(can.Message(arbitration_id=PROBE_ID, is_extended_id=False, data=[0x55]))
        time.sleep(0.2)
    _say("probed")


# -- the hub ----------------------------------------------------------------------------------------
class Capture(threading.Thread):
    """Every UDP datagram to the group's port crossing the bridge: (source address, CAN id)."""

    def __init__(self, ifname: str):
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        # room for every frame of the run even if this thread is starved (2 cores, 8 sessions)
        self.sock.setsockopt(socket.SOL_SOCKET, 33, 32 << 20)  # SO_RCVBUFFORCE (root)
        self.sock.bind((ifname, 0))
        self.frames: list[tuple[float, str, int]] = []
        self.igmp: list[str] = []
        self.stop = threading.Event()
        self.lock = threading.Lock()

    def run(self) -> None:
        from can.interfaces.udp_multicast.utils import unpack_message

        while not self.stop.is_set():
            r, _, _ = select.select([self.sock], [], [], 0.1)
            if not r:
                continue
            pkt = self.sock.recv(65535)
            if len(pkt) < 34 or struct.unpack_from("!H", pkt, 12)[0] != 0x0800:
                continue
            ihl = (pkt[14] & 0x0F) * 4
            proto, src = pkt[23], socket.inet_ntoa(pkt[26:30])
            if proto == 2:
                with self.lock:
                    self.igmp.append(src)
                continue
            if proto != 17:
                continue
            udp = 14 + ihl
            if struct.unpack_from("!H", pkt, udp + 2)[0] != PORT:
                continue
            try:
                cob = unpack_message(pkt[udp + 8:]).arbitration_id
            except Exception:  # noqa: BLE001 - not a python-can datagram: counted with id -1
                cob = -1
            with self.lock:
                self.frames.append((time.time(), src, cob))

    def by_source(self) -> dict[str, dict]:
        with self.lock:
            out: dict[str, dict] = {}
            for _, src, cob in self.frames:
                d = out.setdefault(src, {"frames": 0, "ids": {}})
                d["frames"] += 1
                d["ids"][hex(cob)] = d["ids"].get(hex(cob), 0) + 1
            return out


def _own_namespace(pid: int, timeout_s: float = 60.0) -> None:
    """Wait until ``unshare -n`` (``pid``) has entered its new network namespace. The veth end
    moved into ``pid``'s namespace before that stays in the hub's (seen in CI on a loaded host:
    ``ip addr add ... dev c1`` then fails in the role's empty namespace)."""
    mine = os.readlink("/proc/self/ns/net")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if os.readlink(f"/proc/{pid}/ns/net") != mine:
                return
        except FileNotFoundError:
            raise RuntimeError(f"the role process {pid} ended before it had a network namespace") from None
        time.sleep(0.005)
    raise TimeoutError(f"the role process {pid} had no network namespace of its own after {timeout_s:g} s")


class Role:
    def __init__(self, name: str, idx: int):
        self.name = name
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(["unshare", "-n", sys.executable, str(SCRIPT), "--role", name],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        host, child = f"h{idx}", f"c{idx}"
        _own_namespace(self.proc.pid)
        _run("ip", "link", "add", host, "type", "veth", "peer", "name", child)
        _run("ip", "link", "set", child, "netns", str(self.proc.pid))
        _run("ip", "link", "set", host, "master", "br0")
        _run("ip", "link", "set", host, "up")
        ns = ["nsenter", "-t", str(self.proc.pid), "-n"]
        _run(*ns, "ip", "link", "set", "lo", "up")
        _run(*ns, "ip", "addr", "add", f"{ADDR[name]}/24", "dev", child)
        _run(*ns, "ip", "link", "set", child, "up")
        _run(*ns, "ip", "route", "add", "224.0.0.0/4", "dev", child)

    def send(self, line: str) -> None:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def read(self, timeout_s: float):
        r, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        if not r:
            raise TimeoutError(f"{self.name}: nothing within {timeout_s} s")
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"{self.name} ended (exit {self.proc.wait()})")
        return json.loads(line)


def hub() -> None:
    _run("ip", "link", "set", "lo", "up")
    _run("ip", "link", "add", "br0", "type", "bridge")
    _run("ip", "link", "set", "br0", "type", "bridge", "mcast_snooping", "0")  # flood the group to every port
    _run("ip", "link", "set", "br0", "up")
    cap = Capture("br0")
    cap.start()
    roles = {}
    try:
        roles["drive"] = Role("drive", 2)
        assert roles["drive"].read(60) == "ready"
        roles["mebm"] = Role("mebm", 3)
        assert roles["mebm"].read(60) == "ready"
        roles["master"] = Role("master", 1)
        assert roles["master"].read(60) == "ready"
        time.sleep(0.5)  # mebm listening (it waits for SYNC: nothing is on the bus before the master starts)
        roles["master"].send("go")
        master = roles["master"].read(120)
        mebm = roles["mebm"].read(60)
        time.sleep(0.3)
        before_probe = cap.by_source()
        roles["mebm"].send("probe")
        assert roles["mebm"].read(30) == "probed"
        time.sleep(0.3)
        after_probe = cap.by_source()
        roles["drive"].send("stop")
        drive = roles["drive"].read(30)
    finally:
        for r in roles.values():
            try:
                r.proc.stdin.close()
            except OSError:
                pass
            try:
                r.proc.wait(10)
            except subprocess.TimeoutExpired:
                r.proc.kill()
        cap.stop.set()
    with cap.lock:
        igmp = sorted(set(cap.igmp))
    print(json.dumps({"addresses": ADDR, "master": master, "mebm": mebm, "drive": drive,
                      "capture_before_probe": before_probe, "capture_after_probe": after_probe,
                      "igmp_sources": igmp, "probe_id": hex(PROBE_ID)}))


if __name__ == "__main__":
    _quiet()
    if len(sys.argv) == 3 and sys.argv[1] == "--role":
        {"drive": role_drive, "master": role_master, "mebm": role_mebm}[sys.argv[2]]()
    else:
        hub()

"""``mbpoll`` (Debian's package; libmodbus), a Modbus master mebm did not write, against
``mebm sim-controller modbus`` in another process: it reads the register map, starts a
round trip with one function-16 write of the control block, and reads the positions as
32-bit values (big-endian words), which agree with mebm's own decoding (docs/register-map.md)."""

from __future__ import annotations

import os
import re
import select
import shutil
import subprocess
import sys
import time

import pytest

from acquisition.modbus import register_map as mm
from acquisition.types import AxisState, RoundTripProgram

MBPOLL = shutil.which("mbpoll")
if MBPOLL is None:
    if os.environ.get("CI") == "true":
        pytest.fail("mbpoll is missing (Debian package mbpoll; .ci/run installs it)", pytrace=False)
    pytest.skip("mbpoll is missing (apt-get install -y mbpoll)", allow_module_level=True)


def mbpoll(port: int, *args: str, write: tuple[int, ...] = ()) -> list[int]:
    """Run mbpoll once (PDU addressing, -0) and return the values it printed, in order;
    ``write``: the values to write instead of reading (function 6, or 16 for several)."""
    out = subprocess.run([MBPOLL, "-m", "tcp", "-a", "1", "-0", "-1", "-o", "5", "-p", str(port), *args,
                          "127.0.0.1", *map(str, write)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    return [int(v) for v in re.findall(r"^\[\d+\]:\s+(-?\d+)", out.stdout, flags=re.M)]


@pytest.fixture(scope="module")
def sim_port():
    proc = subprocess.Popen(
        [sys.executable, "-m", "api.cli", "sim-controller", "modbus", "--port", "0", "--backlash-um", "120",
         "--servo-rate-hz", "1000", "--duration-s", "300"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 120)
        assert ready, "sim-controller did not start within 120 s"
        line = proc.stdout.readline()
        yield int(re.search(r"modbus://127\.0\.0\.1:(\d+)", line).group(1))
    finally:
        proc.terminate()
        proc.wait(10)


def test_mbpoll_reads_the_register_map_header(sim_port):
    words = mbpoll(sim_port, "-r", "0", "-c", "28", "-t", "4")
    assert len(words) == 28
    cfg = mm.decode_config(words[mm.CONFIG_BASE:mm.CONFIG_BASE + mm.CONFIG_WORDS], version=words[0])
    assert cfg.version == mm.MAP_VERSION and cfg.servo_rate_hz == 1000.0
    assert cfg.record_words == mm.RECORD_WORDS
    # the same u32 values read by mbpoll as 32-bit integers, high word first (-B)
    assert mbpoll(sim_port, "-r", str(mm.COUNTS_PER_REV), "-c", "3", "-t", "4:int", "-B") == [
        cfg.scale.counts_per_rev, int(cfg.scale.table_nm_per_count), 1000]


def test_mbpoll_starts_a_round_trip_and_reads_the_moving_axis(sim_port):
    program = RoundTripProgram(0.0, 20.0, 1200.0, acceleration_mm_s2=500.0, dwell_s=0.1)
    # acknowledge whatever state a previous test left, then parameters and START in one write
    mbpoll(sim_port, "-r", str(mm.COMMAND), "-t", "4", write=(3,))
    control = mm.encode_program(program, 1)
    mbpoll(sim_port, "-r", str(mm.COMMAND), "-t", "4", write=tuple(control))
    seen = []
    for _ in range(200):
        status = mbpoll(sim_port, "-r", "0", "-c", str(mm.STATUS_WORDS), "-t", "4")
        s = mm.decode_status(status)
        both = mbpoll(sim_port, "-r", str(mm.MOTOR_POS), "-c", "2", "-t", "4:int", "-B")
        seen.append((s.state, s.table_counts, both))
        if s.state == AxisState.DONE:
            break
        time.sleep(0.05)
    states = [x[0] for x in seen]
    assert AxisState.RUNNING in states and states[-1] == AxisState.DONE
    # the table moved out to the end of the program and came back (10 nm per count)
    tables_mm = [x[1] * 1e-5 for x in seen]
    assert max(tables_mm) > 15.0 and max(tables_mm) - tables_mm[-1] > 15.0
    # mbpoll's 32-bit reading of motor and table, once at rest, is mebm's decoding of the status block
    s = mm.decode_status(mbpoll(sim_port, "-r", "0", "-c", str(mm.STATUS_WORDS), "-t", "4"))
    assert mbpoll(sim_port, "-r", str(mm.MOTOR_POS), "-c", "2", "-t", "4:int", "-B") == [s.motor_counts,
                                                                                         s.table_counts]

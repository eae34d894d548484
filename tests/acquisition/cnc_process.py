"""A stand-in for the CNC, run as its own process: after a delay it starts a round trip on a
``mebm-modbus/1`` controller with a plain pymodbus client, as a CNC or PLC program would.

    python -m tests.acquisition.cnc_process PORT DELAY_S START_MM END_MM FEED_MM_MIN ACCEL_MM_S2 DWELL_S [--ack]

``--ack``: once the program is DONE, acknowledge it at once (back to IDLE), as a CNC that
clears its program's end state would.

It imports nothing of mebm: the registers are written as docs/register-map.md describes
them (one function-16 request, parameters then command, from register 40).
"""

from __future__ import annotations

import sys
import time

from pymodbus.client import ModbusTcpClient

COMMAND_START = 1
COMMAND_ACKNOWLEDGE = 3
STATE_RUNNING, STATE_DONE = 1, 2


def words_i32(v: int) -> list[int]:
    v &= 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


def main(argv: list[str]) -> int:
    port, delay_s = int(argv[0]), float(argv[1])
    start_mm, end_mm, feed_mm_min, accel_mm_s2, dwell_s = map(float, argv[2:7])
    time.sleep(delay_s)
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=5)
    if not client.connect():
        print("cnc: cannot connect", file=sys.stderr)
        return 2
    try:
        words = [COMMAND_START, *words_i32(round(start_mm * 1000)), *words_i32(round(end_mm * 1000)),
                 *words_i32(round(feed_mm_min * 1000)), int(round(accel_mm_s2)), int(round(dwell_s * 1000))]
        rr = client.write_registers(40, words, device_id=1)
        if rr.isError():
            print(f"cnc: start refused: {rr}", file=sys.stderr)
            return 3
        if "--ack" in argv[7:]:
            deadline = time.monotonic() + 60.0
            while client.read_holding_registers(1, count=1, device_id=1).registers[0] != STATE_DONE:
                if time.monotonic() > deadline:
                    print("cnc: the program did not end within 60 s", file=sys.stderr)
                    return 4
                time.sleep(0.002)
            client.write_registers(40, [COMMAND_ACKNOWLEDGE], device_id=1)
    finally:
        client.close()
    print("cnc: round trip started", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""A contour (a circle, a line) LinuxCNC runs, recorded for mebm: both axes' motor
encoder, linear scale and commanded position, latched in the same servo period by a
sampler of six pins (``sampler.N.pin.0..5``: first axis motor, scale, command, second
axis the same), read by halsampler.

:func:`record_contour` runs a program mebm was given (an ``.ngc`` file LinuxCNC can read)
and returns the samples from its start to its end; it fails as the driver does (e-stop,
machine off, LinuxCNC stopped, any sample the FIFO dropped).
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass

import numpy as np

from acquisition.errors import ControllerTimeoutError, LostSamplesError, ProtocolError
from acquisition.linuxcnc import hal
from acquisition.linuxcnc.errors import EstopError, MachineOffError
from acquisition.linuxcnc.rsh import RshClient

CONTOUR_COLUMNS = 6


@dataclass(frozen=True)
class ContourRecording:
    """Samples of one program run: ``time_s`` from the sampler's numbering, and per axis
    (the two axes in the sampler's order) motor (joint units, mm), scale and command (mm)."""

    time_s: np.ndarray
    motor_mm: tuple[np.ndarray, np.ndarray]
    table_mm: tuple[np.ndarray, np.ndarray]
    command_mm: tuple[np.ndarray, np.ndarray]
    servo_rate_hz: float

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def since(self, i: int) -> "ContourRecording":
        """The recording from sample ``i`` on."""
        return ContourRecording(self.time_s[i:], tuple(a[i:] for a in self.motor_mm),
                                tuple(a[i:] for a in self.table_mm), tuple(a[i:] for a in self.command_mm),
                                self.servo_rate_hz)


async def _run(host: str, port: int, program_path: str, sampler: int, timeout_s: float,
               max_duration_s: float) -> ContourRecording:
    rsh = RshClient(host, port, timeout_s=timeout_s)
    await rsh.open(enable=True)
    session = hal.SamplerSession(sampler, CONTOUR_COLUMNS)
    try:
        rate = 1.0 / await asyncio.to_thread(hal.thread_period_s, f"sampler.{sampler}")
        await asyncio.to_thread(session.open, timeout_s)
        await rsh.set("mode auto")
        await rsh.set(f"open {program_path}")
        session.reader.take()
        await rsh.set("run")
        tags, vals, seen_running = [], [], False
        t0 = time.monotonic()
        while True:
            await asyncio.sleep(0.1)
            machine = (await rsh.get("machine"))[0].upper() == "ON"
            estop = (await rsh.get("estop"))[0].upper() == "ON"
            if estop:
                raise EstopError(f"LinuxCNC went to E-STOP during the contour {program_path}")
            if not machine:
                raise MachineOffError(f"LinuxCNC switched the machine off during the contour {program_path}")
            status = (await rsh.get("program_status"))[0].upper()
            t, v = session.reader.take()
            tags.append(t)
            vals.append(v)
            lost = await asyncio.to_thread(session.dropped)
            if lost:
                raise LostSamplesError(f"sampler.{sampler} dropped {lost} sample(s) during the contour",
                                       lost_samples=lost)
            if status in ("RUNNING", "PAUSED"):
                seen_running = True
            elif seen_running:
                break
            elif time.monotonic() - t0 > 3.0:
                raise ProtocolError(f"LinuxCNC did not run {program_path} (program status {status})")
            if time.monotonic() - t0 > max_duration_s:
                await rsh.set("abort")
                raise ControllerTimeoutError(f"the contour {program_path} ran longer than {max_duration_s:g} s")
    finally:
        await asyncio.to_thread(session.close)
        await rsh.close()
    c = np.concatenate(tags)
    v = np.concatenate(vals)
    return ContourRecording((c - c[0]) / rate, (v[:, 0], v[:, 3]), (v[:, 1], v[:, 4]), (v[:, 2], v[:, 5]), rate)


def record_contour(host: str, port: int, program_path: str, *, sampler: int = 2, timeout_s: float = 2.0,
                   max_duration_s: float = 120.0) -> ContourRecording:
    """Run ``program_path`` on LinuxCNC at ``host:port`` (linuxcncrsh) and record it."""
    return asyncio.run(_run(host, port, program_path, sampler, timeout_s, max_duration_s))

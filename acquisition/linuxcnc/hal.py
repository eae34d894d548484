"""LinuxCNC's HAL through its own tools: ``halcmd`` for pins and threads, ``halsampler``
for the sampler's FIFO. Both talk to the HAL of this host (its shared memory), so the
driver runs on the LinuxCNC computer, as the LinuxCNC user or root.

:class:`HalSampler` runs ``halsampler -t -c N`` and parses its lines (the sample number,
then the sampler's pins in order) in a reader thread; ``overrun`` lines (the FIFO was full
and the sampler dropped samples) are counted, never skipped.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from acquisition.errors import ControllerConnectionError, ControllerTimeoutError
from acquisition.linuxcnc.errors import HalPinError

S32 = 1 << 32


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise ControllerConnectionError(f"{name} not found: mebm's LinuxCNC driver runs on the LinuxCNC computer "
                                        "(linuxcnc-uspace installed)")
    return path


def halcmd(*args: str, timeout_s: float = 5.0) -> str:
    """``halcmd -s ARGS`` (script output); a failure to reach HAL is a connection error."""
    try:
        proc = subprocess.run([_tool("halcmd"), "-s", *args], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise ControllerTimeoutError(f"halcmd {' '.join(args)} did not answer within {timeout_s:g} s") from None
    if proc.returncode != 0:
        err = (proc.stderr or proc.stdout).strip()
        if "not found" in err:
            raise HalPinError(f"HAL: {err}", pin=args[-2] if args[0] == "setp" else args[-1])
        if "connected to a signal" in err:
            raise HalPinError(f"HAL: {err}: mebm sets it (leave it unconnected, docs/controllers.md)", pin=args[1])
        raise ControllerConnectionError(f"halcmd {' '.join(args)} failed ({err or proc.returncode}): is LinuxCNC "
                                        "(its HAL) running?")
    return proc.stdout


@dataclass(frozen=True)
class HalPin:
    """One line of ``halcmd -s show pin``."""

    name: str
    type: str
    direction: str
    signal: str | None


def show_pin(name: str) -> HalPin:
    """The pin called exactly ``name``; :class:`HalPinError` when there is none."""
    for line in halcmd("show", "pin", name).splitlines():
        w = line.split()
        if len(w) >= 5 and w[4] == name:
            return HalPin(name, w[1], w[2], w[6] if len(w) >= 7 else None)
    raise HalPinError(f"HAL has no pin {name!r}: check the pin name (halcmd show pin) in the controller URL",
                      pin=name)


def thread_period_s(function: str) -> float:
    """The period of the realtime thread that runs ``function`` (``halcmd show thread``)."""
    for line in halcmd("show", "thread").splitlines():
        w = line.split()
        if len(w) >= 5 and function in w[5:]:
            return int(w[0]) * 1e-9
    raise HalPinError(f"no HAL thread runs {function!r}: add 'addf {function} servo-thread' "
                      "(docs/controllers.md)", pin=function)


def getp(name: str) -> str:
    return halcmd("getp", name).strip()


def setp(name: str, value: str) -> None:
    halcmd("setp", name, value)


class HalSampler:
    """``halsampler -t -c CHANNEL``, its lines parsed in a thread: :meth:`take` hands over
    ``(sample numbers unwrapped, values [n, columns])`` and the overruns seen since."""

    def __init__(self, channel: int, columns: int):
        self.channel, self.columns = int(channel), int(columns)
        self._proc: subprocess.Popen | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._rows: deque = deque()
        self.overruns = 0  # 'overrun' lines: gaps in the data
        self.bad_lines = 0
        self.lines = 0
        self.eof = False
        self.stderr = ""
        self._last_tag: int | None = None
        self._wrap = 0
        self.t_last_line = time.monotonic()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def start(self) -> None:
        cmd = [_tool("halsampler"), "-t", "-c", str(self.channel)]
        stdbuf = shutil.which("stdbuf")
        if stdbuf:
            cmd = [stdbuf, "-oL", *cmd]  # a line as soon as it is read from the FIFO
        self._proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
        self._thread = threading.Thread(target=self._read, name=f"halsampler-{self.channel}", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        proc = self._proc
        for line in proc.stdout:
            self.t_last_line = time.monotonic()
            w = line.split()
            if not w:
                continue
            with self._lock:
                self.lines += 1
                if w[0] == "overrun":
                    self.overruns += 1
                    continue
                if len(w) != self.columns + 1:
                    self.bad_lines += 1
                    continue
                try:
                    tag = int(w[0])
                    vals = [float(x) for x in w[1:]]
                except ValueError:
                    self.bad_lines += 1
                    continue
                if self._last_tag is not None and tag < self._last_tag - S32 // 2:
                    self._wrap += S32  # the s32 sample number wrapped
                self._last_tag = tag
                self._rows.append((tag + self._wrap, vals))
        self.stderr = proc.stderr.read() if proc.stderr else ""
        self.eof = True

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            rows = list(self._rows)
            self._rows.clear()
        if not rows:
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.columns))
        return (np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows)),
                np.asarray([r[1] for r in rows], dtype=float))

    def wait_quiet(self, quiet_s: float, timeout_s: float) -> None:
        """Until no line came for ``quiet_s`` (the FIFO's backlog is read)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.eof or time.monotonic() - self.t_last_line >= quiet_s:
                return
            time.sleep(0.01)
        raise ControllerTimeoutError(f"halsampler -c {self.channel} still reading after {timeout_s:g} s with the "
                                     "sampler disabled: is another sampler writing to it?")

    def stop(self) -> None:
        proc, self._proc = self._proc, None
        if proc is not None:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(2.0)
        if self._thread is not None:
            self._thread.join(2.0)  # it reads to the end of the output, then stops
            self._thread = None
        if proc is not None:
            for f in (proc.stdout, proc.stderr):
                try:
                    f.close()
                except (OSError, ValueError):
                    pass


class SamplerSession:
    """A sampler read from the present servo period on: ``open()`` disables the sampler,
    starts halsampler, reads and drops the FIFO's backlog, notes the ``overruns`` pin and
    enables the sampler again; ``dropped()`` is how many samples the FIFO has dropped since
    (read after taking samples: any sample written after a drop is then counted);
    ``close()`` stops halsampler and leaves ``enable`` as it was found."""

    def __init__(self, channel: int, columns: int):
        self.channel, self.columns = int(channel), int(columns)
        self.reader: HalSampler | None = None
        self._enable_before: str | None = None
        self._overruns0 = 0

    def open(self, timeout_s: float) -> None:
        n = self.channel
        self._enable_before = getp(f"sampler.{n}.enable")
        setp(f"sampler.{n}.enable", "0")  # the backlog is read and dropped; nothing new comes in
        self.reader = HalSampler(n, self.columns)
        self.reader.start()
        self.reader.wait_quiet(0.1, 5.0)
        if self.reader.eof:
            raise ControllerConnectionError(f"halsampler -c {n} ended at once: {self.reader.stderr.strip()}")
        self.reader.take()
        self.reader.overruns = 0
        self._overruns0 = int(getp(f"sampler.{n}.overruns"))
        lines = self.reader.lines
        setp(f"sampler.{n}.enable", "1")
        end = time.monotonic() + timeout_s
        while self.reader.lines == lines:
            if time.monotonic() > end or self.reader.eof:
                raise ControllerTimeoutError(f"sampler.{n} recorded nothing in {timeout_s:g} s: is its thread "
                                             "running (LinuxCNC started)?")
            time.sleep(0.002)

    def dropped(self) -> int:
        """Samples the FIFO dropped since :meth:`open` (the pin, or halsampler's overrun lines)."""
        pin = int(getp(f"sampler.{self.channel}.overruns")) - self._overruns0
        return max(pin, self.reader.overruns if self.reader is not None else 0)

    def close(self) -> None:
        reader, self.reader = self.reader, None
        if reader is not None:
            reader.stop()
        if self._enable_before is not None:
            try:  # the sampler as it was found
                setp(f"sampler.{self.channel}.enable", "1" if self._enable_before.upper() in ("TRUE", "1") else "0")
            except Exception:  # noqa: BLE001 - closing never fails (LinuxCNC may be gone)
                pass
            self._enable_before = None

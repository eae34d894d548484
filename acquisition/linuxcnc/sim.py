"""mebm's simulated machine on a real controller: LinuxCNC with the configuration in
``sim/`` (interpreter, planner, pid loop, servo thread and sampler are LinuxCNC's; the
feed axes with their backlash are simulated in HAL by stock components, mebm_chain.hal).

:class:`LinuxcncSim` writes the configuration with its settings into a run directory
(backlash, loop closed on the motor encoder or the scale, P and FF1, a compensation
table), starts LinuxCNC headless (linuxcncrsh on ``port``) as ``user`` when run as root
(rtapi_app refuses root; HAL then runs in POSIX non-realtime mode), and stops it. The
operator's part, e-stop off and machine on, is :meth:`LinuxcncSim.power_on`: a simulated
machine only. ``mebm sim-controller linuxcnc`` and the tests use it.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from core.errors import InputError, MebmError

SIM_DIR = Path(__file__).resolve().parent / "sim"
LOOPS = ("semi", "full")
#: The HAL pins of the simulated X axis (joint 0) that mebm's driver reads.
MOTOR_PIN, SCALE_PIN = "x-motor.out", "x-scale.out"


class SimStartError(MebmError, RuntimeError):
    """The simulated LinuxCNC machine did not start (LinuxCNC missing, a port taken, a bad
    configuration); the message carries the end of LinuxCNC's own output."""


@dataclass(frozen=True)
class SimSettings:
    """The simulated machine. ``loop``: ``semi`` (pid on the motor encoder) or ``full`` (on
    the linear scale); ``p_gain_per_s``: pid P (the position loop gain K, 1/s); ``ff1``: pid
    FF1 (1: full velocity feed-forward); ``drive_tau_s``: the drive's velocity loop time
    constant; ``scale_resolution_um``: the linear scales' resolution (their reading is
    rounded to it: the quantisation is their noise); ``comp_file``: a LinuxCNC compensation
    table for joints 0 and 1 (``COMP_FILE_TYPE`` = ``comp_type``)."""

    backlash_um: float = 120.0
    loop: str = "semi"
    p_gain_per_s: float = 30.0
    ff1: float = 0.0
    drive_tau_s: float = 0.0
    scale_resolution_um: float = 0.001
    port: int = 5007
    servo_period_ns: int = 1_000_000
    comp_file: str | None = None
    comp_type: int = 1

    def __post_init__(self) -> None:
        if self.loop not in LOOPS:
            raise InputError(f"loop (={self.loop!r}) must be one of {LOOPS}")
        if not 0 <= self.backlash_um < 5000:
            raise InputError(f"backlash_um (={self.backlash_um}) must be in 0..5000")
        if not self.p_gain_per_s > 0:
            raise InputError(f"p_gain_per_s (={self.p_gain_per_s}) must be > 0")
        if not 0 <= self.ff1 <= 2:
            raise InputError(f"ff1 (={self.ff1}) must be in 0..2")
        if not 0 <= self.drive_tau_s < 1:
            raise InputError(f"drive_tau_s (={self.drive_tau_s}) must be in 0..1 s")
        if not 0.001 <= self.scale_resolution_um <= 100:
            raise InputError(f"scale_resolution_um (={self.scale_resolution_um}) must be in 0.001..100")
        if not 1 <= self.port <= 65535:
            raise InputError(f"port (={self.port}) must be 1..65535")
        if not 100_000 <= self.servo_period_ns <= 10_000_000:
            raise InputError(f"servo_period_ns (={self.servo_period_ns}) must be 100000..10000000")
        if self.comp_type not in (0, 1):
            raise InputError(f"comp_type (={self.comp_type}) must be 0 or 1")


def set_ini(text: str, section: str, key: str, value: str) -> str:
    """``text`` with ``KEY = value`` in ``[section]`` (replaced, or added at its end)."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.strip() == f"[{section}]"), None)
    if start is None:
        return text.rstrip("\n") + f"\n\n[{section}]\n{key} = {value}\n"
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    for i in range(start + 1, end):
        if re.match(rf"\s*{re.escape(key)}\s*=", lines[i]):
            lines[i] = f"{key} = {value}"
            return "\n".join(lines) + "\n"
    while end > start + 1 and not lines[end - 1].strip():
        end -= 1
    lines.insert(end, f"{key} = {value}")
    return "\n".join(lines) + "\n"


def linuxcnc_available() -> str | None:
    """None when LinuxCNC (uspace) can run here, else why not."""
    for tool in ("linuxcnc", "linuxcncrsh", "halcmd", "halsampler", "rtapi_app"):
        if shutil.which(tool) is None:
            return f"{tool} not found: install linuxcnc-uspace (apt-get install --no-install-recommends linuxcnc-uspace)"
    return None


class LinuxcncSim:
    """One simulated machine. ``run_dir``: where its configuration is written (a fresh
    temporary directory when None); ``user``: the account LinuxCNC runs as when this
    process is root."""

    def __init__(self, settings: SimSettings = SimSettings(), *, run_dir: str | Path | None = None,
                 user: str | None = None):
        self.settings = settings
        self._own_dir = run_dir is None  # a temporary directory of ours: removed by stop()
        self.run_dir = Path(run_dir) if run_dir is not None else Path(tempfile.mkdtemp(prefix="mebm-linuxcnc-"))
        self.user = user
        self.proc: subprocess.Popen | None = None
        self.log_path = self.run_dir / "linuxcnc.log"

    @property
    def url(self) -> str:
        """The driver URL of the simulated X axis (joint 0)."""
        return f"linuxcnc://127.0.0.1:{self.settings.port}?joint=0&motor_pin={MOTOR_PIN}&scale_pin={SCALE_PIN}"

    def write_config(self) -> Path:
        s = self.settings
        self.run_dir.mkdir(parents=True, exist_ok=True)
        for f in SIM_DIR.iterdir():
            if f.is_file():
                shutil.copy(f, self.run_dir / f.name)
        ini = (SIM_DIR / "mebm_sim.ini").read_text()
        half_mm = s.backlash_um / 2000.0
        ini = set_ini(ini, "DISPLAY", "DISPLAY", f"linuxcncrsh --port {s.port}")
        ini = set_ini(ini, "EMCMOT", "SERVO_PERIOD", str(s.servo_period_ns))
        ini = set_ini(ini, "MEBM_CHAIN", "BACKLASH_MM", f"{s.backlash_um / 1000.0:.6f}")
        ini = set_ini(ini, "MEBM_CHAIN", "BACKLASH_HALF_MM", f"{half_mm:.6f}")
        ini = set_ini(ini, "MEBM_CHAIN", "BACKLASH_NEG_HALF_MM", f"{-half_mm:.6f}")
        period_s = s.servo_period_ns * 1e-9
        ini = set_ini(ini, "MEBM_CHAIN", "DRIVE_GAIN", f"{period_s / (s.drive_tau_s + period_s):.6f}")
        res_mm = s.scale_resolution_um / 1000.0
        ini = set_ini(ini, "MEBM_CHAIN", "SCALE_RESOLUTION_MM", f"{res_mm:.9f}")
        ini = set_ini(ini, "MEBM_CHAIN", "SCALE_COUNTS_PER_MM", f"{1.0 / res_mm:.6f}")
        ini = set_ini(ini, "MEBM_CHAIN", "SCALE_ZERO_MM", f"{-1e6 * res_mm:.9f}")
        ini = ini.replace("HALFILE = loop_semi.hal", f"HALFILE = loop_{s.loop}.hal")
        for j in (0, 1):
            ini = set_ini(ini, f"JOINT_{j}", "P", f"{s.p_gain_per_s:g}")
            ini = set_ini(ini, f"JOINT_{j}", "FF1", f"{s.ff1:g}")
            if s.comp_file is not None:
                comp = self.run_dir / f"comp_joint{j}.txt"
                shutil.copy(s.comp_file, comp)
                ini = set_ini(ini, f"JOINT_{j}", "COMP_FILE", str(comp))
                ini = set_ini(ini, f"JOINT_{j}", "COMP_FILE_TYPE", str(s.comp_type))
        path = self.run_dir / "mebm_sim.ini"
        path.write_text(ini)
        if self.user and os.geteuid() == 0:
            shutil.chown(self.run_dir, self.user)
            for f in self.run_dir.iterdir():
                shutil.chown(f, self.user)
        return path

    def _command(self, ini: Path) -> list[str]:
        cmd = ["linuxcnc", str(ini)]
        if os.geteuid() == 0:
            if not self.user:
                raise InputError("LinuxCNC refuses to run as root (rtapi_app): name an unprivileged account for it "
                                 "(--user NAME)")
            cmd = ["runuser", "-u", self.user, "--", "env", f"HOME={self.run_dir}", *cmd]
        return cmd

    def start(self, timeout_s: float = 60.0) -> None:
        """Start LinuxCNC and wait until linuxcncrsh answers a hello."""
        why = linuxcnc_available()
        if why:
            raise SimStartError(why)
        if _answers(self.settings.port):
            raise SimStartError(f"port {self.settings.port} already answers: another LinuxCNC is running")
        try:
            ini = self.write_config()
            cmd = self._command(ini)
            with open(self.log_path, "w") as log:
                self.proc = subprocess.Popen(cmd, cwd=self.run_dir, stdout=log, stderr=subprocess.STDOUT,
                                             stdin=subprocess.DEVNULL, start_new_session=True)
        except BaseException:
            self._remove_own_dir()
            raise
        end = time.monotonic() + timeout_s
        while not _answers(self.settings.port):
            if self.proc.poll() is not None or time.monotonic() > end:
                tail = self.log_text()[-2000:]
                self.stop()  # (removes a temporary run directory: the log's end is in the message)
                raise SimStartError(f"LinuxCNC did not start (linuxcncrsh on port {self.settings.port}):\n{tail}")
            time.sleep(0.1)

    def log_text(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def rsh(self, *commands: str, timeout_s: float = 5.0) -> list[str]:
        """Send ``commands`` on an enabled linuxcncrsh session (the operator's): each reply."""
        out = []
        with socket.create_connection(("127.0.0.1", self.settings.port), timeout=timeout_s) as sock:
            f = sock.makefile("rwb")

            def line() -> str:
                while True:
                    raw = f.readline()
                    if not raw:
                        raise ConnectionError("linuxcncrsh closed the connection")
                    text = raw.decode(errors="replace").strip("\r\n ")
                    if text:
                        return text

            def send(text: str) -> None:
                f.write(text.encode() + b"\r\n")
                f.flush()

            for text in ("hello EMC sim 1.0", "set echo off"):
                send(text)
                line()
            send("set enable EMCTOO")
            send("set verbose on")
            line()
            for text in commands:
                send(text)
                out.append(line())
        return out

    def power_on(self) -> None:
        """The operator's part: e-stop off, machine on."""
        replies = self.rsh("set estop off", "set machine on")
        if any("NAK" in r for r in replies):
            raise SimStartError(f"LinuxCNC refused e-stop off / machine on: {replies}")

    def stop(self) -> None:
        """Shut LinuxCNC down (its own shutdown first, then its process group)."""
        proc, self.proc = self.proc, None
        if proc is None:
            self._remove_own_dir()
            return
        if proc.poll() is None:
            try:
                self.rsh("shutdown", timeout_s=2.0)
            except (OSError, ConnectionError):
                pass
            try:
                proc.wait(15.0)
            except subprocess.TimeoutExpired:
                pass
        for sig in (signal.SIGTERM, signal.SIGKILL):
            if proc.poll() is not None:
                break
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                proc.wait(10.0)
            except subprocess.TimeoutExpired:
                pass
        self._remove_own_dir()

    def _remove_own_dir(self) -> None:
        if self._own_dir:
            shutil.rmtree(self.run_dir, ignore_errors=True)

    def __enter__(self) -> "LinuxcncSim":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def _answers(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5) as sock:
            sock.sendall(b"hello EMC probe 1.0\r\n")
            return sock.recv(64).upper().startswith(b"HELLO ACK")
    except OSError:
        return False

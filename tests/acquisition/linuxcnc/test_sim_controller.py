"""``mebm sim-controller linuxcnc``: LinuxCNC runs until the command is stopped, and a
stopped command leaves no LinuxCNC behind (it runs in a session of its own, out of reach
of the terminal's Ctrl-C and of a signal to the command alone)."""

from __future__ import annotations

import os
import pwd
import re
import signal
import subprocess
import sys
from pathlib import Path

from acquisition.linuxcnc.sim import linuxcnc_available
from tests.acquisition.linuxcnc.rig import linuxcnc_user, one_linuxcnc_at_a_time, unavailable
from tests.ports import free_port
from tests.waiting import until

ROOT = Path(__file__).resolve().parents[3]


def _processes_naming(text: str) -> list[int]:
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if text in (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    found.append(int(d.name))
            except OSError:  # (ended meanwhile)
                pass
    return found


def test_sigterm_stops_linuxcnc_and_removes_its_configuration():
    why = linuxcnc_available()
    if why:
        unavailable(why)
    user = linuxcnc_user()
    port = free_port()  # linuxcncrsh's, not the other LinuxCNC tests' default
    cmd = [sys.executable, "-m", "api.cli", "sim-controller", "linuxcnc", "--port", str(port)]
    cmd += ["--user", user] if user else []
    with one_linuxcnc_at_a_time():
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            line = proc.stdout.readline()
            m = re.search(r"configuration in (\S+)\); mebm measure --controller '(linuxcnc://[^']+)'", line)
            assert m, line + proc.stdout.read()
            run_dir, url = Path(m.group(1)), m.group(2)
            assert url.startswith(f"linuxcnc://127.0.0.1:{port}?joint=0&motor_pin=") and run_dir.is_dir()
            assert _processes_naming(str(run_dir)), "no LinuxCNC process runs on the configuration"
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=120) == 0, proc.stdout.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert not run_dir.exists()
        # LinuxCNC's processes end with their shutdown; a deadline, not a measurement
        until(lambda: not _processes_naming(str(run_dir)) and not _users_processes(user),
              "LinuxCNC's processes to end after the command stopped", limit_s=30.0)


def _users_processes(user: str | None) -> list[int]:
    """Processes of LinuxCNC's own account (none other runs while the host lock is held)."""
    if user is None:
        return []
    uid = pwd.getpwnam(user).pw_uid
    return [int(d.name) for d in Path("/proc").iterdir() if d.name.isdigit() and _uid(d) == uid]


def _uid(d: Path) -> int | None:
    try:
        return os.stat(d).st_uid
    except OSError:
        return None

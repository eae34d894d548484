"""The scheduling of what stands for hardware in the network-namespace CANopen rigs."""

from __future__ import annotations

import os


def hardware_priority() -> str:
    """A simulated drive or CNC master stands for hardware with real-time behaviour: on a
    host shared by many it gets round-robin real-time priority where allowed (it sleeps
    between SYNCs; the kernel's RT throttling bounds it anyway). mebm runs as it would.
    Returns the scheduling it got, for the rig's report."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(10))
        return "SCHED_RR"
    except (OSError, AttributeError):
        return "normal"

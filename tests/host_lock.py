"""Host-wide turns for what the tests run that stands for hardware with timing of its own
(the real-time network-namespace rigs, LinuxCNC's one HAL): the test processes of a run take
turns through an exclusive lock on one file of the temporary directory, held for the run."""

from __future__ import annotations

import contextlib
import fcntl
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def host_lock(name: str) -> Iterator[None]:
    """Hold the host's lock ``name`` (other holders of the same name wait)."""
    with open(Path(tempfile.gettempdir()) / f"mebm-{name}.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)

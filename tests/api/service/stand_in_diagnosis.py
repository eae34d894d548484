"""A stand-in for the gap diagnosis, computed by the jobs' worker process in
test_gap_jobs.py. Its own module, importing nothing of mebm: a spawned worker imports the
module of the function it runs, and the service's gap module (core.gap, numba, scipy)
would cost every worker start seconds the tests only sit in."""

from __future__ import annotations

import os
import time


def where_am_i(folder: str, plan: dict) -> dict:
    """The runs asked for (``plan["requested"]``) say what to do: runs=99 dies the way an out-of-memory kill does: the process ends without an answer;
    runs=98 never ends by itself: it marks that it runs, then takes an hour."""
    runs = plan["requested"]
    if runs == 99:
        os._exit(137)
    if runs == 98:
        open(os.path.join(folder, "running"), "w").close()  # noqa: SIM115
        time.sleep(3600)
    return {"pid": os.getpid(), "folder": folder, "runs": runs, "nice": os.nice(0)}

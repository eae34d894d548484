"""Which SYNC a synchronous TPDO answers (CiA 301), from bus timestamps alone.

Pure: no bus, no threads, no clock. The CANopen driver feeds it every SYNC it sends
(``sync(k, t_s)``, ``k`` the running SYNC number whose low byte-ish 1..240 form is the
SYNC counter on the wire) and every TPDO it receives (``frame(t_s, payload)``), in
whatever order they reach it, and gets back ``(k, payload)`` pairs.

Two ways to pair, as CiA 301 allows:

- **By SYNC counter**: a frame that carries the counter value (1..240) of the SYNC it
  latched on is paired with the most recent SYNC of that counter value. Exact whatever
  the delay, as long as it is under 240 SYNC periods.
- **By order within the synchronous window** (object 0x1007): a synchronous PDO is sent
  within ``window_s`` after its SYNC, and the SYNC producer never sends the next SYNC
  sooner than that, so a frame belongs to the latest SYNC sent at or before its bus
  timestamp, if it lies within that SYNC's window. Frames that reach the driver out of
  order (a later frame first) still pair correctly: the pairing uses timestamps, not
  the order of arrival.

What cannot be paired is counted, never guessed: ``late`` (outside every window, or
older than the history), ``duplicates`` (a second frame for an already answered
SYNC). A SYNC left without a frame is a lost sample, seen by the caller as a gap in
the ``k`` it receives.
"""

from __future__ import annotations

import bisect
from collections import deque

from core.errors import InputError, require_positive

SYNC_COUNTER_MAX = 240  # CiA 301: the SYNC counter runs 1..240 (object 0x1019)


def sync_counter_byte(k: int) -> int:
    """The SYNC counter value (1..240) carried on the wire by SYNC number ``k`` (k >= 1)."""
    return (int(k) - 1) % SYNC_COUNTER_MAX + 1


class SyncMatcher:
    """Pairs TPDO frames with the SYNCs they answer; see the module docstring.

    ``window_s``: synchronous window length (s), at most the SYNC period.
    ``history``: how many recent SYNCs are kept for pairing late arrivals.
    """

    def __init__(self, window_s: float, *, history: int = 1024):
        self.window_s = require_positive("window_s", window_s)
        if history < 2:
            raise InputError(f"history (={history}) must be >= 2 SYNCs")
        self._t: deque[float] = deque(maxlen=history)  # SYNC bus times, non-decreasing
        self._k: deque[int] = deque(maxlen=history)
        self._answered: set[int] = set()
        self.matched = 0
        self.late = 0
        self.duplicates = 0

    def sync(self, k: int, t_s: float) -> None:
        """SYNC number ``k`` went on the bus at ``t_s`` (same clock as the frames' timestamps)."""
        if self._k and (k <= self._k[-1] or t_s < self._t[-1]):
            raise InputError(f"SYNC {k} at {t_s} s is not after SYNC {self._k[-1]} at {self._t[-1]} s")
        if len(self._k) == self._k.maxlen:
            self._answered.discard(self._k[0])
        self._t.append(float(t_s))
        self._k.append(int(k))

    def restamp(self, k: int, t_s: float) -> bool:
        """Move SYNC ``k`` to its bus timestamp ``t_s`` (its echo on the bus), when that keeps
        the SYNCs in order; ``sync()`` is given the time just before sending, which a busy
        host can make earlier than the frame's time on the wire. False if not applied."""
        for i in range(len(self._k) - 1, max(len(self._k) - SYNC_COUNTER_MAX, 0) - 1, -1):
            if self._k[i] == k:
                lo = self._t[i - 1] if i > 0 else float("-inf")
                hi = self._t[i + 1] if i + 1 < len(self._t) else float("inf")
                if lo <= t_s <= hi:
                    self._t[i] = float(t_s)
                    return True
                return False
        return False

    def frame(self, t_s: float, payload=None, *, counter: int | None = None) -> tuple[int, object] | None:
        """The SYNC this frame answers, as ``(k, payload)``; None if it cannot be paired (counted)."""
        k = self._by_counter(counter, t_s) if counter is not None else self._by_window(t_s)
        if k is None:
            self.late += 1
            return None
        if k in self._answered:
            self.duplicates += 1
            return None
        self._answered.add(k)
        self.matched += 1
        return k, payload

    def _by_window(self, t_s: float) -> int | None:
        i = bisect.bisect_right(self._t, t_s) - 1  # the latest SYNC at or before the frame
        if i < 0 or t_s - self._t[i] > self.window_s:
            return None
        return self._k[i]

    def _by_counter(self, counter: int, t_s: float) -> int | None:
        if not 1 <= counter <= SYNC_COUNTER_MAX:
            return None
        i = bisect.bisect_right(self._t, t_s) - 1
        while i >= 0:  # the most recent SYNC of that counter value sent before the frame
            if sync_counter_byte(self._k[i]) == counter:
                return self._k[i]
            i -= 1
        return None

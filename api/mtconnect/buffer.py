"""The agent's sequence-numbered ring buffer of observations, and its checkpoint.

Every observation gets the next sequence number (1, 2, 3...). The buffer keeps the
newest ``size`` of them for ``/sample``; the checkpoint keeps the newest of each
DataItem for ``/current`` (however old). ``firstSequence`` is the oldest sequence still
in the buffer, ``lastSequence`` the newest, ``nextSequence`` the one the next
observation will get (MTConnect Part 1, section 6: the agent's buffer).
"""

from __future__ import annotations

import collections
import itertools
import threading
from dataclasses import dataclass, replace

from api.mtconnect.model import Value


class OutOfRangeError(ValueError):
    """``from`` is outside firstSequence..nextSequence (an OUT_OF_RANGE error document)."""


@dataclass(frozen=True)
class Observation:
    sequence: int
    device: str  # the Device's id
    component: str  # the component's id (the Device's id for a device-level DataItem)
    v: Value


@dataclass(frozen=True)
class Window:
    """A consistent view of the buffer's sequence numbers and the observations asked for."""

    first: int
    last: int
    next: int
    observations: tuple[Observation, ...]


def _same(old: Value, new: Value) -> bool:
    """Nothing to observe: the same value at the same time; or, whatever the time, still
    UNAVAILABLE, or the same condition (a condition is reported when it changes)."""
    if old == new:
        return True
    if replace(old, timestamp=new.timestamp) != new:
        return False
    return new.value is None or new.data_item.category == "CONDITION"


class ObservationBuffer:
    def __init__(self, size: int):
        if size < 1:
            raise ValueError(f"buffer size (={size}) must be >= 1")
        self.size = size
        self._ring: collections.deque[Observation] = collections.deque(maxlen=size)
        self._current: dict[str, Observation] = {}  # DataItem id -> its newest observation
        self._next = 1
        self._lock = threading.Lock()
        self._added = threading.Condition(self._lock)

    def add(self, device: str, component: str, values: list[Value], *, only_changed: bool = True) -> int:
        """Append the values (those that differ from the DataItem's current observation in
        value, level or timestamp, unless ``only_changed`` is False); returns how many."""
        n = 0
        with self._lock:
            for v in values:
                cur = self._current.get(v.data_item.id)
                if only_changed and cur is not None and _same(cur.v, v):
                    continue
                ob = Observation(self._next, device, component, v)
                self._next += 1
                self._ring.append(ob)
                self._current[v.data_item.id] = ob
                n += 1
            if n:
                self._added.notify_all()
        return n

    def wait(self, next_sequence: int, timeout_s: float) -> bool:
        """Wait until an observation numbered ``next_sequence`` or later exists (True) or
        ``timeout_s`` passed (False)."""
        with self._added:
            return self._added.wait_for(lambda: self._next > next_sequence, timeout_s)

    def _bounds(self) -> tuple[int, int, int]:
        first = self._ring[0].sequence if self._ring else self._next
        return first, self._next - 1, self._next

    def bounds(self) -> tuple[int, int, int]:
        """(firstSequence, lastSequence, nextSequence)."""
        with self._lock:
            return self._bounds()

    def current(self) -> Window:
        with self._lock:
            first, last, nxt = self._bounds()
            obs = tuple(sorted(self._current.values(), key=lambda o: o.sequence))
        return Window(first, last, nxt, obs)

    def sample(self, start: int | None, count: int) -> Window:
        """Up to ``count`` (>= 1) observations from sequence ``start`` on (default: the
        oldest kept); the Window's ``next`` is the sequence after the last one returned."""
        with self._lock:
            first, last, nxt = self._bounds()
            start = first if start is None else start
            if not first <= start <= nxt:
                raise OutOfRangeError(f"'from' (={start}) must be greater than or equal to {first} "
                                      f"and less than or equal to {nxt}")
            offset = start - first
            obs = tuple(itertools.islice(self._ring, offset, offset + count))
        return Window(first, last, obs[-1].sequence + 1 if obs else nxt, obs)

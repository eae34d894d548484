"""The rendered figures (PNG bytes) of the REST plot endpoints and the dashboard, one
cache for both.

A figure is a function of stored results, which never change once stored, and of a few
settings (the axis' title, tasks and limit, the plotted range): :func:`api.service.figures.axis.figure_key`
names all of them, so a cached PNG is served only while every input is the one it was
drawn from, and never goes stale. Bounded: the ``size`` most recently used figures are
kept. Requests for a figure that is being drawn wait for that one drawing instead of
drawing it again: concurrent requests for one figure cost one render.

The plotted range's start (``since``) is rounded down to ``resolution_s`` (:meth:`FigureCache.snap`)
before the figure is keyed and drawn: a client cannot make every request a new render by
asking from a slightly different second, and all ``since`` within one step share one entry."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from datetime import datetime, timezone


class FigureCache:
    """The last ``size`` rendered figures, least recently used dropped first."""

    def __init__(self, size: int = 128, resolution_s: float = 3600.0):  # PNGs of 50-150 kB: at most ~20 MB
        if not resolution_s > 0:
            raise ValueError(f"resolution_s (={resolution_s}) must be > 0")
        self.size = size
        self.resolution_s = resolution_s
        self._d: OrderedDict[Hashable, bytes] = OrderedDict()
        self._lock = threading.Lock()
        self._drawing: dict[Hashable, threading.Event] = {}
        self.hits = 0
        self.misses = 0

    def snap(self, t: datetime | None) -> datetime | None:
        """``t`` rounded down to a multiple of ``resolution_s`` since the epoch (UTC; naive
        is taken as UTC); None stays None."""
        if t is None:
            return None
        aware = t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)
        epoch_s = aware.timestamp()
        snapped = epoch_s - (epoch_s % self.resolution_s)
        return datetime.fromtimestamp(snapped, tz=timezone.utc)

    def __len__(self) -> int:
        return len(self._d)

    def get(self, key: Hashable) -> bytes | None:
        with self._lock:
            png = self._d.get(key)
            if png is not None:
                self._d.move_to_end(key)
            return png

    def put(self, key: Hashable, png: bytes) -> None:
        with self._lock:
            self._d[key] = png
            self._d.move_to_end(key)
            while len(self._d) > self.size:
                self._d.popitem(last=False)

    def clear(self) -> None:
        """Drop every cached figure (a figure being drawn is still handed to its waiters)."""
        with self._lock:
            self._d.clear()

    def get_or_render(self, key: Hashable, render: Callable[[], bytes]) -> bytes:
        """The figure under ``key``, drawn by ``render()`` if no one has. While one
        request draws it, the others for the same key wait for its result (if that
        drawing fails, the next of them draws it)."""
        while True:
            with self._lock:
                png = self._d.get(key)
                if png is not None:
                    self._d.move_to_end(key)
                    self.hits += 1
                    return png
                drawing = self._drawing.get(key)
                if drawing is None:
                    drawing = self._drawing[key] = threading.Event()
                    self.misses += 1
                    break
            drawing.wait()
        try:
            png = render()
            self.put(key, png)
            return png
        finally:
            with self._lock:
                del self._drawing[key]
            drawing.set()

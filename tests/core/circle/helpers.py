"""Circles drawn from formulas (not the twin), for the figures' exact values."""

from __future__ import annotations

import numpy as np

from core.circle import CircularTest, Instrument, test_from_positions

EXACT = Instrument("trace", resolution_um=0.0, accuracy_um=0.0, name="exact")


def drawn_path(radius_mm, direction, *, n=3600, centre_um=(0.0, 0.0), ellipse_um=0.0, ellipse_deg=0.0,
               start_deg=17.0, extra=None):
    """Positions (mm) of a path r(θ) = R + e cos 2(θ - ellipse_deg) (+ extra(θ), µm) about
    ``centre_um``, sampled in the order ``direction`` runs it."""
    t = np.deg2rad(start_deg) + np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    if direction == "cw":
        t = t[::-1]
    r_um = radius_mm * 1e3 + ellipse_um * np.cos(2 * (t - np.deg2rad(ellipse_deg)))
    if extra is not None:
        r_um = r_um + extra(t)
    return (centre_um[0] + r_um * np.cos(t)) * 1e-3, (centre_um[1] + r_um * np.sin(t)) * 1e-3


def drawn_test(radius_mm=50.0, *, directions=("ccw", "cw"), instrument=EXACT, feed_mm_min=1000.0,
               **kw) -> CircularTest:
    return test_from_positions({d: drawn_path(radius_mm, d, **kw) for d in directions}, radius_mm=radius_mm,
                               feed_mm_min=feed_mm_min, plane=("x", "y"), instrument=instrument)

"""The circular test's polar plot: what it draws, checked on the figure's artists."""

from __future__ import annotations

import numpy as np
import pytest

from api.service.figures.circle import Band, SpikeMark, Summary, lsq_deviation_um, polar, polar_figure, spike_peak

R_MM = 50.0
QUADRANTS = ((0.0, "x", 9.0), (90.0, "y", 6.0), (180.0, "x", 9.0), (270.0, "y", 6.0))  # where, which axis, height


def synthetic_pass(direction: str, *, centre_um=(4.0, -3.0), radius_dev_um=2.5, level_um=0.0, seed=0):
    """A pass about the nominal circle: a circle off the nominal centre, an oval, and a spike of
    known height after each quadrant point in the direction of travel (decaying over ~2°)."""
    rng = np.random.default_rng(seed)
    a = np.linspace(0.0, 360.0, 3600, endpoint=False)
    if direction == "cw":
        a = (360.0 - a) % 360.0
    th = np.deg2rad(a)
    about_lsq = level_um + 1.5 * np.cos(2 * th) + rng.normal(0.0, 0.1, a.size)
    for q, _axis, h in QUADRANTS:
        ahead = (a - q) % 360.0 if direction == "ccw" else (q - a) % 360.0
        about_lsq = about_lsq + np.where(ahead < 15.0, h * np.exp(-ahead / 2.0), 0.0)
    radial = about_lsq + centre_um[0] * np.cos(th) + centre_um[1] * np.sin(th) + radius_dev_um
    return a, radial


def marks(predicted: dict | None = None):
    predicted = predicted if predicted is not None else {"x": (8.0, 1.2), "y": (5.0, 1.0)}
    return [SpikeMark(axis, q, d, h, 0.8, 2.0, *(predicted.get(axis) or (None, None)))
            for q, axis, h in QUADRANTS for d in ("ccw", "cw")]


def figure(*, passes=None, spikes=None, band=Band("ring-50", 20.0, 18.0), summary=None):
    passes = passes or {d: synthetic_pass(d, seed=i) for i, d in enumerate(("ccw", "cw"))}
    return polar_figure(passes, radius_mm=R_MM, feed_mm_min=2000.0, plane=("x", "y"), centre_offset_um=(4.0, -3.0),
                        mean_radius_deviation_um=2.5, spikes=marks() if spikes is None else spikes,
                        summary=summary or Summary(12.0, 11.6, 1.0, 3.0, 0.5,
                                                   {"x": "agree (E_n = 0.4)", "y": "larger (E_n = 1.8)"},
                                                   ("x: OK on ring-50",)),
                        band=band, title="vmc-850 x/y")


def by_gid(fig, gid: str):
    found = [a for a in fig.axes[0].get_children() if a.get_gid() == gid]
    assert len(found) == 1, f"{gid}: {len(found)} artists"
    return found[0]


def gids(fig) -> set[str]:
    return {a.get_gid() for a in fig.axes[0].get_children() if a.get_gid()}


def test_the_lsq_reference_removes_an_offset_circle_exactly_enough():
    """A circle of R + 7 µm centred 12 µm off the nominal centre: its exact radius about the
    nominal centre, minus the first-order correction, is the LSQ circle itself (0)."""
    cx_um, cy_um, dr_um = 12.0, -9.0, 7.0
    th = np.linspace(0, 2 * np.pi, 3601)
    x = cx_um * 1e-3 + (R_MM + dr_um * 1e-3) * np.cos(th)
    y = cy_um * 1e-3 + (R_MM + dr_um * 1e-3) * np.sin(th)
    about_nominal_um = (np.hypot(x, y) - R_MM) * 1e3
    rest = lsq_deviation_um(np.rad2deg(th), about_nominal_um, (cx_um, cy_um), dr_um)
    assert np.max(np.abs(rest)) < 0.01  # c²/2R = 2e-3 µm
    assert np.max(np.abs(about_nominal_um - dr_um)) > 10.0  # and the correction was not nothing


def test_both_directions_are_drawn_about_the_lsq_circle():
    passes = {d: synthetic_pass(d, seed=i) for i, d in enumerate(("ccw", "cw"))}
    fig = figure(passes=passes)
    for d, (a, radial) in passes.items():
        line = by_gid(fig, f"pass-{d}")
        theta, r = line.get_data()
        np.testing.assert_allclose(theta, np.deg2rad(a))  # every sample (fewer than the thinning bound)
        np.testing.assert_allclose(r, lsq_deviation_um(a, radial, (4.0, -3.0), 2.5))
    ccw, cw = by_gid(fig, "pass-ccw"), by_gid(fig, "pass-cw")
    assert ccw.get_color() != cw.get_color() and ccw.get_linestyle() != cw.get_linestyle()
    assert "counter-clockwise" in ccw.get_label() and "clockwise" in cw.get_label()
    _, r0 = by_gid(fig, "lsq-circle").get_data()
    assert np.all(r0 == 0.0)


def test_the_tolerance_band_stands_on_the_undisturbed_circle():
    level = 1.7
    passes = {d: synthetic_pass(d, seed=i, level_um=level) for i, d in enumerate(("ccw", "cw"))}
    fig = figure(passes=passes, band=Band("ring-50", 20.0, 18.0))
    verts = by_gid(fig, "tolerance-band").get_paths()[0].vertices[:, 1]
    # the undisturbed level: the median of the spikes' peaks minus their heights (the bars' feet),
    # within the synthetic level ± its oval's 1.5 µm
    feet = [by_gid(fig, f"spike-{axis}-{q:g}-{d}").get_data()[1][0] for q, axis, _ in QUADRANTS for d in ("ccw", "cw")]
    assert verts.min() == pytest.approx(np.median(feet))
    assert abs(verts.min() - level) < 1.5
    assert verts.max() - verts.min() == pytest.approx(20.0)
    _, warn = by_gid(fig, "warning-ring").get_data()
    assert warn[0] - verts.min() == pytest.approx(18.0)
    assert "ring-50" in by_gid(fig, "tolerance-band").get_label()
    # the band fits on the plot
    assert fig.axes[0].get_ylim()[1] > verts.max()


def test_no_band_without_a_judged_task():
    fig = figure(band=None)
    assert not {"tolerance-band", "warning-ring"} & gids(fig)
    assert {"pass-ccw", "pass-cw", "lsq-circle"} <= gids(fig)


def test_each_spike_is_marked_with_its_height_and_eq8_beside_it():
    fig = figure()
    for q, axis, h in QUADRANTS:
        for d in ("ccw", "cw"):
            key = f"{axis}-{q:g}-{d}"
            theta, (base, peak) = by_gid(fig, f"spike-{key}").get_data()
            assert peak - base == pytest.approx(h)  # the bar is the measured height
            # at the peak, which lies after the quadrant point in the direction of travel
            ahead = (np.rad2deg(theta[0]) - q) % 360 if d == "ccw" else (q - np.rad2deg(theta[0])) % 360
            assert ahead < 4.0
            # its foot is the synthetic circle there: no level, the oval's 1.5 cos 2θ, the noise
            assert base == pytest.approx(1.5 * np.cos(np.deg2rad(2 * q)), abs=0.5)
            predicted = {"x": 8.0, "y": 5.0}[axis]
            _, (at,) = by_gid(fig, f"eq8-{key}").get_data()
            assert at == pytest.approx(base + predicted)
            label = by_gid(fig, f"spike-label-{key}").get_text()
            assert f"{h:.1f} ± 0.8 µm" in label and f"Eq. 8: {predicted:.1f}" in label and axis in label


def test_without_a_backlash_measurement_there_is_no_eq8_mark():
    fig = figure(spikes=marks(predicted={}))
    assert not any(g.startswith("eq8-") for g in gids(fig))
    assert sum(g.startswith("spike-label-") for g in gids(fig)) == 8
    assert "Eq. 8" not in by_gid(fig, "spike-label-x-0-ccw").get_text()


def test_the_legend_side_says_g_h_and_the_verdicts():
    fig = figure()
    text = next(t for t in fig.axes[1].texts if t.get_gid() == "summary").get_text()
    assert "G (least squares) = 12.0 ± 1.0 µm" in text and "G (minimum zone) = 11.6" in text
    assert "H = 3.0 ± 0.5 µm" in text
    assert "x: agree (E_n = 0.4)" in text and "y: larger" in text and "x: OK on ring-50" in text
    labels = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert any("Eq. 8" in t for t in labels) and any("tolerance of ring-50" in t for t in labels)


def test_one_direction_has_no_hysteresis():
    a, radial = synthetic_pass("ccw")
    fig = figure(passes={"ccw": (a, radial)}, spikes=[m for m in marks() if m.direction == "ccw"],
                 summary=Summary(10.0, 9.8, 1.0))
    assert "pass-cw" not in gids(fig)
    assert sum(g.startswith("spike-x") or g.startswith("spike-y") for g in gids(fig)) == 4
    text = next(t for t in fig.axes[1].texts if t.get_gid() == "summary").get_text()
    assert "H: one direction only" in text


def test_a_long_pass_is_thinned_with_its_spikes_kept():
    a = np.linspace(0.0, 360.0, 200_000, endpoint=False)
    radial = np.zeros_like(a)
    radial[(a > 90.0) & (a < 90.01)] = 25.0  # a spike narrower than a pixel
    fig = figure(passes={"ccw": (a, radial)}, spikes=[], band=None, summary=Summary(25.0, 25.0, 1.0))
    _, r = by_gid(fig, "pass-ccw").get_data()
    assert len(r) <= 4000
    assert np.max(lsq_deviation_um(a, radial, (4.0, -3.0), 2.5)) == pytest.approx(np.max(r))


def test_spike_peak_looks_ahead_in_the_direction_of_travel():
    a = np.arange(0.0, 360.0, 0.5)
    d = np.zeros_like(a)
    d[a == 92.0] = 5.0  # after 90° for ccw travel
    d[a == 88.0] = 7.0  # after 90° for cw travel
    assert spike_peak(a, d, SpikeMark("y", 90.0, "ccw", 5.0, 0.5)) == (92.0, 5.0)
    assert spike_peak(a, d, SpikeMark("y", 90.0, "cw", 7.0, 0.5)) == (88.0, 7.0)
    assert spike_peak(a[(a < 80) | (a > 130)], d[(a < 80) | (a > 130)], SpikeMark("y", 90.0, "ccw", 5.0, 0.5)) is None


def test_it_renders_a_png():
    png = polar({d: synthetic_pass(d) for d in ("ccw", "cw")}, radius_mm=R_MM, feed_mm_min=2000.0, plane=("x", "y"),
                centre_offset_um=(4.0, -3.0), mean_radius_deviation_um=2.5, spikes=marks(),
                summary=Summary(12.0, 11.6, 1.0, 3.0, 0.5), band=Band("ring-50", 20.0, None), title="a $name$")
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20000


def test_spike_peak_is_where_the_analysis_found_it():
    a = np.arange(0.0, 360.0, 0.5)
    d = np.zeros_like(a)
    d[a == 93.0], d[a == 100.0] = 4.0, 6.0
    assert spike_peak(a, d, SpikeMark("y", 90.0, "ccw", 4.0, 0.5, peak_deg=93.1)) == (93.0, 4.0)
    assert spike_peak(a, d, SpikeMark("y", 90.0, "ccw", 6.0, 0.5, 4.0)) == (100.0, 6.0)  # 3 widths
    assert spike_peak(a, d, SpikeMark("y", 90.0, "ccw", 6.0, 0.5), window_deg=5.0) == (93.0, 4.0)
    assert spike_peak(a, d, SpikeMark("x", 0.0, "cw", 0.0, 0.5, peak_deg=359.9))[0] == 0.0  # across 360°

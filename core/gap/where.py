"""Where the nominal model's gap lies: motion phase, position, spectrum, angle, conditions.

Inputs are the nominal residuals (µm) of the runs; the result is a :class:`Where`
with one sentence and the numbers behind it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d

from core.gap.data import Contour, RoundTrip
from core.gap.report import Where
from core.gap.roundtrip import residual_periods_mm, rms, slow_and_envelope
from core.history import pearson_r

QUADRANT_WINDOW_DEG = 10.0
# A table that rattles: on a round trip, the table minus the nut travel above 20 Hz (what
# is left after a 50 ms moving mean), its 50 ms moving RMS over RATTLE_MIN_UM, on at least
# RATTLE_MIN_FRACTION of the moving samples. A backlash crossing at a reversal lasts a few
# windows; white encoder noise is 0.05-1 µm; a stick-slipping or hunting chain is tens of
# µm through whole strokes (seen: 58-71 Hz, 22-42 µm RMS).
# A rattle is a cycle: its spectrum is tonal, at least RATTLE_MIN_TONALITY of the power above
# 20 Hz within ±10 % of the dominant frequency and its first five harmonics (a stick-slip
# sawtooth or a hunting chain: 0.86-1.0). A late table latch with a timing jitter leaves
# a white error of 5-20 µm at speed, 0.05-0.24 by that measure: that is not a rattle.
RATTLE_WINDOW_S = 0.05
RATTLE_MIN_UM = 5.0
RATTLE_MIN_FRACTION = 0.2
RATTLE_MIN_TONALITY = 0.5
RATTLE_HARMONICS = 5
# A table that breaks away at rest: while the command stands still (from BREAKAWAY_SETTLE_S
# after it stopped), the table stays put for BREAKAWAY_STUCK_S (the range of its
# BREAKAWAY_HOLD_MEAN_S moving mean within a quarter of the jump threshold) and then moves
# by at least that threshold within BREAKAWAY_JUMP_S. The threshold is BREAKAWAY_MIN_UM or
# BREAKAWAY_NOISE_FACTOR times the robust spread of the table's 10 ms steps at rest, the
# larger. That is static friction above the Coulomb level: with the position loop closed on
# the table scale, the motor keeps creeping toward a table held short of its target,
# winding the chain up until it gives, and the table slips (stick-slip at standstill). A
# chain without static friction (a two-mass chain on rolling guides) follows the creeping
# motor smoothly; the stop's own transients (the servo settling, a chain ringing or hunting
# across its backlash) fall within the settling time. A finding needs BREAKAWAY_MIN_EVENTS
# still stretches with a break-away over the round trips: a machine's friction repeats.
# On generated data: found on 18 of the independent plant's 49 friction cases (mixed ones
# included), on none of its 239 others and on none of the twin's 144 (its chains do not
# break away at rest). A loop closed on the motor encoder does not creep, so no break-away
# shows there: the observation can name friction, its absence says nothing.
BREAKAWAY_SETTLE_S = 0.2
BREAKAWAY_STUCK_S = 0.03
BREAKAWAY_JUMP_S = 0.01
BREAKAWAY_HOLD_MEAN_S = 0.005  # the hold's range is taken on a 5 ms moving mean (the encoder noise averaged)
BREAKAWAY_MIN_UM = 5.0
BREAKAWAY_NOISE_FACTOR = 8.0
BREAKAWAY_MIN_EVENTS = 2
REVERSAL_MARGIN_MM = 1.0
ACCEL_FRACTION = 0.1


def moving_mask(u_mm: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the samples where the nut moves, its velocity in mm/s): faster than 5 % of the
    stroke's top speed (its 99th percentile)."""
    v = np.gradient(u_mm, t_s)
    return np.abs(v) > 0.05 * max(float(np.percentile(np.abs(v), 99)), 1e-9), v


def rt_phases(run: RoundTrip, backlash_um: float) -> np.ndarray:
    """Phase label per sample: 0 rest, 1 reversal transient, 2 acceleration, 3 constant velocity."""
    t, u = run.t_s, run.u_mm
    moving, v = moving_mask(u, t)
    cmd = run.command_mm if run.command_mm is not None else u
    acc = np.gradient(np.gradient(cmd, t), t)
    n = max(1, int(round(0.01 / run.dt_s)))
    if n > 1:
        acc = np.convolve(acc, np.ones(n) / n, mode="same")
    amax = max(float(np.percentile(np.abs(acc), 99.5)), 1e-9)
    phase = np.where(moving, np.where(np.abs(acc) > ACCEL_FRACTION * amax, 2, 3), 0)
    sign = np.sign(v) * moving
    starts = np.flatnonzero((sign[1:] != 0) & (sign[1:] != sign[:-1])) + 1
    reach = backlash_um * 1e-3 + REVERSAL_MARGIN_MM
    for s in starts:
        moved = np.abs(u[s:] - u[s])
        k = np.flatnonzero(moved >= reach)
        end = s + (int(k[0]) if k.size else moved.size)
        phase[max(s - n, 0) : end] = 1
    return phase


PHASE_NAMES = {0: "rest", 1: "reversal", 2: "acceleration", 3: "constant_velocity"}


def rattles(rts: Sequence[RoundTrip]) -> list[dict]:
    """The round trips (train and test alike) on which the table rattles against the nut:
    stick-slip, or a chain hunting across its backlash. It is an observation of the data,
    made whatever the diagnosis names: a rattle is the signature of the chain effects
    (friction, compliance) whose phase a model driven by the recorded motor cannot follow,
    so a technician is told where it is even when no candidate explains it. Per round
    trip that rattles: its file, axis, split and feed, the fraction of its moving samples
    that rattle, the median moving RMS there (µm), and the dominant frequency (Hz) and
    tonality (``RATTLE_MIN_TONALITY``) of the longest rattling stretch, and whether it rattles
    in both stroke directions (:func:`_both_directions`). The threshold is
    ``RATTLE_MIN_UM``, not a multiple of the noise floor: a rattle at tens of Hz inflates
    that estimate itself (to 5.5 µm where every stroke stick-slips)."""
    out = []
    for r in rts:
        m = (r.x_mm[r.start :] - r.u_mm[r.start :]) * 1e3
        n = int(round(RATTLE_WINDOW_S / r.dt_s))
        if n < 3 or m.size < 4 * n:
            continue
        low, mrms = slow_and_envelope(m, n)
        hp = m - low
        mov, v = moving_mask(r.u_mm[r.start :], r.t_s[r.start :])
        hot = mov & (mrms > RATTLE_MIN_UM)
        if not mov.any() or hot.sum() < RATTLE_MIN_FRACTION * mov.sum():
            continue
        # the longest run of rattling samples: its spectrum
        edges = np.flatnonzero(np.diff(np.r_[0, hot.astype(np.int8), 0]))
        i0, i1 = max(zip(edges[::2], edges[1::2]), key=lambda e: e[1] - e[0])
        seg = hp[i0:i1]
        if seg.size < 2 * n:
            continue
        power = np.abs(np.fft.rfft((seg - seg.mean()) * np.hanning(seg.size))) ** 2
        f = np.fft.rfftfreq(seg.size, r.dt_s)
        band = f >= 1.0 / RATTLE_WINDOW_S
        if not band.any() or not power[band].sum() > 0.0:
            continue
        freq = float(f[band][int(np.argmax(power[band]))])
        harm = np.zeros(f.size, bool)
        for k in range(1, RATTLE_HARMONICS + 1):
            harm |= np.abs(f - k * freq) <= 0.1 * freq
        tonality = float(power[band & harm].sum() / power[band].sum())
        if tonality < RATTLE_MIN_TONALITY:
            continue
        out.append({"file": r.file, "axis": r.axis, "split": r.split, "feed_mm_min": round(float(r.feed_mm_min), 1),
                    "fraction_of_stroke": round(float(hot.sum() / mov.sum()), 3),
                    "rms_um": round(float(np.median(mrms[hot])), 2), "frequency_hz": round(freq, 1),
                    "tonality": round(tonality, 3), "both_directions": _both_directions(hot, mov, v)})  # fmt: skip
    return out


def _both_directions(hot: np.ndarray, mov: np.ndarray, v: np.ndarray) -> bool:
    """Whether a round trip rattles in both of its stroke directions: at least
    ``RATTLE_MIN_FRACTION`` of the moving samples of each direction. Stick-slip is a forced
    relaxation cycle of a symmetric friction below its critical speed, so every slow stroke
    sticks and slips, out and back alike; a chain that hunts is a self-excited cycle that a
    stroke falls into or not depending on how it began, often in one direction only."""
    out = True
    for side in (v > 0, v < 0):
        m = mov & side
        out &= bool(m.any()) and float(hot[m].sum()) >= RATTLE_MIN_FRACTION * float(m.sum())
    return out


def stick_slips(found: Sequence[Mapping]) -> bool:
    """Whether :func:`rattles`' findings are stick-slip's: some round trip rattles, and every
    one that rattles does so in both stroke directions (:func:`_both_directions`). False for
    no rattle, and for a chain that hunts in one direction only on any round trip."""
    return bool(found) and all(f.get("both_directions", False) for f in found)


def _stroke_label(f: Mapping) -> str:
    """A finding's round trip as the observations name it, up to its feed: "rt_x_00.csv (axis x,
    train, 600 mm/min" (the caller adds what was seen and closes the parenthesis)."""
    return f"{f['file']} (axis {f['axis']}, {f['split']}, {f['feed_mm_min']:.0f} mm/min"


def rattle_sentence(found: Sequence[Mapping]) -> str:
    """One sentence on :func:`rattles`' findings (empty when there are none)."""
    if not found:
        return ""
    sides = {True: ", out and back", False: ", one direction only"}
    parts = [f"{_stroke_label(f)}: {f['rms_um']:.1f} µm RMS at {f['frequency_hz']:.0f} Hz over "
             f"{f['fraction_of_stroke'] * 100:.0f} % of the stroke{sides.get(f.get('both_directions'), '')})"
             for f in found]  # fmt: skip
    return (f"The table rattles against the nut on {len(found)} round trip(s): {'; '.join(parts)}. That is stick-slip "
            "or a chain hunting across its backlash (friction or compliance), whose cycle a model driven by the "
            "recorded motor may not follow.")


def breakaways(rts: Sequence[RoundTrip]) -> list[dict]:
    """The round trips (train and test alike) on which the table breaks away at rest: while
    the command stands still, the table held for ``BREAKAWAY_STUCK_S`` and then jumping by
    the threshold (module comment above ``BREAKAWAY_SETTLE_S``) within ``BREAKAWAY_JUMP_S``.
    Static friction above the Coulomb level, the position loop winding the chain up until it
    gives: an observation of the data, made whatever the diagnosis names. Per round trip
    with a break-away: its file, axis, split and feed, the number of still stretches with
    one (``events``), the largest jump (µm) and the threshold it was held to (µm). Empty
    unless the round trips hold ``BREAKAWAY_MIN_EVENTS`` such stretches together. A round
    trip without command columns is not looked at (its still stretches are not known)."""
    out = []
    for r in rts:
        if r.command_mm is None or r.t_s.size < 3:
            continue
        dt = r.dt_s
        nj, ns = max(1, int(round(BREAKAWAY_JUMP_S / dt))), max(1, int(round(BREAKAWAY_STUCK_S / dt)))
        still = np.abs(np.gradient(r.command_mm, r.t_s)) < 1e-9
        edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
        settle = int(round(BREAKAWAY_SETTLE_S / dt))
        # the stretches the command stands still in, after a motion, from the settling time on
        segs = [(a + settle, b) for a, b in zip(edges[::2], edges[1::2]) if a > 0 and b - a - settle > ns + nj]
        if not segs:
            continue
        x = r.x_mm * 1e3
        steps = np.concatenate([x[a + nj : b] - x[a : b - nj] for a, b in segs])
        spread = 1.4826 * float(np.median(np.abs(steps - np.median(steps))))
        jump_min = max(BREAKAWAY_MIN_UM, BREAKAWAY_NOISE_FACTOR * spread)
        jumps = []
        n_mean = max(1, int(round(BREAKAWAY_HOLD_MEAN_S / dt)))
        for a, b in segs:
            xs = x[a:b]
            held = uniform_filter1d(xs, n_mean, mode="nearest")  # the hold is judged without the encoder noise
            d = xs[nj:] - xs[:-nj]  # the table's travel over the next BREAKAWAY_JUMP_S
            for i in np.flatnonzero(np.abs(d) >= jump_min):
                if i >= ns and np.ptp(held[i - ns : i + 1]) <= 0.25 * jump_min:  # held, then it jumps
                    jumps.append(float(np.max(np.abs(d[i : i + nj]))))
                    break  # one per still stretch
        if jumps:
            out.append({"file": r.file, "axis": r.axis, "split": r.split, "feed_mm_min": round(float(r.feed_mm_min), 1),
                        "events": len(jumps), "jump_um": round(max(jumps), 1), "threshold_um": round(jump_min, 1)})  # fmt: skip
    return out if sum(f["events"] for f in out) >= BREAKAWAY_MIN_EVENTS else []


def breakaway_sentence(found: Sequence[Mapping]) -> str:
    """One sentence on :func:`breakaways`' findings (empty when there are none)."""
    if not found:
        return ""
    parts = [f"{_stroke_label(f)}: {f['events']} time(s), up to {f['jump_um']:.1f} µm)" for f in found]
    return (f"The table breaks away at rest on {len(found)} round trip(s): {'; '.join(parts)}. While the command "
            "stands still, the table stays put and then jumps within 10 ms: static friction above the Coulomb level, "
            "the position loop winding the chain up until it gives (stick-slip at standstill).")


START_UP_DEG = 20.0  # a circle that starts from rest on its data arc: its first degrees are the start-up


def _start_up_mask(c: Contour, n: int) -> np.ndarray:
    """Scored samples of a circle in its start-up transient: the first START_UP_DEG of a
    data arc entered from rest (no feed-in arc)."""
    arc = c.meta.get("data_arc") or {}
    out = np.zeros(n, bool)
    if arc.get("lead_in_deg", 1.0) > 0.5 or c.command_mm is None:
        return out
    a, b = c.axes
    k = c.scored
    cx, cy = c.meta["centre_mm"]
    th = np.degrees(np.unwrap(np.arctan2(c.command_mm[b][k] - cy, c.command_mm[a][k] - cx)))
    out[: k.size] = np.abs(th - th[0]) <= START_UP_DEG
    return out


def _sentence_conditions(rs: Mapping[str, float | None]) -> str:
    strong = [(k, r) for k, r in rs.items() if r is not None and abs(r) >= 0.7]
    if not strong:
        return ""
    k, r = max(strong, key=lambda kr: abs(kr[1]))
    name = {"feed_mm_min": "feed", "acceleration_mm_s2": "acceleration", "temperature_c": "temperature"}[k]
    return f"; per run it {'grows' if r > 0 else 'shrinks'} with {name} (r = {r:+.2f})"


def locate(
    rts: Sequence[RoundTrip], rt_resid: Sequence[np.ndarray], contours: Sequence[Contour],
    ct_resid: Sequence[np.ndarray], backlash_um: Mapping[str, float], lead_mm: Mapping[str, float],
    ka_mm: Mapping[str, float], all_runs: Sequence[tuple[object, np.ndarray]],
) -> Where:
    """Localise the test residuals (``rts``/``contours`` with their residuals) and relate
    per-run RMS to feed, acceleration and temperature over ``all_runs`` ((run, residual))."""
    details: dict = {}
    ss_rt = sum(float(np.sum(r**2)) for r in rt_resid)
    ss_ct = sum(float(np.sum(r**2)) for r in ct_resid)
    kind = "round_trip" if ss_rt >= ss_ct else (contours[0].kind if contours else "round_trip")
    conds = {}
    if len(all_runs) >= 3:
        per = np.array([rms(r) for _, r in all_runs])
        for key in ("feed_mm_min", "acceleration_mm_s2", "temperature_c"):
            # a temperature counts where a thermometer read it, not a run's stand-in
            use = np.array([key != "temperature_c" or run.temperature_measured for run, _ in all_runs])
            vals = [getattr(run, key) for (run, _), u in zip(all_runs, use) if u]
            if use.sum() >= 3 and all(v is not None for v in vals):
                conds[key] = pearson_r(np.array(vals, float), per[use])
    details["r_run_rms_vs"] = conds
    cond_text = _sentence_conditions(conds)
    phase = axis = None
    angle = None
    position = None
    if kind == "round_trip" and rts:
        by_axis: dict[str, float] = {}
        for run, r in zip(rts, rt_resid):
            by_axis[run.axis] = by_axis.get(run.axis, 0.0) + float(np.sum(r**2))
        axis = max(by_axis, key=by_axis.get)
        sel = [(run, r) for run, r in zip(rts, rt_resid) if run.axis == axis]
        ph_all = np.concatenate([rt_phases(run, backlash_um.get(axis, 0.0))[run.start :] for run, _ in sel])
        r_all = np.concatenate([r for _, r in sel])
        u_all = np.concatenate([run.u_mm[run.start :] for run, _ in sel])
        ph_rms = {PHASE_NAMES[k]: rms(r_all[ph_all == k]) for k in (1, 2, 3) if np.any(ph_all == k)}
        details["rms_by_phase_um"] = {k: round(v, 3) for k, v in ph_rms.items()}
        phase = max(ph_rms, key=ph_rms.get) if ph_rms else None
        moving = ph_all > 0
        edges = np.linspace(u_all[moving].min(), u_all[moving].max(), 21)
        idx = np.clip(np.digitize(u_all, edges) - 1, 0, 19)
        bins = np.array([rms(r_all[moving & (idx == k)]) if np.any(moving & (idx == k)) else 0.0 for k in range(20)])
        kmax = int(np.argmax(bins))
        position = float(0.5 * (edges[kmax] + edges[kmax + 1]))
        details["rms_by_position_um"] = {"position_mm": (0.5 * (edges[1:] + edges[:-1])).round(1).tolist(),
                                         "rms_um": bins.round(3).tolist()}  # fmt: skip
        periods, spec = residual_periods_mm([run for run, _ in sel], [r[run.fit_idx - run.start] for run, r in sel],
                                            lead_mm[axis], ka_mm[axis], n=1)  # fmt: skip
        dom = spec.get("dominant_period_mm")
        details["spectrum"] = spec
        match = ""
        if dom is not None and spec.get("power", 0) > 20:
            for name, base in (("screw lead", lead_mm[axis]), ("motor revolution k_a", ka_mm[axis])):
                for h in (1, 2, 3, 4):
                    if abs(dom - base / h) / (base / h) < 0.03:
                        match = f"{name}" + (f"/{h}" if h > 1 else "")
                        break
                if match:
                    break
            match = f"; its spectrum along the travel peaks at a period of {dom:.2f} mm" + (
                f" (the {match})" if match else " (not the lead or k_a: a gear or other period)")
        ratio = ph_rms.get(phase, 0.0) / max(min(ph_rms.values()), 1e-9) if ph_rms else 1.0
        summary = (
            f"round trips of axis {axis}: largest in the {phase.replace('_', ' ')} phase "
            f"(RMS {ph_rms[phase]:.2f} µm, {ratio:.1f}x the quietest phase), "
            f"largest near {position:.0f} mm of travel (binned RMS {bins[kmax]:.2f} µm vs median "
            f"{np.median(bins):.2f} µm){match}{cond_text}."
        )
    elif contours:
        by_axis: dict[str, float] = {}
        angs, rr, starts = [], [], []
        for c, r in zip(contours, ct_resid):
            if c.kind != "circle":
                continue
            angs.append(c.angle_deg())
            rr.append(r)
            starts.append(_start_up_mask(c, r.size))
        if angs:
            st = np.concatenate(starts)
            r_cat = np.concatenate(rr)
            if st.any() and (~st).any():
                rms_st, rms_else = rms(r_cat[st]), rms(r_cat[~st])
                details["rms_start_up_um"] = round(rms_st, 3)
                details["rms_after_start_up_um"] = round(rms_else, 3)
                if rms_st > 1.5 * rms_else and float(np.sum(r_cat[st] ** 2)) > 0.5 * float(np.sum(r_cat**2)):
                    summary = (
                        f"circles: in the start-up transient at the beginning of the data arc (the first "
                        f"{START_UP_DEG:g}° after a start from rest: RMS {rms_st:.2f} µm vs {rms_else:.2f} µm after "
                        f"it){cond_text}."
                    )
                    return Where(kind=kind, phase="start_up", axis=None, angle_deg=None, position_mm=None,
                                 summary=summary, details=details)  # fmt: skip
            ang = np.concatenate(angs)
            r_all = np.concatenate(rr)
            win = {}
            for q in (0.0, 90.0, 180.0, 270.0):
                d = np.abs((ang - q + 180.0) % 360.0 - 180.0)
                win[q] = rms(r_all[d <= QUADRANT_WINDOW_DEG])
            d_any = np.min([np.abs((ang - q + 180.0) % 360.0 - 180.0) for q in win], axis=0)
            rest = rms(r_all[d_any > QUADRANT_WINDOW_DEG])
            near = rms(r_all[d_any <= QUADRANT_WINDOW_DEG])
            details["rms_quadrant_windows_um"] = {f"{q:g}": round(v, 3) for q, v in win.items()}
            details["rms_elsewhere_um"] = round(rest, 3)
            a0, a1 = contours[0].axes
            first = win[0.0] ** 2 + win[180.0] ** 2
            second = win[90.0] ** 2 + win[270.0] ** 2
            if near > 1.3 * rest:
                phase = "reversal"
                axis = a0 if first >= second else a1
                angle = (0.0, 180.0) if first >= second else (90.0, 270.0)
                summary = (
                    f"circles: at the quadrant transitions where axis {axis} reverses ({angle[0]:g}° and "
                    f"{angle[1]:g}°: RMS {near:.2f} µm within ±{QUADRANT_WINDOW_DEG:g}° vs {rest:.2f} µm "
                    f"elsewhere){cond_text}."
                )
            else:
                phase = "constant_velocity"
                bins = np.linspace(0, 360, 37)
                idx = np.clip(np.digitize(ang, bins) - 1, 0, 35)
                b = np.array([rms(r_all[idx == k]) if np.any(idx == k) else 0.0 for k in range(36)])
                kmax = int(np.argmax(b))
                angle = (float(bins[kmax] + 5.0),)
                summary = (
                    f"circles: spread around the whole circle (RMS {rest:.2f} µm away from the quadrant "
                    f"transitions, {near:.2f} µm at them), largest near {angle[0]:.0f}°{cond_text}."
                )
        else:
            r_all = np.concatenate(ct_resid)
            summary = f"lines: contour error RMS {rms(r_all):.2f} µm{cond_text}."
    else:
        summary = "no test residual to localise."
    return Where(kind=kind, phase=phase, axis=axis, angle_deg=angle, position_mm=position, summary=summary,
                 details=details)  # fmt: skip

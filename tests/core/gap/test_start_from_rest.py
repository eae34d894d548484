"""A contour whose command moves at its first sample: in motion or from rest, by the encoders.

A command that moves at the first interval is either a recording begun in motion (the
axes follow it at its speed, the loop at its steady lag: the model gets a pre-roll along
the path) or a program that steps to its feed from rest (the encoders stand still while
the loop takes up its lag: the model starts from rest too). The encoders' own way over
the first samples, against the command's, tells which. Starting from rest, the model's
nut starts where the encoders put it in the backlash, also on a line, which moves each
axis one way only.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from core.gap import diagnose
from core.gap.contour import SimMemo, contour_plain_residual_um, models_for, start_side
from core.gap.data import prepare_contour, start_speed_fraction
from core.sim import AxisModel, Effects, Encoders, circle, line, simulate

ENC = Encoders(table_noise_um=0.3, motor_noise_um=0.3)
KA = 8.0
GAIN = 12.0


# -- the decision on the run's arrays ---------------------------------------------------


def _run(kind: str, start: str, rate_hz: float, noise_um: float, rng) -> Run:
    """A circle (R 40 mm) or a line (30°) at 1200 mm/min whose command moves from the
    first sample on. Both axes follow it as a proportional loop of gain GAIN along the
    path: ``start="rest"`` from standing still at the first sample (the way covered is
    v (t - (1 - e^-Kt) / K)), ``"motion"`` at the steady lag v / K."""
    v = 1200.0 / 60.0
    t = np.arange(int(2.0 * rate_hz)) / rate_hz
    s_cmd = v * t
    s_enc = v * (t - (1 - np.exp(-GAIN * t)) / GAIN) if start == "rest" else v * (t - 1.0 / GAIN)
    if kind == "circle":
        r, th0 = 40.0, math.radians(-90.0)

        def at(s):
            return np.stack([r * np.cos(th0 + s / r), r * np.sin(th0 + s / r)])

        fields = {"radius_mm": r, "centre_mm": (0.0, 0.0), "direction": "ccw", "start_angle_deg": -90.0,
                  "sweep_deg": 90.0}  # fmt: skip
    else:
        th = math.radians(30.0)

        def at(s):
            return np.stack([s * math.cos(th), s * math.sin(th)])

        fields = {"angle_deg": 30.0, "length_mm": float(s_cmd[-1]), "start_mm": (0.0, 0.0)}
    cmd, enc = at(s_cmd), at(s_enc)
    cols = {"time_s": t}
    for i, a in enumerate("xy"):
        cols[f"{a}_command_mm"] = cmd[i]
        cols[f"{a}_table_mm"] = enc[i] + rng.normal(0.0, noise_um * 1e-3, t.size)
        cols[f"{a}_motor_rev"] = (enc[i] + rng.normal(0.0, noise_um * 1e-3, t.size)) / KA
    spec = RunSpec(file=f"{kind}.csv", kind=kind, axes=("x", "y"), feed_mm_min=1200.0, temperature_c=20.0, **fields)
    return Run(spec, cols)


AXES = {a: AxisSpec(a, KA, 16.0, GAIN, (-100.0, 100.0)) for a in "xy"}


@pytest.mark.parametrize("kind", ["circle", "line"])
@pytest.mark.parametrize("rate_hz, noise_um", [(250.0, 0.3), (1000.0, 0.3), (1000.0, 0.0), (100.0, 3.0)])
def test_the_pre_roll_is_added_only_when_the_encoders_move_at_the_first_interval(kind, rate_hz, noise_um):
    rng = np.random.default_rng(5)
    for start in ("rest", "motion"):
        run = _run(kind, start, rate_hz, noise_um, rng)
        c = prepare_contour(run, "train", AXES)
        got = c.meta["start"]
        assert got["command_moves"], got
        assert got["in_motion"] == (start == "motion"), (start, got)
        if start == "motion":
            assert c.program.record_from_s > 0.5  # the pre-roll: loop time constants before the record
            assert got["encoder_fraction"] == pytest.approx(1.0, abs=0.1)
        else:
            assert c.program.record_from_s == 0.0 and c.t_s[0] == 0.0
            assert got["encoder_fraction"] < 0.4
        # the program's command at the first sample is the recorded one either way
        first = c.program.positions(np.array([c.t_s[0]]))[:, 0]
        assert first == pytest.approx([run.command_mm("x")[0], run.command_mm("y")[0]], abs=1e-9)


def test_the_start_is_read_over_a_window_that_lifts_the_commands_way_above_the_noise():
    """A slow feed sampled fast: one interval's way (1.7 µm at 100 mm/min, 1 kHz) is within
    a few noise deviations of a difference; the window grows to 20 of them (but not past
    one loop time constant), and the fraction stays near 0 from rest and 1 in motion."""
    t = np.arange(2000) / 1000.0
    v = 100.0 / 60.0
    cmd = np.stack([v * t, np.zeros_like(t)])
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.3e-3, (2, t.size))
    rest = np.stack([v * (t - (1 - np.exp(-GAIN * t)) / GAIN), np.zeros_like(t)]) + noise
    steady = np.stack([v * (t - 1.0 / GAIN), np.zeros_like(t)]) + noise
    f_rest, w_rest = start_speed_fraction(t, cmd, rest, GAIN)
    f_move, w_move = start_speed_fraction(t, cmd, steady, GAIN)
    assert f_rest < 0.2 and f_move == pytest.approx(1.0, abs=0.2)
    assert 0.002 < w_rest == w_move < 1.0 / GAIN


# -- whole diagnoses on the twin --------------------------------------------------------


def _axes():
    return {a: AxisModel(name=a, transmission_mm_per_rev=KA, screw_lead_mm=16.0, position_gain_per_s=k,
                         backlash_um=b, encoders=ENC, effects=Effects())
            for a, b, k in zip("xy", (40.0, 70.0), (12.0, 25.0))}  # fmt: skip


def _circles(start: str, rng) -> Dataset:
    """Nominal circles recorded from their first sample on, the command moving there:
    ``"rest"`` the feed commanded from the first instant with the machine at rest (no
    acceleration ramp, the data arc from the first sample), ``"motion"`` the recording
    begun on the data arc 120° into the circle, the axes already at feed."""
    ax = _axes()
    runs = []
    conds = [(40.0, 800.0, "ccw"), (60.0, 1200.0, "cw"), (20.0, 2500.0, "cw")]
    for i, (r, feed, d) in enumerate(conds):
        if start == "rest":
            prog = circle(r, (200.0, 300.0), feed, d, 30.0, 360.0, lead_in_deg=0.0, lead_out_deg=45.0)
            prog = replace(prog, record_from_s=0.0, record_to_s=prog.duration_s)
        else:
            prog = circle(r, (200.0, 300.0), feed, d, 30.0, 360.0, lead_in_deg=120.0, lead_out_deg=45.0,
                          acceleration_mm_s2=800.0)
            prog = replace(prog, record_to_s=prog.duration_s)
        tr = simulate(ax, prog, rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"circle_{i}.csv", split="test" if i == len(conds) - 1 else "train"))
    return Dataset(MachineSpec("m", {a: m.to_axis_spec((0.0, 800.0)) for a, m in ax.items()}), tuple(runs))


@pytest.mark.parametrize("start", ["rest", "motion"])
def test_a_nominal_circle_whose_command_moves_at_its_first_sample_is_none_at_the_noise_floor(start):
    ds = _circles(start, np.random.default_rng(7))
    rep = diagnose(ds)
    assert rep.effect == "none", rep.text()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um, rep.text()
    c = prepare_contour(ds.runs[0], "train", ds.machine.axes)
    assert c.meta["start"]["command_moves"]
    assert c.meta["start"]["in_motion"] == (start == "motion")


def _lines(rng) -> Dataset:
    """Nominal lines as the twin runs them: both axes step to the feed from rest, the first
    (X) axis reversely engaged (the nut on the far flank: it crosses the backlash before
    the table moves), the second (Y) directly engaged."""
    ax = _axes()
    runs = []
    for i, (ang, length, feed) in enumerate(((30.0, 60.0, 800.0), (120.0, 80.0, 1200.0), (60.0, 50.0, 2500.0))):
        tr = simulate(ax, line(ang, length, feed, (200.0, 300.0)), rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"line_{i}.csv", split="test" if i == 2 else "train"))
    return Dataset(MachineSpec("m", {a: m.to_axis_spec((0.0, 800.0)) for a, m in ax.items()}), tuple(runs))


def test_a_line_from_rest_starts_its_model_where_the_encoders_put_the_nut():
    """A line moves each axis one way: the nut's place at rest is read against the moving
    samples alone (the far flank: the backlash's width of d = table - k_a motor) and put
    in each model's own gap."""
    ds = _lines(np.random.default_rng(3))
    for run in ds.runs:
        c = prepare_contour(run, "train", ds.machine.axes)
        assert not c.meta["start"]["in_motion"] and c.program.record_from_s == 0.0
        sgn_x, delta_x = c.program.meta["rest_one_way_mm"]["x"]
        sgn_y, delta_y = c.program.meta["rest_one_way_mm"]["y"]
        assert -sgn_x * delta_x * 1e3 == pytest.approx(40.0, abs=1.5)  # X: the whole backlash to cross
        assert delta_y * 1e3 == pytest.approx(0.0, abs=1.5)  # Y: on the flank that drives it
        m = models_for(ds.machine.axes, {"x": 40.0, "y": 70.0})
        assert start_side(c.program, "x", m["x"]) == pytest.approx(-sgn_x, abs=0.08)
        assert start_side(c.program, "y", m["y"]) == pytest.approx(sgn_y, abs=0.05)
        # the nominal model with the true backlash explains the start to the noise
        res = contour_plain_residual_um(c, SimMemo().table(c, m))
        assert float(np.sqrt(np.mean(res[:25] ** 2))) < 1.0


def test_nominal_lines_stepping_to_their_feed_from_rest_are_none_at_the_noise_floor():
    ds = _lines(np.random.default_rng(7))
    rep = diagnose(ds)
    assert rep.effect == "none", rep.text()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um, rep.text()

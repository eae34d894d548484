"""A linear scale's interpolation error (a 20 µm signal period, 2 µm) on a quiet machine:
the noise floor is read where the encoders stand still, so the error does not raise it
(in motion it aliases into every sample's differences), and the cyclic family's scale
form finds the period and names it."""

import importlib

import numpy as np
import pytest

from core.gap import GapSettings, diagnose
from core.gap.data import choose_split, prepare_runs
from core.gap.families.cyclic_error import scale_period_mm
from core.sim import CyclicError, Effects, Encoders
from tests.core.gap import test_effects as te

dg = importlib.import_module("core.gap.diagnose")  # core.gap.diagnose is also the function
QUIET = Encoders(table_noise_um=0.1, motor_noise_um=0.1, table_resolution_um=0.05)
SCALE = Effects(cyclic_error=CyclicError.of((0.020, 2.0, 30.0), on="scale"))


@pytest.fixture(scope="module")
def reports():
    def run(effects):
        old, te.ENC = te.ENC, QUIET
        try:
            ds = te._round_trips(effects, np.random.default_rng(7))
        finally:
            te.ENC = old
        return ds, diagnose(ds, GapSettings(keep_curves=False, second_effect=False))

    return run(Effects()), run(SCALE)


def test_the_scale_error_is_named_cyclic_error_and_its_gap_halved(reports):
    _, (_, rep) = reports
    assert rep.effect == "cyclic_error", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    params = rep.candidates[0].params
    amp = np.hypot(params["y.scale_sin_20.000um_um"], params["y.scale_cos_20.000um_um"])
    assert amp == pytest.approx(2.0, abs=0.3), rep.text()


def test_the_floor_is_the_floor_of_the_same_machine_without_it(reports):
    (_, quiet), (_, rep) = reports
    assert rep.to_dict()["noise_floor_from"] == "rest"
    assert rep.noise_floor_um == pytest.approx(quiet.noise_floor_um, rel=0.2), (rep.noise_floor_um, quiet.noise_floor_um)
    assert rep.gap_before_um > 2.0 * rep.noise_floor_um  # not answered "within the noise"


def test_the_period_is_found_only_where_there_is_one(reports):
    (quiet_ds, _), (scale_ds, _) = reports

    def train_rts(ds):
        rts, _ = prepare_runs(ds, choose_split(ds))
        return [r for r in rts if r.split == "train"]

    assert scale_period_mm(train_rts(scale_ds)) == pytest.approx(0.020, rel=1e-3)
    assert scale_period_mm(train_rts(quiet_ds)) is None


def test_a_record_at_rest_reads_its_own_noise_while_in_motion_the_period_aliases():
    """1 kHz samples of a table at 1500 mm/min (25 µm apart) with a 20 µm, 2 µm scale
    error and 0.1 µm of noise, standing still 0.5 s at each end."""
    rng = np.random.default_rng(1)
    dt, v = 1e-3, 25.0  # s, mm/s
    t = np.arange(0.0, 5.0, dt)
    x_true = np.clip(v * (t - 0.5), 0.0, v * 4.0)
    x = x_true + 2e-3 * np.sin(2 * np.pi * x_true / 0.020) + 1e-4 * rng.standard_normal(t.size)
    moving = dg.white_level_um([x * 1e3])
    at_rest = dg.rest_level_um([dg.rest_differences_um(t, x, v * 60.0)])
    assert moving > 5 * 0.1
    assert at_rest == pytest.approx(0.1, rel=0.2)
    never_still = np.arange(0.0, 4.0, dt) * v
    assert dg.rest_level_um([dg.rest_differences_um(np.arange(0.0, 4.0, dt), never_still, v * 60.0)]) is None

"""Datasets the diagnosis cannot work on end in a clear GapError."""

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.errors import InputError
from core.gap import GapError, Split, choose_split, diagnose, prepare_runs
from core.sim import AxisModel, Encoders, round_trip, simulate

AXIS = AxisModel(name="y", backlash_um=50.0, encoders=Encoders(table_noise_um=0.2))
MACHINE = MachineSpec(id="m", axes={"y": AXIS.to_axis_spec((0.0, 200.0))})


def _rt(file, split=None, feed=1000.0, temp=20.0):
    tr = simulate({"y": AXIS}, round_trip(10.0, 60.0, feed, 500.0, 0.3), temperature_c=temp, rate_hz=200.0)
    return tr.to_run(file, split=split)


def test_gap_error_is_an_input_error():
    assert issubclass(GapError, InputError)


def test_a_single_run_is_refused():
    with pytest.raises(GapError, match="at least 2"):
        diagnose(Dataset(MACHINE, (_rt("a.csv"),)))


def test_no_test_run_is_refused():
    ds = Dataset(MACHINE, (_rt("a.csv", "train"), _rt("b.csv", "train")))
    with pytest.raises(GapError, match="no run has split 'test'"):
        diagnose(ds)


def test_an_axis_missing_from_the_machine_is_refused():
    ds = Dataset(MACHINE, (_rt("a.csv", "train"), _rt("b.csv", "test")))
    other = MachineSpec(id="m", axes={"x": replace(MACHINE.axes["y"], name="x")})
    with pytest.raises(GapError, match=r"axis 'y'.*not in machine.axes"):
        diagnose(Dataset(other, ds.runs))


def test_an_axis_without_its_screw_lead_is_refused_with_the_field_to_add():
    ds = Dataset(MACHINE, (_rt("a.csv", "train"), _rt("b.csv", "test")))
    no_lead = MachineSpec(id="m", axes={"y": replace(MACHINE.axes["y"], screw_lead_mm=None)})
    with pytest.raises(GapError, match=r"axis 'y' has no screw_lead_mm.*machine\.axes\.y in dataset\.json"):
        diagnose(Dataset(no_lead, ds.runs))


def test_a_test_axis_without_train_runs_is_refused():
    ax = AxisModel(name="x", backlash_um=30.0)
    m = MachineSpec(id="m", axes={"y": MACHINE.axes["y"], "x": ax.to_axis_spec((0.0, 200.0))})
    tr = simulate({"x": ax}, round_trip(10.0, 60.0, 1000.0, 500.0, 0.3, axis="x"), rate_hz=200.0)
    ds = Dataset(m, (_rt("a.csv", "train"), _rt("b.csv", "test"), tr.to_run("c.csv", split="test")))
    with pytest.raises(GapError, match="no train round trip of that axis"):
        diagnose(ds)


def test_split_without_fields_holds_out_whole_runs_at_the_extreme_temperature():
    runs = tuple(_rt(f"r{i}.csv", temp=t) for i, t in enumerate((18.0, 20.0, 22.0, 31.0)))
    sp = choose_split(Dataset(MACHINE, runs))
    assert sp.test == ("r3.csv",)
    assert set(sp.train) == {"r0.csv", "r1.csv", "r2.csv"}
    assert "temperature" in sp.how and "31" in sp.how


def test_split_without_fields_falls_back_to_the_extreme_feed():
    runs = tuple(_rt(f"r{i}.csv", feed=f) for i, f in enumerate((800.0, 1000.0, 1200.0, 3000.0)))
    sp = choose_split(Dataset(MACHINE, runs))
    assert sp.test == ("r3.csv",) and "feed" in sp.how


def test_prepare_runs_marks_each_run_by_the_split_it_is_given_or_chooses():
    runs = tuple(_rt(f"r{i}.csv", feed=f) for i, f in enumerate((800.0, 1000.0, 1200.0, 3000.0)))
    ds = Dataset(MACHINE, runs)
    rts, cts = prepare_runs(ds)
    assert cts == [] and [r.file for r in rts] == [f"r{i}.csv" for i in range(4)]
    assert [r.split for r in rts] == ["train", "train", "train", "test"]  # choose_split's: the extreme feed
    assert {r.axis for r in rts} == {"y"}
    rts, _ = prepare_runs(ds, Split(("r1.csv", "r2.csv", "r3.csv"), ("r0.csv",), "given"))
    assert [r.split for r in rts] == ["test", "train", "train", "train"]


def test_pure_noise_dataset_is_none_and_the_json_follows_the_contract():
    rng = np.random.default_rng(3)
    runs = []
    for i, (f, t) in enumerate(((600.0, 18.0), (900.0, 20.0), (1200.0, 22.0), (2500.0, 30.0))):
        tr = simulate({"y": AXIS}, round_trip(10.0, 90.0, f, 500.0, 0.3), temperature_c=t, rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"r{i}.csv", split="test" if i == 3 else "train"))
    rep = diagnose(Dataset(MACHINE, tuple(runs)))
    assert rep.effect == "none"
    d = rep.to_dict()
    assert d["format"] == "mebm-gap/1"
    for key in ("effect", "where", "gap_before_um", "gap_after_um", "split", "candidates"):
        assert key in d
    for key in ("kind", "phase", "axis", "angle_deg", "position_mm", "summary"):
        assert key in d["where"]
    assert d["split"] == {"train": ["r0.csv", "r1.csv", "r2.csv"], "test": ["r3.csv"], "how": d["split"]["how"]}
    assert d["gap_after_um"] == d["gap_before_um"]
    assert {c["effect"] for c in d["candidates"]} >= {"none", "thermal", "friction", "servo_dynamics"}
    servo = next(c for c in d["candidates"] if c["effect"] == "servo_dynamics")
    assert servo["identifiable"] is False and "not identifiable from round trips" in servo["notes"]
    assert abs(rep.gap_before_um - rep.noise_floor_um) < 0.5 * rep.noise_floor_um
    assert "Diagnosis: none" in rep.text()
    _every_added_key_is_documented(d)


SPEC_KEYS = {"format", "effect", "where", "gap_before_um", "gap_after_um", "split", "candidates"}


def _every_added_key_is_documented(d: dict) -> None:
    """The keys the JSON adds to the spec's required ones are named in docs/gap-diagnosis.md
    §7 (the shared spec is read-only here and lists none of them)."""
    doc = (Path(__file__).resolve().parents[3] / "docs" / "gap-diagnosis.md").read_text(encoding="utf-8")
    m = re.search(r"^## 7\. The JSON.*?(?=^## )", doc, re.M | re.S)
    assert m, "docs/gap-diagnosis.md has no section '## 7. The JSON'"
    named = set(re.findall(r"`([a-z_]+)`", m.group(0)))
    added = (set(d) - SPEC_KEYS) | {"how"} | {"details"} | set(d["where"]["details"]) | set(d["thresholds"])
    added |= {k for c in d["candidates"] + d["pairs"] for k in c} - {"effect", "gap_after_um", "params"}
    added |= {k for f in d["where"]["details"]["rattle"] + d["where"]["details"]["breakaway"] for k in f}
    assert set(d["split"]) == {"train", "test", "how"} and {"rattle", "breakaway"} <= set(d["where"]["details"])
    assert not added - named, f"keys of the gap JSON not in docs/gap-diagnosis.md §7: {sorted(added - named)}"

import json

import pytest

from api.cli.main import main
from storage.dataset import read_dataset


def test_demo_reproduces_the_papers_verdict(capsys):
    # June 7th: b̄ 239.5 µm -> TBE 45.47 µm > 45 µm: restore below 236.0 µm
    assert main(["demo", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["round_trip"]["backlash_mean_um"] == pytest.approx(239.5, abs=0.5)
    assert d["decision"]["state"] == "ALARM"
    assert d["decision"]["backlash_limit_um"] == pytest.approx(236.0, abs=0.1)
    assert d["decision"]["tasks"][0]["tbe_um"] == pytest.approx(45.47, abs=0.1)


def test_demo_below_the_limit_is_ok_and_writes_a_dataset(tmp_path, capsys):
    assert main(["demo", "--backlash-um", "180", "--out", str(tmp_path / "ds")]) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].startswith("OK: mean backlash 180.0 µm")
    assert "travel variation within 300 mm v_300 (µm)" in out and "mean travel deviation e_p (µm/1000 mm)" in out
    ds = read_dataset(tmp_path / "ds")
    assert [r.spec.kind for r in ds.runs] == ["round_trip"]
    assert main(["analyze", str(tmp_path / "ds"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["backlash_mean_um"] == pytest.approx(180.0, abs=0.5)

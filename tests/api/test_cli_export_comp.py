"""``mebm export-comp``: a dataset run to a controller's table file, errors in one line."""

from __future__ import annotations

import numpy as np
import pytest

from api.cli.main import main
from core.dataset import Dataset, MachineSpec
from storage.dataset import write_dataset
from tests.api.service.comp_twin import AXIS, TRAVEL_MM, read_linuxcnc, simulate_round_trip, truth_um


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("comp") / "twin"
    run = simulate_round_trip().to_run("rt_y_00.csv")
    write_dataset(folder, Dataset(MachineSpec("twin", {"y": AXIS.to_axis_spec(TRAVEL_MM)}), (run,)))
    return folder


def test_writes_a_linuxcnc_table_that_reproduces_the_twin(dataset, tmp_path, capsys):
    out = tmp_path / "y.comp"
    code = main(["export-comp", str(dataset), "--run", "rt_y_00.csv", "--format", "linuxcnc", "--comp-type", "0",
                 "--step-mm", "10", "--joint", "1", "--reference-mm", "0", "--out", str(out)])
    said = capsys.readouterr().out
    assert code == 0 and f"wrote {out}" in said and "31 points" in said
    nom, fwd, rev = read_linuxcnc(out.read_text(), 0)
    t_fwd, t_rev = truth_um(nom, reference_mm=0.0)
    assert nom.size == 31 and np.max(np.abs(fwd - t_fwd)) < 0.5 and np.max(np.abs(rev - t_rev)) < 0.5


def test_csv_to_standard_output(dataset, capsys):
    assert main(["export-comp", str(dataset), "--run", "rt_y_00.csv", "--format", "csv"]) == 0
    out = capsys.readouterr().out
    assert "position_mm,forward_um,reverse_um,backlash_um" in out and "mean backlash b =" in out


@pytest.mark.parametrize(("argv", "message"), [
    (["--run", "nope.csv", "--format", "csv"], "no run 'nope.csv'"),
    (["--run", "rt_y_00.csv", "--format", "csv", "--step-mm", "0"], "step_mm"),
    (["--run", "rt_y_00.csv", "--format", "csv", "--loop-encoder", "table"], "linear scale"),
])
def test_errors_are_one_line_and_non_zero(dataset, capsys, argv, message):
    code = main(["export-comp", str(dataset), *argv])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("mebm export-comp: error:") and message in err
    assert err.count("\n") == 1

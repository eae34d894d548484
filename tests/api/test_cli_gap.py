"""``mebm gap diagnose`` and ``mebm gap benchmark`` end to end."""

import json
import re

import numpy as np
import pytest

from api.cli.main import main
from core.dataset import Dataset, MachineSpec
from core.sim import AxisModel, CyclicError, Effects, Encoders, round_trip, simulate
from storage.dataset import write_dataset


def _dataset(tmp_path, n_runs=4):
    axis = AxisModel(name="y", backlash_um=50.0, encoders=Encoders(table_noise_um=0.2),
                     effects=Effects(cyclic_error=CyclicError.of((16.0, 4.0, 0.0))))
    rng = np.random.default_rng(1)
    runs = []
    for i, (feed, temp) in enumerate(((600.0, 18.0), (1000.0, 20.0), (1400.0, 22.0), (2400.0, 30.0))[:n_runs]):
        tr = simulate({"y": axis}, round_trip(10.0 + 10 * i, 110.0 + 10 * i, feed, 600.0, 0.3), temperature_c=temp,
                      rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"rt_{i}.csv", split=("test" if i == 3 else "train") if n_runs > 1 else None))
    folder = tmp_path / "ds"
    write_dataset(folder, Dataset(MachineSpec("cli", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs)))
    return folder


def test_diagnose_prints_the_report_and_writes_json_and_plots(tmp_path, capsys):
    folder = _dataset(tmp_path)
    out = tmp_path / "gap.json"
    plots = tmp_path / "plots"
    assert main(["gap", "diagnose", str(folder), "--json", str(out), "--plots", str(plots)]) == 0
    text = capsys.readouterr().out
    assert "Diagnosis: cyclic_error" in text
    assert "effect" in text and "gap after (µm)" in text
    doc = json.loads(out.read_text())
    assert doc["format"] == "mebm-gap/1" and doc["effect"] == "cyclic_error"
    assert doc["gap_after_um"] < 0.5 * doc["gap_before_um"]
    assert doc["split"]["test"] == ["rt_3.csv"]
    assert sorted(p.name for p in plots.iterdir()) == ["gap_rt_3.png"]


def test_diagnose_json_to_stdout_is_only_json(tmp_path, capsys):
    folder = _dataset(tmp_path)
    assert main(["gap", "diagnose", str(folder), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["format"] == "mebm-gap/1"


def test_a_single_run_is_one_error_line_and_a_failure_code(tmp_path, capsys):
    folder = _dataset(tmp_path, n_runs=1)
    assert main(["gap", "diagnose", str(folder)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mebm gap: error:") and "at least 2" in err[0]


def _assert_prints_the_confusion_matrix_and_scores(text: str, plant: str) -> None:
    assert f"plant {plant}" in text
    assert "confusion matrix" in text and "named correctly" in text and "median gap_after/gap_before" in text
    assert "second effect recall" in text and "within 2x the noise floor" in text


def test_benchmark_prints_the_confusion_matrix_and_scores(tmp_path, capsys):
    """The independent plant's benchmark (the twin's: the test of ``--only`` below)."""
    plant = "independent"
    out = tmp_path / "bench.json"
    assert main(["gap", "benchmark", "--cases", "1", "--seed", "4", "--small", "--plant", plant,
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    _assert_prints_the_confusion_matrix_and_scores(text, plant)
    doc = json.loads(out.read_text())
    assert doc["n_cases"] == 1 and len(doc["cases"]) == 1 and doc["plant"] == plant
    assert doc["cases"][0]["label"] in doc["confusion"]


def test_benchmark_labels_are_balanced_and_a_quarter_mixed():
    from core.gap_benchmark import LABELS, labels_for

    labs = labels_for(48, np.random.default_rng(3))
    assert sum(1 for x in labs if not x) == 48 // len(LABELS)  # every label equally often
    mixed = [x for x in labs if len(x) == 2]
    assert len(mixed) == 12 and all(a != b and "none" not in x for x in mixed for a, b in [x])


@pytest.mark.parametrize("cases", ["0", "-3"])
def test_benchmark_refuses_no_cases(cases, capsys):
    assert main(["gap", "benchmark", "--cases", cases]) != 0
    assert "--cases" in capsys.readouterr().err


def test_benchmark_reports_effect_cases_the_data_did_not_show_beside_the_score():
    from api.cli.gap import format_summary
    from core.gap_benchmark import BenchmarkResult, CaseResult

    def case(i, labels, diagnosed, before, noise=0.4):
        return CaseResult(i, "+".join(labels) or "none", diagnosed, before, before, noise, 1.0, "", labels)

    res = BenchmarkResult((case(0, (), "none", 0.5), case(1, ("friction",), "none", 0.7),  # hidden: 0.7 <= 0.8
                           case(2, ("thermal",), "thermal", 9.0), case(3, ("compliance",), "none", 5.0)), 7)
    assert [c.index for c in res.hidden_effect_cases()] == [1]
    assert res.fraction_correct == 0.5  # the headline keeps every case
    assert res.fraction_correct_visible() == pytest.approx(2 / 3)
    text = format_summary(res)
    assert "did not show): 1; named correctly without them: 2/3 = 66.7 %" in text
    assert res.to_dict()["effect_cases_within_2x_noise"] == 1
    assert "answers with a candidate not told apart from them: 0; of them wrong: 0" in text


def test_benchmark_counts_answers_that_came_with_a_close_alternative():
    from api.cli.gap import format_summary
    from core.gap_benchmark import BenchmarkResult, CaseResult

    def case(i, labels, diagnosed, alternatives):
        return CaseResult(i, "+".join(labels), diagnosed, 20.0, 10.0, 0.4, 1.0, "", labels, (diagnosed,),
                          close_alternatives=alternatives)

    res = BenchmarkResult((case(0, ("compliance",), "compliance", ("friction",)),  # right, close call
                           case(1, ("friction",), "compliance", ("friction",)),  # wrong, the truth was close
                           case(2, ("friction",), "compliance", ("thermal",)),  # wrong, the truth was not
                           case(3, ("thermal",), "thermal", ())), 7)
    assert res.close_alternative_cases == (3, 2, 1)
    assert res.to_dict()["close_alternative_cases"] == [3, 2, 1]
    assert "answers with a candidate not told apart from them: 3; of them wrong: 2, with an injected effect " \
           "among those candidates: 1" in format_summary(res)


def test_a_case_whose_diagnosis_raises_is_scored_wrong_not_a_stopped_benchmark(monkeypatch):
    import importlib

    from core.gap_benchmark import SMALL, diagnose_case

    dg = importlib.import_module("core.gap.diagnose")  # the module (core.gap.diagnose is also the function)

    def boom(*a, **k):
        raise ValueError("array must not contain infs or NaNs")

    monkeypatch.setattr(dg, "diagnose", boom)
    res = diagnose_case((0, ("thermal",), 5, SMALL, "twin", True, None))
    assert res.diagnosed == "error" and not res.correct and "infs or NaNs" in res.axis


def test_one_case_of_a_benchmark_again_and_its_dataset_written(tmp_path, capsys):
    """--only re-runs a case of a draw with the data of the whole run (case 3 of seed 4's
    three is a `none` case: a quick diagnosis); --write-datasets leaves it as a dataset
    folder that `mebm gap diagnose` reads, with truth.json beside it, written by the worker
    process that generated it (--jobs 2). The twin's summary is printed as the
    independent plant's is (the confusion matrix and the scores)."""
    from core.gap_benchmark import SMALL, benchmark_case, run_benchmark

    out = tmp_path / "bench.json"
    assert main(["gap", "benchmark", "--cases", "3", "--seed", "4", "--small", "--plant", "twin", "--only", "3",
                 "--write-datasets", str(tmp_path / "cases"), "--json", str(out), "--jobs", "2"]) == 0
    text = capsys.readouterr().out
    assert [line.split(":")[0] for line in text.splitlines() if line.startswith("twin case")] == ["twin case   3/3"]
    assert "only cases 3 of the 3 drawn from seed 4" in text
    _assert_prints_the_confusion_matrix_and_scores(text, "twin")
    doc = json.loads(out.read_text())
    assert doc["plant"] == "twin" and doc["n_cases"] == 1
    (case,) = doc["cases"]
    assert case["label"] in doc["confusion"]
    assert case["index"] == 2 and case["labels"] == []
    # the same data as in the whole run: the written dataset is the benchmark's case
    folder = tmp_path / "cases" / "twin-seed4-case003"
    truth = json.loads((folder / "truth.json").read_text())
    assert truth["labels"] == [] and truth["case"] == 3 and truth["seed"] == 4
    labs, ds, _ = benchmark_case("twin", 3, 4, 2, SMALL)
    assert labs == ()
    from storage.dataset import read_dataset

    back = read_dataset(folder)
    assert [r.spec.file for r in back.runs] == [r.spec.file for r in ds.runs]
    for r0, r1 in zip(ds.runs, back.runs):
        for col, v in r0.columns.items():
            np.testing.assert_allclose(r1.columns[col], v, rtol=0, atol=1e-6)
    assert main(["gap", "diagnose", str(folder), "--json", "-"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["effect"] == "none"
    assert doc["gap_before_um"] == pytest.approx(case["gap_before_um"], rel=0.01)
    # the case's JSON keeps every candidate's and pair's test gap and the decision, as the
    # diagnosis of the written dataset gives them (figures masked: the CSV rounds to 1 nm)
    assert set(case["candidate_gaps_um"]) == {c["effect"] for c in doc["candidates"]} and len(doc["candidates"]) > 1
    for c in doc["candidates"]:
        assert case["candidate_gaps_um"][c["effect"]] == pytest.approx(c["gap_after_um"], rel=0.01)
    assert case["pair_gaps_um"] == pytest.approx({p["effect"]: p["gap_after_um"] for p in doc["pairs"]}, rel=0.01)

    def masked(text):
        return re.sub(r"\d+(\.\d+)?", "#", text)

    assert case["decision"] and masked(case["decision"]) == masked(doc["decision"])
    assert case["close_alternatives"] == [a["effect"] for a in doc["close_alternatives"]]
    # a case outside the draw is refused by run_benchmark itself too, not only by the CLI
    with pytest.raises(ValueError, match="only"):
        run_benchmark(3, 4, SMALL, only=[3])


def test_a_kept_dataset_is_the_one_diagnosed_and_generated_once(monkeypatch):
    """The harness, not the diagnosis: the diagnosis is a recorder here (what it makes of
    a benchmark case is tested by the other tests of this file and in tests/core/gap)."""
    import importlib

    bm = importlib.import_module("core.gap_benchmark")
    dg = importlib.import_module("core.gap.diagnose")  # the module (core.gap.diagnose is also the function)
    made, kept, diagnosed = [], [], []
    real = bm._plant_case

    def counted(*a, **k):
        out = real(*a, **k)
        made.append(out[0])
        return out

    def recorded(ds, *a, **k):
        diagnosed.append(ds)
        raise ValueError("recorded, not diagnosed")

    monkeypatch.setattr(bm, "_plant_case", counted)
    monkeypatch.setattr(dg, "diagnose", recorded)
    res = bm.run_benchmark(3, 4, bm.SMALL, only=[2], keep_dataset=lambda i, labs, ds, truth: kept.append((i, labs, ds)))
    assert len(made) == 1 and [(i, labs) for i, labs, _ in kept] == [(2, ())]
    assert kept[0][2] is made[0] and len(diagnosed) == 1 and diagnosed[0] is made[0]
    assert res.cases[0].index == 2 and res.cases[0].diagnosed == "error"


@pytest.mark.parametrize("only", ["0", "4", "x", ","])
def test_benchmark_refuses_cases_it_did_not_draw(only, capsys):
    assert main(["gap", "benchmark", "--cases", "3", "--only", only]) != 0
    assert "--only" in capsys.readouterr().err

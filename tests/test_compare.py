"""`wiloc compare` and `wiloc report` over several results files: problems named by the run they concern."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import ends_in_one_error
from test_cli_output import OUTPUT_SCHEMA
from test_evaluate_frames import UNCOVERED
from test_results_order import MAP_RUN, _edited, _halves_swapped, _write_run
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.decisions import Decisions
from wiloc.errors import WilocError
from wiloc.evaluation.results import make_results, read_results, write_results
from wiloc.evaluation.results_header import ResultsHeader

runner = CliRunner()


def _run(path: Path, queries: int) -> Path:
    """A threshold run of ``queries`` frames q0, q1, ... against the map frames r0, r1, r2, each
    matched to its own place."""
    decisions = Decisions(match=np.arange(queries) % 3, difference=np.full(queries, 0.2),
                          confidence=np.full(queries, 0.8), stage=np.full(queries, "update"))
    header = ResultsHeader(method="threshold", descriptor="sad", query=str(path.parent / path.stem), map="/r")
    write_results(path, make_results(decisions, query_names=[f"q{i}" for i in range(queries)],
                                     ref_names=["r0", "r1", "r2"], header=header))
    return path


@pytest.fixture
def runs(tmp_path: Path) -> list[Path]:
    """Two runs against one map of 3 frames, of 3 and of 2 query frames, and a 3 x 3 mask fitting the first."""
    np.save(tmp_path / "gt.npy", np.eye(3))
    return [_run(tmp_path / "a" / "day.csv", 3), _run(tmp_path / "b" / "day.csv", 2)]


def test_a_ground_truth_matrix_that_does_not_fit_a_run_names_the_run(runs: list[Path], tmp_path: Path) -> None:
    """With several runs, 'matrix is 3 x 3, expected 2 x 3' did not say which run it does not fit."""
    gt = tmp_path / "gt.npy"
    source = api.TruthSource(kind="matrix", path=gt)
    assert api.evaluate(runs[0], source).summary.frames == 3
    with pytest.raises(WilocError, match=rf"{gt}: does not fit the run {runs[1]}: matrix is 3 x 3, expected 2 x 3 "
                                         r"\(query x reference frames\)"):
        api.compare(runs, source)
    with pytest.raises(WilocError, match=r"does not fit the run in memory \(query .*b[/\\]day, method threshold\): "
                                         "matrix is 3 x 3, expected 2 x 3"):
        api.compare([read_results(path) for path in runs], source)


@pytest.mark.parametrize("command", ["compare", "report"])
def test_compare_and_report_name_the_run_a_ground_truth_does_not_fit(command: str, runs: list[Path],
                                                                      tmp_path: Path) -> None:
    gt = tmp_path / "gt.npy"
    page = ["-o", str(tmp_path / "page.html")] if command == "report" else []
    result = runner.invoke(app, [command, *map(str, runs), "--gt", f"matrix:{gt}", *page])
    ends_in_one_error(result, 1, f"{gt}: does not fit the run {runs[1]}: matrix is 3 x 3, expected 2 x 3")
    assert not (tmp_path / "page.html").exists()


def test_a_run_of_no_frames_is_said_to_hold_none(tmp_path: Path) -> None:
    """A results file of no rows (a followed run that has decided nothing yet, an edit) was said
    not to fit the ground truth: 'none of the 0 query frames has a reference frame of the same name'."""
    empty = _run(tmp_path / "empty.csv", 0)
    for args in (["evaluate", empty], ["compare", empty, _run(tmp_path / "day.csv", 3)]):
        ends_in_one_error(runner.invoke(app, list(map(str, args))), 1, f"{empty}: holds no rows: there is no frame to score")
    with pytest.raises(WilocError, match=r"^the run in memory \(query .*empty, method threshold\) holds no frames"):
        api.evaluate(read_results(empty), api.TruthSource())


def test_compare_json_gives_each_run_its_truth_warnings_as_evaluate_does(tmp_path: Path) -> None:
    """compare's --json runs had no ``truth_warnings``: a warning about one run's ground truth (its
    last three frames have none) was in ``warnings`` alone, where evaluate's run holds its own."""
    covered = _write_run(tmp_path / "a" / "walk-sad-online.csv", MAP_RUN)
    uncovered = _write_run(tmp_path / "b" / "walk-sad-online.csv", MAP_RUN, UNCOVERED)
    gt = ["--gt", "aligned", "--tolerance", "0"]
    result = runner.invoke(app, ["compare", str(covered), str(uncovered), *gt, "--json"])
    assert result.exit_code == 0, result.output
    shown = json.loads(result.stdout)
    OUTPUT_SCHEMA.validate(shown)
    evaluated = runner.invoke(app, ["evaluate", str(uncovered), *gt, "--json"])
    expected = json.loads(evaluated.stdout)["runs"][0]["truth_warnings"]
    assert [run["truth_warnings"] for run in shown["runs"]] == [[], expected]
    assert expected and [f"warning: {uncovered}: {line}" for line in expected] == shown["warnings"]


def test_compare_warns_of_rows_out_of_their_runs_order_naming_the_file(tmp_path: Path) -> None:
    """A run whose rows were moved is scored in its run's order, and compare says so of that file."""
    written = _write_run(tmp_path / "walk-sad-online.csv", MAP_RUN)
    shuffled = _edited(written, _halves_swapped, "shuffled.csv")
    result = runner.invoke(app, ["compare", str(shuffled), "--gt", "aligned:index", "--tolerance", "0"])
    assert result.exit_code == 0, result.output
    (line,) = [line for line in result.stderr.splitlines() if "rows are out of their run's order" in line]
    assert line.startswith(f"warning {shuffled}: 12 of 12 rows are out of their run's order"), line


def test_table2_marks_no_worst_traversal_where_no_threshold_reaches_the_precision(tmp_path: Path) -> None:
    """Where no global threshold reaches a target precision (a run's most confident match is
    wrong, so 100 % is out of reach), every traversal's recall is 0 and none is the worst."""
    def most_confident_wrong(rows: list[str]) -> list[str]:  # frame 2's match is wrong: make it the surest
        cells = rows[2].split(",")
        return [*rows[:2], ",".join([*cells[:3], "0.99", *cells[4:]]), *rows[3:]]

    runs = [_edited(_write_run(tmp_path / f"{walk}.csv", replace(MAP_RUN, query=f"/data/{walk}")),
                    most_confident_wrong, f"{walk}-top-wrong.csv") for walk in ("walk", "other")]
    comparison = api.compare(runs, api.TruthSource(kind="aligned", tolerance=0), precisions=[100.0, 50.0])
    unmet = comparison.table2[comparison.table2["precision"] == 100.0]
    assert len(unmet) == 2 and unmet["threshold"].isna().all() and not unmet["worst"].any()
    assert comparison.table2[comparison.table2["precision"] == 50.0]["worst"].sum() == 1

"""Recall@K as place recognition reports it: each frame's K best-ranked map frames, kept in the
results file by methods that rank the map, scored under the same ground truth as R@1."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import places, write_traversal
from typer.testing import CliRunner

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.candidates import RANKED, best_candidates
from wiloc.cli import app
from wiloc.decisions import Decisions
from wiloc.evaluation.metrics import recall_at_k, summarize
from wiloc.evaluation.results import make_results, read_results, write_results
from wiloc.evaluation.results_header import ResultsHeader
from wiloc.evaluation.truth_source import TruthSource

runner = CliRunner()
REF = [f"f{i:02d}.png" for i in range(30)]
QUERY = ["f05.png", "f10.png", "f15.png", "f20.png", "new.png"]  # new.png: a place absent from the map


def _ranking() -> np.ndarray:
    """By construction, with +-2 frames of tolerance: f05 right at rank 1, f10 at rank 3, f15 at
    rank 7, f20 not among its 10; new.png has no true match whatever it ranks."""
    return np.array([[5, 0, 1, 2, 26, 27, 28, 29, 24, 25],
                     [20, 21, 9, 0, 1, 2, 3, 4, 5, 6],
                     [0, 1, 2, 3, 4, 5, 16, 27, 28, 29],
                     [0, 1, 2, 3, 4, 5, 6, 7, 8, 9],
                     [29, 28, 27, 26, 25, 24, 23, 22, 21, 20]])


def _truth(tolerance: int = 2):
    return TruthSource(tolerance=tolerance).load(QUERY, REF, "query", False, 0)


def test_best_candidates_rank_ascending_ties_by_position_and_skip_non_candidates() -> None:
    row = np.array([3.0, 1.0, np.inf, 1.0, 0.5, 2.0, np.nan, 1.0])
    assert best_candidates(row, 4).tolist() == [4, 1, 3, 7]
    assert best_candidates(-row, 3, descending=True).tolist() == [4, 1, 3]  # evidence: high is alike
    assert best_candidates(row).tolist() == [4, 1, 3, 7, 5, 0]  # fewer candidates than K
    assert best_candidates(np.full(5, np.inf)).tolist() == []
    tied = np.zeros(3 * RANKED)
    assert best_candidates(tied).tolist() == list(range(RANKED))


@pytest.mark.parametrize("window", [2, 8])  # 8: often every ranked position is within the window
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_compiled_pass_over_a_block_reads_each_row_as_the_numpy_functions_do(dtype: type, window: int) -> None:
    from wiloc.candidates import finite_minimum
    from wiloc.methods.online import near_miss
    from wiloc.methods.row_kernels import best_of_rows

    rng = np.random.default_rng(3)
    rows = rng.integers(0, 6, (400, 40)).astype(dtype)  # many ties
    for r, row in enumerate(rows):  # rows with NaN, +-inf, few or no candidates
        kind = r % 8
        if kind == 1:
            row[rng.integers(0, 40, 3)] = np.nan
        elif kind == 2:
            row[rng.integers(0, 40, 30)] = np.inf
        elif kind == 3:
            row[rng.integers(0, 40, 2)] = -np.inf
        elif kind == 4:
            row[:] = np.inf
            row[rng.integers(0, 40)] = 1.0
        elif kind == 5:
            row[:] = np.inf
    ranking, counts = np.empty((rows.shape[0], RANKED), dtype=np.int64), np.empty(rows.shape[0], dtype=np.intp)
    match, minimum, near = np.empty(rows.shape[0], dtype=np.intp), np.empty(rows.shape[0]), np.empty(rows.shape[0])
    best_of_rows(rows, window, ranking, counts, match, minimum, near)
    for r, row in enumerate(rows.astype(np.float64)):
        assert ranking[r, :counts[r]].tolist() == best_candidates(row).tolist()
        assert (ranking[r, counts[r]:] == -1).all()
        z, m = finite_minimum(row)
        assert match[r] == z
        np.testing.assert_equal(minimum[r], m)
        if z >= 0:
            np.testing.assert_equal(near[r], near_miss(row, z, None, window))


def test_recall_at_k_counts_a_true_match_among_the_k_best_of_frames_that_have_one() -> None:
    truth = _truth()
    assert truth.has_match().tolist() == [True, True, True, True, False]
    ranking = _ranking()
    recalls = [recall_at_k(ranking, truth, k) for k in (1, 5, 10)]
    assert recalls == [1 / 4, 2 / 4, 3 / 4]  # new.png is in no denominator
    exact = _truth(tolerance=0)  # f10's rank-3 frame f09 is one frame off: a miss at +-0
    assert [recall_at_k(ranking, exact, k) for k in (1, 5, 10)] == [1 / 4, 1 / 4, 1 / 4]
    undecided = ranking.copy()
    undecided[0] = -1  # f05 without a ranking (undecided): a miss, still in the denominator
    assert recall_at_k(undecided, truth, 10) == 2 / 4


def test_recall_at_1_from_the_ranking_is_the_r_at_1_of_the_matches() -> None:
    truth, ranking = _truth(), _ranking()
    summary = summarize(ranking[:, 0], np.full(len(QUERY), 0.5), truth, ranking)
    assert summary.recall_at_1 == recall_at_k(ranking, truth, 1)
    assert summary.recall_at_n == {5: 2 / 4, 10: 3 / 4}
    # a ranking of 10 candidates (files of older versions) tells no Recall@20; N = 1 is R@1 of the matches
    assert summarize(ranking[:, 0], np.full(len(QUERY), 0.5), truth, ranking, (1, 2, 20)).recall_at_n == {2: 1 / 4}
    without = summarize(ranking[:, 0], np.full(len(QUERY), 0.5), truth)
    assert "recall_at_5" not in without.as_dict() and "recall_at_10" not in without.as_dict()


def test_rankings_shorter_than_an_older_files_ten_tell_every_recall_at_n() -> None:
    """Rankings that all stop short (catgraph's nodes holding weight, a small map) hold every
    candidate: Recall@10 and @20 are told, equal to the recall over the whole ranking, where they
    were left out of the tables and the JSON without a word."""
    truth, ranking = _truth(), _ranking()[:, :4]
    summary = summarize(ranking[:, 0], np.full(len(QUERY), 0.5), truth, ranking, (1, 5, 10, 20))
    assert summary.recall_at_n == {n: recall_at_k(ranking, truth, 4) for n in (5, 10, 20)}
    assert summary.recall_at_n[20] == 2 / 4


def _decisions() -> Decisions:
    ranking = _ranking()
    ranking[4] = -1  # new.png undecided
    match = ranking[:, 0]
    return Decisions(match=match, difference=np.where(match >= 0, 0.1, np.nan),
                     confidence=np.where(match >= 0, 0.8, np.nan),
                     stage=np.where(match >= 0, "update", "init"), ranking=ranking)


def test_the_ranking_goes_through_the_results_file_and_evaluate_reads_it(tmp_path: Path) -> None:
    results = make_results(_decisions(), query_names=QUERY, ref_names=REF, header=ResultsHeader(method="online", mode="map"))
    path = tmp_path / "run.csv"
    write_results(path, results)
    assert "f10.png,f20.png,0.1,0.8,update,20 21 9 0 1 2 3 4 5 6" in path.read_text()
    assert path.read_text().rstrip().endswith("new.png,,,,init,")
    back = read_results(path)
    np.testing.assert_array_equal(back.ranking, _decisions().ranking)
    from_file, in_memory = api.evaluate(path, TruthSource()), api.evaluate(results, TruthSource())
    assert from_file.summary.as_dict() == in_memory.summary.as_dict()
    assert from_file.summary.recall_at_n == {5: 2 / 4, 10: 3 / 4}


def test_a_results_file_without_the_column_reports_no_recall_at_k(tmp_path: Path) -> None:
    path = tmp_path / "old.csv"
    write_results(path, make_results(_decisions(), query_names=QUERY, ref_names=REF, header=ResultsHeader(method="online")))
    lines = path.read_text().splitlines()
    path.write_text("\n".join(l if l.startswith("# ") else l.rsplit(",", 1)[0] for l in lines) + "\n")
    old = read_results(path)
    assert old.ranking is None and "ranking" not in old.frames.columns
    summary = api.evaluate(path, TruthSource()).summary
    assert summary.recall_at_n == {} and "recall_at_10" not in summary.as_dict()
    assert summary.recall_at_1 == 1 / 4  # R@1 stands without the ranking


@pytest.fixture
def runs(tmp_path: Path, cache_dir: Path) -> dict[str, Path]:
    """An online and a catgraph run of a query against its map (24 places)."""
    scenes = places(24)
    ref = write_traversal(tmp_path / "ref", scenes, 1.0, 1)
    query = write_traversal(tmp_path / "query", scenes, 0.7, 2)
    paths = {}
    for method in ("online", "catgraph"):
        paths[method] = tmp_path / f"{method}.csv"
        result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", method,
                                     "--out", str(paths[method]), "--jobs", "1"])
        assert result.exit_code == 0, result.output
    return paths


def test_evaluate_and_compare_report_recall_at_n_for_every_ranking_run(runs: dict[str, Path], tmp_path: Path) -> None:
    online, catgraph = runs["online"], runs["catgraph"]
    assert read_results(online).ranking.shape == (24, RANKED)
    ranked = read_results(catgraph)
    np.testing.assert_array_equal(ranked.ranking[:, 0], ranked.match_index)  # the posterior's mode first
    report = json.loads(runner.invoke(app, ["evaluate", str(online), str(catgraph), "--json"]).stdout)
    by_method = {run["method"]: run for run in report["runs"]}
    for method in ("online", "catgraph"):
        run = by_method[method]
        assert run["recall_at_1"] <= run["recall_at_5"] <= run["recall_at_10"] and "recall_at_20" not in run
    expected = api.evaluate(online, TruthSource()).summary.as_dict()
    assert by_method["online"]["recall_at_10"] == pytest.approx(expected["recall_at_10"])
    args = ["compare", str(online), str(catgraph), "--recall-at", "1,5,10,20"]
    table1 = {row["method"]: row for row in json.loads(runner.invoke(app, [*args, "--json"]).stdout)["runs"]}
    assert table1["online"]["recall_at_5"] == pytest.approx(expected["recall_at_5"])
    assert table1["catgraph"]["recall_at_10"] <= table1["catgraph"]["recall_at_20"]
    text = runner.invoke(app, ["evaluate", str(online), str(catgraph)], env={"COLUMNS": "120"}).stdout
    assert "R@5 (a true match in the 5 best)" in text and "R@10 (a true match in the 10 best)" in text
    assert "R@1/5/10/20" in runner.invoke(app, args, env={"COLUMNS": "120"}).stdout


@pytest.mark.parametrize("text", ["0", "21", "5,x", ""])
def test_recall_at_outside_the_ranking_is_a_usage_error(runs: dict[str, Path], text: str) -> None:
    result = runner.invoke(app, ["evaluate", str(runs["online"]), "--recall-at", text])
    assert result.exit_code == 2 and "--recall-at" in result.output


@pytest.mark.realdata
def test_recall_at_k_on_gardens_point(data_root: Path, real_data_cache: Path, cache_dir: Path) -> None:
    folder = data_root / "gardens-point-walking"
    run = api.localize(folder / "day_left", reference=folder / "day_right", descriptor="sad", method="online",
                       cache=Cache(real_data_cache))
    evaluation = api.evaluate(run, TruthSource())
    s = evaluation.summary
    assert run.results.ranking is not None and run.results.ranking.shape[1] == RANKED
    ranked = s.as_dict()
    assert 0.0 < s.recall_at_1 <= ranked["recall_at_5"] <= ranked["recall_at_10"] <= 1.0
    assert recall_at_k(run.results.ranking, evaluation.truth, 1) == s.recall_at_1
    np.testing.assert_array_equal(run.results.ranking[:, 0], run.results.match_index)

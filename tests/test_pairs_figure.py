"""The pairs figure's choice of examples: `evaluate --pairs-plot` with `--pairs N` and `--wrong-only`."""
from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from helpers import places, write_traversal
from wiloc import api
from wiloc.figures.run_figures import example_pairs

runner = CliRunner()


@pytest.fixture
def run(tmp_path: Path, cache_dir: Path) -> Path:
    """Online results on a route whose query runs 5 places past the map's end (so some are wrong)."""
    scenes = places(45)
    ref = write_traversal(tmp_path / "ref", scenes[:40], 1.0, 1)
    query = write_traversal(tmp_path / "query", scenes, 0.7, 2)
    return api.localize(query, reference=ref, method="online", out=tmp_path / "query-sad-online.csv", jobs=1).path


def test_pairs_takes_n_right_and_n_wrong_or_the_wrong_only(run: Path) -> None:
    evaluation = api.evaluate(run, api.TruthSource(kind="aligned"))
    wrong = int(((evaluation.results.match_index >= 0) & ~evaluation.correct).sum())
    assert wrong >= 2
    two = example_pairs(evaluation, 2)
    assert [pair.correct for pair in two] == [True, True, False, False]
    assert [p.confidence for p in two[:2]] == sorted((p.confidence for p in two[:2]), reverse=True)
    only = example_pairs(evaluation, 5, wrong_only=True)
    assert len(only) == min(5, wrong) and not any(pair.correct for pair in only)
    assert [p.query_name for p in only[:2]] == [p.query_name for p in two[2:]]  # the most confident wrong first


def test_pairs_options_on_the_command_line(run: Path, tmp_path: Path) -> None:
    from wiloc.cli import app

    figure = tmp_path / "pairs.png"
    result = runner.invoke(app, ["evaluate", str(run), "--pairs-plot", str(figure), "--pairs", "1", "--wrong-only"])
    assert result.exit_code == 0, result.output
    assert figure.read_bytes()[:4] == b"\x89PNG"
    for option in (["--pairs", "2"], ["--wrong-only"]):
        result = runner.invoke(app, ["evaluate", str(run), *option])
        assert result.exit_code == 2 and "applies to --pairs-plot only" in result.stderr
    result = runner.invoke(app, ["evaluate", str(run), "--pairs-plot", str(figure), "--pairs", "0"])
    assert result.exit_code == 2 and "--pairs" in result.stderr

"""The pairs figure's choice of examples: `evaluate --pairs-plot` with `--pairs N` and `--wrong-only`."""
from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from helpers import places, write_traversal
from wiloc import api
from wiloc.errors import ParameterError
from wiloc.figures.run_figures import ImagePair, example_pairs

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
    for count in ("0", "21"):  # beyond 20 of each, a figure took minutes and gigabytes
        result = runner.invoke(app, ["evaluate", str(run), "--pairs-plot", str(figure), "--pairs", count])
        assert result.exit_code == 2 and "--pairs" in result.stderr
    with pytest.raises(ParameterError, match="count: must be from 1 to 20 pairs of each kind, got 21"):
        example_pairs(api.evaluate(run, api.TruthSource(kind="aligned")), 21)


def test_the_pairs_of_a_slice_are_of_its_frames_numbered_as_in_the_run(run: Path, tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """evaluate refused --pairs-plot with --frames; it draws the slice's pairs alone, each query
    captioned with its frame's number in the run, and the title names the slice."""
    from matplotlib.figure import Figure

    from wiloc.cli import app
    from wiloc.figures import plots

    drawn: list[tuple[list[ImagePair], Figure]] = []
    pairs_figure = plots.pairs_figure
    monkeypatch.setattr(plots, "pairs_figure", lambda pairs, title: drawn.append(
        (list(pairs), pairs_figure(pairs, title))) or drawn[-1][1])
    figure = tmp_path / "pairs.png"
    result = runner.invoke(app, ["evaluate", str(run), "--frames", "10:20", "--pairs-plot", str(figure),
                                 "--pairs", "20"])
    assert result.exit_code == 0, result.output
    assert figure.read_bytes()[:4] == b"\x89PNG"
    (pairs, fig), = drawn
    whole = api.evaluate(run, api.TruthSource(kind="aligned"))
    decided = [k for k in range(10, 20) if whole.results.match_index[k] >= 0]
    assert decided and sorted(pair.frame for pair in pairs) == decided  # every decided frame of 10-19, no other
    names = whole.results.frames["frame"].tolist()
    assert all(pair.query_name == names[pair.frame] for pair in pairs)
    captions = [ax.get_title() for ax in fig.axes[::3][:len(pairs)]]
    assert captions == [f"query frame {pair.frame}, {pair.query_name}" for pair in pairs]
    assert " ".join(fig.get_suptitle().split()).endswith("the most confident right and wrong matches of frames 10:20")

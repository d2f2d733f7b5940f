"""Figures are written as non-empty PNG files of the expected layout; a suffix that is no figure
format is refused before drawing."""
from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import matplotlib.colors
import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from wiloc.metrics import pr_curve, precision_at_thresholds
from wiloc.model import HistogramModel
from wiloc.errors import WilocError
from wiloc.plots import check_plot_path, plot_matrix, plot_model, plot_pairs, plot_pr, plot_reliability, plot_threshold
from wiloc.reliability import reliability_bins
from wiloc.run_figures import ImagePair, MatrixPicture

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_png(path: Path) -> np.ndarray:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = matplotlib.image.imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert np.ptp(image[..., :3]) > 0  # something was drawn, not a blank canvas
    return image


@pytest.fixture
def run() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    correct = rng.random(200) < 0.7
    confidence = np.clip(rng.normal(np.where(correct, 0.7, 0.4), 0.15), 0, 1)
    return confidence, correct


def test_plot_pr_writes_png(tmp_path: Path, run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    curves = {"online": pr_curve(confidence, correct, 180),
              "threshold": pr_curve(confidence[::-1], correct, 180)}
    out = plot_pr(curves, tmp_path / "sub" / "pr.png")
    assert out == tmp_path / "sub" / "pr.png"
    read_png(out)


def test_a_figure_is_written_whole_or_not_at_all(tmp_path: Path, run: tuple[np.ndarray, np.ndarray],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    confidence, correct = run
    curves = {"online": pr_curve(confidence, correct, 180)}
    path = tmp_path / "pr.png"
    path.write_bytes(b"the figure of an earlier run")

    def full_disk(self: Figure, file: BinaryIO, **kwargs: object) -> None:
        file.write(PNG_SIGNATURE)  # a start that looks like a figure, then the disk is full
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", full_disk)
    with pytest.raises(WilocError, match="cannot write the figure .*No space left on device"):
        plot_pr(curves, path)
    assert path.read_bytes() == b"the figure of an earlier run"
    assert [p.name for p in tmp_path.iterdir()] == ["pr.png"]  # no temporary file left either
    monkeypatch.undo()
    read_png(plot_pr(curves, path))  # the next run replaces it


def _colour_columns(image: np.ndarray, colour: str) -> np.ndarray:
    """Columns of the plot area (the upper 70 % of ``image``, above the legend) near ``colour``."""
    plot_area = image[: int(0.7 * image.shape[0]), :, :3]
    near = np.all(np.abs(plot_area - matplotlib.colors.to_rgb(colour)) < 0.06, axis=-1)
    return np.flatnonzero(near.any(axis=0))


def test_plot_model_overlays_both_histograms_on_one_axis(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    model = HistogramModel.from_range(0.0, 1.0, bins=100)
    model.add_same(rng.normal(0.3, 0.08, 500))
    model.add_different(rng.normal(0.6, 0.1, 2000))
    image = read_png(plot_model(model, tmp_path / "model.png", title="SAD, day_right"))
    red, blue = _colour_columns(image, "tab:red"), _colour_columns(image, "tab:blue")
    # one axis: the two outlines share the horizontal range of one plot, the same-place one left
    assert np.median(red) < np.median(blue)
    assert red.min() < blue.min() < red.max() < blue.max()


def test_plot_threshold_writes_png(tmp_path: Path, run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    grid = np.linspace(0, 1, 101)
    series = {"probabilistic / day": (grid, precision_at_thresholds(confidence, correct, grid)),
              "threshold / day": (grid, precision_at_thresholds(1 - confidence, correct, grid))}
    read_png(plot_threshold(series, tmp_path / "fig5.png"))


def test_plot_reliability_writes_png_with_legend_below_the_axes(tmp_path: Path,
                                                               run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    series = {"online day_left": reliability_bins(confidence, correct),
              "threshold day_left": reliability_bins(np.full(10, 0.5), np.ones(10, dtype=bool))}
    image = read_png(plot_reliability(series, tmp_path / "sub" / "reliability.png"))[..., :3]
    height, width = image.shape[:2]
    for colour in ("#1f77b4", "#ff7f0e"):  # matplotlib's C0 and C1, one per run
        near = np.all(np.abs(image - matplotlib.colors.to_rgb(colour)) < 0.06, axis=-1)
        assert near[: int(0.6 * height)].any()  # drawn in the data
        assert near[int(0.85 * height):].any()  # and in the legend, below the axes


def test_plot_reliability_draws_p_new_place_beside_in_each_runs_colour(tmp_path: Path,
                                                                     run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    series = {"online day_left": reliability_bins(confidence, correct),
              "catgraph day_left": reliability_bins(confidence, correct)}
    new_place = {"catgraph day_left": reliability_bins(1 - confidence, ~correct)}  # the second run's: C1
    image = read_png(plot_reliability(series, tmp_path / "reliability.png", new_place=new_place))[..., :3]
    height, width = image.shape[:2]
    right = image[: int(0.6 * height), width // 2:]  # the P(new place) column's diagram
    near = {colour: np.all(np.abs(right - matplotlib.colors.to_rgb(colour)) < 0.06, axis=-1).any()
            for colour in ("#1f77b4", "#ff7f0e")}
    assert near == {"#1f77b4": False, "#ff7f0e": True}
    assert width > read_png(plot_reliability(series, tmp_path / "one.png")).shape[1]  # a second column


def test_an_unknown_figure_suffix_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(WilocError, match=r"pr\.pgn: '\.pgn' is not a figure format.*\.png"):
        check_plot_path(tmp_path / "pr.pgn")
    with pytest.raises(WilocError, match="no suffix"):
        plot_pr({}, tmp_path / "pr")
    check_plot_path(tmp_path / "pr.PDF")  # any case


def test_plot_threshold_marks_table_ii_thresholds(tmp_path: Path) -> None:
    grid = np.linspace(0, 1, 11)
    nothing = {"online day": (grid, np.full(11, np.nan))}  # no line of its own: only the mark is C0
    image = read_png(plot_threshold(nothing, tmp_path / "fig5.png", marks={"online": [(100.0, 0.5), (99.0, 0.5)]}))
    plot_area = image[: int(0.6 * image.shape[0]), :, :3]
    near = np.all(np.abs(plot_area - matplotlib.colors.to_rgb("#1f77b4")) < 0.08, axis=-1)
    columns = np.flatnonzero(near.sum(axis=0) > 0.1 * plot_area.shape[0])  # a vertical (dotted) line
    assert columns.size and np.ptp(columns) < 5  # one line for both targets sharing the threshold


def test_plot_matrix_draws_right_and_wrong_matches(tmp_path: Path) -> None:
    n = 30
    image = np.abs(np.subtract.outer(np.arange(n), np.arange(n))).astype(np.float64)
    match = np.arange(n)
    match[20:] = 3  # wrong
    picture = MatrixPicture(image=image, shape=(n, n), truth_rows=np.arange(n), truth_cols=np.arange(n),
                            match=match, correct=match == np.arange(n), confidence=np.full(n, 0.9),
                            query="q", reference="r", descriptor="sad")
    drawn = read_png(plot_matrix(picture, tmp_path / "matrix.png"))[..., :3]
    for colour in ("#2ca02c", "#d62728"):
        assert np.all(np.abs(drawn - matplotlib.colors.to_rgb(colour)) < 0.08, axis=-1).any()
    assert "ndarray(30 x 30)" in repr(picture) and len(repr(picture)) < 400


def test_plot_pairs_shows_each_example(tmp_path: Path) -> None:
    gray = np.tile(np.arange(64, dtype=np.uint8), (48, 1))
    pairs = [ImagePair("q1.png", "r1.png", None, 0.99, True, gray, gray, None),
             ImagePair("q2.png", "r9.png", "r2.png", 0.8, False, gray, gray[::-1], gray)]
    image = read_png(plot_pairs(pairs, tmp_path / "pairs.png"))
    assert image.shape[0] > image.shape[1] * 0.5  # one row per example
    assert "correct=False" in repr(pairs[1]) and "ndarray(48 x 64)" in repr(pairs[1])


def test_every_figure_the_docs_show_exists_and_every_figure_in_docs_img_is_shown() -> None:
    """The plots the examples regenerate into docs/img/ (``--update-docs``) are the ones the pages
    embed: none missing, none left over."""
    import re

    docs = Path(__file__).resolve().parents[1] / "docs"
    shown = {Path(m).name for page in docs.glob("*.md") for m in re.findall(r"\(img/([^)]+)\)", page.read_text())}
    kept = {p.name for p in (docs / "img").iterdir()}
    assert shown and shown == kept
    for name in kept:
        picture = matplotlib.image.imread(docs / "img" / name)
        assert picture.shape[0] > 200 and picture.shape[1] > 200, name

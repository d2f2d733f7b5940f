"""Figures are written as non-empty PNG files of the expected layout; a suffix that is no figure
format is refused before drawing."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import BinaryIO

import matplotlib.colors
import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from wiloc.errors import WilocError
from wiloc.evaluation.metrics import pr_curve, precision_at_thresholds
from wiloc.model import HistogramModel
from wiloc.figures.plots import (check_plot_path, plot_matrix, plot_model, plot_pairs, plot_pr, plot_reliability,
                                 plot_threshold, pr_figure, reliability_figure, run_styles, threshold_figure, timeline_figure)
from wiloc.evaluation.reliability import reliability_bins, wilson_interval
from wiloc.figures.run_figures import ImagePair, MatrixPicture, Timeline

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


@pytest.mark.parametrize("suffix", ["eps", "ps"])
def test_a_postscript_figure_prints_no_line_of_matplotlib(tmp_path: Path, run: tuple[np.ndarray, np.ndarray],
                                                          suffix: str, caplog: pytest.LogCaptureFixture) -> None:
    """PostScript has no transparency: matplotlib's line saying so went to stderr, in no form of
    wiloc's and missing from --json's warnings."""
    confidence, correct = run
    with caplog.at_level(logging.WARNING):
        path = plot_pr({"online day_left": pr_curve(confidence, correct, 200)}, tmp_path / f"pr.{suffix}")
    assert path.read_bytes()[:4] == b"%!PS" and not caplog.records


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


def _visible(fig: Figure) -> list:
    return [ax for ax in fig.axes if ax.axison]


def test_reliability_is_one_panel_per_run_with_counts_under_the_bins_and_intervals(
        tmp_path: Path, run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    series = {"online day_left": reliability_bins(confidence, correct),
              "threshold day_left": reliability_bins(np.full(10, 0.55), np.ones(10, dtype=bool))}
    fig = reliability_figure(series)
    panels = _visible(fig)
    assert len(panels) == 2
    for ax, bins in zip(panels, series.values()):
        assert [text.get_text() for text in ax.texts] == [str(n) for n in bins.count]  # a count under each bin
        points, _, (bars,) = ax.containers[0].lines  # the line, its caps, its interval bars
        filled = bins.count > 0
        assert np.allclose(points.get_xdata(), bins.mean_confidence[filled])
        low, high = wilson_interval(bins.share_correct[filled] * bins.count[filled], bins.count[filled])
        segments = bars.get_segments()
        assert np.allclose([seg[:, 1].min() for seg in segments], low)
        assert np.allclose([seg[:, 1].max() for seg in segments], high)
    assert points.get_color() == "C1"  # the second method's colour
    image = read_png(plot_reliability(series, tmp_path / "sub" / "reliability.png"))[..., :3]
    width = image.shape[1]
    for colour, half in (("#1f77b4", slice(0, width // 2)), ("#ff7f0e", slice(width // 2, width))):
        near = np.all(np.abs(image[:, half] - matplotlib.colors.to_rgb(colour)) < 0.06, axis=-1)
        assert near.any()  # each run in its own panel, in its method's colour


def test_a_p_new_place_panel_only_for_the_runs_given_it(run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    series = {"online day_left": reliability_bins(confidence, correct),
              "catgraph day_left": reliability_bins(confidence, correct)}
    assert len(_visible(reliability_figure(series, new_place={}))) == 2
    fig = reliability_figure(series, new_place={"catgraph day_left": reliability_bins(1 - confidence, ~correct)})
    panels = _visible(fig)
    assert len(panels) == 3 and panels[2].get_title() == "catgraph day_left: P(new place)"
    assert panels[2].get_xlabel() == "P(new place)"
    assert panels[2].containers[0].lines[0].get_color() == "C1"  # catgraph's colour


def test_every_reliability_panel_names_its_axes_when_their_meanings_differ(run: tuple[np.ndarray, np.ndarray]) -> None:
    """A P(new place) panel beside confidence panels names its own axes (P(new place), share
    without a true match), and a confidence panel above a P(new place) one its own, where only the
    outer panels kept labels: one of the other meaning's, or none. Panels of one meaning still
    name their axes once: at the left, and under the last panel of each column (with its numbers),
    also where the row below is short."""
    confidence, correct = run
    names = ["online day_left", "catgraph day_left", "online night_right"]
    series = {name: reliability_bins(confidence, correct) for name in names}
    new_place = {name: reliability_bins(1 - confidence, ~correct) for name in names[:2]}
    panels = _visible(reliability_figure(series, new_place=new_place))
    assert len(panels) == 5
    for ax in panels:
        new = ax.get_title().endswith("P(new place)")
        assert (ax.get_xlabel(), ax.get_ylabel()) == (("P(new place)", "share without a true match") if new
                                                      else ("confidence", "share correct"))
    alike = _visible(reliability_figure({**series, "threshold day_left": reliability_bins(confidence, correct)}))
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in alike] == [
        ("", "share correct"), ("confidence", ""), ("confidence", ""), ("confidence", "share correct")]
    assert all(ax.xaxis.get_major_ticks()[0].label1.get_visible() == bool(ax.get_xlabel()) for ax in alike)


def test_one_encoding_colour_is_the_method_line_style_the_traversal(run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    names = ["online day_left", "catgraph day_left", "online night_right", "catgraph night_right"]
    curves = {name: pr_curve(confidence, correct, 180) for name in names}
    grid = np.linspace(0, 1, 11)
    series = {name: (grid, precision_at_thresholds(confidence, correct, grid)) for name in names}
    for fig in (pr_figure(curves), threshold_figure(series)):
        drawn = {line.get_label(): (line.get_color(), line.get_linestyle()) for line in fig.axes[0].lines}
        assert drawn == {"online day_left": ("C0", "-"), "catgraph day_left": ("C1", "-"),
                         "online night_right": ("C0", "--"), "catgraph night_right": ("C1", "--")}
    assert run_styles(["online [runs/a] day_left", "online [runs/b] day_left"]) == {
        "online [runs/a] day_left": ("C0", "-"), "online [runs/b] day_left": ("C1", "-")}


def test_timeline_marks_right_and_wrong_and_shades_frames_without_a_true_match(tmp_path: Path) -> None:
    n = 30
    match = np.arange(n)
    match[20:] = 3
    has_match = np.arange(n) < 25
    timeline = Timeline(match=match, correct=(match == np.arange(n)) & has_match,
                        confidence=np.linspace(0, 1, n), new_place=np.where(has_match, 0.1, 0.9),
                        has_match=has_match, truth_rows=np.arange(25), truth_cols=np.arange(25))
    fig = timeline_figure(timeline)
    labels = [text.get_text() for text in fig.legends[0].get_texts()]
    assert "decided match, right (20)" in labels and "decided match, wrong (10)" in labels
    assert "P(new place)" in labels and "no true match in the map" in labels
    assert len(fig.axes[0].patches) == 1  # one shaded span: frames 25-29
    assert "n=30" in repr(timeline) or "ndarray(30)" in repr(timeline)


def test_an_unknown_figure_suffix_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(WilocError, match=r"pr\.pgn: '\.pgn' is not a figure format.*\.png"):
        check_plot_path(tmp_path / "pr.pgn")
    with pytest.raises(WilocError, match="no suffix"):
        plot_pr({}, tmp_path / "pr")
    check_plot_path(tmp_path / "pr.PDF")  # any case


def test_a_pgf_figure_without_tex_is_refused_before_any_work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                            run: tuple[np.ndarray, np.ndarray]) -> None:
    """matplotlib measures a .pgf figure's text with TeX: without it the option is refused as it
    is read, in one line naming the option, not after the work with matplotlib's words."""
    from helpers import ends_in_one_error
    from typer.testing import CliRunner

    from wiloc.cli import app

    monkeypatch.setattr("wiloc.figures.plots.shutil.which", lambda name: None)  # no TeX here
    monkeypatch.chdir(tmp_path)
    with pytest.raises(WilocError, match=r"pr\.pgf: '\.pgf' figures need xelatex .*not installed; write a \.pdf"):
        plot_pr({"online q": run}, tmp_path / "pr.pgf")
    for command in (["evaluate", "R", "--pr-plot", "pr.pgf"], ["compare", "R", "--threshold-plot", "t.pgf"],
                    ["localize", "Q", "--model-plot", "m.pgf"]):
        ends_in_one_error(CliRunner().invoke(app, command), 2, f"{command[-2]}: '.pgf' figures need xelatex")
    assert list(tmp_path.iterdir()) == []
    check_plot_path(tmp_path / "pr.pdf")


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


def test_pairs_of_a_run_without_a_wrong_match_say_none_to_show(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """--pairs-plot --wrong-only of a run whose every match is right: the figure says there is none
    to show under its title, where it said 'no decided match to show' of a run of decided matches."""
    from wiloc.figures import plots

    drawn: list[Figure] = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or Path(path))
    plots.plot_pairs([], tmp_path / "pairs.png", title="online on day_left (sad): the most confident wrong matches")
    assert [text.get_text() for ax in drawn[0].axes for text in ax.texts] == ["none to show"]


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


@pytest.mark.parametrize("runs", [2, 30])
def test_a_legend_of_many_runs_fits_the_figure_and_leaves_the_axes_their_room(runs: int,
                                                                               run: tuple[np.ndarray, np.ndarray]) -> None:
    """Constrained layout took a long legend's room from the axes of a fixed-size figure: thirty
    runs with their Table II thresholds left the axes a sliver and cut the legend off at the
    figure's edges."""
    confidence, correct = run
    names = [f"catgraph [seed{i}/night_right-sad-catgraph] night_right" for i in range(runs)]
    grid = np.linspace(0, 1, 11)
    series = {name: (grid, precision_at_thresholds(confidence, correct, grid)) for name in names}
    marks = {name.rsplit(" ", 1)[0]: [(100.0, 0.4 + i / 100), (99.0, 0.3)] for i, name in enumerate(names)}
    for fig in (pr_figure({name: pr_curve(confidence, correct, 180) for name in names}),
                threshold_figure(series, marks=marks)):
        fig.canvas.draw()
        legend, axes = fig.legends[0].get_window_extent(), fig.axes[0].get_window_extent()
        assert fig.bbox.x0 <= legend.x0 and legend.x1 <= fig.bbox.x1 and fig.bbox.y0 <= legend.y0
        assert legend.y1 < axes.y0 and axes.height / fig.dpi > 2.5


def test_figure_5_names_table_2_thresholds_with_the_tables_digits(run: tuple[np.ndarray, np.ndarray]) -> None:
    """The legend printed 0.989 for a threshold the tables print as 0.98928 (two thresholds
    0.9897 and 0.9903 would both have read 0.990): it writes each as the tables do."""
    from wiloc.labels import threshold_text

    confidence, correct = run
    grid = np.linspace(0, 1, 11)
    fig = threshold_figure({"catgraph night_right": (grid, precision_at_thresholds(confidence, correct, grid))},
                           marks={"catgraph": [(99.0, 0.98928)]})
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert f"catgraph: Table II threshold {threshold_text(0.98928)} (99 % precision)" in texts
    assert threshold_text(0.98928) != "0.989"

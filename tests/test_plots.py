"""Figures are written as non-empty PNG files of the expected layout."""
from __future__ import annotations

from pathlib import Path

import matplotlib.colors
import matplotlib.image
import numpy as np
import pytest

from wiloc.metrics import pr_curve, precision_at_thresholds
from wiloc.model import HistogramModel
from wiloc.plots import plot_model, plot_pr, plot_reliability, plot_threshold
from wiloc.reliability import reliability_bins

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


def test_plot_model_writes_two_panels(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    model = HistogramModel.from_range(0.0, 1.0, bins=100)
    model.add_same(rng.normal(0.3, 0.08, 500))
    model.add_different(rng.normal(0.6, 0.1, 2000))
    image = read_png(plot_model(model, tmp_path / "model.png", title="SAD, day_right"))
    assert image.shape[1] > image.shape[0]  # two panels side by side


def test_plot_threshold_writes_png(tmp_path: Path, run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    grid = np.linspace(0, 1, 101)
    series = {"probabilistic / day": (grid, precision_at_thresholds(confidence, correct, grid)),
              "threshold / day": (grid, precision_at_thresholds(1 - confidence, correct, grid))}
    read_png(plot_threshold(series, tmp_path / "fig5.png"))


def test_plot_reliability_writes_png_with_legend_beside_the_axes(tmp_path: Path,
                                                                run: tuple[np.ndarray, np.ndarray]) -> None:
    confidence, correct = run
    series = {"online day_left": reliability_bins(confidence, correct),
              "threshold day_left": reliability_bins(np.full(10, 0.5), np.ones(10, dtype=bool))}
    image = read_png(plot_reliability(series, tmp_path / "sub" / "reliability.png"))[..., :3]
    height, width = image.shape[:2]
    for colour in ("#1f77b4", "#ff7f0e"):  # matplotlib's C0 and C1, one per run
        near = np.all(np.abs(image - matplotlib.colors.to_rgb(colour)) < 0.06, axis=-1)
        assert near[:, : int(0.75 * width)].any()  # drawn in the data
        assert near[: height // 4, int(0.76 * width):].any()  # and in the legend, right of the axes

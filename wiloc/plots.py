"""Figures written to files: PR curves, the learned histograms (Figure 1), precision vs threshold,
the reliability diagram.

Figures are built on ``matplotlib.figure.Figure`` with the Agg canvas, never through pyplot, so
no global figure state is kept and nothing is shown; the format follows the file suffix.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from wiloc.metrics import PRCurve
from wiloc.model import HistogramModel
from wiloc.reliability import ReliabilityBins

STYLES = ("-", "--", ":", "-.")
"""Line styles telling apart lines of one colour."""


def _figure(ncols: int = 1, width: float = 6.0, nrows: int = 1, height: float = 4.5,
            **subplots: Any) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, list(np.atleast_1d(fig.subplots(nrows, ncols, **subplots)).ravel())


def _save(fig: Figure, path: str | Path) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    return out


def plot_pr(curves: dict[str, PRCurve], path: str | Path, title: str = "Precision-recall") -> Path:
    """Precision against recall, one line per run; the curves start at (recall 0, precision 1)."""
    fig, (ax,) = _figure()
    for name, curve in curves.items():
        recall = np.concatenate([[0.0], curve.recall])
        precision = np.concatenate([[1.0], curve.precision])
        ax.plot(recall, precision, label=name, linewidth=1.5)
    ax.set(xlim=(0, 1), ylim=(0, 1.02), xlabel="recall", ylabel="precision", title=title)
    ax.grid(alpha=0.3)
    if curves:
        ax.legend(loc="best")
    return _save(fig, path)


def plot_model(model: HistogramModel, path: str | Path, title: str = "Learned probability model") -> Path:
    """Figure 1: the (smoothed) histograms P(d | L) and P(d | not L), one panel each."""
    fig, axes = _figure(ncols=2, width=10.0)
    centres = (model.edges[:-1] + model.edges[1:]) / 2
    panels = [(model.p_d_given_same(centres), model.b, "P(d | L): same place", "tab:red"),
              (model.p_d_given_different(centres), model.c, "P(d | ¬L): different place", "tab:blue")]
    for ax, (density, counts, label, colour) in zip(axes, panels):
        ax.stairs(density, model.edges, fill=True, alpha=0.6, color=colour)
        ax.set(xlabel="difference d", ylabel="probability",
               title=f"{label}, {int(counts.sum())} samples")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    return _save(fig, path)


def plot_threshold(series: dict[str, tuple[np.ndarray, np.ndarray]], path: str | Path,
                   title: str = "Precision against threshold") -> Path:
    """Figure 5: precision against normalised threshold, one line per method and traversal.

    ``series`` maps a label "method traversal" to (thresholds, precision); lines whose labels
    share the first word (the method) share a colour, as the paper's red and blue, and traversals
    differ by line style. NaN precision (nothing accepted) leaves a gap.
    """
    fig, (ax,) = _figure()
    colours: dict[str, str] = {}
    lines_of: dict[str, int] = {}
    for name, (thresholds, precision) in series.items():
        method = (name.split(maxsplit=1) or [""])[0]
        colour = colours.setdefault(method, f"C{len(colours)}")
        style = STYLES[lines_of.get(method, 0) % len(STYLES)]
        lines_of[method] = lines_of.get(method, 0) + 1
        x = np.asarray(thresholds, dtype=np.float64)
        order = np.argsort(x)
        ax.plot(x[order], np.asarray(precision, dtype=np.float64)[order], label=name, color=colour,
                linestyle=style, linewidth=1.5)
    ax.set(xlim=(0, 1), xlabel="normalised threshold", ylabel="precision", title=title)
    ax.grid(alpha=0.3)
    if series:
        ax.legend(loc="best")
    return _save(fig, path)


def plot_reliability(series: dict[str, ReliabilityBins], path: str | Path,
                     title: str = "Reliability: share correct against confidence") -> Path:
    """Reliability diagram: per confidence bin, the share of correct matches against the bin's
    mean confidence (on the diagonal when calibrated), one line per run; below, the decided frames
    per bin (log scale), one bar per run. Colours repeat after ten runs, with another line style.
    The legend sits outside the axes."""
    fig, (ax, counts) = _figure(width=8.0, nrows=2, height=6.0, sharex=True, height_ratios=[3, 1])
    ax.plot([0, 1], [0, 1], color="0.5", linestyle="--", linewidth=1, label="calibrated")
    for k, (name, bins) in enumerate(series.items()):
        filled = bins.count > 0
        ax.plot(bins.mean_confidence[filled], bins.share_correct[filled], marker="o", markersize=4,
                linewidth=1.5, color=f"C{k}", linestyle=STYLES[k // 10 % len(STYLES)], label=name)
        width = np.diff(bins.edges) * 0.8 / max(len(series), 1)
        counts.bar(bins.edges[:-1] + np.diff(bins.edges) * 0.1 + width * k, bins.count, width=width,
                   align="edge", color=f"C{k}")
    ax.set(xlim=(0, 1), ylim=(0, 1.02), ylabel="share correct", title=title)
    counts.set(xlabel="confidence", ylabel="frames")
    counts.set_yscale("log")
    for axes in (ax, counts):
        axes.set_xticks(np.linspace(0, 1, 11))
        axes.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper")
    return _save(fig, path)

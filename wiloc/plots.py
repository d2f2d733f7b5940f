"""Figures written to files: PR curves, the learned histograms (Figure 1), precision vs threshold.

Figures are built on ``matplotlib.figure.Figure`` with the Agg canvas, never through pyplot, so
no global figure state is kept and nothing is shown; the format follows the file suffix.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from wiloc.metrics import PRCurve
from wiloc.model import HistogramModel


def _figure(ncols: int = 1, width: float = 6.0) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, list(np.atleast_1d(fig.subplots(1, ncols)))


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
    styles = ["-", "--", ":", "-."]
    for name, (thresholds, precision) in series.items():
        method = (name.split(maxsplit=1) or [""])[0]
        colour = colours.setdefault(method, f"C{len(colours)}")
        style = styles[lines_of.get(method, 0) % len(styles)]
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

"""Figures written to files: PR curves, the learned histograms (Figure 1), precision against
threshold (Figure 5), the reliability diagram, the difference matrix with the decided matches
and the ground truth, and example image pairs.

Figures are built on ``matplotlib.figure.Figure`` with the Agg canvas, never through pyplot, so
no global figure state is kept and nothing is shown; the format follows the file suffix, which
:func:`check_plot_path` checks before any drawing. Legends sit beside the axes, never over data.
"""
from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from wiloc.atomic import written_whole
from wiloc.errors import WilocError
from wiloc.metrics import PRCurve
from wiloc.model import HistogramModel
from wiloc.reliability import ReliabilityBins

if TYPE_CHECKING:
    from wiloc.run_figures import ImagePair, MatrixPicture

STYLES = ("-", "--", ":", "-.")
"""Line styles telling apart lines of one colour."""
FORMATS = tuple(sorted(FigureCanvasAgg.get_supported_filetypes()))
"""File suffixes (without the dot) the figures can be written as."""
CORRECT, WRONG, TRUTH = "#2ca02c", "#d62728", "white"


def check_plot_path(path: str | Path) -> None:
    """WilocError naming the file when its suffix is no figure format (``pr.pgn``)."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        shown = f"'.{suffix}'" if suffix else "no suffix"
        raise WilocError(path, f"{shown} is not a figure format; end the name in one of "
                               f"{', '.join('.' + f for f in FORMATS)}")


def _figure(ncols: int = 1, width: float = 6.0, nrows: int = 1, height: float = 4.5,
            **subplots: Any) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, list(np.atleast_1d(fig.subplots(nrows, ncols, **subplots)).ravel())


def _save(fig: Figure, path: str | Path) -> Path:
    """The figure written to ``path`` whole or not at all, in the format its suffix names."""
    out = Path(path)
    check_plot_path(out)
    try:
        with written_whole(out, "the figure", binary=True) as file:
            fig.savefig(file, format=out.suffix.lower().lstrip("."), dpi=120)
    except RuntimeError as exc:  # a format whose tool is missing (pgf: TeX)
        raise WilocError(out, f"cannot write the figure ({exc})") from None
    return out


def _title(fig: Figure, title: str) -> None:
    """The figure's title above everything (legends included), wrapped to the figure's width."""
    width = int(fig.get_figwidth() * 11)
    fig.suptitle("\n".join(textwrap.wrap(title, width)), fontsize="medium")


def _legend_beside(fig: Figure, ax: Axes) -> None:
    """The axes' legend below them, outside the data, in two columns."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncols=2 if len(handles) > 2 else len(handles),
                   fontsize="small")


def _span(values: Sequence[float], low: float, high: float, step: float = 0.1) -> tuple[float, float]:
    """An axis range on the ``step`` grid within [low, high] that holds ``values``, with a margin."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return low, high
    start = max(low, math.floor(min(finite) / step) * step)
    stop = min(high, math.ceil(max(finite) / step) * step)
    return (start, high) if stop - start < step else (start, stop)


def plot_pr(curves: Mapping[str, PRCurve], path: str | Path, title: str = "Precision-recall") -> Path:
    """Precision against recall, one line per run; the curves start at (recall 0, precision 1).
    The axes span what the curves reach (to the next tenth), the legend sits beside them."""
    fig, (ax,) = _figure(width=8.0)
    for k, (name, curve) in enumerate(curves.items()):
        recall = np.concatenate([[0.0], curve.recall])
        precision = np.concatenate([[1.0], curve.precision])
        ax.plot(recall, precision, label=name, linewidth=1.5, color=f"C{k % 10}", linestyle=STYLES[k // 10 % 4])
    recalls = [float(c.recall.max()) for c in curves.values() if c.recall.size]
    precisions = [float(c.precision.min()) for c in curves.values() if c.precision.size]
    ax.set(xlim=(0.0, _span(recalls, 0.0, 1.0)[1]), ylim=(_span(precisions, 0.0, 1.0)[0], 1.02),
           xlabel="recall", ylabel="precision")
    _title(fig, title)
    ax.grid(alpha=0.3)
    _legend_beside(fig, ax)
    return _save(fig, path)


def plot_model(model: HistogramModel, path: str | Path, title: str = "Learned probability model") -> Path:
    """Figure 1: the two learned histograms on one axis, as the shares of their samples per bin
    (P(d | L) same place, P(d | not L) different place). The model's smoothing gives every bin a
    small floor (pseudo-count / total); that floor is no data, so it is only stated below."""
    fig, (ax,) = _figure(width=8.0)
    floors = []
    for counts, label, colour in ((model.b, "P(d | L): same place", "tab:red"),
                                  (model.c, "P(d | ¬L): different place", "tab:blue")):
        total = float(counts.sum())
        share = counts / total if total > 0 else np.zeros_like(counts)
        ax.stairs(share, model.edges, fill=True, alpha=0.35, color=colour)
        ax.stairs(share, model.edges, color=colour, linewidth=1.2, label=f"{label}, {int(total):,} samples")
        floors.append(model.smoothing / (total + model.smoothing * model.n_bins))
    used = np.flatnonzero((model.b + model.c) > 0)
    if used.size:
        margin = 2 * (model.edges[1] - model.edges[0])
        ax.set_xlim(model.edges[used[0]] - margin, model.edges[used[-1] + 1] + margin)
    ax.plot([], [], " ", label=f"not drawn: the model's smoothing, {model.smoothing:g} per bin "
                               f"(a floor of {floors[0]:.2g} and {floors[1]:.2g})")
    ax.set(xlabel="difference d", ylabel="share of the histogram's samples")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    _title(fig, title)
    _legend_beside(fig, ax)
    return _save(fig, path)


def plot_threshold(series: Mapping[str, tuple[np.ndarray, np.ndarray]], path: str | Path,
                   title: str = "Precision against threshold",
                   marks: Mapping[str, Sequence[tuple[float, float]]] | None = None) -> Path:
    """Figure 5: precision against normalised threshold, one line per method and traversal.

    ``series`` maps a label "method traversal" to (thresholds, precision); lines whose labels
    share the first word (the method) share a colour, as the paper's red and blue, and traversals
    differ by line style. NaN precision (nothing accepted) leaves a gap. ``marks`` maps a method
    to Table II's global thresholds, (target precision in %, threshold), drawn as vertical lines
    in the method's colour.
    """
    fig, (ax,) = _figure(width=8.0)
    colours: dict[str, str] = {}
    lines_of: dict[str, int] = {}
    for name, (thresholds, precision) in series.items():
        method = (name.split(maxsplit=1) or [""])[0]
        colour = colours.setdefault(method, f"C{len(colours) % 10}")
        style = STYLES[lines_of.get(method, 0) % len(STYLES)]
        lines_of[method] = lines_of.get(method, 0) + 1
        x = np.asarray(thresholds, dtype=np.float64)
        order = np.argsort(x)
        ax.plot(x[order], np.asarray(precision, dtype=np.float64)[order], label=name, color=colour,
                linestyle=style, linewidth=1.5)
    for method, points in (marks or {}).items():
        by_threshold: dict[float, list[float]] = {}
        for target, threshold in points:
            if math.isfinite(threshold):
                by_threshold.setdefault(threshold, []).append(target)
        for threshold, targets in by_threshold.items():
            ax.axvline(threshold, color=colours.get(method, "0.3"), linestyle=":", linewidth=1.2,
                       label=f"{method}: Table II threshold {threshold:.3f} "
                             f"({', '.join(f'{t:g} %' for t in targets)} precision)")
    ax.set(xlim=(0, 1), xlabel="normalised threshold", ylabel="precision")
    _title(fig, title)
    ax.grid(alpha=0.3)
    _legend_beside(fig, ax)
    return _save(fig, path)


def plot_reliability(series: Mapping[str, ReliabilityBins], path: str | Path,
                     title: str = "Reliability: share correct against confidence",
                     new_place: Mapping[str, ReliabilityBins] | None = None) -> Path:
    """Reliability diagram: per confidence bin, the share of correct matches against the bin's
    mean confidence (on the diagonal when calibrated), one line per run; below, the decided frames
    per bin (log scale), one bar per run. With ``new_place`` (runs that give P(new place)), a
    second column does the same for P(new place) against the share of frames without a true
    match, each run in its colour of the first. Colours repeat after ten runs, with another line
    style. The legend sits outside the axes."""
    columns = 2 if new_place else 1
    fig, axes = _figure(ncols=columns, width=8.0 if columns == 1 else 12.0, nrows=2, height=6.0, sharex="col",
                        height_ratios=[3, 1])
    colour = {name: k for k, name in enumerate(series)}
    _reliability_panel(axes[0], axes[columns], series, colour, "confidence", "share correct")
    if new_place:
        _reliability_panel(axes[1], axes[3], new_place, colour, "P(new place)", "share without a true match")
    _title(fig, title if not new_place else f"{title}; P(new place) against frames without a true match")
    _legend_beside(fig, axes[0])
    return _save(fig, path)


def _reliability_panel(ax: Axes, counts: Axes, series: Mapping[str, ReliabilityBins], colour: Mapping[str, int],
                       probability: str, share: str) -> None:
    """One column of the reliability diagram: the diagonal and a line per run above, the frames
    per bin below (a bar per run); run ``name`` in colour ``colour[name]``."""
    ax.plot([0, 1], [0, 1], color="0.5", linestyle="--", linewidth=1, label="calibrated")
    for slot, (name, bins) in enumerate(series.items()):
        k = colour.get(name, slot)
        filled = bins.count > 0
        ax.plot(bins.mean_confidence[filled], bins.share_correct[filled], marker="o", markersize=4,
                linewidth=1.5, color=f"C{k % 10}", linestyle=STYLES[k // 10 % len(STYLES)], label=name)
        width = np.diff(bins.edges) * 0.8 / max(len(series), 1)
        counts.bar(bins.edges[:-1] + np.diff(bins.edges) * 0.1 + width * slot, bins.count, width=width,
                   align="edge", color=f"C{k % 10}")
    ax.set(xlim=(0, 1), ylim=(0, 1.02), ylabel=share)
    counts.set(xlabel=probability, ylabel="frames")
    counts.set_yscale("log")
    for axes in (ax, counts):
        axes.set_xticks(np.linspace(0, 1, 11))
        axes.grid(alpha=0.3)


def plot_matrix(picture: MatrixPicture, path: str | Path, title: str = "Differences") -> Path:
    """The query x reference difference matrix as a heat map (darker: more alike; blank: never a
    candidate), the ground truth's same-place pairs as a light band, and each decided match as a
    dot: green when right, red when wrong, larger when more confident."""
    n_query, n_ref = picture.shape
    side = 7.0
    fig, (ax,) = _figure(width=side * 1.35, height=side * min(max(n_query / max(n_ref, 1), 0.5), 1.3) + 0.8)
    image = np.where(np.isfinite(picture.image), picture.image, np.nan)
    shown = ax.imshow(image, cmap="viridis", aspect="auto", interpolation="nearest",
                      extent=(-0.5, n_ref - 0.5, n_query - 0.5, -0.5))
    fig.colorbar(shown, ax=ax, label=f"difference d ({picture.descriptor})", shrink=0.8)
    dot = max(1.0, 12.0 * min(1.0, 300.0 / max(n_query, 1)))
    ax.scatter(picture.truth_cols, picture.truth_rows, s=dot * 0.35, c=TRUTH, alpha=0.35, linewidths=0,
               label="ground truth: same place")
    decided = picture.match >= 0
    size = dot * (0.4 + 1.6 * np.clip(np.nan_to_num(picture.confidence), 0.0, 1.0))
    for mask, colour, label in ((decided & picture.correct, CORRECT, "decided match, right"),
                                (decided & ~picture.correct, WRONG, "decided match, wrong")):
        rows = np.flatnonzero(mask)
        ax.scatter(picture.match[rows], rows, s=size[rows], c=colour, linewidths=0, label=f"{label} ({rows.size})")
    _title(fig, title)
    ax.set(xlim=(-0.5, n_ref - 0.5), ylim=(n_query - 0.5, -0.5),
           xlabel=f"reference frame ({picture.reference})", ylabel=f"query frame ({picture.query})")
    legend = fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize="small",
                        facecolor="0.85")
    for handle in legend.legend_handles:  # legend markers of a readable size, whatever the dots' size
        handle.set_alpha(1.0)
        handle.set_sizes([30.0])
    return _save(fig, path)


def plot_pairs(pairs: Sequence[ImagePair], path: str | Path, title: str = "Example matches") -> Path:
    """One row per example: the query image, the map image it was matched to, and for a wrong
    match the map image of its true place, each titled with its name; the row says whether the
    match is right and how confident it was."""
    rows = max(len(pairs), 1)
    fig, axes = _figure(ncols=3, nrows=rows, width=10.0, height=2.6 * rows + 0.6)
    for k, pair in enumerate(pairs):
        verdict = "right" if pair.correct else "wrong"
        cells = ((pair.query_image, f"query {pair.query_name}"),
                 (pair.match_image, f"matched {pair.match_name}\n{verdict}, confidence {pair.confidence:.3f}"),
                 (pair.truth_image, f"true place {pair.truth_name}" if pair.truth_name else ""))
        for ax, (image, caption) in zip(axes[3 * k: 3 * k + 3], cells):
            ax.set_axis_off()
            if image is not None:
                ax.imshow(image, cmap="gray" if image.ndim == 2 else None)
                colour = CORRECT if pair.correct else WRONG
                ax.set_title(caption, fontsize="small", color=colour if "matched" in caption else "black")
            elif not pair.correct and not pair.truth_name and caption == "":
                ax.text(0.5, 0.5, "no true place\nin the map", ha="center", va="center", fontsize="small")
    for ax in axes[3 * len(pairs):]:
        ax.set_axis_off()
    if not pairs:
        axes[1].text(0.5, 0.5, "no decided match to show", ha="center", va="center")
    _title(fig, title)
    return _save(fig, path)

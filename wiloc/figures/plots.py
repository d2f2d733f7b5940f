"""Figures written to files: PR curves, the learned histograms (Figure 1), precision against
threshold (Figure 5), the reliability diagram, the difference matrix with the decided matches
and the ground truth, a run's timeline of confidences, and example image pairs.

Runs are drawn in one encoding everywhere: colour = method, line style = query traversal
(:func:`run_styles`). Each ``plot_*`` writes the figure its ``*_figure`` twin builds (the HTML
report embeds those figures instead, :func:`figure_bytes`).

Figures are built on ``matplotlib.figure.Figure`` with the Agg canvas, never through pyplot, so
no global figure state is kept and nothing is shown; the format follows the file suffix, which
:func:`check_plot_path` checks before any drawing. Legends sit beside the axes, never over data.
"""
from __future__ import annotations

import io
import logging
import math
import shutil
import textwrap
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from numpy.typing import NDArray
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from wiloc.atomic import written_whole
from wiloc.errors import WilocError
from wiloc.evaluation.comparison import RunName
from wiloc.evaluation.metrics import PRCurve
from wiloc.evaluation.reliability import ReliabilityBins, wilson_interval
from wiloc.labels import threshold_text
from wiloc.model import HistogramModel

if TYPE_CHECKING:
    from wiloc.figures.run_figures import ImagePair, MatrixPicture, Timeline

STYLES = ("-", "--", ":", "-.")
"""Line styles telling apart the traversals of one method."""
NEW_PLACE = "#9467bd"
"""P(new place)'s colour in a run's timeline."""
FORMATS = tuple(sorted(FigureCanvasAgg.get_supported_filetypes()))
"""File suffixes (without the dot) the figures can be written as."""
CORRECT, WRONG, TRUTH = "#2ca02c", "#d62728", "white"
AXES_ROOM = 3.6
"""Inches of a figure's height kept for its title, axes and their labels above a legend beside them."""
LEGEND_MARGIN = 0.2
"""Inches of a figure's width beyond its legend's."""


def check_plot_path(path: str | Path) -> None:
    """WilocError naming the file when its suffix is no figure format (``pr.pgn``), or is one whose
    tool is missing (``.pgf`` without TeX), so that the option is refused before the work."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        shown = f"'.{suffix}' is not a figure format" if suffix else "the name has no suffix (a name such as " \
            "'.png' is all name, a hidden file's)"
        raise WilocError(path, f"{shown}; end the name in one of {', '.join('.' + f for f in FORMATS)}")
    tex = matplotlib.rcParams["pgf.texsystem"]
    if suffix == "pgf" and shutil.which(tex) is None:
        raise WilocError(path, f"'.pgf' figures need {tex} (matplotlib measures their text with TeX), which is "
                               "not installed; write a .pdf or .svg instead")


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
        with written_whole(out, "the figure", binary=True) as file, _postscript_quiet():
            fig.savefig(file, format=out.suffix.lower().lstrip("."), dpi=120)
    except RuntimeError as exc:  # a format whose tool is missing (pgf: TeX)
        raise WilocError(out, f"cannot write the figure ({exc})") from None
    return out


@contextmanager
def _postscript_quiet() -> Iterator[None]:
    """PostScript (.ps, .eps) has no transparency: matplotlib draws the translucent parts (legend
    frames, shaded bands) opaque and says so in a log line of its own on stderr, which is no
    output of wiloc's (nor one of its warnings)."""
    log = logging.getLogger("matplotlib.backends.backend_ps")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def figure_bytes(fig: Figure, format: str = "png", dpi: int = 100) -> bytes:
    """The figure as the bytes of a file of ``format`` (png, jpeg, svg, ...), for embedding; a
    JPEG at quality 85 (a heat map is many times smaller so than as PNG)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format=format, dpi=dpi, **({"pil_kwargs": {"quality": 85}} if format == "jpeg" else {}))
    return buffer.getvalue()


def run_styles(names: Sequence[str]) -> dict[str, tuple[str, str]]:
    """(colour, line style) per run name "method traversal" (``comparison.run_names``, whose
    :class:`RunName` knows its parts; other text is split at its last space): one colour per
    method and one line style per query traversal, in order of first appearance."""
    colours: dict[str, str] = {}
    styles: dict[str, str] = {}
    drawn = {}
    for name in names:
        method, traversal = _method_traversal(name)
        drawn[name] = (colours.setdefault(method, f"C{len(colours) % 10}"),
                       styles.setdefault(traversal, STYLES[len(styles) % len(STYLES)]))
    return drawn


def _method_traversal(name: str) -> tuple[str, str]:
    """A run name's method and traversal: a RunName's own, else "method traversal" split at its
    last space (a name without one is a method)."""
    if isinstance(name, RunName):
        return name.method, name.traversal
    method, _, traversal = name.rpartition(" ")
    return (method, traversal) if method else (traversal, "")


def _title(fig: Figure, title: str) -> None:
    """The figure's title above everything (legends included), wrapped to the figure's width."""
    width = int(fig.get_figwidth() * 11)
    fig.suptitle("\n".join(textwrap.wrap(title, width)), fontsize="medium")


def _legend_beside(fig: Figure, ax: Axes) -> None:
    """The axes' legend below them, outside the data, in two columns, or one when two would be
    wider than the figure. The figure grows to hold it (taller by the legend's rows beyond what
    leaves the axes ``AXES_ROOM``, wider for labels longer than it is wide): constrained layout
    takes a legend's room from the axes, so that thirty runs left them a sliver and cut the
    legend off at the figure's edges."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    renderer = fig.canvas.get_renderer()
    for ncols in (2, 1) if len(handles) > 2 else (len(handles),):
        legend = fig.legend(handles, labels, loc="outside lower center", ncols=ncols, fontsize="small")
        box = legend.get_window_extent(renderer)
        if ncols == 1 or box.width <= fig.bbox.width:
            break
        legend.remove()
    fig.set_size_inches(max(fig.get_figwidth(), box.width / fig.dpi + LEGEND_MARGIN),
                        max(fig.get_figheight(), box.height / fig.dpi + AXES_ROOM))


def _span(values: Sequence[float], low: float, high: float, step: float = 0.1) -> tuple[float, float]:
    """An axis range on the ``step`` grid within [low, high] that holds ``values``, with a margin."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return low, high
    start = max(low, math.floor(min(finite) / step) * step)
    stop = min(high, math.ceil(max(finite) / step) * step)
    return (start, high) if stop - start < step else (start, stop)


def pr_figure(curves: Mapping[str, PRCurve], title: str = "Precision-recall") -> Figure:
    """Precision against recall (the paper's Figure 4), one line per run (colour = method, line
    style = traversal: see :func:`run_styles`); the curves start at (recall 0, precision 1). The
    axes span what the curves reach (to the next tenth), the legend sits beside them."""
    fig, (ax,) = _figure(width=8.0)
    styles = run_styles(list(curves))
    for name, curve in curves.items():
        recall = np.concatenate([[0.0], curve.recall])
        precision = np.concatenate([[1.0], curve.precision])
        colour, style = styles[name]
        ax.plot(recall, precision, label=name, linewidth=1.5, color=colour, linestyle=style)
    recalls = [float(c.recall.max()) for c in curves.values() if c.recall.size]
    precisions = [float(c.precision.min()) for c in curves.values() if c.precision.size]
    ax.set(xlim=(0.0, _span(recalls, 0.0, 1.0)[1]), ylim=(_span(precisions, 0.0, 1.0)[0], 1.02),
           xlabel="recall", ylabel="precision")
    _title(fig, title)
    ax.grid(alpha=0.3)
    _legend_beside(fig, ax)
    return fig


def plot_pr(curves: Mapping[str, PRCurve], path: str | Path, title: str = "Precision-recall") -> Path:
    """:func:`pr_figure` written to ``path``."""
    check_plot_path(path)
    return _save(pr_figure(curves, title), path)


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


def threshold_figure(series: Mapping[str, tuple[np.ndarray, np.ndarray]],
                     title: str = "Precision against threshold",
                     marks: Mapping[str, Sequence[tuple[float, float]]] | None = None) -> Figure:
    """Figure 5: precision against normalised threshold, one line per method and traversal.

    ``series`` maps a run name to (thresholds, precision); colour = method, line style =
    traversal (:func:`run_styles`), as the paper's red and blue. NaN precision (nothing accepted)
    leaves a gap. ``marks`` maps a method to Table II's global thresholds, (target precision in
    %, threshold), drawn as vertical dotted lines in the method's colour.
    """
    fig, (ax,) = _figure(width=8.0)
    styles = run_styles(list(series))
    colours = {_method_traversal(name)[0]: styles[name][0] for name in series}
    for name, (thresholds, precision) in series.items():
        colour, style = styles[name]
        x = np.asarray(thresholds, dtype=np.float64)
        order = np.argsort(x)
        ax.plot(x[order], np.asarray(precision, dtype=np.float64)[order], label=name, color=colour,
                linestyle=style, linewidth=1.5)
    for method, points in (marks or {}).items():
        colour = colours.setdefault(method, f"C{len(colours) % 10}")
        by_threshold: dict[float, list[float]] = {}
        for target, threshold in points:
            if math.isfinite(threshold):
                by_threshold.setdefault(threshold, []).append(target)
        for threshold, targets in by_threshold.items():
            ax.axvline(threshold, color=colour, linestyle=":", linewidth=1.2,
                       label=f"{method}: Table II threshold {threshold_text(threshold)} "
                             f"({', '.join(f'{t:g} %' for t in targets)} precision)")
    ax.set(xlim=(0, 1), xlabel="normalised threshold", ylabel="precision")
    _title(fig, title)
    ax.grid(alpha=0.3)
    _legend_beside(fig, ax)
    return fig


def plot_threshold(series: Mapping[str, tuple[np.ndarray, np.ndarray]], path: str | Path,
                   title: str = "Precision against threshold",
                   marks: Mapping[str, Sequence[tuple[float, float]]] | None = None) -> Path:
    """:func:`threshold_figure` written to ``path``."""
    check_plot_path(path)
    return _save(threshold_figure(series, title, marks), path)


def reliability_figure(series: Mapping[str, ReliabilityBins],
                       title: str = "Reliability: share correct against confidence",
                       new_place: Mapping[str, ReliabilityBins] | None = None) -> Figure:
    """Reliability as small multiples, one panel per run: per confidence bin, the share of correct
    matches against the bin's mean confidence (on the diagonal when calibrated) with its 95 %
    Wilson interval, and under each bin its count of decided frames. With ``new_place`` (the runs
    whose P(new place) can be judged: some frame has no true match), one more panel per such run
    does the same for P(new place) against the share of frames without a true match. Panels are
    in the run's colour (colour = method, :func:`run_styles`)."""
    panels = [(name, bins, "confidence", "share correct") for name, bins in series.items()]
    panels += [(f"{name}: P(new place)", bins, "P(new place)", "share without a true match")
               for name, bins in (new_place or {}).items()]
    ncols = min(3, max(len(panels), 1))
    nrows = math.ceil(max(len(panels), 1) / ncols)
    fig, axes = _figure(ncols=ncols, nrows=nrows, width=3.8 * ncols + 0.4, height=3.4 * nrows + 0.7,
                        sharex=True, sharey=True)
    styles = run_styles(list(series))
    alike = len({(probability, share) for _, _, probability, share in panels}) <= 1
    for k, (ax, (name, bins, probability, share)) in enumerate(zip(axes, panels)):
        colour = styles.get(name.removesuffix(": P(new place)"), ("C0", "-"))[0]
        _reliability_panel(ax, bins, colour)
        ax.set_title("\n".join(textwrap.wrap(name, 40)), fontsize="small")
        last_in_column = k + ncols >= len(panels)
        if last_in_column:  # no panel below to show the shared axis' numbers
            ax.xaxis.set_tick_params(labelbottom=True)
        # axes of one meaning are named once, on the last panel of a column and the first of a
        # row; axes of mixed meanings (confidence, P(new place)) on every panel
        ax.set(xlabel=probability if last_in_column or not alike else "",
               ylabel=share if k % ncols == 0 or not alike else "")
    for ax in axes[len(panels):]:
        ax.set_axis_off()
    if not panels:
        axes[0].text(0.5, 0.5, "no run to show", ha="center", va="center")
    _title(fig, f"{title}; 95 % Wilson intervals, decided frames per bin along the bottom"
           + ("; P(new place) against the frames without a true match" if new_place else ""))
    return fig


def plot_reliability(series: Mapping[str, ReliabilityBins], path: str | Path,
                     title: str = "Reliability: share correct against confidence",
                     new_place: Mapping[str, ReliabilityBins] | None = None) -> Path:
    """:func:`reliability_figure` written to ``path``."""
    check_plot_path(path)
    return _save(reliability_figure(series, title, new_place), path)


def _reliability_panel(ax: Axes, bins: ReliabilityBins, colour: str) -> None:
    """One run's reliability panel: the diagonal, the filled bins' share against mean confidence
    with Wilson intervals, and each bin's count written at the bottom under the bin."""
    ax.plot([0, 1], [0, 1], color="0.5", linestyle="--", linewidth=1)
    filled = bins.count > 0
    low, high = wilson_interval(np.rint(bins.share_correct[filled] * bins.count[filled]), bins.count[filled])
    x, y = bins.mean_confidence[filled], bins.share_correct[filled]
    ax.errorbar(x, y, yerr=np.clip(np.vstack([y - low, high - y]), 0.0, None), color=colour, marker="o", markersize=4,
                linewidth=0.8, capsize=2, elinewidth=1)
    centres = (bins.edges[:-1] + bins.edges[1:]) / 2
    for centre, count in zip(centres, bins.count):
        ax.text(centre, 0.015, f"{int(count)}", ha="center", va="bottom", fontsize=6,
                color="0.2" if count else "0.6", transform=ax.get_xaxis_transform())
    ax.set(xlim=(0, 1), ylim=(-0.08, 1.05))
    ax.set_xticks(bins.edges[::2])
    ax.grid(alpha=0.3)


def matrix_figure(picture: MatrixPicture, title: str = "Differences") -> Figure:
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
    return fig


def plot_matrix(picture: MatrixPicture, path: str | Path, title: str = "Differences") -> Path:
    """:func:`matrix_figure` written to ``path``."""
    check_plot_path(path)
    return _save(matrix_figure(picture, title), path)


def timeline_figure(timeline: Timeline, title: str = "Timeline") -> Figure:
    """A run frame by frame: above, the map frame each query frame was matched to (green right,
    red wrong) over the ground truth's true places (light grey); below, the confidence of each
    decided match (green right, red wrong) and P(new place) where the run gives it. Frames without
    a true match in the map are shaded in both. Query frames are numbered as the run numbers
    them: a slice's from its start (``timeline.first``)."""
    n, first = timeline.match.size, timeline.first
    frames = first + np.arange(n)
    fig, (top, bottom) = _figure(nrows=2, width=10.0, height=5.0, sharex=True, height_ratios=[3, 2])
    top.scatter(first + timeline.truth_rows, timeline.truth_cols, s=6, c="0.8", linewidths=0,
                label="ground truth: true place")
    decided = timeline.match >= 0
    for mask, colour, label in ((decided & timeline.correct, CORRECT, "right"),
                                (decided & ~timeline.correct, WRONG, "wrong")):
        rows = np.flatnonzero(mask)
        top.scatter(frames[rows], timeline.match[rows], s=6, c=colour, linewidths=0,
                    label=f"decided match, {label} ({rows.size})")
        bottom.scatter(frames[rows], np.clip(timeline.confidence[rows], 0.0, 1.0), s=6, c=colour, linewidths=0)
    bottom.plot(frames, np.clip(timeline.confidence, 0.0, 1.0), color="0.6", linewidth=0.6, label="confidence")
    if timeline.new_place is not None:
        bottom.plot(frames, timeline.new_place, color=NEW_PLACE, linewidth=1.0, label="P(new place)")
    for start, stop in _runs_of(~timeline.has_match):
        for ax in (top, bottom):
            ax.axvspan(first + start - 0.5, first + stop - 0.5, color="0.5", alpha=0.15, linewidth=0)
    if (~timeline.has_match).any():
        bottom.fill_between([], [], color="0.5", alpha=0.15, label="no true match in the map")
    top.set(ylabel="map frame", xlim=(first - 0.5, first + n - 0.5))
    bottom.set(xlabel="query frame", ylabel="confidence", ylim=(-0.03, 1.03))
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    handles = [h for ax in (top, bottom) for h in ax.get_legend_handles_labels()[0]]
    labels = [label for ax in (top, bottom) for label in ax.get_legend_handles_labels()[1]]
    fig.legend(handles, labels, loc="outside lower center", ncols=3, fontsize="small", markerscale=2)
    _title(fig, title)
    return fig


def _runs_of(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(start, stop) of each run of consecutive True entries."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def pairs_figure(pairs: Sequence[ImagePair], title: str = "Example matches") -> Figure:
    """One row per example: the query image, the map image it was matched to, and for a wrong
    match the map image of its true place, each titled with its name (the query's with its frame
    number in the run, where the pair knows it); the row says whether the match is right and how
    confident it was."""
    rows = max(len(pairs), 1)
    fig, axes = _figure(ncols=3, nrows=rows, width=10.0, height=2.6 * rows + 0.6)
    for k, pair in enumerate(pairs):
        verdict = "right" if pair.correct else "wrong"
        query = f"query {pair.query_name}" if pair.frame is None else f"query frame {pair.frame}, {pair.query_name}"
        cells = ((pair.query_image, query),
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
        axes[1].text(0.5, 0.5, "none to show", ha="center", va="center")  # the title says of what
    _title(fig, title)
    return fig


def plot_pairs(pairs: Sequence[ImagePair], path: str | Path, title: str = "Example matches") -> Path:
    """:func:`pairs_figure` written to ``path``."""
    check_plot_path(path)
    return _save(pairs_figure(pairs, title), path)

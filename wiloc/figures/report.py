"""One comparison as a self-contained HTML page (``wiloc report``): the summary tables, the
precision-recall, threshold and reliability figures, per run a timeline and the difference matrix
with its decisions, and a frame browser (query, decided match and true place side by side).

The page needs no network: figures are embedded PNGs (the difference matrices JPEGs), images
small JPEG thumbnails (data URIs), styles and the browser's script inline
(``wiloc/figures/report_page.html``, ``report.css``, ``report.js``). A run whose image folders are gone
still gets its tables and figures; its browser shows names without pictures, and the page says
why.
"""
from __future__ import annotations

import base64
import html
import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from wiloc.atomic import written_whole
from wiloc.description.traversals import stage
from wiloc.errors import WilocError
from wiloc.evaluation.reliability import NEW_PLACE_KEYS
from wiloc.labels import threshold_text
from wiloc.version import __version__

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

    from wiloc.cache.store import Cache
    from wiloc.description.traversals import Progress
    from wiloc.evaluation.comparison import Comparison, Evaluation

THUMB_WIDTH = 160
"""Width in pixels of the images in the frame browser."""
THUMB_BUDGET = 15_000_000
"""Bytes of thumbnails at most: beyond it they are made again at half the width."""
CONFIDENT = 0.9
"""The browser's filter "confident and wrong" starts at this confidence (the page can change it)."""

TABLE1_COLUMNS = {"method": "method", "traversal": "traversal", "recall_at_100": "R@100%P", "recall_at_99": "R@99%P",
                  "recall_at_90": "R@90%P", "auc": "AUC", "recall_at_1": "R@1", "recall_at_5": "R@5",
                  "recall_at_10": "R@10", "frames": "frames"}
CALIBRATION_COLUMNS = {"method": "method", "traversal": "traversal", "ece": "ECE", "brier": "Brier",
                       "mean_confidence": "mean conf.", "share_correct": "share correct"}
NEW_PLACE_COLUMNS = {"method": "method", "traversal": "traversal", "new_place_ece": "ECE", "new_place_brier": "Brier",
                     "new_place_mean_confidence": "mean P(new place)",
                     "new_place_share_correct": "share without a true match"}
TABLE2_COLUMNS = {"method": "method", "precision": "target precision %", "threshold": "threshold",
                  "traversal": "traversal", "recall": "recall", "worst": "worst"}


@dataclass
class Report:
    """A report written: its file, size in bytes, the thumbnails' width and what building it
    found to note (image folders missing, a matrix that could not be drawn); the page notes these
    and each run's ground-truth doubts (``Evaluation.truth_doubts``) too."""

    path: Path
    size: int
    thumb_width: int
    images: int
    notes: list[str] = field(default_factory=list)


def write_report(comparison: Comparison, path: Path, *, cache: Cache, title: str = "wiloc report",
                 thumb_width: int = THUMB_WIDTH, scope: Sequence[str] = (),
                 progress: Progress | None = None) -> Report:
    """Build the page of ``comparison`` and write it to ``path`` whole (or not at all). ``cache``
    gives back the runs' descriptors for the difference matrices; ``scope`` are lines shown under
    the ground truth that say what of the runs was scored (``wiloc report --frames``: which frames
    of each)."""
    from wiloc.evaluation.comparison import run_names

    notes: list[str] = []
    images = Thumbnails()
    names = run_names(comparison.evaluations)
    runs = [_browser_run(name, e, images, notes, cache) for name, e in zip(names, comparison.evaluations)]
    for width in _halvings(thumb_width):
        data = images.encode(width, stage(progress, "thumbnails"))
        if sum(map(len, data)) <= THUMB_BUDGET:
            break
    figures = _figures(comparison, names, cache, notes, stage(progress, "figures"))
    doubts = [f"{e.path or e.name}: {doubt}" for e in comparison.evaluations for doubt in e.truth_doubts]
    page = _page(comparison, title, figures, runs, data, doubts + notes, scope)  # a page is read on its own
    with written_whole(Path(path), "the report") as file:
        file.write(page)
    return Report(path=Path(path), size=len(page.encode("utf-8")), thumb_width=width, images=len(images.paths),
                  notes=notes)


def _halvings(width: int) -> list[int]:
    """The thumbnail widths to try: ``width``, then half of it down to 40 pixels."""
    widths = [width]
    while widths[-1] // 2 >= 40:
        widths.append(widths[-1] // 2)
    return widths


# ------------------------------------------------------------------------------------------- images

class Thumbnails:
    """The image files the page shows, each once, as JPEG data URIs of one width."""

    def __init__(self) -> None:
        self.paths: list[Path] = []
        self._index: dict[Path, int] = {}

    def add(self, path: Path) -> int:
        """The index of ``path`` among the page's images (added when new)."""
        if path not in self._index:
            self._index[path] = len(self.paths)
            self.paths.append(path)
        return self._index[path]

    def encode(self, width: int, progress: Callable[[int, int], None] | None = None) -> list[str]:
        """Every image as a data URI of a JPEG ``width`` pixels wide (an empty string for an image
        that cannot be read: the browser then shows its name only)."""
        uris = []
        for done, path in enumerate(self.paths, 1):
            uris.append(thumbnail_uri(path, width))
            if progress:
                progress(done, len(self.paths))
        return uris


def thumbnail_uri(path: Path, width: int, quality: int = 75) -> str:
    """An image file as a data URI of a JPEG ``width`` pixels wide, or as wide as it is when it is
    narrower ("" when it cannot be read)."""
    import cv2

    from wiloc.figures.run_figures import read_rgb

    try:
        image = read_rgb(path)
    except WilocError:
        return ""
    width = min(width, image.shape[1])
    height = max(1, round(image.shape[0] * width / image.shape[1]))
    small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    if small.ndim == 3:
        small = cv2.cvtColor(small, cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return "data:image/jpeg;base64," + base64.b64encode(encoded.tobytes()).decode("ascii") if ok else ""


def _browser_run(name: str, e: Evaluation, images: Thumbnails, notes: list[str], cache: Cache) -> dict[str, Any]:
    """One run for the frame browser: per query frame its name, match, true place, confidence,
    P(new place), verdict and the indices of the three images (-1: none), and the run's number of
    the first frame and its count of frames, from which the browser numbers the frames as the run
    does (a slice's, ``--frames``, from its start). Images that are no longer the run's
    (``run_figures.checked_entries``) are not shown, and the page says why."""
    from wiloc.figures.run_figures import checked_entries, run_traversals, true_places, unchecked_folders

    names = e.results.frames["frame"].tolist()
    ref_names = e.results.reference_frames or names
    match, place = e.results.match_index, true_places(e)
    query = reference = Path()
    try:
        query, reference, _ = run_traversals(e)
        for folder in (query, reference):
            if not folder.is_dir():
                raise WilocError(e.path, f"{folder} {'is not an image folder' if folder.exists() else 'does not exist'}")
        checked_entries(e, cache)
        notes.extend(unchecked_folders(e))
        shown = True
    except WilocError as exc:
        notes.append(f"{name}: no images in the frame browser, {exc.problem}")
        shown = False

    def image(folder: Path, index: int, frames: list[str]) -> int:
        return images.add(folder / frames[index]) if shown and index >= 0 else -1

    p_new = e.results.new_place
    return {"name": name, "results": str(e.path or e.name), "frames": names, "first": e.first_frame,
            "run_frames": e.run_frames or len(names),
            "match": [ref_names[m] if m >= 0 else None for m in match.tolist()],
            "truth": [ref_names[t] if t >= 0 else None for t in place.tolist()],
            "confidence": _numbers(e.confidence), "new_place": None if p_new is None else _numbers(p_new),
            "correct": e.correct.astype(bool).tolist(), "has_match": np.asarray(e.truth.has_match()).tolist(),
            "query_image": [image(query, k, names) for k in range(len(names))],
            "match_image": [image(reference, int(m), ref_names) for m in match.tolist()],
            "truth_image": [image(reference, int(t), ref_names) for t in place.tolist()]}


def _numbers(values: Any) -> list[float | None]:
    """Floats for JSON to the 9 significant digits a results file keeps, so that the browser's
    confidence filter counts the frames the cut tables count (rounded to 4 places, 0.989995526 was
    0.99 there); NaN as null."""
    return [float(f"{v:.9g}") if math.isfinite(v) else None for v in np.asarray(values, dtype=np.float64).tolist()]


# ------------------------------------------------------------------------------------------ figures

@dataclass
class Figures:
    """The page's figures as data URIs (or the reason one is missing)."""

    pr: str
    threshold: str
    reliability: str
    timelines: list[str]
    matrices: list[str]  # "" where a matrix could not be drawn (the notes say why)


def _figure_uri(fig: Figure, format: str = "png") -> str:
    """The figure as a data URI: a PNG (lines and text stay sharp), or a JPEG for heat maps."""
    from wiloc.figures.plots import figure_bytes
    return f"data:image/{format};base64," + base64.b64encode(figure_bytes(fig, format, dpi=90)).decode("ascii")


def _figures(comparison: Comparison, names: Sequence[str], cache: Cache, notes: list[str],
             progress: Callable[[int, int], None] | None) -> Figures:
    """The comparison's figures, then each run's timeline and difference matrix (a matrix that
    cannot be rebuilt is noted instead)."""
    from wiloc.evaluation.comparison import new_place_series, pr_series, reliability_series, threshold_marks, threshold_series
    from wiloc.figures import plots
    from wiloc.figures.run_figures import matrix_picture, run_timeline

    evaluations = comparison.evaluations
    figures = Figures(
        pr=_figure_uri(plots.pr_figure(pr_series(comparison), title="Precision-recall")),
        threshold=_figure_uri(plots.threshold_figure(threshold_series(comparison), marks=threshold_marks(comparison),
                                                     title="Precision against threshold (Figure 5)")),
        reliability=_figure_uri(plots.reliability_figure(reliability_series(evaluations),
                                                         new_place=new_place_series(evaluations))),
        timelines=[], matrices=[])
    for done, (name, e) in enumerate(zip(names, evaluations)):
        if progress:
            progress(done, len(evaluations))
        figures.timelines.append(_figure_uri(plots.timeline_figure(run_timeline(e), title=f"{name}: frame by frame")))
        try:
            picture = matrix_picture(e, cache)
            title = f"{name}: differences, decided matches and ground truth"
            figures.matrices.append(_figure_uri(plots.matrix_figure(picture, title=title), "jpeg"))
        except WilocError as exc:
            said = exc.problem if exc.where in (None, str(e.path)) else str(exc)  # the folder it missed named
            notes.append(f"{name}: no difference matrix, {said}")
            figures.matrices.append("")
    if progress:
        progress(len(evaluations), len(evaluations))
    return figures


# --------------------------------------------------------------------------------------------- page

def _table(frame: pd.DataFrame, columns: Mapping[str, str], percent: Sequence[str] = (),
           general: Sequence[str] = (), thresholds: Sequence[str] = ()) -> str:
    """A DataFrame as an HTML table of ``columns`` (key: header) it has; ``percent`` columns as
    percentages, ``general`` ones as short as they go (100, 99.5), ``thresholds`` with the digits
    that say them (:func:`wiloc.labels.threshold_text`), other floats to 3 places, NaN as a dash."""
    keys = [key for key in columns if key in frame and not (frame[key].isna().all() and key.startswith("recall_at_"))]
    head = "".join(f"<th>{html.escape(columns[key])}</th>" for key in keys)
    rows = []
    for record in frame.to_dict(orient="records"):
        texts = [f"{record[key]:g}" if key in general else threshold_text(record[key]) if key in thresholds
                 else _cell(record[key], key in percent) for key in keys]
        cells = "".join(f"<td>{html.escape(text)}</td>" for text in texts)
        rows.append(f"<tr>{cells}</tr>")
    return f'<table class="metrics"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>'


def _cell(value: Any, percent: bool) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "*" if value else ""
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            return "-"
        return f"{value:.1%}" if percent else f"{value:.3f}"
    return str(value)


def _cut_columns(comparison: Comparison, scalars: Mapping[str, str], prefix: str = "") -> dict[str, str]:
    """A calibration table's columns: its ``scalars``, then precision / recall / accepted per cut
    (the confidence's, or with ``prefix`` "new_place_" P(new place)'s)."""
    columns = dict(scalars)
    for key in comparison.cut_table.columns:
        if "@" in key and key.startswith(prefix) and (prefix or not key.startswith(NEW_PLACE_KEYS)):
            measure, cut = key.removeprefix(prefix).split("@")
            columns[key] = f"{measure} @{cut}"
    return columns


def _new_place_table(comparison: Comparison) -> str:
    """P(new place)'s calibration and cuts, one row per run that says it (as ``wiloc compare``
    prints them), or a note that no run does."""
    table = comparison.cut_table
    given = table[table[f"{NEW_PLACE_KEYS}ece"].notna()] if f"{NEW_PLACE_KEYS}ece" in table else table.iloc[:0]
    if given.empty:
        return '<p class="note">no run says P(new place)</p>'
    columns = _cut_columns(comparison, NEW_PLACE_COLUMNS, NEW_PLACE_KEYS)
    return _table(given, columns, general=[key for key in columns if key.startswith(f"{NEW_PLACE_KEYS}accepted@")])


def _page(comparison: Comparison, title: str, figures: Figures, runs: list[dict[str, Any]], images: list[str],
          notes: list[str], scope: Sequence[str]) -> str:
    """The whole HTML page."""
    folder = resources.files("wiloc.figures")
    template = folder.joinpath("report_page.html").read_text(encoding="utf-8")
    data = json.dumps({"runs": runs, "images": images, "confident": CONFIDENT}, separators=(",", ":"))
    per_run = "".join(
        f'<details class="run"{" open" if k == 0 else ""}><summary>{html.escape(run["name"])} '
        f'<span class="file">{html.escape(run["results"])}</span></summary>'
        f'<img class="figure" alt="timeline of {html.escape(run["name"])}" src="{timeline}">'
        + (f'<img class="figure" alt="difference matrix of {html.escape(run["name"])}" src="{matrix}">' if matrix
           else '<p class="note">no difference matrix (see the notes above)</p>')
        + "</details>"
        for k, (run, timeline, matrix) in enumerate(zip(runs, figures.timelines, figures.matrices)))
    options = "".join(f'<option value="{k}">{html.escape(run["name"])}</option>' for k, run in enumerate(runs))
    parts = {
        "title": html.escape(title),
        "css": folder.joinpath("report.css").read_text(encoding="utf-8"),
        "script": folder.joinpath("report.js").read_text(encoding="utf-8"),
        "version": html.escape(__version__),
        "ground_truth": html.escape(comparison.ground_truth),
        "scope": "".join(f'<p class="scope">{html.escape(line)}</p>' for line in scope),
        "notes": "".join(f"<li>{html.escape(note)}</li>" for note in notes),
        "notes_hidden": "" if notes else " hidden",
        "table1": _table(comparison.table1, TABLE1_COLUMNS, [k for k in TABLE1_COLUMNS if k.startswith("recall_at")]),
        "calibration": _table(comparison.cut_table, _cut_columns(comparison, CALIBRATION_COLUMNS)),
        "new_place": _new_place_table(comparison),
        "table2": _table(comparison.table2, TABLE2_COLUMNS, ["recall"], ["precision"], ["threshold"]) if len(comparison.table2) else
        '<p class="note">not computed</p>',
        "pr": figures.pr, "threshold": figures.threshold, "reliability": figures.reliability,
        "runs": per_run, "run_options": options, "confident": f"{CONFIDENT:g}",
        "data": data.replace("<", "\\u003c"),  # no "</script>" or "<!--" inside the script element
    }
    return re.sub(r"\{\{(\w+)\}\}", lambda m: parts[m.group(1)], template)

"""Which frames of a run are scored, and in what order: its rows in the order the run decided
the frames (:func:`in_run_order`), as ``wiloc.evaluation.comparison.score`` reads them.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from wiloc.cache.entries import EXTERNAL
from wiloc.errors import WilocError
from wiloc.evaluation.results import Results
from wiloc.evaluation.results_header import ResultsHeader, header_line, read_header
from wiloc.sources.frames import natural_sorted

#: The query traversal of a run in memory that records none (``Localizer.results()`` without ``query``).
UNNAMED_QUERY = "unnamed"


def in_run_order(path: Path | None, results: Results) -> Results:
    """``results`` with its rows in the order its run decided the frames, as ground truth that
    counts frames by position reads them (a matrix, positives, VPR-Bench's indices, aligned by
    index, sequence mode's earlier frames): a file sorted by confidence, or its halves swapped,
    scores as the file the run wrote. The file itself records that order: in sequence mode its
    header's ``reference_frames`` (the run's own frames, in order), where a row of another frame,
    or a listed frame without a row, is a WilocError naming it; for a batch run on a folder or a
    video (a ``query_digest`` in map mode, no bag ``topic``, no imported descriptors) the frames'
    natural order, in which such a run lists them. Other runs (frame by frame, followed, a bag's
    in message order, an imported matrix's in its rows' order) keep the rows' order."""
    header, names = results.header, results.frames["frame"].tolist()
    if header.sequence and header.reference_frames:
        order = list(header.reference_frames)
    elif (not header.sequence and header.query_digest is not None and header.topic is None
          and (header.descriptor or "").partition(":")[0] != EXTERNAL):
        order = natural_sorted(names)
    else:
        return results
    rank = {name: i for i, name in enumerate(order)}
    run = "" if path else f" in the run {run_name(path, header)}"
    stray = next((i for i, name in enumerate(names) if name not in rank), None)
    if stray is not None:
        line = f"line {read_header(path)[1] + 2 + stray}: " if path else ""
        raise WilocError(path, f"{line}frame '{names[stray]}' is not one of the run's frames (its header's "
                               f"reference_frames){run}")
    if len(names) < len(order):
        present = set(names)
        missing = next(name for name in order if name not in present)
        listed = f" (line {header_line(path, 'reference_frames')})" if path else ""
        raise WilocError(path, f"no row for frame '{missing}', which its header's reference_frames{listed} "
                               f"lists{run}: the file is incomplete or was edited")
    rows = np.argsort([rank[name] for name in names], kind="stable")
    if (rows == np.arange(len(names))).all():
        return results
    return replace(results, frames=results.frames.iloc[rows].reset_index(drop=True))


def out_of_order(path: Path | None, results: Results, ordered: Results) -> str | None:
    """The warning for rows that :func:`in_run_order` moved (sorted or moved by hand, or a frame
    renamed, which moves every row between its old and new place): their count and the first, as
    the file holds it; None when every row stood in its place."""
    found = results.frames["frame"].to_numpy()
    moved = np.flatnonzero(found != ordered.frames["frame"].to_numpy())
    if not moved.size:
        return None
    line = f"line {read_header(path)[1] + 2 + int(moved[0])}, " if path else ""
    kept = "the order of its reference_frames" if results.header.sequence else "its frames' natural order"
    return (f"{moved.size} of {found.size} rows are out of their run's order ({kept}), the first at {line}frame "
            f"'{found[moved[0]]}': scored in the run's order")


def run_name(path: Path | None, header: ResultsHeader) -> str:
    """A run as messages name it: its results file, or for a run in memory its query and method."""
    return str(path) if path else f"in memory (query {header.query or UNNAMED_QUERY}, method {header.method})"

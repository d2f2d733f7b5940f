"""Which frames of a run are scored, and in what order: its rows in the order the run decided
the frames (:func:`in_run_order`), and a slice of them (``wiloc evaluate --frames 20:``), say the
first frames of a run, where a filter locks on, against the steady state after them.

``wiloc.evaluation.comparison.score`` calls these; a slice is checked in one place,
:func:`check_frames`, for the library and the command line alike.
"""
from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from wiloc.cache.entries import EXTERNAL
from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.groundtruth import Truth
from wiloc.evaluation.results import Results
from wiloc.evaluation.results_header import ResultsHeader, header_line, read_header
from wiloc.sources.natural_order import natural_sorted

#: The query traversal of a run in memory that records none (``Localizer.results()`` without ``query``).
UNNAMED_QUERY = "unnamed"

_BOUND = r"\s*(-?\d+)?\s*"
_SLICE = re.compile(rf"{_BOUND}:{_BOUND}")
_EXAMPLES = "give START:STOP as in Python, e.g. 20: (from the 21st frame on), :20 (the first 20) or 100:300"


def check_frames(frames: slice | str | None) -> slice | None:
    """The frames of each run to score, as a slice of its frames in the run's order (None: every
    frame), given as a slice or as its text (``20:``, ``:20``, ``100:300``; a negative number
    counts from the end, as in Python). Anything else (a step, a list of slices, a bound that is no
    whole number, a number alone, which could mean a frame or a count) is a ParameterError naming
    ``frames``."""
    if frames is None:
        return None
    if isinstance(frames, str):
        found = _SLICE.fullmatch(frames)
        if found is None:
            why = (" (one slice is taken, not a list of them)" if "," in frames else
                   " (a step is not taken)" if frames.count(":") > 1 else "")
            raise ParameterError("frames", f"'{frames}'{why}: {_EXAMPLES}")
        frames = slice(*(None if bound is None else int(bound) for bound in found.groups()))
    if not isinstance(frames, slice) or frames.step is not None or \
            any(b is not None and (isinstance(b, (bool, np.bool_)) or not isinstance(b, (int, np.integer)))
                for b in (frames.start, frames.stop)):
        raise ParameterError("frames", f"a slice of whole numbers without a step, such as slice(20, None) "
                                       f"or '20:', got {frames!r}")
    return slice(None if frames.start is None else int(frames.start), None if frames.stop is None else int(frames.stop))


def frames_text(frames: slice) -> str:
    """A checked slice as ``--frames`` takes it: ``20:``, ``:20``, ``100:300``."""
    return ":".join("" if bound is None else str(bound) for bound in (frames.start, frames.stop))


def frame_rows(frames: slice, count: int, run: str) -> np.ndarray:
    """The rows of a run of ``count`` frames that a checked slice ``frames`` picks, in order; a
    ParameterError naming ``frames`` and the ``run`` when it picks none (``300:`` of 200 frames)."""
    rows = np.arange(count)[frames]
    if not rows.size:
        raise ParameterError("frames", f"'{frames_text(frames)}' selects none of the {count} frames of the run {run}")
    return rows


def of_frames(results: Results, truth: Truth, rows: np.ndarray) -> tuple[Results, Truth]:
    """A run and its ground truth cut to the query frames at ``rows`` (in the run's order): the
    reference frames, and in sequence mode each frame's earlier frames, stay as they were; the
    truth's warnings that count query frames count those alone (:meth:`Truth.of_queries`)."""
    return _with_rows(results, rows), truth.of_queries(rows)


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
        line = f"line {_line(path, stray)}: " if path else ""
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
    return _with_rows(results, rows)


def _with_rows(results: Results, rows: np.ndarray) -> Results:
    """``results`` holding its rows at ``rows``, in that order."""
    return replace(results, frames=results.frames.iloc[rows].reset_index(drop=True))


def _line(path: Path, row: int) -> int:
    """The line of a results file that holds its data row ``row`` (counted from 0)."""
    return read_header(path)[1] + 2 + row


def out_of_order(path: Path | None, results: Results, ordered: Results) -> str | None:
    """The warning for rows that :func:`in_run_order` moved (sorted or moved by hand, or a frame
    renamed, which moves every row between its old and new place): their count and the first, as
    the file holds it; None when every row stood in its place."""
    found = results.frames["frame"].to_numpy()
    moved = np.flatnonzero(found != ordered.frames["frame"].to_numpy())
    if not moved.size:
        return None
    line = f"line {_line(path, int(moved[0]))}, " if path else ""
    kept = "the order of its reference_frames" if results.header.sequence else "its frames' natural order"
    return (f"{moved.size} of {found.size} rows are out of their run's order ({kept}), the first at {line}frame "
            f"'{found[moved[0]]}': scored in the run's order")


def run_name(path: Path | None, header: ResultsHeader) -> str:
    """A run as messages name it: its results file, or for a run in memory its query and method."""
    return str(path) if path else f"in memory (query {header.query or UNNAMED_QUERY}, method {header.method})"

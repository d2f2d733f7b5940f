"""Ground truth: the four forms of SPEC.md section 7, read into one boolean truth matrix (the
forms VPR datasets ship are in :mod:`wiloc.evaluation.truth_formats`, aligned traversals in
:mod:`wiloc.evaluation.aligned`, the choice among all of them in
:mod:`wiloc.evaluation.truth_source`).

Every reader returns a :class:`Truth` over the frame names it is given (queries x references).
Frames are matched to ground-truth rows by file name; the matrix form, which carries no names, is
matched by position and its shape is checked. Names that match only in part are reported with
counts in ``Truth.warnings``; no match at all is a :class:`~wiloc.errors.WilocError`.
See docs/evaluation.md for the formats and examples.
"""
from __future__ import annotations

import csv
import re
import unicodedata
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from numbers import Real
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.spatial import cKDTree

from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.truth_warnings import QueryFramesWarning, query_frames_without, unmatched
from wiloc.given import COLUMN_NAMES, EARTH_RADIUS_M, check_file, check_lat_lon, check_metres, why_unmatched
from wiloc.reprs import short_repr

KINDS = ("aligned", "positions", "pairs", "matrix", "vprbench", "positives", "utm-names", "exif")
FOLDER_KINDS = ("utm-names", "exif")
"""Forms read from the traversals themselves (their file names, their images' EXIF): no file."""


class TruthMismatch(WilocError):
    """Ground truth that does not fit a run's frames (a matrix of another shape, indices or names
    of frames the run lacks): the reader names the file; :func:`~wiloc.evaluation.comparison.score`
    adds which run, :meth:`of_run`, since with several runs the frame counts alone do not tell."""

    def of_run(self, run: str) -> TruthMismatch:
        """The same problem, saying that ``run`` is the run the ground truth does not fit."""
        return TruthMismatch(self.where, f"does not fit the run {run}: {self.problem}")


@short_repr
@dataclass
class Truth:
    """Which (query, reference) frame pairs are the same place, with the names of both axes."""

    matrix: sparse.csr_array
    query_names: list[str]
    ref_names: list[str]
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.matrix = sparse.csr_array(self.matrix, dtype=np.bool_)
        self.matrix.eliminate_zeros()
        self.matrix.sum_duplicates()  # sorted indices too: is_true searches them
        shape = (len(self.query_names), len(self.ref_names))
        if self.matrix.shape != shape:
            raise ValueError(f"truth matrix is {self.matrix.shape}, names give {shape}")

    @property
    def sequence(self) -> bool:
        """True when queries and references are the same frames (loop closure in one traversal)."""
        return self.query_names == self.ref_names

    def has_match(self) -> NDArray[np.bool_]:
        """Per query frame: whether at least one reference frame is the same place."""
        return np.diff(self.matrix.indptr) > 0

    def of_queries(self, rows: NDArray[np.int64]) -> Truth:
        """The truth of the query frames at ``rows`` alone, in that order (the reference frames as
        they are), with its warnings that count query frames (:class:`QueryFramesWarning`) counted
        over those frames: a run scored on a slice of its frames is warned about the frames scored."""
        warnings = [line for warning in self.warnings
                    for line in (warning.of_rows(rows) if isinstance(warning, QueryFramesWarning) else [warning])]
        return Truth(self.matrix[rows], [self.query_names[k] for k in rows], list(self.ref_names), warnings)

    def is_true(self, query_idx: ArrayLike, ref_idx: ArrayLike) -> NDArray[np.bool_]:
        """Whether each (query, reference) index pair is the same place; reference -1 gives False.
        Each pair is looked up in the sorted keys of the true pairs: ``np.isin`` over them took 13 s
        of CPU for 20,000 pairs against a truth of 10 million (+-250 frames), the search 0.03 s."""
        q = np.asarray(query_idx, dtype=np.int64)
        r = np.asarray(ref_idx, dtype=np.int64)
        q, r = np.broadcast_arrays(q, r)
        n_ref = np.int64(self.matrix.shape[1])
        valid = (r >= 0) & (r < n_ref)
        wanted = q * n_ref + np.where(valid, r, 0)
        keys = self._keys
        at = np.minimum(np.searchsorted(keys, wanted), max(keys.size - 1, 0))
        return valid & (keys[at] == wanted) if keys.size else np.zeros(wanted.shape, dtype=bool)

    @cached_property
    def _keys(self) -> NDArray[np.int64]:
        """Row x n_ref + column of every true pair, in increasing order (a canonical CSR's order)."""
        rows = np.repeat(np.arange(self.matrix.shape[0], dtype=np.int64), np.diff(self.matrix.indptr))
        return rows * np.int64(self.matrix.shape[1]) + self.matrix.indices.astype(np.int64)


def truth_from_pairs(rows: NDArray[np.int64], cols: NDArray[np.int64], query_names: Sequence[str],
                      ref_names: Sequence[str], warnings: list[str]) -> Truth:
    """A Truth with True at each (row, col); duplicates collapse, columns off the end are dropped."""
    n_ref = len(ref_names)
    keep = (cols >= 0) & (cols < n_ref)
    rows, cols = rows[keep], cols[keep]
    matrix = sparse.coo_array((np.ones(rows.size, dtype=np.bool_), (rows, cols)),
                              shape=(len(query_names), n_ref))
    return Truth(matrix.tocsr(), list(query_names), list(ref_names), warnings)


def position_spans(centres: NDArray[np.int64], tolerance: ArrayLike,
                   n_ref: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The reference frames centre - T .. centre + T in the reference's order, as (first, stop)
    within the n_ref frames; none (stop == first) where the centre is -1. T may differ per centre,
    and callers clip it to n_ref (a band that wide covers the whole map) so that it fits int64."""
    tol = np.broadcast_to(np.asarray(tolerance, dtype=np.int64), centres.shape)
    first = np.clip(centres - tol, 0, n_ref)
    return first, np.where(centres >= 0, np.clip(centres + tol + 1, 0, n_ref), first)


def band(rows: NDArray[np.int64], first: NDArray[np.int64],
         stop: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Expand each row into (row, first .. stop - 1). A band marking more than MAX_TRUE_PAIRS
    pairs is refused before anything is allocated."""
    width = stop - first
    total = check_pair_count(int(width.sum()), "tolerance")
    starts = np.cumsum(width) - width
    offset = np.arange(total, dtype=np.int64) - np.repeat(starts, width)
    return np.repeat(rows, width), np.repeat(first, width) + offset


MAX_TRUE_PAIRS = 50_000_000
"""The most (query, reference) pairs a ground truth may mark true: 1.2 GB as index pairs."""


def check_pair_count(total: int, parameter: str) -> int:
    """``total`` true pairs, refused (naming ``parameter``, the tolerance or radius that makes them)
    when more than :data:`MAX_TRUE_PAIRS`, before they are allocated."""
    if total > MAX_TRUE_PAIRS:
        raise WilocError(None, f"this {parameter} makes {total:,} true pairs (at most {MAX_TRUE_PAIRS:,}): "
                               "every frame would match most of the map", parameter=parameter)
    return total


def name_index(names: Sequence[str]) -> pd.Index:
    """Frame names to look up, each in Unicode's composed form (NFC), so that a name typed on Linux
    matches the same name copied from macOS (decomposed, NFD); kept as given where two names
    differ in that alone."""
    composed = [unicodedata.normalize("NFC", name) for name in names]
    return pd.Index(composed if len(set(composed)) == len(set(names)) else list(names), dtype=object)


def lookup(wanted: Sequence[str], names: Sequence[str]) -> NDArray[np.int64]:
    """Position of each wanted name among ``names``, -1 where it is not a frame."""
    return name_index(names).get_indexer(name_index(wanted)).astype(np.int64)


def check_tolerance(tolerance: int) -> int:
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, np.integer)) or tolerance < 0:
        raise WilocError(None, f"must be a whole number of frames >= 0, got {tolerance!r}", parameter="tolerance")
    return int(tolerance)


def holds_indices(names: Sequence[str]) -> bool:
    """Whether frame names are their indices in the traversal, as a video's are (``000005``)."""
    return bool(names) and all(name.isascii() and name.isdigit() for name in names)


def frame_indices(names: Sequence[str]) -> NDArray[np.int64]:
    """Each frame's index in its traversal, as aligned ground truth by index reads it: the number
    a video's frame names hold (``000005``: its index in the video, which sampling every n-th
    frame or at a frame rate keeps), else the frame's position."""
    if holds_indices(names):
        return np.array([int(name) for name in names], dtype=np.int64)
    return np.arange(len(names), dtype=np.int64)


LeftOut = Sequence[tuple[int, str]]
"""The reference's frames a run left out (unreadable): (position in its full order, name) pairs,
as a results header's ``reference_left_out`` records them."""


def full_order(ref_names: Sequence[str], left_out: LeftOut) -> tuple[list[str], NDArray[np.int64]]:
    """The reference's frames in its full order, those left out put back at their positions, and
    each one's column among ``ref_names`` (-1: left out); a TruthMismatch when they do not fit."""
    n = len(ref_names) + len(left_out)
    positions = np.array([position for position, _ in left_out], dtype=np.int64)
    names = [name for _, name in left_out]
    if (((positions < 0) | (positions >= n)).any() or np.unique(positions).size < positions.size
            or not set(names).isdisjoint(ref_names)):
        raise TruthMismatch("reference_left_out", f"its frames left out ({', '.join(names)}) do not fit among the "
                                                  f"map's {len(ref_names)} frames")
    column = np.full(n, -1, dtype=np.int64)
    column[np.setdiff1d(np.arange(n), positions)] = np.arange(len(ref_names))
    full = np.empty(n, dtype=object)
    full[column >= 0], full[positions] = list(ref_names), names
    return full.tolist(), column


def past_left_out(ref_names: Sequence[str], left_out: LeftOut, truth_of: Callable[[list[str]], Truth]) -> Truth:
    """The truth ``truth_of`` gives over the reference's full order (:func:`full_order`), over
    its kept frames: a band counts the frames left out, yet they are no candidates (dropped)."""
    full, column = full_order(ref_names, left_out)
    truth = truth_of(full)
    pairs = truth.matrix.tocoo()
    kept = column[pairs.col] >= 0
    return truth_from_pairs(pairs.row[kept].astype(np.int64), column[pairs.col[kept]], truth.query_names, ref_names,
                            truth.warnings)


def _read_csv(path: Path) -> pd.DataFrame:
    """A CSV's rows as text under its header's column names (stripped, lower case), indexed by
    line number. Cells are kept as written (a quoted name keeps its spaces), but for spaces after
    a comma and empty cells past the header's columns (a comma at each line's end, as spreadsheets
    export); blank lines are read past. A row of other cells than the header names is a
    WilocError naming its line, so that no cell is read under another column."""
    path = Path(path)
    check_file(path)
    rows, lines = [], []
    try:
        with path.open(encoding="utf-8-sig", newline="") as handle:  # newline="": quoted line breaks
            reader = csv.reader(handle, skipinitialspace=True)
            columns = [cell.strip().lower() for cell in next((row for row in reader if any(row)), [])]
            header = reader.line_num
            for row in reader:
                cells = row[:len(columns)] if not any(row[len(columns):]) else row
                if any(cells) and len(cells) != len(columns):
                    raise WilocError(path, f"line {reader.line_num}: {len(row)} cell(s), where the header "
                                           f"(line {header}) names {len(columns)} columns")
                if any(cells):
                    rows.append(cells)
                    lines.append(reader.line_num)
    except (csv.Error, UnicodeDecodeError) as exc:
        raise WilocError(path, f"not a readable CSV ({exc})") from exc
    return pd.DataFrame(rows, columns=columns, index=lines, dtype=str)


def _require_columns(path: Path, frame: pd.DataFrame, columns: Sequence[str], header: str) -> None:
    """A WilocError naming the columns missing from ``frame`` (read from ``path``), with the
    file's first line as it is and, where that line shows why, what to change: another separator
    than commas, or no header at all (a first line of data; ``header`` is one that would do)."""
    missing = [c for c in columns if c not in frame.columns]
    if not missing:
        return
    with Path(path).open(encoding="utf-8-sig", errors="replace") as handle:
        first = handle.readline().strip()
    fields = [field.strip().strip('"') for field in re.split(r"[,;\t]", first)]
    if ("," not in first) and (";" in first or "\t" in first):
        hint = "; columns must be separated by commas"
    elif any(pd.notna(pd.to_numeric(field, errors="coerce")) or re.search(r"\.[A-Za-z]\w{1,4}$", field)
             for field in fields):
        hint = f"; the first line must be a header naming the columns, such as '{header}'"
    else:
        hint = ""
    shown = first if len(first) <= 80 else first[:77] + "..."
    raise WilocError(path, f"missing column(s) {', '.join(missing)}: its first line is '{shown}'{hint}")


def _require_rows(path: Path, frame: pd.DataFrame, columns: Sequence[str], header: str, rows: tuple[str, str]) -> None:
    """A WilocError naming ``path`` for a column named twice, no row below the header (``rows``:
    what the lines list and each line, ``("pairs", "each true match")``) or a row with an empty
    cell in ``columns``, naming its line: nothing is read under another column, nor skipped."""
    if (twice := frame.columns[frame.columns.duplicated() & (frame.columns != "")]).size:
        raise WilocError(path, f"its header line names column '{twice[0]}' twice")
    if frame.empty:
        raise WilocError(path, f"holds no {rows[0]}, only its header line: list {rows[1]} below it as a line {header}")
    empty = frame[list(columns)] == ""
    if empty.to_numpy().any():
        line, cells = next((line, cells) for line, cells in empty.iterrows() if cells.any())
        raise WilocError(path, f"line {line}: its {cells.idxmax()} cell is empty; each line is {header}")


def _numeric(path: Path, frame: pd.DataFrame, columns: Sequence[str]) -> NDArray[np.float64]:
    """The named columns as float64; any empty, non-numeric or NaN cell -> WilocError."""
    values = frame[list(columns)].apply(pd.to_numeric, errors="coerce").to_numpy(np.float64)
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        raise WilocError(path, f"{int(bad.sum())} row(s) have a missing or non-numeric "
                               f"{'/'.join(columns)} value (first: line {frame.index[bad.argmax()]})")
    return values


def _no_duplicates(path: Path, frame: pd.DataFrame, columns: Sequence[str]) -> None:
    dup = frame.duplicated(subset=list(columns))
    if dup.any():
        first = frame.loc[dup, list(columns)].iloc[0].tolist()
        raise WilocError(path, f"{int(dup.sum())} duplicate row(s) of {'/'.join(columns)} "
                               f"(first: {', '.join(first)})")


@dataclass(frozen=True)
class Positions:
    """Where frames were taken: ``names`` and their ``coords``, metres (x, y) or degrees
    (lat, lon) when ``geographic``; ``source`` names where they came from in messages."""

    source: Path | str
    names: pd.Index
    coords: NDArray[np.float64]
    geographic: bool


def _read_positions(path: Path) -> Positions:
    """Names, coordinates and whether they are lat/lon (else metric x,y) from a positions CSV."""
    frame = _read_csv(path)
    for other, column in COLUMN_NAMES.items():
        if other in frame.columns and column not in frame.columns:
            frame = frame.rename(columns={other: column})
    _require_columns(path, frame, ["name"], "name,x,y")
    _require_rows(path, frame, ["name"], "name,x,y", ("positions", "each frame's position"))
    if {"lat", "lon"} <= set(frame.columns):
        geographic, columns = True, ["lat", "lon"]
    elif {"x", "y"} <= set(frame.columns):
        geographic, columns = False, ["x", "y"]
    else:
        raise WilocError(path, "positions need columns name,x,y (metres) or name,lat,lon (degrees); "
                               f"found {', '.join(frame.columns)}")
    _no_duplicates(path, frame, ["name"])
    coords = _numeric(path, frame, columns)
    if geographic:
        check_lat_lon(coords, path)
    else:
        check_metres(coords, path)
    return Positions(path, name_index(frame["name"]), coords, geographic)


def _unit_vectors(latlon_deg: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points on the unit sphere for (lat, lon) in degrees."""
    lat, lon = np.radians(latlon_deg[:, 0]), np.radians(latlon_deg[:, 1])
    return np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def _frames_with_positions(positions: Positions, frames: Sequence[str],
                           role: str) -> tuple[NDArray[np.int64], NDArray[np.float64], list[str]]:
    """Frame indices that have a position, their coordinates, and warnings about partial matches."""
    where, names = positions.source, positions.names
    at = names.get_indexer(name_index(frames))
    found = at >= 0
    if not found.any():
        raise TruthMismatch(where, f"no name matches any of the {len(frames)} {role} frames"
                                + why_unmatched(list(names), frames))
    what = f"{role} frames have no ground-truth row (never a true match)"
    warnings = (query_frames_without(where, ~found, what) if role == "query"  # a slice of the run counts its own
                else unmatched(where, int((~found).sum()), len(frames), what))
    unused = len(names) - int(np.unique(at[found]).size)
    warnings += unmatched(where, unused, len(names), f"ground-truth rows name no {role} frame")
    return np.flatnonzero(found).astype(np.int64), positions.coords[at[found]], warnings


def check_radius(radius: float) -> float:
    """The radius in metres, a finite number >= 0 (a ParameterError naming ``radius`` otherwise)."""
    if isinstance(radius, bool) or not isinstance(radius, Real) or not 0 <= radius < np.inf:
        shown = radius if isinstance(radius, Real) else repr(radius)
        raise ParameterError("radius", f"must be a finite number >= 0 metres, got {shown}")
    return float(radius)


def truth_within(query: Positions, ref: Positions, radius: float, query_names: Sequence[str],
                 ref_names: Sequence[str]) -> Truth:
    """Frames within ``radius`` metres of each other are the same place: Euclidean on x,y, the
    great-circle distance on lat,lon (a sphere of the mean Earth radius, found as the chord
    between unit vectors). Every positions-based form (CSV files, @UTM names, EXIF GPS) ends
    here. Passing the same ``Positions`` twice is sequence mode."""
    reach = check_radius(radius)
    if query.geographic != ref.geographic:
        raise WilocError(ref.source, f"uses {'lat/lon' if ref.geographic else 'x/y'} but {query.source} uses "
                                     f"{'lat/lon' if query.geographic else 'x/y'}")
    q_idx, q_pts, warnings = _frames_with_positions(query, query_names, "query")
    r_idx, r_pts, r_warn = _frames_with_positions(ref, ref_names, "reference")
    if not (ref is query and list(query_names) == list(ref_names)):
        warnings += r_warn
    if query.geographic:
        q_pts, r_pts = _unit_vectors(q_pts), _unit_vectors(r_pts)
        reach = 2.0 * np.sin(min(reach / EARTH_RADIUS_M, np.pi) / 2.0)
    q_tree, r_tree = cKDTree(q_pts), cKDTree(r_pts)
    check_pair_count(int(q_tree.count_neighbors(r_tree, reach)), "radius")  # counted without allocating them
    near = q_tree.sparse_distance_matrix(r_tree, reach, output_type="ndarray")
    if r_idx.size > 1 and near.size == q_idx.size * r_idx.size:
        warnings.append(_all_near(query, ref, radius))
    return truth_from_pairs(q_idx[near["i"]], r_idx[near["j"]], query_names, ref_names, warnings)


def _all_near(query: Positions, ref: Positions, radius: float) -> str:
    """The warning for positions that put every query frame within the radius of every reference
    frame, so that any match counts as right; GPS degrees given as x,y (read as metres) do so."""
    coords = np.concatenate([query.coords, ref.coords])
    degrees = (not query.geographic and bool(np.all(np.abs(coords) <= 180))
               and float(np.ptp(coords, axis=0).max()) < 1.0)
    hint = ("; its x,y look like degrees: give GPS positions as columns lat,lon" if degrees
            else "; a smaller radius tells places apart")
    return (f"{query.source}: every query frame lies within {radius:g} m of every reference frame, so "
            f"every match counts as right{hint}")


def positions_truth(query_csv: Path, ref_csv: Path, radius: float, query_names: Sequence[str],
                    ref_names: Sequence[str]) -> Truth:
    """Positions form: frames within ``radius`` metres of each other are the same place.

    CSV columns ``name,x,y`` (metres, Euclidean) or ``name,lat,lon`` (degrees; great-circle
    distance, see :func:`truth_within`). Sequence mode: pass the same CSV twice.
    """
    check_radius(radius)
    query = _read_positions(query_csv)
    same_file = Path(query_csv).resolve() == Path(ref_csv).resolve()
    ref = query if same_file else _read_positions(ref_csv)
    return truth_within(query, ref, radius, query_names, ref_names)


def pairs_truth(csv: Path, query_names: Sequence[str], ref_names: Sequence[str], left_out: LeftOut = ()) -> Truth:
    """Pairs form: CSV rows ``query,reference`` list every true match (optional ``tolerance``).

    A ``tolerance`` column widens a row to +-T frames around the reference in the reference's
    order, its frames ``left_out`` counted too (as :func:`wiloc.evaluation.aligned.aligned_truth`
    counts them). Query frames without a row have no true match.
    """
    if left_out:
        return past_left_out(ref_names, left_out, lambda full: pairs_truth(csv, query_names, full))
    path = Path(csv)
    frame = _read_csv(path)
    _require_columns(path, frame, ["query", "reference"], "query,reference")
    _require_rows(path, frame, ["query", "reference"], "query,reference", ("pairs", "each true match"))
    _no_duplicates(path, frame, ["query", "reference"])
    if "tolerance" in frame.columns:
        tol = _numeric(path, frame, ["tolerance"])[:, 0]
        if (bad := (tol < 0) | (tol != np.round(tol))).any():
            raise WilocError(path, "tolerance must be a whole number of frames >= 0 "
                                   f"(first: line {frame.index[bad.argmax()]})")
        tolerance = np.minimum(tol, len(ref_names)).astype(np.int64)  # 1e30 would wrap to a negative band
    else:
        tolerance = np.zeros(len(frame), dtype=np.int64)
    q = lookup(frame["query"], query_names)
    r = lookup(frame["reference"], ref_names)
    usable = (q >= 0) & (r >= 0)
    if not usable.any():
        column, names = ("query", query_names) if not (q >= 0).any() else ("reference", ref_names)
        raise TruthMismatch(path, f"none of the {len(frame)} rows names a known query frame and a "
                               f"known reference frame{why_unmatched(frame[column].tolist(), names)}")
    warnings = unmatched(path, int((q < 0).sum()), len(frame), "rows name no query frame (skipped)")
    warnings += unmatched(path, int((r < 0).sum()), len(frame),
                           "rows name no reference frame (skipped)")
    rows, cols = band(q[usable], *position_spans(r[usable], tolerance[usable], len(ref_names)))
    return truth_from_pairs(rows, cols, query_names, ref_names, warnings)


def restrict_sequence(truth: Truth, exclude_recent: int) -> Truth:
    """Sequence mode: keep only true matches to earlier frames outside the recent window (i < k - R).

    Frames k - R .. k are never candidates in sequence mode, so they cannot count as true matches
    (nor make a frame count towards recall).
    """
    if not truth.sequence:
        raise WilocError(None, "sequence restriction needs the same frames as queries and references")
    if int(exclude_recent) != exclude_recent or exclude_recent < 0:
        raise WilocError(None, f"exclude-recent must be a whole number >= 0, got {exclude_recent}")
    coo = truth.matrix.tocoo()
    keep = coo.col.astype(np.int64) < coo.row.astype(np.int64) - int(exclude_recent)
    return truth_from_pairs(coo.row[keep].astype(np.int64), coo.col[keep].astype(np.int64),
                             truth.query_names, truth.ref_names, list(truth.warnings))

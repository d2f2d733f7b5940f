"""Results files: one CSV per query traversal with a self-describing header.

Layout (documented in docs/formats.md): header lines start with ``# `` and hold ``key: value`` pairs, read and
written by ``wiloc.evaluation.results_header``; the first is ``# wiloc-results: 1``. Then a plain CSV table, one
row per query frame. Batch files are written to a temporary name and renamed, so a killed run never leaves a
file that looks complete. A followed run's file (``follow: True`` in its header, no ``frames`` count) grows a
row per frame as it is decided: each row is one write, and a torn last row is cut off when the run resumes.
"""
from __future__ import annotations

import csv
import difflib
import io
import math
import os
import stat
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from wiloc.atomic import cut_to_whole_lines, write_error, written_whole
from wiloc.decisions import Decision, Decisions
from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.results_header import ResultsHeader, header_line, parse_header, read_header
from wiloc.evaluation.results_lock import results_lock
from wiloc.model import HistogramModel
from wiloc.reprs import short_repr

if TYPE_CHECKING:
    from wiloc.methods.base import Method

BASE_COLUMNS = ("frame", "match", "difference", "confidence", "stage")
RANKING = "ranking"  # the column of each frame's best candidates (methods that rank; docs/formats.md)
NEW_PLACE = "new_place"  # the column of each frame's P(new place) (methods that say it: docs/formats.md)
TEXT_COLUMNS = ("frame", "match", "stage", RANKING)


@short_repr
@dataclass
class Results:
    """One localization run: what was run (``header``) and what it decided (``frames``)."""

    header: ResultsHeader
    frames: pd.DataFrame
    reference_frames: list[str] = field(default_factory=list)

    @property
    def method(self) -> str:
        return self.header.method

    @property
    def model(self) -> HistogramModel | None:
        data = self.header.model
        return HistogramModel.from_dict(data) if data else None

    @property
    def match_index(self) -> np.ndarray:
        """Reference positions of the matched frames (-1 when undecided)."""
        lookup = {name: i for i, name in enumerate(self.reference_frames)}
        return np.array([lookup.get(m, -1) if isinstance(m, str) else -1
                         for m in self.frames["match"]], dtype=np.int64)

    @property
    def confidence(self) -> np.ndarray:
        return self.frames["confidence"].to_numpy(dtype=np.float64)

    @property
    def new_place(self) -> np.ndarray | None:
        """Each frame's probability that it shows a place absent from the map (NaN where not
        given); None for a run without the column (methods that do not say it)."""
        if NEW_PLACE not in self.frames.columns:
            return None
        return self.frames[NEW_PLACE].to_numpy(dtype=np.float64)

    def save(self, path: str | os.PathLike) -> Path:
        """Write these results as a results file (:func:`write_results`, atomically), never over a
        file that is none (a frame, a table of one's own) nor while a run (``--follow``) holds it."""
        if os.fspath(path).endswith(("/", os.sep)):
            raise ParameterError("path", f"{os.fspath(path)!r} names a folder: give the results file's name")
        path = Path(path)
        with results_lock(path):
            write_results(path, self)
        return path

    @property
    def ranking(self) -> np.ndarray | None:
        """Each frame's best candidates as reference positions, best first, padded with -1
        (frames x K); None for a run without the column (seqslam, files of older versions)."""
        if RANKING not in self.frames.columns:
            return None
        return parse_ranking(self.frames[RANKING].tolist())


def ranking_text(ranking: Any) -> str:
    """A ranking as its results-file cell: positions separated by spaces, best first."""
    return " ".join(str(int(i)) for i in ranking if i >= 0)


def _positions(text: str) -> list[int] | None:
    """A ranking cell's positions; None when it is not whole numbers separated by spaces."""
    parts = str(text).split()
    return [int(part) for part in parts] if all(part.isdigit() for part in parts) else None


def parse_ranking(cells: list[str]) -> np.ndarray:
    """A results column's rankings (checked by :func:`read_results`): frames x the longest, padded with -1."""
    rows = [_positions(text) or [] for text in cells]
    ranking = np.full((len(rows), max(map(len, rows), default=0)), -1, dtype=np.int64)
    for out, row in zip(ranking, rows):
        out[:len(row)] = row
    return ranking


def decisions_to_frame(decisions: Decisions, query_names: list[str], ref_names: list[str]) -> pd.DataFrame:
    """The per-frame table of a run, with frame names instead of positions."""
    matched = np.full(len(decisions), "", dtype=object)
    decided = decisions.match >= 0
    matched[decided] = np.asarray(ref_names, dtype=object)[decisions.match[decided]]
    table = {"frame": list(query_names), "match": matched, "difference": decisions.difference,
             "confidence": decisions.confidence, "stage": decisions.stage, **decisions.columns}
    if decisions.ranking is not None:
        table[RANKING] = [ranking_text(row) for row in decisions.ranking]
    return pd.DataFrame(table)


def _write_atomically(path: Path, header: ResultsHeader, write_table: Any, mode: int | None = None) -> None:
    """Write the header lines and then ``write_table(file)``, whole or not at all
    (``atomic.written_whole``). The file gets ``mode``, else the usual new-file mode."""
    with written_whole(path, "the results file", mode=mode) as out:
        out.write(header.text())
        write_table(out)


def make_results(decisions: Decisions, *, query_names: list[str], ref_names: list[str],
                 header: ResultsHeader) -> Results:
    """A run's results in memory, with the header a results file holds: ``header`` (what was
    run) completed with the row count, the method's parameters, its model and the map's frames."""
    frame = decisions_to_frame(decisions, query_names, ref_names)
    header = replace(header, frames=len(frame), params=decisions.params,
                     model=decisions.model.to_dict() if decisions.model is not None else None,
                     reference_frames=tuple(ref_names))
    return Results(header=header, frames=frame, reference_frames=list(ref_names))


def write_results(path: Path, results: Results) -> bool:
    """Write a results file atomically (keeping the mode of a file it replaces); True when it
    replaced one."""
    path = Path(path)
    try:
        mode: int | None = path.stat().st_mode & 0o7777
    except OSError:  # nothing there, or a name no file can have (which writing says)
        mode = None
    replaced = mode is not None
    _write_atomically(path, results.header, lambda out: _write_table(out, results.frames), mode=mode)
    return replaced


def _write_table(out: Any, frames: pd.DataFrame) -> None:
    """Write ``frames`` as a results file's table: its column line, then one :func:`_csv_line` a row."""
    out.write(_csv_line(list(frames.columns)))
    for row in frames.itertuples(index=False, name=None):
        out.write(_csv_line([_cell(value) for value in row]))


def _cell(value: Any) -> Any:
    """A value as a results table holds it: floats with 9 significant digits, NaN empty."""
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else f"{value:.9g}"
    return value


def _csv_line(cells: list[Any]) -> str:
    """One line of a results table ending in ``\\n``. A cell holding a carriage return is quoted as
    one holding a line feed is: readers (pandas, Python's universal newlines) end a line at
    either, and the csv module quotes only the characters of its line terminator, hence the
    ``\\r\\n`` written and its end replaced."""
    text = io.StringIO()
    csv.writer(text, lineterminator="\r\n").writerow(cells)
    return text.getvalue()[:-2] + "\n"


class ResultsStream:
    """A followed run's results file, written row by row as frames are decided.

    Opening it writes the header (``follow: True``, no ``frames`` count, no model) and the column
    line atomically, unless ``resume`` and the file exists: then a torn last row is cut off and
    :attr:`rows` holds the rows already written (as text), for the caller to replay and check.
    Each :meth:`append` is one write of one whole line, so the file never holds half a row;
    :meth:`finish` writes what the run learned into the header once it ends. ``learned`` names
    the ``params`` the run learns (``Method.facts``), which a resumed file's header may hold
    otherwise than the run's start.
    """

    def __init__(self, path: Path, header: ResultsHeader, columns: tuple[str, ...], *, resume: bool,
                 learned: Collection[str] = ()) -> None:
        self.path = Path(path)
        self.columns = (*BASE_COLUMNS, *columns)
        self.header = replace(header, follow=True)
        self.rows = pd.DataFrame(columns=list(self.columns))
        if resume and self.path.exists():
            cut_to_whole_lines(self.path)  # rows appended after a torn line would join it
            found, self.rows, _ = _read_table(self.path)
            expected = parse_header(self.header.text().splitlines(), self.path)  # as a file gives it back
            if _settings(found, expected, learned) != _settings(expected, expected, learned):
                held = "a run with other settings" if found.follow else "a batch run's rows, which a followed run cannot resume"
                raise WilocError(None, f"{self.path} holds {held}; give another file to start anew", parameter="out")
        else:
            _write_atomically(self.path, self.header, lambda out: out.write(",".join(self.columns) + "\n"))
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    def line(self, decision: Decision) -> str:
        """The CSV line of one decision, as the batch writer formats it."""
        values = {"frame": decision.frame, "match": decision.match_name, "difference": decision.difference,
                  "confidence": decision.confidence, "stage": decision.stage, "new_place": decision.new_place,
                  RANKING: ranking_text(decision.ranking), **decision.extra}
        return _csv_line([_cell(values[c]) for c in self.columns])

    def written_lines(self) -> list[str]:
        """The rows already in the file (when resumed), as :meth:`line` formats them."""
        return [_csv_line(list(row)) for row in self.rows.itertuples(index=False)]

    def append(self, decision: Decision) -> None:
        """Add one decided frame's row; it reaches the OS before this returns."""
        try:
            os.write(self._fd, self.line(decision).encode("utf-8"))
        except OSError as exc:
            raise write_error(self.path, "the results file", exc) from None

    def close(self) -> None:
        os.close(self._fd)

    def finish(self, header: ResultsHeader) -> None:
        """Write ``header``, the run's as it ended (its learned model and parameters, a
        sequence-mode run's query digest), over the file's, keeping its rows and mode: atomically,
        so that a kill meanwhile leaves the file as it was. Called once :meth:`close` has been."""
        with self.path.open(encoding="utf-8", newline="") as handle:
            lines = handle.readlines()
        header_lines = next((i for i, line in enumerate(lines) if not line.startswith("# ")), len(lines))
        body = "".join(lines[header_lines:])  # a row may start with '# ' too: a frame named '# 1.jpg'
        self.header = replace(header, follow=True, frames=None)
        _write_atomically(self.path, self.header, lambda out: out.write(body),
                          mode=stat.S_IMODE(self.path.stat().st_mode))


#: Header lines a followed file of an older wiloc lacks: a resumed file without them is the run's.
FOLLOW_ADDED = ("map_digest", "sampling", "topic", "odometry_topic", "rows", "fabmap_training", "reference_left_out")


def _settings(header: ResultsHeader, expected: ResultsHeader, learned: Collection[str]) -> ResultsHeader:
    """What of a followed file's ``header`` must equal the run's (``expected``) for the run to
    resume it: all but the version that wrote it, what the run learned (its model, the
    ``learned`` params, a sequence-mode query digest and reference frames, the frames seen: written
    as it ends) and the lines (:data:`FOLLOW_ADDED`) and method parameters (added since: their
    default is what it did) that an older version's file lacks, where it lacks them."""
    older = {name: getattr(expected, name) for name in FOLLOW_ADDED if getattr(header, name) is None}
    params = {key: value for key, value in {**expected.params, **header.params}.items() if key not in learned}
    seen = {"reference_frames": ()} if header.sequence else {}
    return replace(header, **older, **seen, wiloc="", model=None, query_digest=None, params=params)


def read_results(path: Path, methods: Mapping[str, type[Method]] | None = None) -> Results:
    """Read a results file written by :func:`write_results` (or a followed run's); WilocError
    naming the file and line when it is not one or holds something no run writes.
    ``methods`` are the registered ones (``wiloc.methods.registry.METHODS``): a file naming one
    has its confidences checked down to that method's ``lowest_confidence`` and its differences
    checked (:func:`_check_differences`); a file naming another (a method a program of its own
    registers), or read without ``methods``, has confidences in [0, 1] and differences unchecked;
    a file naming no method, or one close to a registered name (:func:`_method`), is refused."""
    path = Path(path)
    header, frames, first_line = _read_table(path)
    method = _method(path, header, methods) if methods is not None else None
    if method is not None:
        _check_columns(path, frames, header.method, method, first_line - 1)
    reference = _reference_frames(path, header, frames)
    known = set(reference)
    for i, match in enumerate(frames["match"]):
        if match and match not in known:
            raise WilocError(path, f"line {first_line + i}: match '{match}' is not a frame of the map")
    if RANKING in frames.columns:
        _check_ranking(path, frames, reference, first_line)
    for column in frames.columns.difference(TEXT_COLUMNS):
        numbers = pd.to_numeric(frames[column].replace("", np.nan), errors="coerce")
        bad = numbers.isna() & (frames[column] != "")
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise WilocError(path, f"line {first_line + i}: {column} '{frames[column].iloc[i]}' is not a number")
        frames[column] = numbers.astype(np.float64)
    _check_probabilities(path, frames, header.method, method.lowest_confidence if method else 0.0, first_line)
    if method is not None:
        _check_differences(path, frames, _on_evidence(header, method), first_line)
    _check_decided(path, frames, first_line)
    return Results(header=header, frames=frames, reference_frames=reference)


def _method(path: Path, header: ResultsHeader, methods: Mapping[str, type[Method]]) -> type[Method] | None:
    """The class of the method a results file names, None for a name not among ``methods`` (one a
    program of its own registers: its runs are read, unchecked against its bounds); a WilocError
    naming the file and the line when it names none (every run writes its method's name) or a
    name close to a registered one (:func:`_resembled`): a misspelt ``catgrap`` read as another
    program's method would pass, unchecked, what catgraph's checks refuse."""
    if header.method in methods:
        return methods[header.method]
    if header.method.strip():
        close = _resembled(header.method, methods)
        if close is None:
            return None
        raise WilocError(path, f"line {header_line(path, 'method')}: method '{header.method}' is not registered: "
                               f"did you mean '{close}'? (a program that registers '{header.method}' reads its runs)")
    line = header_line(path, "method")
    if line is None:
        raise WilocError(path, "no 'method' header: the method that wrote the file is unknown")
    raise WilocError(path, f"line {line}: header 'method' is empty: the method that wrote the file is unknown")


#: How alike (difflib's ratio) a results file's method name and a registered one must be for the
#: file's name to be taken as the registered one misspelt: one letter dropped, added or changed in
#: names of six letters or more (``catgrap``, ``onlin``), not another word (``offline``, ``random``).
CLOSE_NAME = 0.8


def _resembled(name: str, methods: Collection[str]) -> str | None:
    """The registered method name ``name`` resembles, compared without case, ``-`` and ``_``
    (``Catgraph``, ``cat-graph`` are catgraph's); None when it resembles none."""
    def key(text: str) -> str:
        return text.lower().replace("-", "").replace("_", "")

    keys = {key(registered): registered for registered in methods}
    close = difflib.get_close_matches(key(name), keys, n=1, cutoff=CLOSE_NAME)
    return keys[close[0]] if close else None


def _check_columns(path: Path, frames: pd.DataFrame, name: str, method: type[Method], line: int) -> None:
    """A WilocError naming the file and its column line (``line``) for a column ``method`` never
    writes: a renamed one (``new_plac``) would otherwise be read as if the run had no such values."""
    known = (*BASE_COLUMNS, *method.columns, *((RANKING,) if method.ranks else ()))
    unknown = [column for column in frames.columns if column not in known]
    if unknown:
        raise WilocError(path, f"line {line}: unknown column(s) {', '.join(map(repr, unknown))}: "
                               f"the method {name} writes {', '.join(known)}")


def _on_evidence(header: ResultsHeader, method: type[Method]) -> bool:
    """Whether a run's rows were FAB-MAP's evidence, whose differences (-r) go below 0: its header
    says ``rows: fabmap``; a followed file of an older version, without the line, may be such a
    run where its method reads evidence and its descriptor is ``bow`` (or not said)."""
    if header.rows is not None:
        return header.rows == "fabmap"
    return "log_ratio" in method.rows and header.descriptor in ("bow", None)


def _check_differences(path: Path, frames: pd.DataFrame, evidence: bool, first_line: int) -> None:
    """A WilocError naming the file and line of a difference no run writes: infinite, or below 0
    where the rows were differences (every metric's are >= 0; FAB-MAP's evidence gives -r, of
    either sign). Empty cells (undecided frames) pass."""
    values = frames["difference"].to_numpy()
    bad = ~np.isnan(values) & ~(np.isfinite(values) & ((values >= 0) | evidence))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        span = "a finite number" if evidence else "a finite number >= 0 (as every run on differences writes it)"
        raise WilocError(path, f"line {first_line + i}: difference {values[i]:g} is not {span}")


def _check_probabilities(path: Path, frames: pd.DataFrame, method: str, lowest: float, first_line: int) -> None:
    """A WilocError naming the file and line of a confidence or P(new place) that no run writes:
    outside [0, 1], or for a method whose confidence goes below 0 to ``lowest`` (``threshold``)
    above 1 or infinite. Empty cells (undecided frames) pass."""
    for column, low in (("confidence", lowest), (NEW_PLACE, 0.0)):
        if column not in frames.columns:
            continue
        values = frames[column].to_numpy()
        bad = ~np.isnan(values) & ~((values >= low) & (values <= 1.0) & np.isfinite(values))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            span = "in [0, 1]" if low == 0.0 else f"a finite number at most 1 (as {method} writes it)"
            raise WilocError(path, f"line {first_line + i}: {column} {values[i]:g} is not {span}")


def _check_decided(path: Path, frames: pd.DataFrame, first_line: int) -> None:
    """A WilocError naming the file and line of a match without a confidence or a confidence
    without a match: a run writes both (a decided frame) or neither, and the metrics would count
    such a frame as decided in one table and not in another."""
    matched = (frames["match"] != "").to_numpy()
    confident = ~np.isnan(frames["confidence"].to_numpy())
    odd = np.flatnonzero(matched != confident)
    if odd.size:
        i = int(odd[0])
        problem = (f"match '{frames['match'].iloc[i]}' has no confidence" if matched[i]
                   else f"confidence {frames['confidence'].iloc[i]:g} without a match")
        raise WilocError(path, f"line {first_line + i}: {problem} (a run writes both or neither)")


def _check_ranking(path: Path, frames: pd.DataFrame, reference: list[str], first_line: int) -> None:
    """A WilocError naming the file and line of a ranking that no run writes: text that is no
    positions, a position off the map, one twice, or a first that is not the match."""
    lookup = {name: i for i, name in enumerate(reference)}
    for i, (text, match) in enumerate(zip(frames[RANKING], frames["match"])):
        positions = _positions(text)
        ranked = np.asarray(positions or [], dtype=np.int64)
        problem = None
        if positions is None:
            problem = f"ranking '{text}' is not positions separated by spaces"
        elif ranked.size and ranked.max() >= len(reference):
            problem = f"ranking names position {int(ranked.max())}; the map has {len(reference)} frames"
        elif np.unique(ranked).size != ranked.size:
            problem = "ranking names a frame twice"
        elif (lookup.get(match, -1) if match else -1) != (int(ranked[0]) if ranked.size else -1):
            problem = "ranking does not start with the match"
        if problem:
            raise WilocError(path, f"line {first_line + i}: {problem}")


def _reference_frames(path: Path, header: ResultsHeader, frames: pd.DataFrame) -> list[str]:
    """The frames matches may name: the header's ``reference_frames``; in sequence mode, when a
    followed run could not list them up front, the query frames themselves."""
    if header.reference_frames:
        return list(header.reference_frames)
    if header.sequence:
        return frames["frame"].tolist()
    raise WilocError(path, "no 'reference_frames' header: the map frames the matches name are unknown")


def _torn(path: Path) -> bool:
    """Whether the last row has no line end (cut short as it was written); spaces after it are none."""
    with path.open("rb") as handle:
        handle.seek(max(0, handle.seek(0, os.SEEK_END) - 4096))
        return not handle.read().rstrip(b" \t").endswith((b"\n", b"\r"))


def _without_blank_lines(path: Path, frames: pd.DataFrame, first_line: int) -> pd.DataFrame:
    """``frames`` without the empty rows of blank lines (or lines of spaces) at the file's end (an
    editor's); a WilocError naming the line of one between rows, which no run writes and which,
    skipped, would move every later row's line number in the messages that name it."""
    blank = (frames == "").all(axis=1).to_numpy()
    kept = int(np.flatnonzero(~blank)[-1]) + 1 if not blank.all() else 0
    if blank[:kept].any():
        raise WilocError(path, f"line {first_line + int(np.flatnonzero(blank)[0])}: a blank line in the table, "
                               "where a run writes none")
    return frames if kept == len(frames) else frames.iloc[:kept].copy()


def _table(path: Path, n_header: int) -> pd.DataFrame:
    """The table after a results file's ``n_header`` header lines, every cell as text (a blank
    line, or one of spaces alone, as a row of empty cells); a WilocError naming the line of what
    no run writes and a table keyed by column names would read unnoticed: a column named twice or
    not at all (pandas renamed them ``new_place.1``, ``Unnamed: 8``), a row of fewer cells than
    columns (pandas filled it with empty ones) or of more."""
    line = n_header + 1  # the column line's
    try:
        with path.open(encoding="utf-8-sig", newline="") as handle:  # newline="": csv reads quoted line breaks
            for _ in range(n_header):
                handle.readline()
            reader = csv.reader(handle)
            columns = next(reader, [])
            if "" in columns:
                raise WilocError(path, f"line {line}: column {columns.index('') + 1} has no name")
            twice = next((name for i, name in enumerate(columns) if name in columns[:i]), None)
            if twice is not None:
                raise WilocError(path, f"line {line}: column '{twice}' twice")
            rows = []
            for row in reader:
                if row and len(row) != len(columns) and (len(row) > 1 or row[0].strip()):  # spaces alone: blank
                    raise WilocError(path, f"line {n_header + reader.line_num}: {len(row)} cell(s), where the "
                                           f"column line (line {line}) names {len(columns)} columns")
                rows.append(row if len(row) == len(columns) else [""] * len(columns))
    except (csv.Error, ValueError) as exc:
        raise WilocError(path, f"unreadable table: {exc}") from None
    return pd.DataFrame(rows, columns=columns, dtype=str)


def _read_table(path: Path) -> tuple[ResultsHeader, pd.DataFrame, int]:
    """A results file's header, its table (every cell as text) and the line number of the
    table's first row."""
    header, n_header = read_header(path)
    if _torn(path):  # a run ends each row: without its end, a row may be cut within its last value
        raise WilocError(path, "its last row is cut short (no line end): " + (
            "the followed run stopped while writing it, or is writing it now; read the file again, or resume the "
            "run, which cuts it off" if header.follow else "the file was cut (a copy that stopped?); localize writes it whole"))
    frames = _table(path, n_header)
    missing = [c for c in BASE_COLUMNS if c not in frames.columns]
    if missing:
        raise WilocError(path, f"missing column(s): {', '.join(missing)}")
    frames = _without_blank_lines(path, frames, n_header + 2)
    if header.frames is not None and len(frames) != header.frames:
        raise WilocError(path, f"holds {len(frames)} rows, its header says {header.frames}: "
                               "the file is incomplete or was edited")
    odd = np.flatnonzero((frames["frame"].duplicated() | (frames["frame"] == "")).to_numpy())  # a run names each once
    if odd.size:
        names, first = frames["frame"].tolist(), n_header + 2
        name = names[odd[0]]
        problem = (f"frame '{name}' again (line {first + names.index(name)} gives it): a run writes one row a frame"
                   if name else "the frame cell is empty: a run names the frame of every row")
        raise WilocError(path, f"line {first + odd[0]}: {problem}")
    return header, frames, n_header + 2

"""The header of a results file, typed: what was run, read and written in this one place.

A header is ``# key: value`` lines (docs/formats.md, "Results files"); the values of
:data:`JSON_KEYS` are JSON, ``fabmap_training`` is a Python list of folder names, the rest text.
Reading checks every value a run's later steps use, so a file no run writes is refused here,
naming the key. A key this version does not know is kept as text (:attr:`ResultsHeader.extra`).
"""
from __future__ import annotations

import ast
import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from wiloc.descriptors.base import METRICS
from wiloc.errors import WilocError
from wiloc.model import HistogramModel
from wiloc.reprs import short_repr

FORMAT_VERSION = "1"
VERSION_KEY = "wiloc-results"
_START = f"# {VERSION_KEY}:".encode()  # a results file's first bytes
_BOM = b"\xef\xbb\xbf"  # a UTF-8 byte-order mark an editor may put before them
JSON_KEYS = ("params", "descriptor_params", "model", "reference_frames", "reference_left_out", "sampling")


@short_repr
@dataclass(frozen=True)
class ResultsHeader:
    """A results file's header. Fields left None are not written (a run that has no such thing:
    no training pair, no video, a followed run's count and query digest); the others always are,
    except ``model``, which a followed run's file holds only once its run has ended. Fields are
    written in this order."""

    method: str = ""
    descriptor: str | None = None  # None: the file does not say (files made by hand)
    descriptor_params: dict[str, Any] = field(default_factory=dict)
    metric: str = ""
    mode: str = ""  # "map" or "sequence"
    query: str = ""
    map: str = ""  # "" in sequence mode
    exclude_recent: int = 0
    wiloc: str = ""  # the version that wrote the file
    train_query: str | None = None
    train_map: str | None = None
    query_digest: str | None = None  # batch runs only (run_figures checks the images against them)
    map_digest: str | None = None  # "" in sequence mode
    sampling: dict[str, Any] | None = None  # a video's or bag's sampling (wiloc.sources.video.Sampling's fields)
    topic: str | None = None  # the query's image topic (and the map's without map_topic)
    map_topic: str | None = None  # a map bag's image topic of another name (--map-topic)
    odometry_topic: str | None = None
    rows: str | None = None  # "fabmap": the rows were FAB-MAP's evidence, not differences
    fabmap_training: tuple[str, ...] | None = None
    frames: int | None = None  # the row count; None in a followed run's file, which grows
    params: dict[str, Any] = field(default_factory=dict)
    model: dict[str, Any] | None = None  # HistogramModel.to_dict()
    reference_frames: tuple[str, ...] = ()
    # the map's frames the run left out (unreadable): (position in the map's full order, name); None: none
    reference_left_out: tuple[tuple[int, str], ...] | None = None
    follow: bool = False
    extra: dict[str, str] = field(default_factory=dict)  # keys this version does not know, as read

    @property
    def sequence(self) -> bool:
        """Whether the run matched the query against its own earlier frames."""
        return self.mode == "sequence"

    def text(self) -> str:
        """The header as a results file holds it: one ``# key: value`` line each."""
        return "".join(f"# {key}: {value}\n" for key, value in self._items())

    def _items(self) -> Iterator[tuple[str, str]]:
        """(key, text) of each line, the format's version first and unknown keys last."""
        yield VERSION_KEY, FORMAT_VERSION
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "extra":
                yield from ((key, _text_line(text)) for key, text in value.items())
            elif not self._written(f.name, value):
                continue
            elif f.name in JSON_KEYS:
                yield f.name, json.dumps(value)
            elif f.name == "fabmap_training":
                yield f.name, str(list(value))
            else:
                yield f.name, _text_line(str(value))

    def _written(self, name: str, value: Any) -> bool:
        """Whether the field has a line: ``model`` in every batch file (null: the method keeps
        none) and in a followed one once its run has ended (where the method keeps one),
        ``follow`` only when true, the others unless None."""
        if name == "model":
            return not self.follow or value is not None
        if name == "follow":
            return bool(value)
        return value is not None


#: What ends a line for a reader of the header: a line feed, a carriage return, and str.splitlines' others.
_LINE_BREAKS = frozenset("\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")


def _text_line(text: str) -> str:
    """A text value as its header line holds it: as it is, or as a JSON string where it holds a
    line break (a folder's name may) or starts with a quote, so that the line stays one line."""
    return json.dumps(text) if text.startswith('"') or not _LINE_BREAKS.isdisjoint(text) else text


def _text_read(text: str) -> str:
    """A text value of a header line as :func:`_text_line` wrote it."""
    if text.startswith('"'):
        try:
            decoded = json.loads(text)
        except json.JSONDecodeError:  # a file written by hand, or before such values were quoted
            return text
        if isinstance(decoded, str):
            return decoded
    return text


def starts_as_results(path: Path) -> bool | None:
    """Whether the file at ``path`` starts as a results file does (its first line
    ``# wiloc-results: ...``, after an editor's byte-order mark); None when it cannot be read (no
    file, a folder). What tells a results file given where other files go."""
    try:
        with Path(path).open("rb") as file:
            return file.read(len(_BOM) + len(_START)).removeprefix(_BOM).startswith(_START)
    except OSError:
        return None


def read_header(path: Path) -> tuple[ResultsHeader, int]:
    """A results file's header and its number of lines; WilocError naming the file when it is
    no results file or its header holds a value no run writes."""
    lines = _header_lines(path)
    return parse_header(lines, path), len(lines)


def _header_lines(path: Path) -> list[str]:
    """A results file's header lines (those starting ``# ``, up to the first that does not)."""
    if path.is_dir():
        raise WilocError(path, "a folder, not a results file (evaluate and compare read the results "
                               "files localize writes, such as runs/day_left-sad-online.csv)")
    if not path.is_file():  # a device or a pipe exists, yet is no file to read a run from
        raise WilocError(path, "not a regular file" if path.exists() else "results file does not exist")
    lines = []
    try:
        with path.open(encoding="utf-8-sig") as handle:  # a byte-order mark (an editor's) is skipped
            for line in handle:
                if not line.startswith("# "):
                    break
                lines.append(line)
    except UnicodeDecodeError:
        raise WilocError(path, "not a wiloc results file (not UTF-8 text)") from None
    return lines


def header_line(path: Path, key: str) -> int | None:
    """The line number of ``key`` in a results file's header; None when the header has no such
    line. For messages naming the line of a value refused later."""
    return next((n for n, line in enumerate(_header_lines(path), 1) if line[2:].partition(": ")[0] == key), None)


def parse_header(lines: Iterable[str], path: Path | None) -> ResultsHeader:
    """The header of ``# key: value`` lines; a WilocError naming the line of a value no run writes,
    or of a key given twice (which of the two counts is no one's guess: an edit by hand)."""
    values: dict[str, Any] = {}
    where: dict[str, int] = {}
    for n, line in enumerate(lines, 1):
        key, sep, value = line[2:].rstrip("\n").partition(": ")
        if not sep:
            raise WilocError(path, f"malformed header line {n}")
        if key in where:
            raise WilocError(path, f"line {n}: header '{key}' again (line {where[key]} gives it): a run writes each "
                                   "key once")
        try:
            values[key] = json.loads(value) if key in JSON_KEYS else _text_read(value)
        except json.JSONDecodeError as exc:
            raise WilocError(path, f"line {n}: header '{key}' is not valid JSON ({exc.msg})") from None
        where[key] = n
    version = values.pop(VERSION_KEY, None)
    if version is None:
        raise WilocError(path, f"not a wiloc results file (no '# {VERSION_KEY}: {FORMAT_VERSION}' header)")
    if version != FORMAT_VERSION:
        raise WilocError(path, f"line {where[VERSION_KEY]}: results format version {version!r} is not one this wiloc "
                               f"reads (it reads {FORMAT_VERSION})")
    known = {f.name for f in fields(ResultsHeader)} - {"extra"}
    typed = {}
    for key, value in values.items():
        try:
            if key in known:
                typed[key] = _typed(path, key, value)
        except WilocError as exc:
            raise WilocError(path, f"line {where[key]}: {exc.problem}") from None
    if typed.get("mode") == "sequence":
        given = next((key for key in ("map", "map_digest") if typed.get(key)), None)
        if given is not None:
            raise WilocError(path, f"header '{given}' names a map, but 'mode' is sequence: a sequence-mode run "
                                   "is its own map")
    return ResultsHeader(**typed, extra={k: v for k, v in values.items() if k not in known})


def _typed(path: Path | None, key: str, value: Any) -> Any:
    """One header value as its field holds it; WilocError naming the key when no run writes it."""
    if key in ("exclude_recent", "frames"):
        if not (value.isascii() and value.isdigit()):
            raise WilocError(path, f"header '{key}' must be a whole number >= 0, got {value!r}")
        return int(value)
    if key == "mode" and value not in ("map", "sequence", ""):  # "": a file made by hand does not say
        raise WilocError(path, f"header 'mode' must be map or sequence, got {value!r}")
    if key == "rows" and value != "fabmap":  # the one kind of rows written (differences: no line)
        raise WilocError(path, f"header 'rows' must be fabmap (a run on FAB-MAP's evidence), got {value!r}")
    if key == "metric" and value not in ("", *METRICS):  # "": a file of an older version does not say
        raise WilocError(path, f"header 'metric' must be one of {', '.join(METRICS)}, got {value!r}")
    if key == "follow":
        return value == "True"
    if key == "reference_frames":
        return _frame_names(path, value)
    if key == "reference_left_out":
        return _left_out(path, value)
    if key == "fabmap_training":
        return _folders(path, value)
    if key == "model":
        return _model(path, value)
    if key in JSON_KEYS:
        if not isinstance(value, dict):
            raise WilocError(path, f"header '{key}' must be a JSON object")
        return value
    return value


def _frame_names(path: Path | None, value: Any) -> tuple[str, ...]:
    """``reference_frames``: each name once (a match by a name given twice would be a place at
    either position); null: none listed."""
    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(name, str) for name in value):
        raise WilocError(path, "header 'reference_frames' must be a list of frame names")
    seen: set[str] = set()
    for name in value:
        if name in seen:
            raise WilocError(path, f"header 'reference_frames' names '{name}' twice")
        seen.add(name)
    return tuple(value)


def _left_out(path: Path | None, value: Any) -> tuple[tuple[int, str], ...] | None:
    """``reference_left_out``: [position, name] pairs in the map's full order, each position
    after the one before (where the frames the run left out go among the map's); null: none."""
    if value is None:
        return None
    pairs = value if isinstance(value, list) else [None]
    if not all(isinstance(pair, list) and len(pair) == 2 and type(pair[0]) is int and isinstance(pair[1], str)
               for pair in pairs) or any(b[0] <= a[0] for a, b in zip([[-1, ""], *pairs], pairs)):
        raise WilocError(path, "header 'reference_left_out' must be a list of [position, name] pairs, positions "
                               "rising from 0")
    return tuple((position, name) for position, name in pairs)


def _folders(path: Path | None, value: str) -> tuple[str, ...]:
    """``fabmap_training``, written as a Python list of folder names."""
    try:
        folders = ast.literal_eval(value)
    except (ValueError, SyntaxError, RecursionError):
        folders = None
    if not isinstance(folders, list) or not all(isinstance(folder, str) for folder in folders):
        raise WilocError(path, f"header 'fabmap_training' must be a list of folders, got {value!r}")
    return tuple(folders)


def _model(path: Path | None, value: Any) -> dict[str, Any] | None:
    """``model``: a histogram model's dict, or None for null (and any empty value)."""
    if not value:
        return None
    try:
        HistogramModel.from_dict(value)
    except (KeyError, TypeError, ValueError) as exc:
        raise WilocError(path, f"header 'model' is not a histogram model ({exc})") from None
    return value

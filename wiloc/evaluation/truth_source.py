"""Which ground truth a run is scored against: a form of SPEC.md section 7 or one that VPR
datasets ship, its files and tolerances (:class:`TruthSource`), read by :func:`load_truth` into
one :class:`~wiloc.evaluation.groundtruth.Truth`."""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.aligned import aligned_truth
from wiloc.evaluation.groundtruth import (FOLDER_KINDS, KINDS, LeftOut, Truth, check_radius, check_tolerance,
                                          full_order, holds_indices, pairs_truth, positions_truth, restrict_sequence)
from wiloc.evaluation.truth_formats import (DEFAULT_RADIUS_M, exif_truth, matrix_truth, npy_form, positives_truth,
                                            utm_names_truth, vprbench_truth)
from wiloc.given import COLUMN_NAMES, check_file_path, is_number


def load_truth(kind: str, path: Path | None, *, query_names: Sequence[str],
               ref_names: Sequence[str], tolerance: int = 0, radius: float | None = None,
               ref_path: Path | None = None, by: Literal["name", "index"] = "name",
               variable: str | None = None, query_folder: Path | None = None,
               ref_folder: Path | None = None, left_out: LeftOut = ()) -> Truth:
    """Read ground truth of the given kind (``KINDS``) for the CLI.

    ``path`` is unused for ``aligned``, ``utm-names`` and ``exif``; for ``positions`` it is the
    query CSV and ``ref_path`` the reference CSV (default: the same file, sequence mode).
    ``utm-names`` and ``exif`` read the traversals: ``query_folder`` and ``ref_folder`` (None:
    sequence mode), within ``radius`` metres (default 25). ``left_out``: the reference's frames
    the run left out, which the forms counting frames in its order (aligned, a pairs file's
    tolerance) count too (a results header's ``reference_left_out``).
    """
    if kind == "aligned":
        truth = aligned_truth(query_names, ref_names, tolerance, by=by, left_out=left_out)
        if by == "index" and list(query_names) != list(ref_names):  # a traversal against itself is not shifted
            full = full_order(ref_names, left_out)[0] if left_out else ref_names  # those left out shift nothing
            truth.warnings += (_shifted_positions(query_names, query_folder, "query")
                               + _shifted_positions(full, ref_folder, "reference"))
        return truth
    if kind not in KINDS:
        raise WilocError(None, f"unknown ground-truth kind {kind!r}; choose one of {', '.join(KINDS)}")
    if kind in FOLDER_KINDS:
        if query_folder is None:
            raise ParameterError("query_folder", f"{kind} ground truth needs the query traversal's folder")
        read = utm_names_truth if kind == "utm-names" else exif_truth
        return read(Path(query_folder), None if ref_folder is None else Path(ref_folder),
                    DEFAULT_RADIUS_M if radius is None else radius, query_names, ref_names)
    if path is None:
        raise ParameterError("path", f"{kind} ground truth needs a file ({kind}:FILE)")
    if kind == "positions":
        if radius is None:
            raise ParameterError("radius", "positions ground truth needs a radius in metres")
        return positions_truth(Path(path), Path(ref_path or path), radius, query_names, ref_names)
    if kind == "pairs":
        return pairs_truth(Path(path), query_names, ref_names, left_out)
    if kind == "vprbench":
        return vprbench_truth(Path(path), query_names, ref_names)
    if kind == "positives":
        return positives_truth(Path(path), query_names, ref_names)
    return matrix_truth(Path(path), query_names, ref_names, variable=variable)


def _shifted_positions(names: Sequence[str], source: Path | None, role: str) -> list[str]:
    """A warning when aligned ground truth by index counts the frames of ``source`` (a traversal
    of the run) by their position in the run, as it does when their names hold no index, and
    those positions are not the frames' own: a bag's frames are named by their stamps, and a
    sampled run (--every, --fps, --start) counts from its first kept frame; a folder's image that
    the run left out (unreadable, and not put back as ``reference_left_out``) shifts every later
    frame. An image the run never listed that reads now was added since: positions are counted by
    the run's own frames, which it is not among, so it shifts nothing and is not said. None when
    nothing is shifted."""
    from wiloc.sources.bags import is_bag  # a later module, read only here
    from wiloc.sources.frames import list_traversal

    if source is None or holds_indices(names):
        return []
    if is_bag(source):
        return [(f"{source}: aligned:index counts its frames by their position in the run, as their names (stamps) "
                 "hold no index: a run that sampled it (--every, --fps, --start) is aligned with other frames "
                 "than their own; score it with a pairs or positions file instead")]
    try:
        listed = list_traversal(source).names if source.is_dir() else []
    except WilocError:  # no longer a folder of images: nothing to tell
        return []
    kept = set(names)
    last = max((i for i, name in enumerate(listed) if name in kept), default=0)
    left = [name for name in listed[:last] if name not in kept and not _readable(source / name)]
    more = f" (and {len(left) - 1} more frames of {source})" if len(left) > 1 else ""
    return [(f"{source / left[0]}: left out of the run{more} (unreadable?), so the position of every later {role} "
             "frame, which aligned:index aligns by, is shifted: align by name or give a pairs file")] if left else []


def _readable(path: Path) -> bool:
    """Whether the image at ``path`` decodes now, as a run reads its frames: one a run did not
    list that does was added since, not left out."""
    from wiloc.sources.frames import read_gray  # a later module, read only here

    try:
        read_gray(path)
    except (WilocError, OSError):  # FrameError is a WilocError
        return False
    return True


def file_form(path: str | Path) -> str:
    """The form of a ground-truth file given without its kind: VPR-Bench's file by its name, a
    .npy by its header (:func:`~wiloc.evaluation.truth_formats.npy_form`: VPR-Bench's rows, positives
    per query or a matrix), a .npz or .mat as a matrix, a CSV by its first line (``query,reference``: pairs; ``x,y`` or
    ``lat,lon`` (or ``latitude,longitude``): positions; numbers alone: a matrix), anything else as pairs, whose
    reader says what is missing."""
    if Path(path).name.lower() == "ground_truth_new.npy":
        return "vprbench"
    if Path(path).suffix.lower() == ".npy":
        return npy_form(Path(path))
    if Path(path).suffix.lower() in (".npz", ".mat"):
        return "matrix"
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as file:
            cells = [cell.strip().lower() for cell in file.readline().split(",")]
    except OSError:  # no such file yet ('{query}' in its name): the pairs reader names the problem
        return "pairs"
    columns = {COLUMN_NAMES.get(cell, cell) for cell in cells}
    if {"x", "y"} <= columns or {"lat", "lon"} <= columns:  # the positions reader says what else is missing
        return "positions"
    return "matrix" if cells != [""] and all(is_number(cell) for cell in cells) else "pairs"


@dataclass(frozen=True)
class TruthSource:
    """Which ground truth to use: a form (SPEC.md section 7) and its files and tolerances.

    ``path`` and ``ref_path`` (text or path-like, kept as text) may contain ``{query}``, replaced
    by the query folder's name, so that several query traversals can each find their own file.
    """

    kind: str = "aligned"
    path: str | os.PathLike[str] | None = None
    ref_path: str | os.PathLike[str] | None = None
    tolerance: int = 2
    radius: float | None = None
    by: Literal["name", "index"] = "name"
    variable: str | None = None  # matrix form, .mat files holding several arrays: which one

    def __post_init__(self) -> None:
        """Path-like files kept as text, as a saved localizer's state writes them to JSON; files of
        another type, the kind, tolerance, ``by`` and radius checked as they are given, before any
        file or folder is read: a ParameterError naming the parameter, not a run's scoring failing later."""
        if self.kind not in KINDS:
            raise ParameterError("kind", f"unknown ground-truth kind {self.kind!r}; choose one of {', '.join(KINDS)}")
        for name in ("path", "ref_path"):
            if isinstance(value := getattr(self, name), os.PathLike):
                object.__setattr__(self, name, os.fspath(value))
            elif value is not None:
                check_file_path(value, name)
        try:
            check_tolerance(self.tolerance)
        except WilocError as exc:  # the reader's error names the parameter; made, it is a ParameterError
            raise ParameterError("tolerance", exc.problem) from None
        if self.by not in ("name", "index"):
            raise ParameterError("by", f"'name' or 'index', got {self.by!r}")
        if self.radius is not None:
            check_radius(self.radius)

    def describe(self) -> str:
        """The ground truth in words, as tables print it: 'aligned, +-2 frames'."""
        if self.kind == "aligned":
            return f"aligned by {self.by}, +-{self.tolerance} frames"
        if self.kind == "positions":
            return f"positions within {self.radius:g} m ({self.path})"
        if self.kind in FOLDER_KINDS:
            radius = DEFAULT_RADIUS_M if self.radius is None else self.radius
            return f"{'@UTM file names' if self.kind == 'utm-names' else 'EXIF GPS'} within {radius:g} m"
        return f"{self.kind} {self.path}"

    def load(self, query_names: list[str], ref_names: list[str], query_folder: str,
             sequence: bool, exclude_recent: int, ref_folder: str = "", left_out: LeftOut = ()) -> Truth:
        """The truth matrix over these frames (sequence mode: earlier frames outside +-R only);
        ``ref_folder`` is the reference traversal, for the forms that read it, ``left_out`` the
        frames of it the run left out (:func:`load_truth`)."""
        name = Path(query_folder).name
        path = _for_query(self.path, name, "path")
        ref_path = _for_query(self.ref_path, name, "ref_path")
        if self.kind == "positions" and path is not None and ref_path is None and not sequence:
            raise ParameterError("ref_path", "a run against a map needs the map's positions file too (the query's "
                                             "positions do not place the map frames)")
        if sequence and ref_path is not None and path is not None and ref_path.resolve() != path.resolve():
            raise ParameterError("ref_path", f"a run in sequence mode is its own map: {ref_path} is not its positions "
                                             f"file {path} (give that file once)")
        truth = load_truth(self.kind, path, query_names=query_names, ref_names=ref_names,
                           tolerance=self.tolerance, radius=self.radius, ref_path=ref_path,
                           by=self.by, variable=self.variable, query_folder=Path(query_folder) if query_folder else None,
                           ref_folder=None if sequence or not ref_folder else Path(ref_folder), left_out=left_out)
        return restrict_sequence(truth, exclude_recent) if sequence else truth


def _for_query(template: str | os.PathLike[str] | None, name: str, parameter: str) -> Path | None:
    """A ground-truth file path with ``{query}`` replaced by the query folder's name (other braces
    are part of the name); a WilocError naming ``parameter`` and the template when the file it
    gives does not exist."""
    if not template:
        return None
    template = os.fspath(template)
    path = Path(template.replace("{query}", name))
    if "{query}" in template and not path.exists():
        raise WilocError(None, f"{path} ({template} for query {name}): file does not exist", parameter=parameter)
    return path


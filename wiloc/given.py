"""Checks on text that users give by hand: whether a file given is a file that holds something,
which line of a CSV of numbers holds another count of them, whether a CSV cell is a number (a
header line or a line of data?), whether frame names are usable (text, non-empty, each once), why the names a
file gives match no frame, whether GPS degrees are in range, and the conventions their CSVs
share (other names of columns, the Earth radius for GPS degrees). The ground-truth readers, odometry, imported descriptor matrices
and maps held in memory share them, so that each problem reads the same wherever it is found."""
from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError, WilocError

EARTH_RADIUS_M = 6_371_008.8
"""Mean Earth radius (IUGG) used for distances between GPS positions (lat/lon) on a sphere."""
COLUMN_NAMES = {"latitude": "lat", "longitude": "lon", "lng": "lon", "long": "lon",
                "filename": "name", "file": "name", "image": "name", "frame": "name"}
"""Other names of the lat/lon columns that GPS logs and exports use, and of a CSV's name column:
positions and odometry CSVs read a header through it."""


def check_file_path(value: object, parameter: str) -> None:
    """A ParameterError naming ``parameter`` when ``value`` is no file's path (text or a path
    object), before pathlib's TypeError says so of a number, a list or None."""
    if not isinstance(value, (str, os.PathLike)):
        raise ParameterError(parameter, f"a file's path (text or a path object), got {type(value).__name__}")


def check_file(path: Path) -> None:
    """A WilocError naming ``path`` unless it is a regular file that holds something: no such
    file, not one (a folder, a device such as /dev/null), or an empty one."""
    if not path.is_file():
        raise WilocError(path, "not a regular file" if path.exists() else "file does not exist")
    if path.stat().st_size == 0:
        raise WilocError(path, "the file is empty (0 bytes)")


def uneven_line(path: Path) -> str | None:
    """The first non-blank line of a CSV of numbers holding another count of values than its
    first line, in words (``line 7 has 5 values where line 1 has 20``), or None: a table of
    numbers needs as many on every line, and numpy's own words for it name its parameters."""
    first: tuple[int, int] | None = None
    with path.open(encoding="utf-8-sig", errors="replace") as handle:
        for n, line in enumerate(handle, 1):
            if not line.strip():
                continue
            count = line.count(",") + 1
            if first is None:
                first = (n, count)
            elif count != first[1]:
                return f"line {n} has {count} values where line {first[0]} has {first[1]}"
    return None


def is_number(text: str) -> bool:
    """Whether a CSV cell reads as a number (telling a header line from a line of data)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def check_lat_lon(latlon: NDArray[np.float64], where: Path | str) -> None:
    """A WilocError naming ``where`` unless every (lat, lon) row is in degrees: lat in [-90, 90],
    lon in [-360, 360] (positions and odometry CSVs headed lat,lon)."""
    if np.any(np.abs(latlon[:, 0]) > 90) or np.any(np.abs(latlon[:, 1]) > 360):
        raise WilocError(where, "lat must lie in [-90, 90] and lon in [-360, 360] degrees")


def check_metres(xy: NDArray[np.float64], where: Path | str, farthest: float = 1e150) -> None:
    """A WilocError naming ``where`` if a coordinate in metres lies beyond ``farthest``: squared
    distances between such points overflow."""
    if xy.size and (largest := float(np.abs(xy).max())) > farthest:
        raise WilocError(where, f"a coordinate of {largest:g} metres is too far out to measure distances "
                                f"(keep coordinates within {farthest:g})")


def check_frame_names(names: Sequence[object], where: Path | str) -> None:
    """A WilocError naming ``where`` unless every name is non-empty text and no two rows share
    one (a match to either row would name the same frame); rows count from 1."""
    first: dict[str, int] = {}
    for row, name in enumerate(names, 1):
        if not isinstance(name, str) or not name:
            raise WilocError(where, f"row {row}: frame name {name!r}; each row needs a non-empty text name")
        if name in first:
            raise WilocError(where, f"rows {first[name]} and {row}: duplicate frame name {name!r}; "
                                    "each row names a frame of its own")
        first[name] = row


def why_unmatched(names: Sequence[str], frames: Sequence[str]) -> str:
    """What the names a file gives (``names``: ground truth's, odometry's) and the traversal's
    ``frames`` show of why none matches, to follow a 'no name matches' error: names that hold a
    folder, differ in suffix or in case from frame names, or are numbers where the frames' are
    not (indices); else an example of each."""
    named = [str(name) for name in names[:1000]]
    framed = set(frames)
    tests = (("hold a folder: frames are matched by file name alone", lambda n: re.split(r"[/\\]", n)[-1]),
             ("differ from the frames' in their suffix", lambda n: n.rsplit(".", 1)[0]),
             ("differ from the frames' in case", str.lower))
    for why, key in tests:
        keyed = {key(frame): frame for frame in frames}
        for name in named:
            if name not in framed and key(name) in keyed:
                return f" (names such as {name!r} {why}, such as {keyed[key(name)]!r})"
    if not named or not frames:
        return ""
    if all(name.isdigit() for name in named) and not all(str(frame).isdigit() for frame in frames[:1000]):
        return (f" (names such as {named[0]!r} are numbers: frames are matched by file name, such as "
                f"{frames[0]!r}, not by index)")
    return f" (names such as {named[0]!r}; the frames are named such as {frames[0]!r})"

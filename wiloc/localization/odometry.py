"""Odometry CSVs: arc length travelled at each frame, for the CAT-Graph motion model.

Three forms, one row per frame, an optional header row:
- ``name,distance``: the distance travelled since the previous frame of the file (the first
  row's value is ignored: nothing was travelled before the first frame);
- ``name,x,y``: the position (metres); arc length is the summed step length in frame order;
- ``name,lat,lon`` (a header naming them): a GPS position (degrees); steps are great-circle.
A header that names these columns (``name``, or ``frame``, ``file``, ``filename``, ``image``;
``distance``, ``x`` and ``y``, or ``lat`` and ``lon`` under their other names) picks them
wherever they stand, other columns (a timestamp, a ``z``) passed over; without one the columns
are taken in order. Frames are matched by file
name. docs/catgraph.md describes how the filter uses them.
"""
from __future__ import annotations

import csv
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError, WilocError
from wiloc.given import COLUMN_NAMES, EARTH_RADIUS_M, check_lat_lon, is_number, why_unmatched
from wiloc.sources.bags import Bag, is_bag


@dataclass(frozen=True)
class Odometry:
    """Per-frame values read from an odometry CSV, in file order."""

    names: tuple[str, ...]
    values: NDArray[np.float64]  # (n, 1) distances or (n, 2) positions
    path: str
    geographic: bool = False  # positions are (lat, lon) degrees, else (x, y) metres

    def arclength(self, names: Sequence[str] | None = None) -> NDArray[np.float64]:
        """Arc length at each of ``names`` (default: the file's order), in that order.

        Every name must appear in the file; names in the file but not asked for are ignored
        (their distances still count: a frame left out of the traversal was still driven past).
        Distances travelled must not be negative, and their rows come in the frames' order.
        """
        order, rows = self._rows(names)
        if not len(rows):
            return np.zeros(0)
        if self.values.shape[1] == 2:
            return self._finite(np.r_[0.0, np.cumsum(self._position_steps(rows))], order)
        with np.errstate(over="ignore", invalid="ignore"):  # checked below
            cumulative = self._finite(np.cumsum(self._travelled()), self.names)[rows]
            return cumulative - cumulative[0]

    def steps(self, names: Sequence[str]) -> NDArray[np.float64]:
        """The distance travelled since the previous of ``names`` (0 for the first): a distance
        file's own values where the frames are consecutive rows (summed over rows left out), so
        that a batch run gives the filter the numbers a Localizer is given frame by frame; the
        arc length differenced again differed in the last bits, and catgraph's draws with them."""
        order, rows = self._rows(names)
        if len(rows) < 2:
            return np.zeros(len(rows))
        if self.values.shape[1] == 2:
            return np.r_[0.0, self._finite(self._position_steps(rows), order[1:])]
        travelled = self._travelled()
        with np.errstate(over="ignore", invalid="ignore"):  # checked: every sum of the steps is at most this
            self._finite(np.cumsum(travelled), self.names)
        return np.r_[0.0, np.add.reduceat(travelled[:rows[-1] + 1], rows[:-1] + 1)]

    def _rows(self, names: Sequence[str] | None) -> tuple[tuple[str, ...], NDArray[np.intp]]:
        """``names`` (default: the file's) and their rows in the file; a WilocError for a name the
        file lacks, or for distances whose rows are out of the frames' order (summed in the
        file's order, they gave negative steps: a log sorted as text, img10 before img2)."""
        order = self.names if names is None else tuple(names)
        index = {name: i for i, name in enumerate(self.names)}
        missing = [name for name in order if name not in index]
        if missing:
            why = why_unmatched(list(self.names), missing) if len(missing) == len(order) else ""  # no name matches
            raise WilocError(self.path, f"no odometry for {len(missing)} frame(s), first {missing[0]!r}{why}")
        rows = np.array([index[name] for name in order], dtype=np.intp)
        back = np.flatnonzero(np.diff(rows) < 0)
        if self.values.shape[1] == 1 and back.size:
            raise WilocError(self.path, f"its rows are not in the frames' order: {order[back[0] + 1]!r} comes before "
                                        f"{order[back[0]]!r}; a name,distance row holds the distance since the row "
                                        "before it, so the rows follow the frames")
        return order, rows

    def _position_steps(self, rows: NDArray[np.intp]) -> NDArray[np.float64]:
        """Metres between the positions of consecutive ``rows`` (not checked finite)."""
        with np.errstate(over="ignore", invalid="ignore"):
            vals = self.values[rows]
            return _great_circle_steps(vals) if self.geographic else np.hypot(*np.diff(vals, axis=0).T)

    def _travelled(self) -> NDArray[np.float64]:
        """A distance file's values, the first row's 0 (travelled before the route), checked >= 0."""
        travelled = self.values[:, 0].copy()
        negative = np.flatnonzero(travelled < 0)
        if negative.size:
            raise WilocError(self.path, f"negative distance at frame {self.names[negative[0]]!r}: "
                                        "expected the distance travelled since the previous frame")
        travelled[0] = 0.0
        return travelled

    def doubt(self) -> str | None:
        """A line when the distances read as the distance from the start rather than from the
        previous frame (every one at least the one before, the last ten times or more the one a
        tenth of the way in: a vehicle that sped up tenfold and never slowed), which the file's
        reading would sum again; None otherwise, and for positions."""
        d = self.values[:, 0]
        if self.values.shape[1] != 1 or d.size < 20 or np.any(np.diff(d) < 0):
            return None
        if not d[-1] >= 10 * d[(d.size - 1) // 10] > 0:
            return None
        return (f"odometry {self.path}: its distances only grow ({d[0]:g} to {d[-1]:g}), as distances from the "
                "start do; a name,distance file holds the distance since the previous frame: give those, or "
                "positions (name,x,y)")

    def _finite(self, arclength: NDArray[np.float64], names: Sequence[str]) -> NDArray[np.float64]:
        """``arclength`` (at ``names``) when every value is finite, else a WilocError naming the
        first frame whose distance from the start no float holds (each value in the file finite,
        their sum not)."""
        too_far = np.flatnonzero(~np.isfinite(arclength))
        if too_far.size:
            raise WilocError(self.path, f"the distance travelled up to frame {names[too_far[0]]!r} is more than a "
                                        "float can hold")
        return arclength


def _great_circle_steps(latlon: NDArray[np.float64]) -> NDArray[np.float64]:
    """Metres between consecutive (lat, lon) positions in degrees, along a sphere of the mean
    Earth radius (haversine), as positions ground truth measures them."""
    lat, lon = np.radians(latlon).T
    h = np.sin(np.diff(lat) / 2) ** 2 + np.cos(lat[:-1]) * np.cos(lat[1:]) * np.sin(np.diff(lon) / 2) ** 2
    return 2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))


def steps(arclength: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance travelled since the previous frame (0 for the first): the filter's u_k."""
    arc = np.asarray(arclength, dtype=np.float64)
    return np.diff(arc, prepend=arc[:1])


def read_odometry(path: str | Path) -> Odometry:
    """Read a ``name,distance`` or ``name,x,y`` CSV; WilocError naming the line on any problem."""
    where = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = [(n, row) for n, row in enumerate(csv.reader(fh), start=1)
                    if row and any(cell.strip() for cell in row)]
    except IsADirectoryError:
        raise WilocError(where, "a folder, not an odometry CSV file") from None
    except FileNotFoundError:
        raise WilocError(where, "file does not exist") from None
    except OSError as exc:  # the path, which the message names first, not again in the OS's words
        raise WilocError(where, f"cannot read odometry: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise WilocError(where, f"cannot read odometry: {exc}") from exc
    columns, geographic = None, False
    if rows and not all(is_number(cell) for cell in rows[0][1][1:]):
        header, (columns, geographic) = rows[0][1], _named_columns(rows[0][1])
        rows = rows[1:]
    if not rows:
        raise WilocError(where, "no odometry rows")
    if columns is not None:
        short = next(((line, row) for line, row in rows if len(row) != len(header)), None)
        if short is not None:
            raise WilocError(where, f"line {short[0]}: expected {len(header)} columns, as the header names, "
                                    f"got {len(short[1])}")
        rows = [(line, [row[i] for i in columns]) for line, row in rows]
    width = len(rows[0][1])
    if width not in (2, 3):
        first = rows[0][1][0]
        hint = "; columns must be separated by commas" if width == 1 and (";" in first or "\t" in first) else ""
        raise WilocError(where, f"line {rows[0][0]}: expected name,distance or name,x,y, "
                                f"got {width} columns{hint}")
    names: list[str] = []
    values = np.empty((len(rows), width - 1), dtype=np.float64)
    for i, (line, row) in enumerate(rows):
        if len(row) != width:
            raise WilocError(where, f"line {line}: expected {width} columns, got {len(row)}")
        cells = [cell.strip() for cell in row]
        if not cells[0]:
            raise WilocError(where, f"line {line}: empty frame name")
        if not all(is_number(cell) for cell in cells[1:]):
            raise WilocError(where, f"line {line}: not a number in {','.join(cells[1:])!r}")
        values[i] = [float(cell) for cell in cells[1:]]
        if not np.all(np.isfinite(values[i])):
            raise WilocError(where, f"line {line}: non-finite value")
        names.append(cells[0])
    twice = [name for name, count in Counter(names).items() if count > 1]
    if twice:
        raise WilocError(where, f"frame {twice[0]!r} appears more than once")
    if geographic:
        check_lat_lon(values, where)
    return Odometry(names=tuple(names), values=values, path=where, geographic=geographic)


def _named_columns(header: list[str]) -> tuple[list[int] | None, bool]:
    """The positions of a header's name column and its ``distance``, ``x,y`` or ``lat,lon``
    columns (under their other names, ``COLUMN_NAMES``), when it names them (other columns, a
    timestamp or a ``z``, are then passed over), and whether they are lat,lon; else None, and the
    columns are taken in order."""
    cells = [COLUMN_NAMES.get(cell.strip().lower(), cell.strip().lower()) for cell in header]
    if "name" not in cells:
        return None, False
    for values in (["distance"], ["x", "y"], ["lat", "lon"]):
        if all(value in cells for value in values):
            return [cells.index("name"), *(cells.index(value) for value in values)], values == ["lat", "lon"]
    return None, False


def bag_odometry(query: Path | None, reference: Path | None, topic: str | None, odometry: Path | None,
                 map_odometry: Path | None) -> tuple[bool, bool]:
    """Whether the query's and the map's odometry come from their ROS bags' ``topic``: for those
    that are bags, when it is given. A ParameterError when no traversal is a bag, or when a bag's
    odometry is also given as a CSV: named ``odometry_topic`` (the option every such run was given,
    spelt by the command line as its own), its problem naming the CSV in no one spelling."""
    if topic is None:
        return False, False
    from_bag = (query is not None and is_bag(Path(query)), reference is not None and is_bag(Path(reference)))
    if not any(from_bag):
        raise ParameterError("odometry_topic", "applies to ROS bags only; neither the query nor the map is one")
    for used, given, whose in zip(from_bag, (odometry, map_odometry), ("query", "map")):
        if used and given is not None:
            raise ParameterError("odometry_topic", f"the {whose}'s bag gives its odometry on the topic; give it "
                                                   f"once, by the topic or as a CSV, not both")
    return from_bag


def traversal_arclength(names: list[str], csv_path: Path | None = None, bag: Path | None = None,
                        topic: str | None = None) -> NDArray[np.float64] | None:
    """A traversal's arc length at each frame of ``names``: along its ROS ``bag``'s odometry
    ``topic`` when both are given, else from its odometry CSV when given, else None."""
    if bag is not None and topic is not None:
        with Bag(Path(bag)) as opened:
            return opened.arclength(topic, names)
    return read_odometry(csv_path).arclength(names) if csv_path is not None else None


def traversal_steps(names: list[str], csv_path: Path | None = None, bag: Path | None = None,
                    topic: str | None = None) -> NDArray[np.float64] | None:
    """A traversal's distance travelled since the previous frame, at each frame of ``names``: its
    CSV's own distances (:meth:`Odometry.steps`), else its bag's arc length differenced."""
    if csv_path is not None and (bag is None or topic is None):
        return read_odometry(csv_path).steps(names)
    arclength = traversal_arclength(names, csv_path, bag, topic)
    return None if arclength is None else steps(arclength)

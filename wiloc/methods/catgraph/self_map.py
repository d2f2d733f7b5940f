"""Sequence mode (loop closure within one traversal): the traversal as its own map, growing by a
node a frame (used by ``wiloc.methods.catgraph.filter``). Where each frame was taken
(:class:`Trail`: the frame index, or the distance its odometry says it travelled) and how far each
frame's look is from the next (:class:`StepBounds`, which marks near-duplicates as the map's own
differences do in map mode). docs/catgraph.md, "Sequence mode", gives the measurements.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import WilocError
from wiloc.methods.catgraph.observation import novelty_weights


class Trail:
    """Sequence mode: where each frame of the traversal was taken, the positions its map's nodes
    take as it grows. With odometry (given with every frame after the first: the distance since
    the frame before) the distance travelled from the first frame; without, the frame index. The
    first frame's odometry, a distance from no frame, is not read."""

    def __init__(self, odometry: bool | None = None, positions: NDArray[np.float64] | None = None) -> None:
        """A trail whose frames come with odometry (True), without (False) or not yet known
        (None: before the second frame), at these positions so far (with odometry)."""
        self.odometry = odometry
        given = np.empty(0) if positions is None else np.asarray(positions, dtype=np.float64)
        self._positions = np.concatenate((given, np.zeros(max(16, given.size))))
        self._size = given.size

    def add(self, frame: int, odometry: float | None) -> None:
        """Frame ``frame`` (the next), with its odometry step or None; a WilocError naming
        ``odometry`` when frames after the first mix steps and none, before anything is added."""
        if frame == 0:
            return
        if frame == 1:
            self.odometry = odometry is not None
            if self.odometry:
                self._append(0.0)
        elif (odometry is not None) != self.odometry:
            raise WilocError("catgraph", f"query frame {frame}: in sequence mode odometry comes with every frame "
                                         "after the first or with none", parameter="odometry")
        if odometry is not None:
            self._append(self._positions[self._size - 1] + odometry)

    def _append(self, position: float) -> None:
        if self._size == self._positions.size:
            self._positions = np.concatenate((self._positions, np.zeros(self._size)))
        self._positions[self._size] = position
        self._size += 1

    def nodes(self, n: int) -> NDArray[np.float64]:
        """The positions of the first ``n`` frames (read-only)."""
        if not self.odometry:
            return np.arange(n, dtype=np.float64)
        nodes = self._positions[:n]
        nodes.flags.writeable = False
        return nodes

    def spans(self, n: int) -> bool:
        """Whether the first ``n`` frames (at least 2) lie along a route of some length: a
        traversal standing still since its first frame has no map to move along yet."""
        return n >= 2 and (not self.odometry or bool(self._positions[n - 1] > self._positions[0]))

    def positions(self) -> NDArray[np.float64]:
        """The positions so far (empty without odometry)."""
        return self._positions[:self._size].copy()


class StepBounds:
    """Sequence mode: how far each frame of the traversal is from the next, bounded from below by
    the rows (no row holds that difference: a frame is compared with frames older than the
    recent window). By the triangle inequality |d(k, j) - d(k, j + 1)| <= d(j, j + 1) for every
    frame k, so the largest such gap over the rows seen bounds d(j, j + 1); frames that repeat
    (a black screen, a train standing at a station) keep a bound near 0 in every row. Relative
    to its median the bound marks the same near-duplicates as the differences themselves: on
    Nordland's first 1,000 summer frames 0.99 of the nodes (0.98 with ``gist``, whose
    difference is no metric) fall on the same side of ``near_duplicate`` with the bound of the 60
    rows before a node joins the map as with the map's own differences."""

    def __init__(self, bounds: NDArray[np.float64] | None = None) -> None:
        self._bounds = np.zeros(0) if bounds is None else np.array(bounds, dtype=np.float64)

    def add(self, row: NDArray[np.floating]) -> None:
        """Take a row (one value per frame compared with); a value not finite (a frame the row
        does not compare with) bounds nothing."""
        with np.errstate(invalid="ignore"):  # inf - inf
            gaps = np.abs(np.diff(np.asarray(row, dtype=np.float64)))
        gaps[~np.isfinite(gaps)] = np.nan  # fmax keeps the bound where a gap is NaN
        if self._bounds.size < gaps.size:
            self._bounds = np.concatenate((self._bounds, np.zeros(gaps.size - self._bounds.size)))
        np.fmax(self._bounds[:gaps.size], gaps, out=self._bounds[:gaps.size])

    def weights(self, n: int, threshold: float) -> NDArray[np.float64]:
        """:func:`novelty_weights` of the first ``n`` frames, from their bounds (against their
        upper median: one partition, where the mean of the two middle values takes two; taken
        anew each frame, as a row raises the bounds)."""
        bounds = np.zeros(n - 1)
        known = min(n - 1, self._bounds.size)
        bounds[:known] = self._bounds[:known]
        middle = bounds.size // 2
        return novelty_weights(bounds, threshold, float(np.partition(bounds, middle)[middle]))

    def state(self) -> NDArray[np.float64]:
        """The bounds so far, for :class:`StepBounds` to start from."""
        return self._bounds.copy()


class SelfMap:
    """The traversal's frames as map nodes: their positions (:class:`Trail`) and near-duplicate
    weights (:class:`StepBounds`), from each frame's odometry and row as it comes."""

    def __init__(self, state: Mapping[str, Any] | None = None, frames: int = 0) -> None:
        """A map of no frames, or continuing from :meth:`state` after ``frames`` frames (a state
        saved before sequence mode took odometry has none)."""
        state = state or {}
        self.trail = Trail(state.get("trail_odometry", False if frames > 1 else None), state.get("trail"))
        self.bounds = StepBounds(state.get("bounds"))

    def add(self, frame: int, odometry: float | None, row: NDArray[np.floating], n_map: int, bounds: bool) -> None:
        """Frame ``frame`` with its odometry step (or None) and its row's values for the frames
        before the recent window, of which the first ``n_map`` are the map's (and must be
        finite); ``bounds``: whether the row's values are differences that bound steps (not
        FAB-MAP's evidence). A WilocError before anything is added when the frame is refused."""
        if n_map >= 2 and not np.isfinite(row[:n_map]).all():
            raise WilocError("catgraph", f"query frame {frame}: expected {n_map} finite values, one per map frame")
        self.trail.add(frame, odometry)
        if bounds:
            self.bounds.add(row)

    def state(self) -> dict[str, Any]:
        """What :class:`SelfMap` continues from."""
        return {"trail": self.trail.positions(), "trail_odometry": self.trail.odometry, "bounds": self.bounds.state()}

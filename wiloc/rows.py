"""Difference matrices as methods read them, and what methods learn from a map's matrix to itself.

A matrix is read block of rows by block of rows (:class:`RowBlocks`: a computed one,
``wiloc.description.differences.ComputedDifferences``, or an array, :class:`ArrayRows`); nothing N x N need
be held. A map's differences to itself reach a method only as their :class:`MapSummary`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray


class RowBlocks(Protocol):
    """A matrix read block of rows by block of rows (e.g. ``ComputedDifferences``)."""

    @property
    def shape(self) -> tuple[int, int]: ...

    def rows(self, start: int, stop: int) -> NDArray[np.floating]: ...


@dataclass(frozen=True)
class ArrayRows:
    """An in-memory matrix as a :class:`RowBlocks` reader."""

    array: NDArray[np.floating]

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = np.shape(self.array)
        return int(rows), int(cols)

    def rows(self, start: int, stop: int) -> NDArray[np.floating]:
        return np.asarray(self.array[start:stop])


@dataclass(frozen=True)
class MapSummary:
    """What methods learn from a map's differences to itself: each frame's smallest difference
    to the frames outside its +-R (inf where there is none) and the largest finite difference
    (0 when there is none)."""

    minima: NDArray[np.float64]
    largest: float

"""Warnings about ground truth that covers a run's frames only in part: counts of items without a
counterpart (:func:`unmatched`), and those counting query frames (:class:`QueryFramesWarning`),
which a slice of the run (``wiloc evaluate --frames``) counts again over its own frames."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray


def unmatched(where: Path | str, count: int, total: int, what: str) -> list[str]:
    """A warning line when some of ``total`` items found no counterpart (none when all did)."""
    return [f"{where}: {count} of {total} {what}"] if count else []


class QueryFramesWarning(str):
    """A warning line counting the query frames a ground truth leaves out (``3 of 40 query frames
    have no ground-truth row``) that holds which (``missing``, a mask over the query frames in
    order), so that a slice of the run is warned about its own frames alone (:meth:`of_rows`)."""

    where: str
    what: str
    missing: NDArray[np.bool_]

    def __new__(cls, where: Path | str, what: str, missing: NDArray[np.bool_]) -> QueryFramesWarning:
        line = super().__new__(cls, unmatched(where, int(missing.sum()), missing.size, what)[0])
        line.where, line.what, line.missing = str(where), what, missing
        return line

    def __getnewargs__(self) -> tuple[str, str, NDArray[np.bool_]]:  # type: ignore[override]  # copied and pickled whole
        return self.where, self.what, self.missing

    def of_rows(self, rows: NDArray[np.int64]) -> list[str]:
        """The warning over the query frames at ``rows`` alone; none when each of them is covered."""
        return query_frames_without(self.where, self.missing[rows], self.what)


def query_frames_without(where: Path | str, missing: NDArray[np.bool_], what: str) -> list[str]:
    """A :class:`QueryFramesWarning` when some query frames (``missing``, a mask over them in
    order) have no counterpart in the ground truth; none when all have one."""
    return [QueryFramesWarning(where, what, np.asarray(missing, dtype=np.bool_))] if np.any(missing) else []

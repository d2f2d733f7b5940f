"""A method run on plain arrays: difference rows in, decisions out, with no files and no cache
(notebooks, benchmarks, tests of a method on its own)."""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from wiloc.decisions import Decisions
from wiloc.description.differences import summarize
from wiloc.errors import ParameterError
from wiloc.methods.base import MapContext, Method, Progress, TrainingRows
from wiloc.rows import ArrayRows, RowBlocks


def run_on_rows(method: Method, rows: Iterable[NDArray[np.float64]], n_frames: int, *,
                map_self: NDArray[np.floating] | RowBlocks | None = None, sequence: bool = False,
                exclude_recent: int = 10, natural_max: float | None = None,
                arclength: NDArray[np.float64] | None = None, odometry: NDArray[np.float64] | None = None,
                training: TrainingRows | None = None, progress: Progress | None = None) -> Decisions:
    """Start ``method`` on plain arrays and step it over ``rows``: the batch run without files.

    ``map_self`` is the map's difference matrix to itself (an array or a row-block reader),
    summarized when the method asks; the map's steps (``MapContext.neighbours``) are read off its
    first off-diagonal.
    """
    shape = None if map_self is None else map_self.shape if hasattr(map_self, "rows") else np.shape(map_self)
    if shape is not None and (len(shape) != 2 or shape[0] != shape[1]):  # else an IndexError inside the method
        raise ParameterError("map_self", f"the map's differences to itself: a square matrix, one row and one "
                                         f"column per map frame; got shape {shape}")
    self_rows = map_self if map_self is None or hasattr(map_self, "rows") else ArrayRows(np.asarray(map_self))
    steps = None if self_rows is None else \
        np.array([self_rows.rows(i, i + 1)[0, i + 1] for i in range(self_rows.shape[0] - 1)], dtype=np.float64)
    method.start(MapContext(sequence=sequence, exclude_recent=exclude_recent,
                            n_map=0 if self_rows is None else self_rows.shape[0], natural_max=natural_max,
                            arclength=arclength,
                            map_summary=None if self_rows is None else lambda: summarize(self_rows, exclude_recent),
                            neighbours=None if steps is None else lambda: steps,
                            training=None if training is None else lambda: training))
    return method.run(rows, n_frames, odometry=odometry, progress=progress)

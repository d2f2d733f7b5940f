"""Which frames a query frame is compared with, and its best match among them.

A *difference row* holds query frame k's differences to its candidate frames, float64, ``np.inf``
where a frame is no candidate. In map mode every reference frame is a candidate. In sequence mode
(loop closure in one traversal) the candidates are the earlier frames i < k - R: the recent window
R (``exclude_recent``) keeps trivially similar neighbours out.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import ParameterError

DEFAULT_EXCLUDE_RECENT = 10
"""R: recent frames that are no candidates (and the band left out of a map's self-differences);
chosen by measurement, see docs/algorithm.md."""


def check_exclude_recent(exclude_recent: int) -> int:
    """R as an int, or a ParameterError naming ``exclude_recent``."""
    if isinstance(exclude_recent, bool) or not isinstance(exclude_recent, (int, np.integer)) or exclude_recent < 0:
        raise ParameterError("exclude_recent", f"must be an integer >= 0, got {exclude_recent!r}")
    return int(exclude_recent)


def mask_recent(row: NDArray[np.float64], k: int, exclude_recent: int) -> NDArray[np.float64]:
    """Sequence mode: frame k's row over the traversal with frames i >= k - R set to inf (in place)."""
    row[max(0, k - exclude_recent):] = np.inf
    return row


def finite_minimum(row: NDArray[np.float64]) -> tuple[int, float]:
    """(argmin, min) over the finite entries of a difference row; (-1, nan) when there are none."""
    if row.size == 0:
        return -1, float("nan")
    z = int(np.argmin(row))
    m = float(row[z])
    return (z, m) if np.isfinite(m) else (-1, float("nan"))

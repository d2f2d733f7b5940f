"""Which frames a query frame is compared with, and its best match among them.

A *difference row* holds query frame k's differences to its candidate frames, float64, ``np.inf``
where a frame is no candidate: the paper's d_ki = d(Z_k, Z_i) over i. In map mode every reference
frame (the map: the paper's base dataset) is a candidate. In sequence mode (loop closure in one
traversal) the candidates are the earlier frames i < k - R: the recent window R
(``exclude_recent``) keeps trivially similar neighbours out.
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


def finite_minimum(row: NDArray[np.floating]) -> tuple[int, float]:
    """(argmin, min) over the finite entries of a difference row; (-1, nan) when there are none."""
    if row.size == 0:
        return -1, float("nan")
    z = int(np.argmin(row))
    m = float(row[z])
    return (z, m) if np.isfinite(m) else (-1, float("nan"))


RANKED = 20
"""K of the ranking a method's results keep per query frame: its K best candidates, enough for
Recall@1, @5, @10 and @20 as place recognition papers report them (docs/evaluation.md)."""


def best_candidates(row: NDArray[np.floating], k: int = RANKED, *, descending: bool = False) -> NDArray[np.int64]:
    """The positions of a row's ``k`` best candidates, best first: ascending difference (or, with
    ``descending``, falling evidence), equal values in order of position, so the first is
    :func:`finite_minimum`'s argmin. Entries that are no candidate (infinite, NaN) are never
    ranked; a row with fewer candidates gives fewer positions."""
    score = -row if descending else row
    kth = np.partition(score, k - 1)[k - 1] if score.size > k else np.nan  # NaN and +inf sort last
    ranked = np.flatnonzero(score <= kth)  # the k best and any tied with the k-th (none if kth is NaN)
    if not (np.isfinite(kth) and np.isfinite(score[ranked]).all()):  # fewer than k candidates, or a -inf
        ranked = np.flatnonzero(np.isfinite(score))
        if ranked.size > k:
            values = score[ranked]
            ranked = ranked[values <= np.partition(values, k - 1)[k - 1]]
    return ranked[np.argsort(score[ranked], kind="stable")][:k].astype(np.int64)

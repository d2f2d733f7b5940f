"""What a single-frame method reads off each difference row, for a block of rows in one compiled
pass: the row's best candidates (its ranking), its minimum and, in map mode, ``online``'s near
miss. ``wiloc.methods.online`` imports this with its first rows, so the command line loads no
numba. Each value is the one of the numpy function it stands for (named in the docstring).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def best_of_rows(rows: NDArray[np.floating], window: int, ranking: NDArray[np.int64], counts: NDArray[np.intp],
                 match: NDArray[np.intp], minimum: NDArray[np.float64], near: NDArray[np.float64]) -> None:
    """For each row r of ``rows``:

    - ``ranking[r, :counts[r]]``: its ``ranking.shape[1]`` best candidates, ascending, equal
      values in order of position, non-finite values never ranked
      (``wiloc.candidates.best_candidates``);
    - ``match[r]``, ``minimum[r]``: ``wiloc.candidates.finite_minimum`` (-1 and NaN when the row
      holds a NaN, a -inf or no finite value, as ``np.argmin`` then gives no finite minimum);
    - ``near[r]``: for a match, the smallest finite value outside +-``window`` of it (NaN when
      there is none): ``wiloc.methods.online.near_miss`` in map mode. The ranking holds it
      (its first position outside the window) unless every ranked position is inside.

    One pass keeps the best values so far; a value goes in only when below the worst of them
    (NaN and +inf never are), so the pass rarely leaves its compare.
    """
    k = ranking.shape[1]
    values = np.empty(k)
    for r in range(rows.shape[0]):
        row = rows[r]
        n = row.size
        spoilt = False  # a NaN or -inf: np.argmin's minimum is not finite
        for i in range(n):
            v = row[i]
            spoilt |= (v != v) | (v == -np.inf)  # noqa: PLR0124 - v != v: NaN
        count = 0
        worst = np.inf
        for i in range(n):
            v = np.float64(row[i])
            if not v < worst or v == -np.inf:
                continue
            at = count if count < k else k - 1
            while at > 0 and values[at - 1] > v:  # after every equal value: ties in order of position
                values[at] = values[at - 1]
                ranking[r, at] = ranking[r, at - 1]
                at -= 1
            values[at] = v
            ranking[r, at] = i
            count = min(count + 1, k)
            if count == k:
                worst = values[k - 1]
        ranking[r, count:] = -1
        counts[r] = count
        z = -1 if spoilt or count == 0 else ranking[r, 0]
        match[r] = z
        minimum[r] = np.nan if z < 0 else np.float64(row[z])
        near[r] = np.nan
        if z < 0:
            continue
        low, high = max(0, z - window), min(n, z + window + 1)
        for c in range(count):
            if ranking[r, c] < low or ranking[r, c] >= high:
                near[r] = np.float64(row[ranking[r, c]])
                break
        if count == k and not np.isfinite(near[r]):  # every ranked position inside the window
            smallest = np.inf
            for i in range(n):
                v = np.float64(row[i])
                if (i < low or i >= high) and np.isfinite(v) and v < smallest:
                    smallest = v
            near[r] = smallest if np.isfinite(smallest) else np.nan

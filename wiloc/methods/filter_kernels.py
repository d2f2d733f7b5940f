"""The CAT-Graph filter's passes over every map node, compiled: one pass each instead of a chain
of numpy expressions (docs/scaling.md gives the per-frame cost before and after).

``wiloc.methods.catgraph`` and ``wiloc.calibration`` import this module with a filter's first
frame, so the command line loads no numba. Each kernel's docstring says which piece of the
filter it computes (docs/catgraph.md, docs/calibration.md) and how its arithmetic relates to the
plain numpy expression it replaces.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def contrast_normalise(row: NDArray[np.float64], half_window: int, sign: float,
                       out: NDArray[np.float64]) -> bool:
    """The sequence score's local contrast: ``out`` = each value of ``sign * row`` minus the mean
    of its +-``half_window`` neighbouring nodes, over their standard deviation (0 where that is
    within rounding of 0); returns whether every value of ``row`` is finite.

    Means are box means over the row extended by its end values (scipy's
    ``uniform_filter1d(..., mode="nearest")``, whose running sums and order of operations this
    repeats: the same values, digit for digit); the std is sqrt(max(mean of squares - mean^2, 0)).
    Two passes: the running sums (sequential), then the normalisation (vectorised).
    """
    n = row.size
    size = 2 * half_window + 1
    total = 0.0
    squares = 0.0
    for k in range(-half_window, half_window + 1):
        x = sign * row[min(max(k, 0), n - 1)]
        total += x
        squares += x * x
    square_sums = np.empty(n)
    out[0], square_sums[0] = total, squares  # out holds the window sums until the second pass
    for i in range(1, n):
        new = sign * row[min(i + half_window, n - 1)]
        old = sign * row[max(i - half_window - 1, 0)]
        total += new - old
        squares += new * new - old * old
        out[i], square_sums[i] = total, squares
    finite = True
    for i in range(n):
        x = sign * row[i]
        finite &= np.isfinite(x)
        mean = out[i] / size
        sd = np.sqrt(max(square_sums[i] / size - mean * mean, 0.0))
        out[i] = (x - mean) / sd if sd > 1e-6 * abs(mean) and sd > 0 else 0.0
    return finite


@njit(cache=True, nogil=True)
def advance(score: NDArray[np.float64], at: NDArray[np.intp], a: NDArray[np.float64],
            contrast: NDArray[np.float64], rate: float, out: NDArray[np.float64],
            lowest: NDArray[np.float64]) -> None:
    """The leaky sequence score one frame on, and its minimum over speeds per node.

    ``out`` (speeds x nodes) = ``score`` read where ``catgraph._shifted_reads`` says, linearly
    interpolated (the score ending at node j continues the one that ended a step back), times
    1 - rate, plus rate times this frame's ``contrast``: the numpy expression
    ``(1 - rate) * ((1 - a) * prev[at] + a * prev[at + 1]) + rate * contrast``, value for value.
    ``lowest[j]`` = ``out[:, j].min()``, the score that re-seeding ranks nodes by.
    """
    prev = score.ravel()
    flat = out.ravel()
    speeds, n = score.shape
    for j in range(n):
        low = np.inf
        for v in range(speeds):
            k = v * n + j
            value = (1.0 - rate) * ((1.0 - a[k]) * prev[at[k]] + a[k] * prev[at[k] + 1]) + rate * contrast[j]
            flat[k] = value
            low = min(low, value)
        lowest[j] = low


@njit(cache=True, nogil=True)
def rank_ratio_sum(ordered: NDArray[np.float64], ratio: NDArray[np.float64]) -> float:
    """Sum over the values of a sorted row of ``ratio[left rank]``: the left rank of a value is
    the number of values below it (equal values share the rank of the first of them).

    With ``ratio`` the rank model's lambda per left rank, this is the sum of lambda over every
    map node as if none were damped as a near duplicate (``RankLikelihood.mean``), without
    ordering the nodes: only the multiset of ranks counts.
    """
    total = 0.0
    left = 0
    for i in range(ordered.size):
        if i > 0 and ordered[i] != ordered[i - 1]:
            left = i
        total += ratio[left]
    return total

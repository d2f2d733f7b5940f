"""The rank likelihood's passes over a row, compiled (``wiloc.methods.catgraph.observation.RankLikelihood``,
docs/calibration.md): each row's distinct ranks, the left rank of any difference in the sorted row,
ln lambda at the particles and the mean ratio over every node.

``wiloc.methods.catgraph.observation`` imports this module with a filter's first frame, so the command line loads
no numba. Each kernel's docstring says how its arithmetic relates to the plain numpy expression it
replaces.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def interpolate(values: NDArray[np.float64], j: NDArray[np.intp], frac: NDArray[np.float64],
                out: NDArray[np.float64]) -> None:
    """Per-node ``values`` read between nodes j and j + 1: ``(1 - frac) * values[j] + frac *
    values[j + 1]`` (eq. 8's interpolated observation, or a near-duplicate weight)."""
    for p in range(j.size):
        out[p] = (1.0 - frac[p]) * values[j[p]] + frac[p] * values[j[p] + 1]


@njit(cache=True, nogil=True)
def distinct_ranks(ordered: NDArray[np.floating], table: NDArray[np.float64],
                   sizes: NDArray[np.intp]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """For every row of sorted values: ``sizes[r]``, its number of distinct values, and (row
    after row in the two returned arrays) ``table`` at the left rank of each distinct value (its
    first place) and how many values share it. NaN never equals itself, so each NaN is a value
    of its own, as numpy's ``!=`` has it. The first places are collected without a branch (a
    sorted row's runs of equal values end at unpredictable places): each place is written as
    the next distinct value's first, and kept only when its value differs from the one before."""
    rows, n = ordered.shape
    for r in range(rows):
        row = ordered[r]
        k = 1 if n else 0
        for i in range(1, n):
            k += row[i] != row[i - 1]
        sizes[r] = k
    t, counts = np.empty(sizes.sum()), np.empty(sizes.sum())
    left = np.empty(n + 1, dtype=np.intp)
    at = 0
    for r in range(rows if n else 0):
        row = ordered[r]
        k = 0
        left[0] = 0
        for i in range(1, n):
            left[k + 1] = i
            k += row[i] != row[i - 1]
        left[k + 1] = n
        for d in range(k + 1):
            t[at + d] = table[left[d]]
            counts[at + d] = left[d + 1] - left[d]
        at += k + 1
    return t, counts


@njit(cache=True, nogil=True)
def table_at_ranks(ordered: NDArray[np.floating], table: NDArray[np.float64], keys: NDArray[np.floating],
                   out: NDArray[np.float64]) -> None:
    """``out`` = ``table[np.searchsorted(ordered, keys, side="left")]``: each key's left rank in
    the sorted row (its values read as float64; NaN sorting last, as numpy's search has it).

    Sixteen keys are searched side by side, each halving its range without a branch on the
    comparison: the particles' keys fall anywhere in the row, and sixteen independent reads per
    halving overlap."""
    n, m = ordered.size, keys.size
    group = 16
    base = np.zeros(group, dtype=np.intp)
    for first in range(0, m, group):
        count = min(group, m - first)
        base[:] = 0
        length = n
        while length > 1:
            half = length >> 1
            for q in range(count):
                at = base[q] + half
                base[q] = at if np.float64(ordered[at]) < np.float64(keys[first + q]) else base[q]
            length -= half
        for q in range(count):
            x = np.float64(keys[first + q])
            if n == 0:
                rank = 0
            elif x != x:  # a NaN key goes after every value but the NaNs
                rank = 0
                while rank < n and np.float64(ordered[rank]) == np.float64(ordered[rank]):
                    rank += 1
            else:
                rank = base[q] + (1 if np.float64(ordered[base[q]]) < x else 0)
            out[first + q] = table[rank]


@njit(cache=True, nogil=True)
def rank_log_ratio(row: NDArray[np.float64], ordered: NDArray[np.floating], table: NDArray[np.float64],
                   j: NDArray[np.intp], frac: NDArray[np.float64], omega: NDArray[np.float64], a: float,
                   t: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """``RankLikelihood.at`` in one call: the difference :func:`interpolate`\\ d at each particle,
    ``t`` = -ln u of its rank (:func:`table_at_ranks`) and ``out`` = ln lambda = ln a_j +
    (1 - a_j) t with a_j = 1 - omega (1 - a), value for value the numpy expressions' (ln a_j
    taken once for the particles of weight 1, nearly all)."""
    d = np.empty(j.size)
    interpolate(row, j, frac, d)
    table_at_ranks(ordered, table, d, t)
    whole = 1.0 - 1.0 * (1.0 - a)
    log_whole = np.log(whole)
    for p in range(j.size):
        if omega[p] == 1.0:
            out[p] = log_whole + (1.0 - whole) * t[p]
        else:
            a_p = 1.0 - omega[p] * (1.0 - a)
            out[p] = np.log(a_p) + (1.0 - a_p) * t[p]


@njit(cache=True, nogil=True)
def ratio_sum(t: NDArray[np.float64], counts: NDArray[np.float64], a: float) -> float:
    """sum of counts x lambda(t) at weight 1: the rank likelihood's total over every map node
    from the row's distinct ranks (``RankLikelihood.mean``), in one pass."""
    whole = 1.0 - 1.0 * (1.0 - a)
    log_whole = np.log(whole)
    total = 0.0
    for i in range(t.size):
        total += counts[i] * np.exp(log_whole + (1.0 - whole) * t[i])
    return total

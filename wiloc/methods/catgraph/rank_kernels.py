"""The rank likelihood's passes over a row, compiled (``wiloc.methods.catgraph.observation.RankLikelihood``,
docs/calibration.md): the left rank of any difference in the sorted row, ln lambda at the
particles and the mean ratio over every node.

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
                   scale: NDArray[np.float64], j: NDArray[np.intp], frac: NDArray[np.float64],
                   omega: NDArray[np.float64], a: float, t: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """``RankLikelihood.at`` in one call: the difference :func:`interpolate`\\ d at each particle,
    ``t`` = -ln u of its rank (:func:`table_at_ranks`) over the node's chance ``scale``
    (interpolated likewise), and ``out`` = ln lambda = ln a_j + (1 - a_j) t with a_j = 1 - omega
    (1 - a), value for value the numpy expressions' (ln a_j taken once for the particles of
    weight 1, nearly all)."""
    d = np.empty(j.size)
    interpolate(row, j, frac, d)
    table_at_ranks(ordered, table, d, t)
    for p in range(j.size):
        t[p] /= (1.0 - frac[p]) * scale[j[p]] + frac[p] * scale[j[p] + 1]
    whole = 1.0 - 1.0 * (1.0 - a)
    log_whole = np.log(whole)
    for p in range(j.size):
        if omega[p] == 1.0:
            out[p] = log_whole + (1.0 - whole) * t[p]
        else:
            a_p = 1.0 - omega[p] * (1.0 - a)
            out[p] = np.log(a_p) + (1.0 - a_p) * t[p]


@njit(cache=True, nogil=True)
def ratio_sum(t: NDArray[np.float64], scale: NDArray[np.float64], omega: NDArray[np.float64], a: float) -> float:
    """sum over every map node of lambda = exp(ln a_j + (1 - a_j) t_j / scale_j), a_j = 1 -
    omega_j (1 - a): the rank likelihood's total over the map (``RankLikelihood.mean``), in one
    pass."""
    whole = 1.0 - 1.0 * (1.0 - a)
    log_whole = np.log(whole)
    total = 0.0
    for i in range(t.size):
        if omega[i] == 1.0:
            total += np.exp(log_whole + (1.0 - whole) * t[i] / scale[i])
        else:
            a_i = 1.0 - omega[i] * (1.0 - a)
            total += np.exp(np.log(a_i) + (1.0 - a_i) * t[i] / scale[i])
    return total


@njit(cache=True, nogil=True)
def chance_scale(total: NDArray[np.float64], weight: NDArray[np.float64], prior: float,
                 out: NDArray[np.float64]) -> None:
    """Each node's chance scale (``RankLikelihood``): ``max(1, (prior + total) / (prior +
    weight))``, the weighted mean of its t with a prior of 1 worth ``prior`` frames."""
    for i in range(out.size):
        out[i] = max(1.0, (prior + total[i]) / (prior + weight[i]))


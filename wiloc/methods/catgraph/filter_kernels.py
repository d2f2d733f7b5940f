"""The CAT-Graph filter's passes over every map node, compiled: one pass each instead of a chain
of numpy expressions (docs/scaling.md gives the per-frame cost before and after).

``wiloc.methods.catgraph.filter`` imports this module with a filter's first frame, so the command line
loads no numba; the rank likelihood's own passes are in ``wiloc.methods.catgraph.rank_kernels``. Each kernel's
docstring says which piece of the filter it computes (docs/catgraph.md) and how its arithmetic
relates to the plain numpy expression it replaces.
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
def advance(score: NDArray[np.float64], at: NDArray[np.intp], a: NDArray[np.float64], runs: NDArray[np.intp],
            contrast: NDArray[np.float64], rate: float, group: NDArray[np.intp], out: NDArray[np.float64],
            lowest: NDArray[np.float64]) -> None:
    """The leaky sequence score one frame on, and its minimum over each group's speeds per node.

    ``out`` (speeds x nodes) = ``score`` read where ``trajectory.shifted_reads`` says (flat
    positions ``at``, fractions ``a``), linearly interpolated (the score ending at node j
    continues the one that ended a step back), times 1 - rate, plus rate times this frame's
    ``contrast``: the numpy expression
    ``(1 - rate) * ((1 - a) * prev[at] + a * prev[at + 1]) + rate * contrast``, value for value.
    ``runs`` (``trajectory.read_runs``: first, end) are long stretches that read consecutive
    positions at one fraction, as evenly spaced nodes give: there the loop vectorises.
    ``lowest[g, j]`` = ``out[group == g, j].min()`` (speed s belongs to group ``group[s]``; the
    forward and the backward paces), the scores that re-seeding ranks nodes by, taken in the
    same pass (speed by speed, as the rows are written); a group without speeds is left as it is.
    """
    prev, flat = score.ravel(), out.ravel()
    n = contrast.size
    keep = 1.0 - rate
    opened = np.zeros(lowest.shape[0], dtype=np.bool_)  # whether a group's lowest holds a row yet
    k = 0
    for r in range(runs.shape[0] + 1):
        end = runs[r, 0] if r < runs.shape[0] else flat.size
        j = k % n
        for k in range(k, end):  # uneven reads: one position at a time
            value = keep * ((1.0 - a[k]) * prev[at[k]] + a[k] * prev[at[k] + 1]) + rate * contrast[j]
            flat[k] = value
            g = group[k // n]
            if j == 0 and not opened[g]:
                opened[g] = True
                lowest[g, :] = np.inf
            lowest[g, j] = min(lowest[g, j], value)
            j = j + 1 if j + 1 < n else 0
        if r == runs.shape[0]:
            break
        k, end = runs[r, 0], runs[r, 1]
        length, first, f = end - k, at[k], a[k]
        g = group[k // n]
        if not opened[g]:  # a run starts a row: when it is its group's first, the row sets the minimum
            opened[g] = True
            lowest[g, :] = np.inf
        here, before, after = flat[k:end], prev[first:first + length], prev[first + 1:first + 1 + length]
        now, low = contrast[k % n:k % n + length], lowest[g, k % n:k % n + length]
        for i in range(length):  # plain indices into views: the loop vectorises
            here[i] = keep * ((1.0 - f) * before[i] + f * after[i]) + rate * now[i]
            low[i] = min(low[i], here[i])
        k = end


@njit(cache=True, nogil=True)
def even_reads(n: int, shifts: NDArray[np.float64], at: NDArray[np.intp], frac: NDArray[np.float64]) -> None:
    """``trajectory.shifted_reads`` of the nodes 0, 1, ..., n - 1 (sequence mode's map, grown by
    one node per frame): what :func:`locate` finds at each position i - shift, value for value,
    in one pass without its division or searches."""
    for v in range(shifts.size):
        base = v * n
        for i in range(n):
            x = i - shifts[v]
            k = min(max(int(x), 0), n - 2)
            at[base + i] = base + k
            frac[base + i] = min(max(x - k, 0.0), 1.0)


@njit(cache=True, nogil=True)
def runs(at: NDArray[np.intp], frac: NDArray[np.float64], n: int, shortest: int, out: NDArray[np.intp]) -> int:
    """``trajectory.read_runs`` in one pass: the stretches (first, end) at least ``shortest`` long
    within one row of n reads that read consecutive positions at one fraction, written to ``out``
    in order; returns how many."""
    count = 0
    first = 0
    for k in range(1, at.size + 1):
        if k == at.size or k % n == 0 or at[k] != at[k - 1] + 1 or frac[k] != frac[k - 1]:
            if k - first >= shortest:
                out[count, 0], out[count, 1] = first, k
                count += 1
            first = k
    return count


@njit(cache=True, nogil=True)
def locate(nodes: NDArray[np.float64], pos: NDArray[np.float64], j: NDArray[np.intp],
           frac: NDArray[np.float64]) -> None:
    """For each particle: ``j``, the node just before it (the last node at or before its position,
    kept within 0..N - 2), and ``frac``, its fraction of the way to node j + 1 (in [0, 1]; 0 where
    the two nodes coincide): ``np.searchsorted(nodes, pos, side="right") - 1`` clipped, and
    ``(pos - nodes[j]) / (nodes[j + 1] - nodes[j])`` clipped, value for value. The node is looked
    up where even spacing would put it, and searched for only when it is not there."""
    n = nodes.size
    spacing = (nodes[n - 1] - nodes[0]) / (n - 1)
    for p in range(pos.size):
        x = pos[p]
        k = min(max(int((x - nodes[0]) / spacing), 0), n - 2) if spacing > 0 else 0
        if not ((k == 0 or nodes[k] <= x) and (k == n - 2 or x < nodes[k + 1])):
            k = min(max(np.searchsorted(nodes, x, side="right") - 1, 0), n - 2)
        gap = nodes[k + 1] - nodes[k]
        j[p] = k
        frac[p] = min(max((x - nodes[k]) / gap, 0.0), 1.0) if gap > 0 else 0.0


@njit(cache=True, nogil=True)
def window_sum(own: NDArray[np.float64], half: int, i: int) -> float:
    """:func:`window_mass` at node i alone, summed in its order."""
    n = own.size
    half = min(half, n)  # a window wider than the map is the whole map (2 half + 1 must not wrap around int64)
    total = 0.0
    if n - 2 * half > 0:
        for k in range(max(i - half, 0), min(i + half, n - 1) + 1):
            total += own[k]
    else:  # a map shorter than the window: np.convolve sums from the last node back
        for k in range(min(i + half, n - 1), max(i - half, 0) - 1, -1):
            total += own[k]
    return total


@njit(cache=True, nogil=True)
def window_mass(own: NDArray[np.float64], half: int, mass: NDArray[np.float64]) -> None:
    """``mass`` = the posterior weight ``own`` summed within +-``half`` nodes of each node.

    Each window is summed in the order ``np.convolve(own, np.ones(2 half + 1))`` sums it for
    half <= 2 (from its first node on; on a map shorter than the window, from its last node
    back): the same values, digit for digit. Inside the map, one shifted pass per window node.
    """
    n = own.size
    inner = n - 2 * half
    if inner > 0:
        centre = mass[half:n - half]
        centre[:] = own[:inner]
        for k in range(1, 2 * half + 1):
            shifted = own[k:k + inner]
            for i in range(inner):  # plain indices into views: the loop vectorises
                centre[i] += shifted[i]
        edges = list(range(half)) + list(range(n - half, n))
    else:
        edges = list(range(n))
    for i in edges:  # where the window is cut short
        mass[i] = window_sum(own, half, i)


@njit(cache=True, nogil=True)
def posterior_mode(j: NDArray[np.intp], frac: NDArray[np.float64], w: NDArray[np.float64], half: int,
                   tie: float, own: NDArray[np.float64], marks: NDArray[np.int64], frame: int) -> tuple[int, float]:
    """The read-out of the posterior: ``own`` = the particles' weight per nearest node
    (``np.bincount(j + (frac >= 0.5), w)``), and the mode of its :func:`window_mass` with the
    mode's mass: among the nodes whose mass is within ``tie`` of the largest, the first of those
    holding most weight themselves.

    Only nodes within +-``half`` of a particle have mass, so only those are summed, each once
    (``marks[i] == frame`` once node i is; ``frame`` differs in every call): the same masses
    and mode as a pass over every node, which this falls back to when the largest mass is not
    beyond ``tie`` (massless nodes would count) or not finite.
    """
    n = own.size
    half = min(half, n)  # a window wider than the map is the whole map: the same masses, work bounded by the map
    own[:] = 0.0
    nearest = np.empty(j.size, dtype=np.intp)
    for p in range(j.size):
        nearest[p] = j[p] + (1 if frac[p] >= 0.5 else 0)
        own[nearest[p]] += w[p]
    nodes = np.empty(min(j.size * (2 * half + 1), n), dtype=np.intp)  # each node is summed once at most
    masses = np.empty(nodes.size)
    count = 0
    top = 0.0
    finite = True
    for p in range(j.size):
        for i in range(max(nearest[p] - half, 0), min(nearest[p] + half, n - 1) + 1):
            if marks[i] != frame:
                marks[i] = frame
                nodes[count], masses[count] = i, window_sum(own, half, i)
                finite &= np.isfinite(masses[count])
                top = max(top, masses[count])
                count += 1
    if not (finite and top - tie > 0.0):  # every node's mass, as the pass over all nodes has it
        masses = np.empty(n)
        window_mass(own, half, masses)
        top = masses.max()
        mode = -1
        for i in range(n):
            if masses[i] >= top - tie and (mode < 0 or own[i] > own[mode]):
                mode = i
        return mode, masses[mode]
    mode = -1
    for c in range(count):  # the most own weight among the near-top masses, the first node among ties
        i = nodes[c]
        if masses[c] >= top - tie and (mode < 0 or own[i] > own[mode] or (own[i] == own[mode] and i < mode)):
            mode = i
    return mode, window_sum(own, half, mode)


@njit(cache=True, nogil=True)
def contrast_rows(rows: NDArray[np.floating], half_window: int, sign: float, out: NDArray[np.float64],
                  finite: NDArray[np.bool_]) -> None:
    """:func:`contrast_normalise` of every row of a block (float32 values read as float64, as
    converting the row first gives): ``out[r]`` and ``finite[r]``."""
    for r in range(rows.shape[0]):
        finite[r] = contrast_normalise(rows[r], half_window, sign, out[r])


@njit(cache=True, nogil=True)
def _logsumexp(x: NDArray[np.float64], use: NDArray[np.bool_], every: bool) -> float:
    """``scipy.special.logsumexp`` of x (where ``use``, unless ``every``), which compiled code
    cannot call: the largest terms kept out of the sum, log1p of the rest."""
    top = -np.inf
    for p in range(x.size):
        if every or use[p]:
            top = max(top, x[p])
    count = 0
    rest = 0.0
    for p in range(x.size):
        if every or use[p]:
            if x[p] == top:
                count += 1
            else:
                rest += np.exp(x[p] - top)
    return np.log1p(rest / count) + np.log(count) + top


@njit(cache=True, nogil=True)
def weigh(log_w: NDArray[np.float64], kept: NDArray[np.bool_], renormalise: bool, log_ratio: NDArray[np.float64],
          log_track: float, log_jump: float, out: NDArray[np.float64], w: NDArray[np.float64]) -> tuple[float, float]:
    """The particles' posterior weights after a frame, in one call (the CAT-Graph filter's eq. 8
    with the unexplained hypothesis): a kept particle's prior log weight (renormalised over the
    kept ones when some were re-seeded) + ln of the track's prior mass + its ln lambda; a
    re-seeded one's ``log_jump``. Returns the log of their total (the map's mass against the
    unexplained hypothesis) and sum w^2 (for the effective sample size); ``out`` = the
    normalised log weights, ``w`` = their exp. Sums run in another order than numpy's, so the
    last digits may differ from the numpy expressions'."""
    m = log_w.size
    shift = _logsumexp(log_w, kept, False) if renormalise else 0.0
    for p in range(m):
        out[p] = log_track + (log_w[p] - shift) + log_ratio[p] if kept[p] else log_jump
    log_map = _logsumexp(out, kept, True)
    squares = 0.0
    for p in range(m):
        out[p] -= log_map
        w[p] = np.exp(out[p])
        squares += w[p] * w[p]
    return log_map, squares

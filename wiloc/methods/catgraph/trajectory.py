"""The CAT-Graph filter's operations on plain arrays along the reference trajectory (used by
``wiloc.methods.catgraph.filter``): the nodes' positions and where particles sit between them, the
sequence score's contrast and shifted reads, choosing among ties the same on every CPU,
systematic resampling, and the posterior's ranking of the map and pace at the decided node. docs/catgraph.md gives the filter
they serve.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from wiloc.candidates import RANKED
from wiloc.errors import WilocError


def node_positions(ref_arclength: NDArray[np.float64] | None, n_nodes: int) -> NDArray[np.float64]:
    """Node positions: the given arc lengths (non-decreasing), else the frame index."""
    if ref_arclength is None:
        return np.arange(n_nodes, dtype=np.float64)
    s = np.asarray(ref_arclength, dtype=np.float64)
    if s.shape != (n_nodes,):
        raise WilocError(None, f"gives {s.size} positions for {n_nodes} map frames", parameter="map_odometry")
    if not np.all(np.isfinite(s)) or np.any(np.diff(s) < 0):
        raise WilocError(None, "the map's distances along its route must be finite and non-decreasing",
                         parameter="map_odometry")
    if not s[-1] > s[0]:
        raise WilocError(None, "the map's route has zero length (the odometry never moves)",
                         parameter="map_odometry")
    return s


def locate(nodes: NDArray[np.float64], pos: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """For each particle: the node j just before it and its fraction a of the way to node j + 1
    (``filter_kernels.locate``)."""
    from wiloc.methods.catgraph import filter_kernels  # numba loads on first use, not with the command line

    j, a = np.empty(pos.size, dtype=np.intp), np.empty(pos.size)
    filter_kernels.locate(nodes, pos, j, a)
    return j, a


def contrast_normalise(row: NDArray[np.float64], half_window: int) -> NDArray[np.float64]:
    """Each difference minus the mean of its +-``half_window`` neighbouring nodes, over their std.

    Removes what a whole stretch of the map shares (a tunnel, snow, a dark scene all look alike
    to every query frame), so a node stands out only by being lower than its neighbours
    (SeqSLAM's local contrast enhancement, on one row: causal). A flat stretch (std within
    rounding of 0) gives 0. One compiled pass (``filter_kernels.contrast_normalise``).
    """
    from wiloc.methods.catgraph import filter_kernels  # numba loads on first use, not with the command line

    out = np.empty(row.size)
    filter_kernels.contrast_normalise(np.asarray(row, dtype=np.float64), half_window, 1.0, out)
    return out


def shifted_reads(nodes: NDArray[np.float64],
                   shifts: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Where each row v of a (speeds x nodes) score is read at s_j - shifts[v], clamped to the
    trajectory: flat indices of the node before and the fraction of the way to the next."""
    j, a = locate(nodes, (nodes[None, :] - shifts[:, None]).ravel())
    return np.arange(shifts.size).repeat(nodes.size) * nodes.size + j, a


def smallest(values: NDArray[np.float64], k: int, rng: np.random.Generator | None = None) -> NDArray[np.intp]:
    """Indices of the ``k`` smallest values; among ties at the k-th value, a uniform draw from
    ``rng`` (else the first in index order). ``np.argpartition``'s choice among ties depends on
    the SIMD loops numpy runs on the CPU at hand, so the same input would re-seed other particles
    or nodes on another machine; and equal weights (after resampling) are all equally weak."""
    if k >= values.size:
        return np.arange(values.size)
    kth = np.partition(values, k - 1)[k - 1]
    below = np.flatnonzero(values < kth)
    ties = np.flatnonzero(values == kth)
    need = k - below.size
    chosen = ties[:need] if rng is None or need == ties.size else rng.choice(ties, need, replace=False)
    return np.concatenate((below, chosen))


def lowest_nodes(score: NDArray[np.float64], top: int) -> NDArray[np.intp]:
    """The ``top`` nodes of lowest score (ties in node order); for one node the argmin (its first
    occurrence), found 10x faster."""
    return np.array([int(np.argmin(score))]) if top == 1 else smallest(score, top)


def even_shifted_reads(n_nodes: int, shifts: NDArray[np.float64],
                       shortest: int = 16) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.intp]]:
    """:func:`shifted_reads` of the nodes 0, 1, ..., n_nodes - 1 (``filter_kernels.even_reads``)
    and their :func:`read_runs`."""
    from wiloc.methods.catgraph import filter_kernels  # numba loads on first use, not with the command line

    at, a = np.empty(shifts.size * n_nodes, dtype=np.intp), np.empty(shifts.size * n_nodes)
    filter_kernels.even_reads(n_nodes, np.asarray(shifts, dtype=np.float64), at, a)
    return at, a, read_runs(at, a, n_nodes, shortest)


def read_runs(at: NDArray[np.intp], a: NDArray[np.float64], n_nodes: int,
               shortest: int = 16) -> NDArray[np.intp]:
    """The stretches of :func:`shifted_reads` (rows: first, end) at least ``shortest`` long
    that stay within one speed's row and read consecutive positions at one fraction: nearly
    everything on evenly spaced nodes, little on uneven ones (``filter_kernels.advance``; found
    by ``filter_kernels.runs``)."""
    from wiloc.methods.catgraph import filter_kernels  # numba loads on first use, not with the command line

    out = np.empty((at.size // shortest + 1, 2), dtype=np.intp)
    return out[:filter_kernels.runs(at, a, n_nodes, shortest, out)]


def posterior_ranking(own: NDArray[np.float64], mode: int, k: int = RANKED) -> NDArray[np.int64]:
    """The filter's ranking of the map for Recall@N: the decided ``mode`` first, then the nodes
    holding most particle weight themselves (``own``), equal weights in order of position.
    Nodes without weight are no candidates, so the ranking may be shorter than ``k``."""
    held = np.flatnonzero(own > 0.0)
    held = held[held != mode]
    order = held[np.argsort(-own[held], kind="stable")][:k - 1]
    return np.concatenate([np.array([mode], dtype=np.int64), order.astype(np.int64)])


def track_pace(j: NDArray[np.intp], frac: NDArray[np.float64], w: NDArray[np.float64],
               speed: NDArray[np.float64], node: int, window: int) -> float:
    """The decided track's pace: the mean pace, by weight ``w``, of the particles (between nodes
    j and j + 1, a ``frac`` of the way) whose nearest node lies within ``window`` nodes of
    ``node``, the decided one (the read-out's window)."""
    near = np.abs(j + frac - node) <= window + 0.5
    return float(np.dot(w[near], speed[near]) / w[near].sum())


def systematic(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.intp]:
    """Indices drawn by systematic resampling (one uniform offset, M evenly spaced pointers)."""
    m = weights.size
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    pointers = (rng.random() + np.arange(m)) / m
    return np.searchsorted(cum, pointers, side="left")

"""The Chow-Liu tree: the tree-structured distribution over binary word variables closest (in
KL divergence) to the training data's, as FAB-MAP uses it (Chow and Liu, 1968).

1. Pairwise mutual information I(z_i; z_j) of the word-presence variables, from the counts of the
   training images (maximum-likelihood, 0 log 0 = 0).
2. The maximum-weight spanning tree over that complete graph: scipy's
   ``minimum_spanning_tree`` on ``(max I + 1) - I``, which keeps every edge weight positive (a
   zero would mean "no edge") and orders spanning trees exactly as their total information.
3. Rooted at the most frequent word (any root gives the same tree distribution), every word's
   parent by a breadth-first walk.
4. Marginals p(z_q = 1) and conditionals p(z_q = 1 | z_parent) from the same counts, smoothed
   with a pseudo-count ``a``: ``p(z_q=1) = (n_q + a) / (N + 2a)`` (Laplace at a = 1) and
   ``p(z_q=1 | z_p=s) = (n_{q,s} + 2a p(z_q=1)) / (n_s + 2a)``, i.e. the ``2a`` pseudo-images
   follow the word's own marginal, so a parent state seen rarely says little and the word falls
   back to independence instead of to 1/2. No probability is ever 0 or 1.

The dense K x K information matrix costs 8 K^2 bytes (8 MB at K = 1000, 200 MB at K = 5000).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from wiloc.errors import ParameterError

#: The pseudo-count ``a`` of the smoothing (docs/fabmap.md).
DEFAULT_SMOOTHING = 1.0


def _occurrences(occurrences: NDArray) -> NDArray[np.float64]:
    z = np.asarray(occurrences)
    if z.ndim != 2 or z.shape[0] < 1 or z.shape[1] < 2:
        raise ValueError(f"occurrences must be (images >= 1, words >= 2); got shape {z.shape}")
    if z.dtype != bool and not np.isin(z, (0, 1)).all():
        raise ValueError("occurrences must be boolean (or 0/1)")
    return z.astype(np.float64)


def mutual_information(occurrences: NDArray) -> NDArray[np.float64]:
    """``(K, K)`` mutual information (nats) between the binary word variables of the rows of
    ``occurrences`` ``(N, K)``; the diagonal is 0."""
    z = _occurrences(occurrences)
    n = z.shape[0]
    ones = z.sum(axis=0)
    both = z.T @ z  # n11[i, j]: images showing both words
    joint = {
        (1, 1): both,
        (1, 0): ones[:, None] - both,
        (0, 1): ones[None, :] - both,
        (0, 0): n - ones[:, None] - ones[None, :] + both,
    }
    marginal = {1: ones / n, 0: 1.0 - ones / n}
    info = np.zeros_like(both)
    with np.errstate(divide="ignore", invalid="ignore"):
        for (a, b), count in joint.items():
            p = count / n
            term = p * np.log(p / (marginal[a][:, None] * marginal[b][None, :]))
            info += np.where(p > 0, term, 0.0)
    np.fill_diagonal(info, 0.0)
    return np.maximum(info, 0.0)  # rounding can leave -1e-17 for independent pairs


@dataclass(frozen=True)
class ChowLiuTree:
    """A rooted Chow-Liu tree over K binary word variables.

    parent: ``(K,)`` int, each word's parent, -1 at the root.
    marginal: ``(K,)`` p(z_q = 1).
    conditional: ``(K, 2)`` p(z_q = 1 | z_parent = 0) and p(z_q = 1 | z_parent = 1); the root's
        two entries are its marginal.
    smoothing: the pseudo-count ``a`` it was fitted with; n_images: N.
    """

    parent: NDArray[np.intp]
    marginal: NDArray[np.float64]
    conditional: NDArray[np.float64]
    smoothing: float
    n_images: int

    @property
    def n_words(self) -> int:
        return int(self.parent.size)

    @property
    def root(self) -> int:
        return int(np.flatnonzero(self.parent < 0)[0])

    @classmethod
    def fit(cls, occurrences: NDArray, smoothing: float = DEFAULT_SMOOTHING) -> ChowLiuTree:
        """The Chow-Liu tree of the word occurrences ``(N, K)`` of N training images."""
        if isinstance(smoothing, bool) or not isinstance(smoothing, (int, float)) \
                or not (np.isfinite(smoothing) and smoothing > 0):
            raise ParameterError("smoothing", f"must be a finite number > 0, got {smoothing!r}")
        z = _occurrences(occurrences)
        n, k = z.shape
        info = mutual_information(z)
        weights = (info.max() + 1.0) - info
        np.fill_diagonal(weights, 0.0)
        tree = minimum_spanning_tree(weights)
        ones = z.sum(axis=0)
        root = int(np.argmax(ones))
        _, predecessors = breadth_first_order(tree, root, directed=False, return_predecessors=True)
        parent = np.where(predecessors < 0, -1, predecessors).astype(np.intp)
        a = float(smoothing)
        marginal = (ones + a) / (n + 2.0 * a)
        source = np.where(parent < 0, np.arange(k), parent)
        parent_on = z[:, source]  # the root counts against itself, then is reset below
        with_parent = (z * parent_on).sum(axis=0)
        parent_ones = parent_on.sum(axis=0)
        conditional = np.empty((k, 2))
        conditional[:, 1] = (with_parent + 2.0 * a * marginal) / (parent_ones + 2.0 * a)
        conditional[:, 0] = (ones - with_parent + 2.0 * a * marginal) / (n - parent_ones + 2.0 * a)
        conditional[root] = marginal[root]
        return cls(parent, marginal, conditional, a, n)

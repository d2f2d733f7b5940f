"""The batch ("trained") frequency model: P(L | d) from labelled training pairs (paper III.B).

It is the comparator that needs ground truth, like FAB-MAP's training phase. By default the
histograms are filled with each training frame's best-match difference m, labelled by whether
that best match is a true match (``pairs="minima"``): this is the distribution of the statistic
the decision is made on. ``pairs="all"`` is the paper's literal III.B (every pair). See
docs/algorithm.md for the measurement behind the default.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Literal

import numpy as np
import scipy.sparse
from numpy.typing import NDArray

from wiloc.errors import WilocError
from wiloc.methods.base import Decisions
from wiloc.methods.online import DEFAULT_BINS, best_matches, finite_minimum, model_from_values
from wiloc.model import HistogramModel, check_options

DEFAULT_TRAIN_SMOOTHING = 0.1
DEFAULT_TRAIN_PAIRS = "minima"

Pairs = Literal["minima", "all"]


def _label_row(labels: NDArray[np.bool_] | scipy.sparse.sparray | scipy.sparse.spmatrix,
               k: int) -> NDArray[np.bool_]:
    """Row k of the truth matrix as a dense boolean array."""
    if scipy.sparse.issparse(labels):
        return np.asarray(labels[[k], :].toarray(), dtype=bool).ravel()
    return np.asarray(labels[k], dtype=bool)


def train_model(rows: Iterable[NDArray[np.float64]],
                labels: NDArray[np.bool_] | scipy.sparse.sparray | scipy.sparse.spmatrix,
                bins: int = DEFAULT_BINS, smoothing: float = DEFAULT_TRAIN_SMOOTHING, *,
                pairs: Pairs = DEFAULT_TRAIN_PAIRS, prior: float | None = None) -> HistogramModel:
    """Fill ``b`` with true-match and ``c`` with false-match differences of a training run.

    ``labels`` (n_train_query x n_candidates, dense bool or scipy.sparse) marks true matches.
    The bin range spans [min(0, lowest), highest] of the training values used.
    """
    check_options(bins, smoothing, prior)
    if pairs not in ("minima", "all"):
        raise WilocError("train", f"pairs must be 'minima' or 'all', got {pairs!r}")
    if scipy.sparse.issparse(labels):
        labels = scipy.sparse.csr_array(labels)
    shape = labels.shape
    same: list[NDArray[np.float64]] = []
    different: list[NDArray[np.float64]] = []
    k = -1
    for k, row in enumerate(rows):
        row = np.asarray(row, dtype=np.float64)
        if k >= shape[0] or row.shape != (shape[1],):
            raise WilocError("train", f"labels are {shape[0]} x {shape[1]}, difference row {k} "
                                      f"has {row.size} values")
        truth = _label_row(labels, k)
        if pairs == "minima":
            z, m = finite_minimum(row)
            if z >= 0:
                (same if truth[z] else different).append(np.array([m]))
        else:
            finite = np.isfinite(row)
            same.append(row[finite & truth])
            different.append(row[finite & ~truth])
    if k + 1 != shape[0]:
        raise WilocError("train", f"got {k + 1} difference rows for {shape[0]} label rows")
    b = np.concatenate(same) if same else np.empty(0)
    c = np.concatenate(different) if different else np.empty(0)
    if b.size == 0 or c.size == 0:
        raise WilocError("train", "training needs both true and false matches "
                                  f"(got {b.size} true, {c.size} false)")
    model = model_from_values(np.concatenate([b, c]), bins, smoothing, prior)
    model.add_same(b)
    model.add_different(c)
    return model


def localize_trained(rows: Iterable[NDArray[np.float64]], n_frames: int,
                     model: HistogramModel) -> Decisions:
    """Best match per frame with confidence P(L | m) from a trained model."""
    match, difference = best_matches(rows, n_frames, "trained")
    decided = match >= 0
    confidence = np.full(n_frames, np.nan)
    confidence[decided] = model.posterior(difference[decided])
    stage = np.where(decided, "update", "none")
    return Decisions(match=match, difference=difference, confidence=confidence, stage=stage,
                     model=model, params={"method": "trained", "bins": model.n_bins,
                                          "smoothing": model.smoothing, "prior": model.prior})

"""The batch ("trained") frequency model: P(L | d) from labelled training pairs (paper III.B).

It is the comparator that needs ground truth, like FAB-MAP's training phase. By default the
histograms are filled with each training frame's best-match difference m, labelled by whether
that best match is a true match (``pairs="minima"``): this is the distribution of the statistic
the decision is made on. ``pairs="all"`` is the paper's literal III.B (every pair: eq. 3's set of
differences, split by label into P(d and L) and P(d and not L)). See
docs/algorithm.md for the measurement behind the default.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from wiloc.candidates import finite_minimum
from wiloc.decisions import Decision
from wiloc.errors import WilocError
from wiloc.methods.base import MapContext, Method
from wiloc.model import HistogramModel
from wiloc.parameters import Parameters, param

if TYPE_CHECKING:
    import scipy.sparse


@dataclass(frozen=True)
class TrainedParams(Parameters):
    """Parameters of the trained comparator."""

    owner = "trained"
    bins: int = param(100, "Histogram bins.", low=1, high=100_000)
    smoothing: float = param(0.1, "Pseudo-count added to every histogram bin.", low=0.0, low_open=True)
    pairs: Literal["minima", "all"] = param("minima", "Training samples: each frame's best match "
                                                      "(minima) or every pair (all, the paper's III.B).")
    prior: float | None = param(None, "P(L); default: the share of same-place training samples.",
                                low=0.0, high=1.0, low_open=True, high_open=True)


def _label_row(labels: NDArray[np.bool_] | scipy.sparse.sparray | scipy.sparse.spmatrix,
               k: int) -> NDArray[np.bool_]:
    """Row k of the truth matrix as a dense boolean array."""
    import scipy.sparse  # scipy loads on first use, not with the command line

    if scipy.sparse.issparse(labels):
        return np.asarray(labels[[k], :].toarray(), dtype=bool).ravel()
    return np.asarray(labels[k], dtype=bool)


def train_model(rows: Iterable[NDArray[np.float64]],
                labels: NDArray[np.bool_] | scipy.sparse.sparray | scipy.sparse.spmatrix,
                params: TrainedParams = TrainedParams()) -> HistogramModel:
    """Fill ``b`` with true-match and ``c`` with false-match differences of a training run.

    ``labels`` (n_train_query x n_candidates, dense bool or scipy.sparse) marks true matches.
    The bin range spans [min(0, lowest), highest] of the training values used. Errors name the
    training pair: ``training`` (rows and labels that do not fit), ``train_path`` (its truth,
    when it labels the samples all true or all false).
    """
    import scipy.sparse

    if scipy.sparse.issparse(labels):
        labels = scipy.sparse.csr_array(labels)
    shape = labels.shape
    same: list[NDArray[np.float64]] = []
    different: list[NDArray[np.float64]] = []
    k = -1
    for k, row in enumerate(rows):
        row = np.asarray(row, dtype=np.float64)
        if k >= shape[0] or row.shape != (shape[1],):
            raise WilocError(None, f"labels are {shape[0]} x {shape[1]}, difference row {k} has {row.size} values",
                             parameter="training")
        truth = _label_row(labels, k)
        if params.pairs == "minima":
            z, m = finite_minimum(row)
            if z >= 0:
                (same if truth[z] else different).append(np.array([m]))
        else:
            finite = np.isfinite(row)
            same.append(row[finite & truth])
            different.append(row[finite & ~truth])
    if k + 1 != shape[0]:
        raise WilocError(None, f"got {k + 1} difference rows for {shape[0]} label rows", parameter="training")
    b = np.concatenate(same) if same else np.empty(0)
    c = np.concatenate(different) if different else np.empty(0)
    if b.size == 0 or c.size == 0:  # the training pair's truth marks too many or too few matches true
        raise WilocError(None, f"training needs both true and false matches (got {b.size} true, {c.size} false): "
                               f"the training truth with a {'larger' if b.size == 0 else 'smaller'} tolerance or "
                               "radius, or another one", parameter="train_path")
    model = HistogramModel.from_values(np.concatenate([b, c]), params.bins, smoothing=params.smoothing,
                                       prior=params.prior)
    model.add_same(b)
    model.add_different(c)
    return model


class Trained(Method):
    """Best match per frame with confidence P(L | m) from a model trained on a labelled pair."""

    name = "trained"
    Params = TrainedParams
    needs = frozenset({"training"})
    columns = ("new_place",)
    params: TrainedParams

    def prepare(self, context: MapContext) -> None:
        if context.training is None:
            raise WilocError("trained", "needs a labelled training pair", parameter="training")
        pair = context.training()
        self._model = train_model(pair.rows, pair.labels, self.params)

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        z, m = finite_minimum(row)
        if z < 0:
            return Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none")
        p = float(self._model.posterior(m))
        return Decision(match=z, difference=m, confidence=p, stage="update", new_place=1.0 - p)

    @property
    def model(self) -> HistogramModel | None:
        return getattr(self, "_model", None)

    def save_state(self) -> dict[str, Any]:
        return {"model": self._model.to_dict()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self._model = HistogramModel.from_dict(state["model"])

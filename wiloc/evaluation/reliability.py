"""How well confidences are calibrated: ECE, Brier score, reliability bins, fixed cuts (SPEC.md 8).

A confidence promises a probability that the decided match is the same place (and P(new place),
where a method gives it, that the frame has no true match in the map: ``summarize_new_place``).
Over the decided frames (a match and a non-NaN confidence; NaN marks the others, as in
wiloc.evaluation.metrics), these measures compare the promise with the share of matches that are correct
under the ground truth.
Confidences outside [0, 1] (the threshold baseline's 1 - d / d_max falls below 0 beyond d_max)
are clipped into [0, 1] for the bins, the means and the Brier score; the cuts compare the
confidences as written, exactly as the precision-recall counting does. See docs/evaluation.md.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from wiloc.evaluation.metrics import _counts_at, _decided
from wiloc.reprs import number_label, short_repr

N_BINS = 10
"""Equal-width confidence bins: [0, 0.1), [0.1, 0.2), ..., [0.9, 1.0]."""

DEFAULT_CUTS = (0.5, 0.9, 0.99)
"""Confidence cuts at which precision and recall are reported: accept confidence >= cut."""

NEW_PLACE_KEYS = "new_place_"
"""What precedes P(new place)'s keys in a flat calibration row (``Calibration.row``)."""


@short_repr
@dataclass(frozen=True)
class ReliabilityBins:
    """Decided frames per equal-width confidence bin, the bins' mean confidence and share correct.

    ``edges`` has one more entry than the bins; the last bin also holds a confidence of exactly 1.
    Empty bins have NaN mean confidence and share correct.
    """

    edges: NDArray[np.float64]
    count: NDArray[np.int64]
    mean_confidence: NDArray[np.float64]
    share_correct: NDArray[np.float64]

    @property
    def ece(self) -> float:
        """Expected calibration error: sum over bins of share of frames x |mean confidence -
        share correct|; NaN when no frame is decided."""
        total = int(self.count.sum())
        if total == 0:
            return float("nan")
        filled = self.count > 0
        gaps = np.abs(self.mean_confidence[filled] - self.share_correct[filled])
        return float(np.sum(self.count[filled] / total * gaps))


@short_repr
@dataclass(frozen=True)
class CutCounts:
    """Precision and recall when accepting decided frames with confidence >= each cut."""

    cuts: NDArray[np.float64]
    accepted: NDArray[np.int64]
    true_positives: NDArray[np.int64]
    precision: NDArray[np.float64]  # NaN where nothing is accepted
    recall: NDArray[np.float64]


def _clipped(confidence: ArrayLike, correct: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Decided frames' confidences clipped to [0, 1], and whether their matches are correct."""
    conf, ok = _decided(confidence, correct)
    return np.clip(conf, 0.0, 1.0), ok


def reliability_bins(confidence: ArrayLike, correct: ArrayLike, bins: int = N_BINS) -> ReliabilityBins:
    """Count, mean confidence and share correct of the decided frames in ``bins`` equal-width bins.

    A confidence on an edge k / bins belongs to the bin starting there; 1.0 to the last bin.
    """
    conf, ok = _clipped(confidence, correct)
    edges = np.arange(bins + 1, dtype=np.float64) / bins  # k / bins exactly, so 0.3 starts a bin
    index = np.clip(np.searchsorted(edges, conf, side="right") - 1, 0, bins - 1)
    count = np.bincount(index, minlength=bins).astype(np.int64)
    filled = count > 0
    mean = np.full(bins, np.nan)
    share = np.full(bins, np.nan)
    mean[filled] = np.bincount(index, weights=conf, minlength=bins)[filled] / count[filled]
    share[filled] = np.bincount(index, weights=ok, minlength=bins)[filled] / count[filled]
    return ReliabilityBins(edges=edges, count=count, mean_confidence=mean, share_correct=share)


def wilson_interval(successes: ArrayLike, count: ArrayLike,
                    z: float = 1.959963984540054) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Wilson score interval (95 % by default) of a share ``successes / count``, per entry:
    unlike the normal approximation it stays within [0, 1] and is not empty at a share of 0 or 1,
    which sparse reliability bins often have. NaN where ``count`` is 0."""
    k = np.asarray(successes, dtype=np.float64)
    n = np.asarray(count, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = k / n
        denominator = 1.0 + z * z / n
        centre = (share + z * z / (2.0 * n)) / denominator
        half = z * np.sqrt(share * (1.0 - share) / n + z * z / (4.0 * n * n)) / denominator
    empty = n <= 0
    low = np.where(empty, np.nan, np.clip(centre - half, 0.0, 1.0))
    return low, np.where(empty, np.nan, np.clip(centre + half, 0.0, 1.0))


def expected_calibration_error(confidence: ArrayLike, correct: ArrayLike, bins: int = N_BINS) -> float:
    """ECE over the decided frames in ``bins`` equal-width bins (NaN when none is decided)."""
    return reliability_bins(confidence, correct, bins).ece


def brier_score(confidence: ArrayLike, correct: ArrayLike) -> float:
    """Mean squared gap between confidence (clipped to [0, 1]) and correctness (0 or 1) over the
    decided frames; NaN when none is decided. Unlike ECE it also rewards sharp confidences."""
    conf, ok = _clipped(confidence, correct)
    return float(np.mean((conf - ok) ** 2)) if conf.size else float("nan")


def counts_at_cuts(confidence: ArrayLike, correct: ArrayLike, n_positive: int,
                   cuts: Sequence[float] = DEFAULT_CUTS) -> CutCounts:
    """Accepted frames, TP, precision and recall at each fixed confidence cut.

    Accepted = decided and confidence >= cut; TP = accepted and correct (an accepted frame with no
    true match is wrong); precision = TP / accepted (NaN when nothing is accepted); recall = TP /
    ``n_positive``, the frames with at least one true match (NaN when there are none: 0 / 0).
    """
    at = np.asarray(cuts, dtype=np.float64).reshape(-1)
    if not np.all((at >= 0.0) & (at <= 1.0)):
        raise ValueError(f"cuts must lie in [0, 1], got {at.tolist()}")
    tp, fp = _counts_at(confidence, correct, at)
    accepted = tp + fp
    precision = np.divide(tp, accepted, out=np.full(at.shape, np.nan), where=accepted > 0)
    recall = tp / n_positive if n_positive > 0 else np.full(at.shape, np.nan)
    return CutCounts(cuts=at, accepted=accepted, true_positives=tp, precision=precision,
                     recall=np.asarray(recall, dtype=np.float64))


@short_repr
@dataclass(frozen=True)
class Calibration:
    """How well one run's confidences are calibrated, over its decided frames."""

    ece: float
    brier: float
    mean_confidence: float  # clipped to [0, 1], as in the bins
    share_correct: float
    bins: ReliabilityBins = field(repr=False)
    cuts: CutCounts = field(repr=False)

    def row(self, prefix: str = "") -> dict[str, float | int]:
        """Flat: the scalars, then precision@c, recall@c and accepted@c per cut c (a table row),
        each key after ``prefix``."""
        row: dict[str, float | int] = {"ece": self.ece, "brier": self.brier,
                                       "mean_confidence": self.mean_confidence,
                                       "share_correct": self.share_correct}
        for cut, precision, recall, accepted in self._cut_rows():
            at = number_label(cut)
            row.update({f"precision@{at}": precision, f"recall@{at}": recall, f"accepted@{at}": accepted})
        return {prefix + key: value for key, value in row.items()}

    def as_dict(self) -> dict[str, Any]:
        """Nested, for --json: the scalars, ``cuts`` and ``reliability`` as lists of dicts."""
        b = self.bins
        return {"ece": self.ece, "brier": self.brier, "mean_confidence": self.mean_confidence,
                "share_correct": self.share_correct,
                "cuts": [{"cut": cut, "precision": precision, "recall": recall, "accepted": accepted}
                         for cut, precision, recall, accepted in self._cut_rows()],
                "reliability": [{"low": float(b.edges[i]), "high": float(b.edges[i + 1]),
                                 "count": int(b.count[i]), "mean_confidence": float(b.mean_confidence[i]),
                                 "share_correct": float(b.share_correct[i])} for i in range(b.count.size)]}

    def _cut_rows(self) -> list[tuple[float, float, float, int]]:
        c = self.cuts
        return [(float(c.cuts[i]), float(c.precision[i]), float(c.recall[i]), int(c.accepted[i]))
                for i in range(c.cuts.size)]


def summarize_calibration(confidence: ArrayLike, correct: ArrayLike, n_positive: int,
                          cuts: Sequence[float] = DEFAULT_CUTS) -> Calibration:
    """ECE, Brier score, mean confidence, share correct, reliability bins and fixed cuts of a run.

    ``confidence`` is NaN for undecided frames; ``correct[i]``: frame i's match is the same place;
    ``n_positive``: frames with at least one true match (the recall denominator).
    """
    conf, ok = _clipped(confidence, correct)
    bins = reliability_bins(confidence, correct)
    return Calibration(ece=bins.ece, brier=brier_score(confidence, correct),
                       mean_confidence=float(conf.mean()) if conf.size else float("nan"),
                       share_correct=float(ok.mean()) if ok.size else float("nan"),
                       bins=bins, cuts=counts_at_cuts(confidence, correct, n_positive, cuts))


def summarize_new_place(new_place: ArrayLike, has_match: ArrayLike,
                        cuts: Sequence[float] = DEFAULT_CUTS) -> Calibration | None:
    """The same measures for P(new place), whose promise is that the frame has no true match in
    the map: ``share_correct`` is the share of such frames, a cut accepts "new place" when
    P(new place) >= it and its recall counts the frames without a true match. Over the frames
    with a P(new place) (not NaN); None when no frame has one."""
    p_new = np.asarray(new_place, dtype=np.float64)
    if not np.any(~np.isnan(p_new)):
        return None
    absent = ~np.asarray(has_match, dtype=np.bool_)
    return summarize_calibration(p_new, absent, int(absent.sum()), cuts)

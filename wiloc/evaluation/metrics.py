"""Exact precision-recall evaluation of single-best-match localization (SPEC.md section 7).

Counting: a decided frame (finite match, non-NaN confidence) with confidence >= tau is accepted;
accepted and truly the same place is a true positive, accepted otherwise a false positive (also
when the frame has no true match at all); recall = TP / frames with at least one true match among
their candidates. Curves are exact: one operating point per distinct confidence, all frames of
equal confidence accepted together. See docs/evaluation.md.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from wiloc.reprs import short_repr

if TYPE_CHECKING:
    from wiloc.evaluation.groundtruth import Truth

PRECISION_LEVELS = (1.0, 0.99, 0.90)
"""The precisions at which recall is reported (the paper's Table I)."""

RANKED_KS = (1, 5, 10)
"""The N of Recall@N reported by default (``--recall-at``) for runs whose results rank the map
(docs/evaluation.md); R@1 is reported for every run, from its decided match."""

OLDER_RANKED = 10
"""Candidates per frame in the rankings of older results files (today's keep
``wiloc.candidates.RANKED``): a file whose longest ranking holds exactly this many tells no
Recall@N beyond it."""

PRECISION_RTOL = 1e-9
"""Relative slack when testing precision >= target: a target given in percent is rounded
(99.9 / 100 > 0.999), yet 999 of 1000 meets it; 100 % stays exact below 10**9 accepted frames."""


@short_repr
@dataclass(frozen=True)
class PRCurve:
    """Operating points in order of falling threshold: accepting every confidence >= threshold."""

    precision: NDArray[np.float64]
    recall: NDArray[np.float64]
    thresholds: NDArray[np.float64]
    tp: NDArray[np.int64]
    fp: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.thresholds.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PRCurve):
            return NotImplemented
        return all(np.array_equal(getattr(self, name), getattr(other, name)) for name in self.__dataclass_fields__)

    __hash__ = None  # type: ignore[assignment]  # arrays: equal curves need not hash alike


def _decided(confidence: ArrayLike, correct: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Confidences and correctness of the decided (non-NaN confidence) frames, checked to match."""
    conf = np.asarray(confidence, dtype=np.float64)
    ok = np.asarray(correct, dtype=np.bool_)
    if conf.ndim != 1 or conf.shape != ok.shape:
        raise ValueError(f"confidence {conf.shape} and correct {ok.shape} must be equal 1-D shapes")
    keep = ~np.isnan(conf)
    return conf[keep], ok[keep]


def _counts_at(confidence: ArrayLike, correct: ArrayLike,
               thresholds: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """True and false positives when accepting confidence >= each threshold (NaN accepts none)."""
    conf, ok = _decided(confidence, correct)
    order = np.argsort(conf, kind="stable")
    conf, ok = conf[order], ok[order]
    # tp_from[i]: correct frames among the i-th smallest confidence and above; tp_from[n] = 0.
    tp_from = np.concatenate([np.cumsum(ok[::-1], dtype=np.int64)[::-1], np.zeros(1, np.int64)])
    first = np.searchsorted(conf, np.asarray(thresholds, dtype=np.float64), side="left")
    tp = tp_from[first]
    return tp, (conf.size - first).astype(np.int64) - tp


def _reaches(tp: ArrayLike, fp: ArrayLike, target: float) -> NDArray[np.bool_]:
    """Whether precision tp / (tp + fp) >= target, in integer form with ``PRECISION_RTOL`` slack."""
    tp = np.asarray(tp, dtype=np.float64)
    return tp >= target * (tp + np.asarray(fp, dtype=np.float64)) * (1.0 - PRECISION_RTOL)


def pr_curve(confidence: ArrayLike, correct: ArrayLike, n_positive: int) -> PRCurve:
    """The exact precision-recall curve, one point per distinct confidence (ties form one step).

    ``correct[i]``: frame i's best match is truly the same place; ``n_positive``: frames with at
    least one true match (recall is 0 everywhere when there are none).
    """
    conf, ok = _decided(confidence, correct)
    if int(ok.sum()) > n_positive:
        raise ValueError(f"{int(ok.sum())} correct matches but only {n_positive} frames with a true match")
    thresholds = np.unique(conf)[::-1]
    tp, fp = _counts_at(conf, ok, thresholds)
    precision = tp / np.maximum(tp + fp, 1)
    recall = tp / n_positive if n_positive > 0 else np.zeros(tp.shape)
    return PRCurve(precision.astype(np.float64), np.asarray(recall, dtype=np.float64),
                   thresholds, tp, fp)


def recall_at_precision(curve: PRCurve, precision: float) -> tuple[float, float]:
    """(recall, threshold): the largest recall among operating points with precision >= target.

    The threshold is the highest one reaching that recall. With no such point: (0.0, NaN).
    """
    ok = np.flatnonzero(_reaches(curve.tp, curve.fp, precision) & (curve.tp + curve.fp > 0))
    if ok.size == 0:
        return 0.0, float("nan")
    best = ok[np.argmax(curve.recall[ok])]  # argmax takes the first, i.e. highest threshold
    return float(curve.recall[best]), float(curve.thresholds[best])


def average_precision(curve: PRCurve) -> float:
    """Area under the PR curve, step-wise with scikit-learn's average_precision_score formula (the
    recall over every frame with a true match, not only the decided ones).

    AP = sum_n (R_n - R_{n-1}) P_n over the operating points, R_0 = 0; no interpolation, so it
    does not reward a precision reached only at a lower threshold.
    """
    gains = np.diff(curve.recall, prepend=0.0)
    return float(np.sum(gains * curve.precision))


def max_f1(curve: PRCurve) -> tuple[float, float]:
    """(F1, threshold) at the operating point of largest F1; (0.0, NaN) when no F1 is above 0."""
    p, r = curve.precision, curve.recall
    f1 = np.divide(2 * p * r, p + r, out=np.zeros_like(p), where=(p + r) > 0)
    if not np.any(f1 > 0):
        return 0.0, float("nan")
    best = int(np.argmax(f1))
    return float(f1[best]), float(curve.thresholds[best])


def recall_at_1(correct: ArrayLike, has_match: ArrayLike) -> float:
    """Share of frames with a true match whose best match is correct, whatever its confidence."""
    ok = np.asarray(correct, dtype=np.bool_)
    positive = np.asarray(has_match, dtype=np.bool_)
    return float(ok[positive].mean()) if positive.any() else 0.0


def ranking_tells(ranking: ArrayLike, n: int) -> bool:
    """Whether rankings (frames x ranks, -1 padding) tell Recall@``n``: a ranking shorter than the
    writer's K holds every candidate (the map is smaller, or catgraph's nodes holding weight are
    fewer), so N beyond the longest is told too, unless that longest is an older file's K of
    ``OLDER_RANKED``, which may have cut candidates off."""
    longest = np.asarray(ranking).shape[1]
    return n <= longest or longest != OLDER_RANKED


def recall_at_k(ranking: ArrayLike, truth: Truth, k: int) -> float:
    """Recall@K as place recognition reports it: the share of frames with a true match that have
    one among their ``k`` best-ranked candidates (``ranking``: frames x ranks, best first, -1
    padding), under the same ground truth and tolerance as :func:`recall_at_1`; frames without a
    true match are left out, frames without a ranking (undecided) count as missed."""
    ranked = np.asarray(ranking, dtype=np.int64)
    if ranked.ndim != 2 or ranked.shape[0] != len(truth.query_names):
        raise ValueError(f"ranking {ranked.shape} must have one row per ground-truth query frame")
    ranked = ranked[:, :k]
    hit = truth.is_true(np.arange(ranked.shape[0])[:, None], ranked).any(axis=1)
    positive = truth.has_match()
    return float(hit[positive].mean()) if positive.any() else 0.0


def precision_at_thresholds(confidence: ArrayLike, correct: ArrayLike,
                            thresholds: ArrayLike) -> NDArray[np.float64]:
    """Precision when accepting confidence >= each threshold (Figure 5); NaN where none is accepted."""
    tp, fp = _counts_at(confidence, correct, thresholds)
    accepted = tp + fp
    return np.divide(tp, accepted, out=np.full(tp.shape, np.nan), where=accepted > 0)


def global_threshold(inputs: Sequence[tuple[ArrayLike, ArrayLike, int]],
                     target_precision: float) -> tuple[float, list[float]]:
    """Table II: the lowest single threshold keeping precision >= target on every traversal.

    ``inputs``: one (confidence, correct, n_positive) per traversal, confidences comparable
    across traversals. A traversal that accepts nothing at a threshold does not violate it.
    Returns the threshold and each traversal's recall at it; (NaN, zeros) when none qualifies.
    """
    decided = [_decided(conf, ok) for conf, ok, _ in inputs]
    candidates = np.unique(np.concatenate([conf for conf, _ in decided] + [np.empty(0)]))
    counts = [_counts_at(conf, ok, candidates) for conf, ok in decided]
    keeps = np.ones(candidates.size, dtype=np.bool_)
    for tp, fp in counts:
        accepted = tp + fp
        keeps &= (accepted == 0) | _reaches(tp, fp, target_precision)
    if not keeps.any():
        return float("nan"), [0.0] * len(inputs)
    at = int(np.argmax(keeps))  # candidates ascend: the first that keeps is the lowest
    recalls = [float(tp[at] / n) if n > 0 else 0.0 for (tp, _), (_, _, n) in zip(counts, inputs)]
    return float(candidates[at]), recalls


@short_repr
@dataclass(frozen=True)
class Summary:
    """Counts and metrics of one run against its ground truth, with the PR curve behind them."""

    frames: int
    decided: int
    with_true_match: int
    recall_at_100: float
    recall_at_99: float
    recall_at_90: float
    auc: float
    max_f1: float
    max_f1_threshold: float
    recall_at_1: float
    curve: PRCurve = field(repr=False)
    recall_at_n: dict[int, float] = field(default_factory=dict)  # Recall@N (N > 1): runs that rank the map only

    def as_dict(self) -> dict[str, float | int]:
        """The counts and metrics as a flat dict, Recall@N as ``recall_at_N`` (no curve; no
        Recall@N a run cannot tell), e.g. for --json or a table row."""
        flat = {name: getattr(self, name) for name in self.__dataclass_fields__ if name not in ("curve", "recall_at_n")}
        return {**flat, **{f"recall_at_{n}": value for n, value in sorted(self.recall_at_n.items())}}


def correct_matches(match: ArrayLike, truth: Truth) -> NDArray[np.bool_]:
    """Per query frame: whether its best match (-1 = none) is truly the same place."""
    m = np.asarray(match, dtype=np.int64)
    if m.shape != (len(truth.query_names),):
        raise ValueError(f"{m.size} matches for {len(truth.query_names)} ground-truth query frames")
    return truth.is_true(np.arange(m.size), m)


def decided_confidence(match: ArrayLike, confidence: ArrayLike) -> NDArray[np.float64]:
    """Per frame: its confidence, NaN when it is undecided (no match, -1, or NaN confidence)."""
    return np.where(np.asarray(match, dtype=np.int64) >= 0, np.asarray(confidence, dtype=np.float64), np.nan)


def summarize(match: ArrayLike, confidence: ArrayLike, truth: Truth, ranking: ArrayLike | None = None,
              recall_at: Sequence[int] = RANKED_KS) -> Summary:
    """All reported metrics of one run: recall at 100/99/90 % precision, AUC, max F1, R@1, counts,
    and with each frame's ``ranking`` (best candidates first) Recall@N for each N > 1 of
    ``recall_at`` that the ranking tells (:func:`ranking_tells`: a results file keeps
    ``wiloc.candidates.RANKED`` candidates per frame, or every one where fewer; older files 10).

    ``match`` and ``confidence`` are per query frame in the order of ``truth.query_names``; a
    frame is decided when its match is >= 0 and its confidence is not NaN.
    """
    m = np.asarray(match, dtype=np.int64)
    correct = correct_matches(m, truth)
    conf = decided_confidence(m, confidence)
    has_match = truth.has_match()
    curve = pr_curve(conf, correct, int(has_match.sum()))
    r100, r99, r90 = (recall_at_precision(curve, p)[0] for p in PRECISION_LEVELS)
    f1, f1_threshold = max_f1(curve)
    return Summary(frames=int(m.size), decided=int((~np.isnan(conf)).sum()),
                   with_true_match=int(has_match.sum()), recall_at_100=r100, recall_at_99=r99,
                   recall_at_90=r90, auc=average_precision(curve), max_f1=f1,
                   max_f1_threshold=f1_threshold, recall_at_1=recall_at_1(correct, has_match),
                   curve=curve, recall_at_n={} if ranking is None else {
                       n: recall_at_k(ranking, truth, n) for n in sorted(set(recall_at))
                       if n > 1 and ranking_tells(ranking, n)})

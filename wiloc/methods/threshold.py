"""The heuristic threshold baseline (paper V.C, SPEC.md section 5).

Same candidates and hypothesis as the online model (z = argmin d_k); the score is m itself and a
match is accepted when m <= t. To share one axis with probabilities, t is normalised to
t / normaliser in [0, 1] and the confidence is 1 - m / normaliser, so accepting frames with
confidence >= 1 - t' is the same as accepting m <= t' * normaliser.
"""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from wiloc.errors import WilocError
from wiloc.methods.base import Decisions
from wiloc.methods.online import best_matches


def localize_threshold(rows: Iterable[NDArray[np.float64]], n_frames: int, *,
                       normaliser: float | None = None) -> Decisions:
    """Best match per frame with confidence 1 - m / normaliser.

    ``normaliser`` is the descriptor's natural maximum difference where it has one (the caller
    knows the descriptor); when None, the largest finite m of the run, so confidences span [0, 1]
    with the worst decided frame at 0.
    """
    if normaliser is not None and not (np.isfinite(normaliser) and normaliser > 0):
        raise WilocError("threshold", f"normaliser must be a positive number, got {normaliser}")
    match, difference = best_matches(rows, n_frames, "threshold")
    decided = match >= 0
    scale = normaliser
    if scale is None:
        largest = float(difference[decided].max()) if decided.any() else 0.0
        scale = largest if largest > 0 else 1.0
    confidence = np.where(decided, 1.0 - difference / scale, np.nan)
    stage = np.where(decided, "update", "none")
    return Decisions(match=match, difference=difference, confidence=confidence, stage=stage,
                     params={"method": "threshold", "normaliser": float(scale),
                             "normaliser_given": normaliser is not None})

"""The common output of every localization method."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.model import HistogramModel


@dataclass
class Decisions:
    """Per query frame: best match, its difference, confidence (higher = more sure) and stage.

    ``match`` is -1 and ``difference``/``confidence`` are NaN for undecided frames (for example
    the online model's initialisation stage). ``columns`` holds method-specific per-frame values
    (``m_r`` for the online model, ``new_place`` for CAT-Graph).
    """

    match: NDArray[np.int64]
    difference: NDArray[np.float64]
    confidence: NDArray[np.float64]
    stage: NDArray[np.str_]
    columns: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    model: HistogramModel | None = None
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.match)
        self.match = np.asarray(self.match, dtype=np.int64)
        self.difference = np.asarray(self.difference, dtype=np.float64)
        self.confidence = np.asarray(self.confidence, dtype=np.float64)
        self.stage = np.asarray(self.stage, dtype=np.str_)
        for name, arr in [("difference", self.difference), ("confidence", self.confidence),
                          ("stage", self.stage), *self.columns.items()]:
            if len(arr) != n:
                raise ValueError(f"{name} has {len(arr)} rows, match has {n}")

    def __len__(self) -> int:
        return len(self.match)

    @property
    def decided(self) -> NDArray[np.bool_]:
        """Frames that carry a decision (a match and a confidence)."""
        return (self.match >= 0) & np.isfinite(self.confidence)

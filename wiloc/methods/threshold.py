"""The heuristic threshold baseline (paper V.C, SPEC.md section 5): the paper's non-probabilistic
model, whose threshold t Table II and Figure 5 set against the probabilistic one.

Same candidates and hypothesis as the online model (z = argmin d_k); the score is m itself and a
match is accepted when m <= t. To share one axis with probabilities, t is normalised to
t / normaliser in [0, 1] and the confidence is 1 - m / normaliser, so accepting frames with
confidence >= 1 - t' is the same as accepting m <= t' * normaliser.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.candidates import finite_minimum
from wiloc.decisions import Decision
from wiloc.errors import ParameterError
from wiloc.methods.base import MapContext, Method, self_summary
from wiloc.parameters import Parameters, param


@dataclass(frozen=True)
class ThresholdParams(Parameters):
    """Parameters of the threshold baseline."""

    owner = "threshold"
    normaliser: float | None = param(None, "The difference that maps to confidence 0; default: the "
                                           "descriptor's largest possible difference, else the map's "
                                           "largest difference to itself.", low=0.0, low_open=True)


def largest_difference(context: MapContext) -> float:
    """The largest finite difference of the map to itself (0 when it has none)."""
    if context.map_summary is None:
        raise ParameterError("normaliser", "needed: the descriptor has no largest possible difference "
                                           "and no map differences are at hand to take it from")
    return self_summary(context).largest


class Threshold(Method):
    """Best match per frame with confidence 1 - m / normaliser.

    The normaliser is the ``normaliser`` parameter when given, else the descriptor's natural
    maximum difference, else the map's largest difference to itself: a constant of the map, so
    that one normalised threshold means one raw threshold for every query against that map.
    """

    name = "threshold"
    Params = ThresholdParams
    lowest_confidence = -math.inf  # 1 - m / normaliser falls below 0 beyond the normaliser
    params: ThresholdParams

    def prepare(self, context: MapContext) -> None:
        scale = self.params.normaliser or context.natural_max or largest_difference(context)
        self._scale = float(scale) if scale > 0 else 1.0

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        z, m = finite_minimum(row)
        if z < 0:
            return Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none")
        return Decision(match=z, difference=m, confidence=1.0 - m / self._scale, stage="update")

    def facts(self) -> dict[str, Any]:
        return {"normaliser_used": self._scale}

    def save_state(self) -> dict[str, Any]:
        return {"scale": self._scale}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self._scale = float(state["scale"])

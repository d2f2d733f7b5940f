"""FAB-MAP 1.0 as a single-frame method: the posterior over the map's places and a new place.

Reads FAB-MAP's evidence rows (``wiloc.methods.fabmap_evidence``: r_j = log p(Z | L_j) - log p(Z | new
place) from bag-of-words descriptors), computed with this method's FAB-MAP parameters (detector
model, new-place model). Per frame, FAB-MAP's posterior (``wiloc.bow.fabmap.model.posterior``): the
places share the prior 1 - ``new_place_prior`` equally, the new place has ``new_place_prior``,
and the normalised posterior is smoothed by ``posterior_smoothing``, so no hypothesis is
certain. The decision is the most probable place; the confidence is the posterior mass within
+-``window`` places of it (the ground truth's tolerance), P(new place) the new place's.
docs/fabmap.md gives the model and every default's source.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.bow.fabmap.params import FabMapParams
from wiloc.decisions import Decision
from wiloc.methods.base import MapContext, Method
from wiloc.parameters import param


@dataclass(frozen=True)
class FabMapMethodParams(FabMapParams):
    """FAB-MAP 1.0's parameters (openFABMAP's defaults) and the confidence's window."""

    owner = "fabmap"
    window: int = param(2, "Places within +-window of the decided one count as the same place for the "
                           "confidence (the ground truth's tolerance).", low=0)


class FabMapMethod(Method):
    """Single-frame FAB-MAP 1.0 on bag-of-words descriptors (map and sequence mode)."""

    name = "fabmap"
    Params = FabMapMethodParams
    rows = frozenset({"log_ratio"})
    columns = ("new_place",)
    params: FabMapMethodParams

    def prepare(self, context: MapContext) -> None:
        pass  # the evidence rows carry everything FAB-MAP learned from the map and its training

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        from wiloc.bow.fabmap.model import posterior  # scipy loads on first use, not with the command line

        if not np.isfinite(row).any():
            return Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none")
        places, new_place = posterior(row, self.params)
        z = int(np.argmax(np.where(np.isfinite(row), row, -np.inf)))
        w = self.params.window
        mass = float(places[max(0, z - w):z + w + 1].sum())
        return Decision(match=z, difference=float(-row[z]), confidence=mass, stage="update", new_place=new_place)

    def save_state(self) -> dict[str, Any]:
        return {}

    def load_state(self, state: Mapping[str, Any]) -> None:
        pass

"""FAB-MAP 1.0 as a single-frame method: the posterior over the map's places and a new place.

Reads FAB-MAP's evidence rows (``wiloc.fabmap.evidence``: r_j = log p(Z | L_j) - log p(Z | new
place) from bag-of-words descriptors). Per frame: the places share the prior 1 - p_new equally,
the new place has p_new (FAB-MAP's ``new_place_prior``, 0.9); the normalised posterior is
smoothed, p <- sigma p + (1 - sigma) / (places + 1) (``posterior_smoothing``, 0.99), so no
hypothesis is certain. The decision is the most probable place; the confidence is the posterior
mass within +-``window`` places of it (the ground truth's tolerance), P(new place) the new
place's. docs/fabmap.md gives the model and every default's source.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.methods.base import Decision, MapContext, Method
from wiloc.parameters import Parameters, param


@dataclass(frozen=True)
class FabMapMethodParams(Parameters):
    """Parameters of the single-frame FAB-MAP posterior (openFABMAP's defaults)."""

    owner = "fabmap"
    new_place_prior: float = param(0.9, "Prior probability that a frame comes from a place not in the map.",
                                   low=0.0, high=1.0, low_open=True, high_open=True)
    posterior_smoothing: float = param(0.99, "sigma in p <- sigma p + (1 - sigma) / (places + 1).",
                                       low=0.0, high=1.0, low_open=True)
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

    def decide(self, row: NDArray[np.float64], odometry: float | None) -> Decision:
        from scipy.special import logsumexp  # scipy loads on first use, not with the command line

        p = self.params
        candidates = np.isfinite(row)
        n = int(candidates.sum())
        if n == 0:
            return Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none")
        log_joint = np.where(candidates, row + np.log1p(-p.new_place_prior) - np.log(n), -np.inf)
        log_new = np.log(p.new_place_prior)
        total = float(np.logaddexp(logsumexp(log_joint), log_new))
        posterior = np.where(candidates, p.posterior_smoothing * np.exp(log_joint - total)
                             + (1.0 - p.posterior_smoothing) / (n + 1), 0.0)
        new_place = p.posterior_smoothing * float(np.exp(log_new - total)) + (1.0 - p.posterior_smoothing) / (n + 1)
        z = int(np.argmax(np.where(candidates, row, -np.inf)))
        mass = float(posterior[max(0, z - p.window):z + p.window + 1].sum())
        return Decision(match=z, difference=float(-row[z]), confidence=mass, stage="update", new_place=new_place)

    def save_state(self) -> dict[str, Any]:
        return {}

    def load_state(self, state: Mapping[str, Any]) -> None:
        pass

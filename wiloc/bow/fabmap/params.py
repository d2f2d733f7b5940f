"""FAB-MAP 1.0's parameters, with their published defaults, validated in one place.

Sources (docs/fabmap.md cites them in full): openFABMAP, the open implementation of FAB-MAP by
Glover et al. (ICRA 2012) built from Cummins and Newman's publications: its sample settings
(``samples/settings.yml``: ``PzGe 0.39``, ``PzGne 0``, ``NewPlaceMethod Sampled``,
``NumSamples 3000``) and its ``FabMap`` constructor (``Pnew = 0.9``, ``sFactor = 0.99``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from wiloc.errors import ParameterError
from wiloc.parameters import Parameters, param

NEW_PLACE_METHODS = ("sampled", "mean-field")


@dataclass(frozen=True)
class FabMapParams(Parameters):
    """Everything FAB-MAP 1.0 needs besides its Chow-Liu tree and training data."""

    false_positive: float = param(
        0.0, "Detector model p(z=1 | e=0): a word seen where its scene element is not.",
        low=0.0, high=1.0, high_open=True)
    false_negative: float = param(
        0.61, "Detector model p(z=0 | e=1): a scene element whose word is missed.",
        low=0.0, high=1.0, low_open=True, high_open=True)
    new_place: Literal["sampled", "mean-field"] = param(
        "sampled", "p(Z | new place): mean likelihood of place models made from training images "
                   "(sampled), or one average place (mean-field).")
    samples: int = param(
        3000, "At most this many training images make the sampled new place (all when fewer).",
        low=1)
    new_place_prior: float = param(
        0.9, "Prior probability that a frame comes from a place not in the map.",
        low=0.0, high=1.0, low_open=True, high_open=True)
    posterior_smoothing: float = param(
        0.99, "sigma in p <- sigma p + (1 - sigma) / (places + 1), so no hypothesis is certain.",
        low=0.0, high=1.0, low_open=True)
    seed: int = param(0, "Seeds the choice of the sampled training images.", low=0)

    def check(self) -> None:
        if self.false_positive >= 1.0 - self.false_negative:
            raise ParameterError("false_positive", f"p(z=1|e=0) = {self.false_positive} must stay "
                                                   f"below p(z=1|e=1) = 1 - false_negative = "
                                                   f"{1.0 - self.false_negative:g}")

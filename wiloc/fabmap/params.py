"""FAB-MAP 1.0's parameters, with their published defaults, validated in one place.

Sources (docs/fabmap.md cites them in full): openFABMAP, the open implementation of FAB-MAP by
Glover et al. (ICRA 2012) built from Cummins and Newman's publications: its sample settings
(``samples/settings.yml``: ``PzGe 0.39``, ``PzGne 0``, ``NewPlaceMethod Sampled``,
``NumSamples 3000``) and its ``FabMap`` constructor (``Pnew = 0.9``, ``sFactor = 0.99``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wiloc.errors import UsageError

NEW_PLACE_METHODS = ("sampled", "mean-field")


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value):
        raise UsageError(name, f"must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class FabMapParams:
    """Everything FAB-MAP 1.0 needs besides its Chow-Liu tree and training data.

    false_positive: detector model p(z = 1 | e = 0), a word seen where its scene element is not.
    false_negative: detector model p(z = 0 | e = 1), a scene element whose word is missed.
    new_place: how p(Z | new place) is approximated: ``sampled`` (the mean likelihood of place
        models made from training images) or ``mean-field`` (one average place).
    samples: at most this many training images make the sampled new-place model (all of them
        when there are fewer), drawn without replacement.
    new_place_prior: prior probability that an observation comes from a place not in the map.
    posterior_smoothing: sigma in p <- sigma p + (1 - sigma) / (places + 1), applied to the
        normalised posterior so no single hypothesis is ever certain.
    seed: seeds the choice of the sampled training images.
    """

    false_positive: float = 0.0
    false_negative: float = 0.61
    new_place: str = "sampled"
    samples: int = 3000
    new_place_prior: float = 0.9
    posterior_smoothing: float = 0.99
    seed: int = 0

    def __post_init__(self) -> None:
        fp = _number("false_positive", self.false_positive)
        fn = _number("false_negative", self.false_negative)
        if not 0.0 <= fp < 1.0:
            raise UsageError("false_positive", f"must lie in [0, 1), got {fp}")
        if not 0.0 < fn < 1.0:
            raise UsageError("false_negative", f"must lie in (0, 1), got {fn}")
        if fp >= 1.0 - fn:
            raise UsageError("false_positive", f"p(z=1|e=0) = {fp} must stay below p(z=1|e=1) = "
                                               f"1 - false_negative = {1.0 - fn}")
        if self.new_place not in NEW_PLACE_METHODS:
            raise UsageError("new_place", f"must be one of {', '.join(NEW_PLACE_METHODS)}, "
                                          f"got {self.new_place!r}")
        for name in ("samples", "seed"):
            value = getattr(self, name)
            low = 1 if name == "samples" else 0
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise UsageError(name, f"must be an integer >= {low}, got {value!r}")
            object.__setattr__(self, name, int(value))
        prior = _number("new_place_prior", self.new_place_prior)
        if not 0.0 < prior < 1.0:
            raise UsageError("new_place_prior", f"must lie strictly between 0 and 1, got {prior}")
        sigma = _number("posterior_smoothing", self.posterior_smoothing)
        if not 0.0 < sigma <= 1.0:
            raise UsageError("posterior_smoothing", f"must lie in (0, 1], got {sigma}")
        for name, value in (("false_positive", fp), ("false_negative", fn),
                            ("new_place_prior", prior), ("posterior_smoothing", sigma)):
            object.__setattr__(self, name, value)

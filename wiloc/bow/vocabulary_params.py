"""How a visual vocabulary is made (``wiloc vocabulary``'s options): a module of its own, light
enough for the command line to build its options from these declarations without loading the
clustering and HDF5 code of :mod:`wiloc.bow.vocabulary`."""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Literal

from wiloc.parameters import Parameters, param


@dataclass(frozen=True)
class VocabularyParams(Parameters):
    """How a vocabulary is made; every field takes part in its cache key."""

    feature: Literal["sift", "orb"] = param("sift", "Local feature: sift (k-means) or orb (k-majority).")
    words: int = param(1000, "K, the number of visual words.", low=2)
    max_features: int = param(500, "Local features kept per image, strongest first.", low=1,
                              high=2**31 - 1)  # OpenCV's detectors take a C int
    max_side: int = param(640, "Images are shrunk so their longer side is at most this many "
                                           "pixels.", low=16)
    iterations: int = param(25, "At most this many clustering rounds (fewer once assignments stop "
                                "changing).", low=1)
    seed: int = param(0, "Seeds the random choice of the initial centres.", low=0)

    def feature_setting(self) -> dict[str, int | str]:
        """What an image's local features depend on: ``extract_features``' keyword arguments
        (the cache keeps features by these, shared by every vocabulary that agrees on them)."""
        return {"feature": self.feature, "max_features": self.max_features, "max_side": self.max_side}

    def to_json(self) -> str:
        """Canonical JSON of the values (numpy scalars as plain numbers)."""
        return json.dumps(self.as_dict(), sort_keys=True, default=lambda v: v.item())

"""FAB-MAP 1.0, the trained bag-of-words comparator (Cummins and Newman, IJRR 2008).

- `ChowLiuTree` (chow_liu.py): word dependencies learned from training word occurrences.
- `Detector` (detector.py): the detector model p(z | e) and the place appearance update.
- `FabMap` (model.py): place models, observation likelihoods, new-place likelihood, posterior.
- `FabMapParams` (params.py): every parameter, its default and its validation.

docs/fabmap.md describes the model, every parameter and its source.
"""
from __future__ import annotations

from wiloc.fabmap.chow_liu import ChowLiuTree, mutual_information
from wiloc.fabmap.detector import Detector
from wiloc.fabmap.model import FabMap
from wiloc.fabmap.params import NEW_PLACE_METHODS, FabMapParams

__all__ = ["NEW_PLACE_METHODS", "ChowLiuTree", "Detector", "FabMap", "FabMapParams",
           "mutual_information"]

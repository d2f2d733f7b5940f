"""FAB-MAP 1.0, the trained bag-of-words comparator (Cummins and Newman, IJRR 2008).

- `ChowLiuTree` (chow_liu.py): word dependencies learned from training word occurrences.
- `Detector` (detector.py): the detector model p(z | e) and the place appearance update.
- `FabMap` (model.py): place models, observation likelihoods, new-place likelihood, posterior.
- `FabMapParams` (params.py): every parameter, its default and its validation.

docs/fabmap.md describes the model, every parameter and its source. The names load on first use
(scipy with them), so the command line, whose ``fabmap`` method declares `FabMapParams`, starts
without scipy.
"""
from __future__ import annotations

import importlib
from typing import Any

_MODULES = {"ChowLiuTree": "chow_liu", "mutual_information": "chow_liu", "Detector": "detector",
            "FabMap": "model", "NEW_PLACE_METHODS": "params", "FabMapParams": "params"}

__all__ = ["NEW_PLACE_METHODS", "ChowLiuTree", "Detector", "FabMap", "FabMapParams",
           "mutual_information"]


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f"module 'wiloc.bow.fabmap' has no attribute {name!r}")
    return getattr(importlib.import_module(f"wiloc.bow.fabmap.{_MODULES[name]}"), name)

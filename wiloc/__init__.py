"""wiloc: training-free appearance-based localization with whole-image descriptors.

The four verbs are plain functions for notebooks and scripts: ``wiloc.describe``,
``wiloc.localize``, ``wiloc.evaluate``, ``wiloc.compare`` (see wiloc.api); ``wiloc.Localizer``
decides frame by frame, for a robot, a camera loop or a notebook (see wiloc.localization.localizer).
"""
from __future__ import annotations

from typing import Any

from wiloc.jitcache import place_numba_cache
from wiloc.version import __version__

place_numba_cache()  # before numba loads: compiled kernels go under wiloc's cache folder (wiloc/jitcache.py)

__all__ = ["Localizer", "__version__", "compare", "describe", "evaluate", "localize"]


def __getattr__(name: str) -> Any:
    """Load wiloc.api on first use of a verb, so that importing a submodule stays light."""
    if name in ("describe", "localize", "evaluate", "compare"):
        from wiloc import api
        return getattr(api, name)
    if name == "Localizer":
        from wiloc.localization.localizer import Localizer
        return Localizer
    raise AttributeError(f"module 'wiloc' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The loaded names and those loaded on first use, so that completion (``wiloc.<Tab>`` in a
    notebook) and ``dir`` show the verbs and ``Localizer`` before they are used."""
    return sorted({*globals(), *__all__})

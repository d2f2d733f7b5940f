"""wiloc: training-free appearance-based localization with whole-image descriptors."""
from __future__ import annotations

__version__ = "0.1.0"

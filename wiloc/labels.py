"""Short names for paths in tables and legends: each path's own name, or as many trailing parts as
keep apart paths of the same name (two datasets' ``winter``: ``nordland/winter`` and
``other/winter``)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import PurePath


def short_names(paths: Sequence[str | PurePath]) -> list[str]:
    """One label per path: its last part, lengthened from the end only where labels clash."""
    parts = [PurePath(str(p)).parts for p in paths]
    labels = [PurePath(*p[-1:]).as_posix() if p else "" for p in parts]
    for depth in range(2, max(map(len, parts), default=0) + 1):
        clashing = {label for label in labels
                    if len({p for p, other in zip(parts, labels) if other == label}) > 1}
        if not clashing:
            break
        labels = [PurePath(*p[-depth:]).as_posix() if label in clashing else label
                  for p, label in zip(parts, labels)]
    return labels

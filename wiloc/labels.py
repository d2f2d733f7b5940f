"""Short texts for tables and legends: names for paths (each path's own name, or as many trailing
parts as keep apart paths of the same name: two datasets' ``winter``, ``nordland/winter`` and
``other/winter``), and a confidence threshold written out with the digits that say it, rounded
down so that a cut there keeps what it accepts."""
from __future__ import annotations

import math
from collections.abc import Sequence
from decimal import ROUND_FLOOR, Decimal
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


def threshold_text(value: float | None) -> str:
    """A confidence threshold written out to say what was chosen: four significant digits of its
    distance to 0 or 1, whichever is nearer, since confidences crowd there (0.99951 is no 1.000,
    and 0.9897 and 0.9903 are not both 0.990); at least 3 decimals as other numbers, no trailing
    zero beyond them; "-" when there is none. Rounded down (0.130062217 is 0.130, not 0.1301), so
    that the text taken as a cut (confidence >= cut is accepted) keeps every frame the threshold
    accepts, the one whose confidence set it too."""
    if value is None or not math.isfinite(value):
        return "-"
    gap = min(abs(value), abs(1.0 - value))
    decimals = 3 if gap == 0 else max(3, 3 - math.floor(math.log10(gap)))
    shortest = Decimal(repr(float(value)))  # 0.29, not the float's 0.28999..., which would round down to 0.289
    down = shortest.quantize(Decimal(1).scaleb(-decimals), rounding=ROUND_FLOOR)
    whole, _, fraction = f"{down:f}".partition(".")
    return f"{whole}.{fraction.rstrip('0').ljust(3, '0')}"

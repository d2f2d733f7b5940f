"""Checks on text that users give by hand: whether a CSV cell is a number (a header line or a
line of data?), and whether frame names are usable (text, non-empty, each once). The ground-truth
readers, odometry, imported descriptor matrices and maps held in memory share them, so that each
problem reads the same wherever it is found."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from wiloc.errors import WilocError


def is_number(text: str) -> bool:
    """Whether a CSV cell reads as a number (telling a header line from a line of data)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def check_frame_names(names: Sequence[object], where: Path | str) -> None:
    """A WilocError naming ``where`` unless every name is non-empty text and no two rows share
    one (a match to either row would name the same frame); rows count from 1."""
    first: dict[str, int] = {}
    for row, name in enumerate(names, 1):
        if not isinstance(name, str) or not name:
            raise WilocError(where, f"row {row}: frame name {name!r}; each row needs a non-empty text name")
        if name in first:
            raise WilocError(where, f"rows {first[name]} and {row}: duplicate frame name {name!r}; "
                                    "each row names a frame of its own")
        first[name] = row

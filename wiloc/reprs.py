"""Short reprs for the objects wiloc returns: one line, whatever they hold.

A report holds arrays of thousands of values, tables and lists of frame names; printed in a
notebook or a log, its repr shows what it is and how big, not every value: arrays and tables by
shape, long lists by length, nested reports by class.
"""
from __future__ import annotations

import os
from dataclasses import fields, is_dataclass
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T", bound=type)

#: Text and sequences up to this length are shown whole.
_SHORT = 60


def number_label(value: float) -> str:
    """The shortest text of ``value`` that reads back as it: ``%g`` where that is exact (0.9, 1),
    else Python's repr (0.9999999, which ``%g`` shows as 1): two numbers never share a label, as
    a confidence cut names its table row and its CSV and JSON keys."""
    text = f"{value:g}"
    return text if float(text) == value else repr(float(value))


def brief(value: Any) -> str:
    """A few characters saying what ``value`` is."""
    if isinstance(value, np.generic):  # a numpy scalar: its value (its shape, (), says nothing)
        return brief(value.item())
    if isinstance(value, os.PathLike):  # its text, the end kept: the file's name tells it apart
        text = os.fspath(value)
        return repr(text) if len(text) <= _SHORT else repr("..." + text[3 - _SHORT:])
    if isinstance(value, float):
        return f"{value:.4g}"
    if value is None or isinstance(value, (bool, int, complex)):
        return repr(value)
    if isinstance(value, str):
        return repr(value) if len(value) <= _SHORT else repr(value[:_SHORT - 3] + "...")
    shape = getattr(value, "shape", None)
    if isinstance(shape, tuple):  # numpy arrays, pandas tables, sparse matrices
        return f"{type(value).__name__}({' x '.join(map(str, shape))})"
    if isinstance(value, (list, tuple, set, frozenset, dict)):
        text = repr(value)
        return text if len(text) <= _SHORT else f"<{type(value).__name__} of {len(value)}>"
    if is_dataclass(value):
        return f"{type(value).__name__}(...)"
    text = repr(value)
    return text if len(text) <= _SHORT else f"<{type(value).__name__}>"


def short_repr(cls: T) -> T:
    """Give a dataclass a one-line repr of its fields, each as :func:`brief` shows it."""
    def __repr__(self: Any) -> str:
        shown = ", ".join(f"{f.name}={brief(getattr(self, f.name))}" for f in fields(self) if f.repr)
        return f"{type(self).__name__}({shown})"

    cls.__repr__ = __repr__  # type: ignore[assignment]
    return cls

"""Declared parameters: one frozen dataclass per method, each field with its help and valid range.

A method's parameters are a subclass of :class:`Parameters` whose fields are made with
:func:`param`. Values are validated in one place (``__post_init__``): type, range or choices from
the declaration, then the class's own cross-field rules (``check``); they are stored as given,
save that a numpy scalar is stored as the Python number it holds and a list or 1-D array of
numbers as a tuple, so that parameters compare, hash and write to JSON alike however they were
given (``np.int64(500)`` from a sweep, ``[-2, 2]`` from a config file). Every
error is a :class:`~wiloc.errors.ParameterError` naming the parameter. The CLI builds its options
from the same declarations (:func:`declared`), so a parameter is described once.
"""
from __future__ import annotations

import math
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any, ClassVar, Literal, TypeVar, get_args, get_origin

import numpy as np

from wiloc.errors import ParameterError
from wiloc.reprs import brief

P = TypeVar("P", bound="Parameters")
INT64 = np.iinfo(np.int64)  # the integers a parameter may hold: what compiled kernels take


def param(default: Any, help: str, *, low: float | None = None, high: float | None = None,
          low_open: bool = False, high_open: bool = False, sequence_only: bool = False,
          odometry_only: bool = False) -> Any:
    """A declared parameter: its default, a one-line help and its valid range (bounds inclusive
    unless ``*_open``; for tuples the range holds for every element); ``sequence_only`` for one
    that a run against a map does not read, ``odometry_only`` for one that a run without the
    query's odometry does not read (given there, either is refused rather than ignored)."""
    return field(default=default, metadata={"help": help, "low": low, "high": high, "low_open": low_open,
                                            "high_open": high_open, "sequence_only": sequence_only,
                                            "odometry_only": odometry_only})


@dataclass(frozen=True)
class Declared:
    """One parameter as declared: what the CLI and the docs show."""

    name: str
    kind: str  # "int", "float", "str", "bool", "floats" (a tuple of numbers)
    default: Any
    help: str
    optional: bool  # None is a valid value (it then means what the help says)
    choices: tuple[str, ...] = ()
    length: int | None = None  # tuples of a fixed length
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    sequence_only: bool = False  # read in sequence mode only: refused with a map
    odometry_only: bool = False  # read with the query's odometry only: refused without it

    @property
    def range_text(self) -> str:
        """The valid range in words: '>= 1', '[0, 1)', 'one of a, b'."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.low is not None and self.high is not None:
            return f"{'(' if self.low_open else '['}{_num(self.low)}, {_num(self.high)}{')' if self.high_open else ']'}"
        if self.low is not None:
            return f"{'>' if self.low_open else '>='} {_num(self.low)}"
        if self.high is not None:
            return f"{'<' if self.high_open else '<='} {_num(self.high)}"
        return ""


def _num(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _kind(annotation: Any) -> tuple[str, bool, tuple[str, ...], int | None]:
    """(kind, optional, choices, fixed tuple length) of a field's type annotation."""
    optional = False
    args = get_args(annotation)
    if get_origin(annotation) in (typing.Union, types.UnionType):
        optional = type(None) in args
        rest = [a for a in args if a is not type(None)]
        annotation = rest[0]
        args = get_args(annotation)
    origin = get_origin(annotation)
    if origin is Literal:
        return "str", optional, tuple(str(a) for a in args), None
    if origin is tuple:
        length = None if len(args) == 2 and args[1] is Ellipsis else len(args)
        return "floats", optional, (), length
    names = {int: "int", float: "float", str: "str", bool: "bool"}
    if annotation not in names:
        raise TypeError(f"unsupported parameter type {annotation!r}")
    return names[annotation], optional, (), None


def declared(cls: type[Parameters]) -> list[Declared]:
    """The declared parameters of a :class:`Parameters` class, in field order."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in fields(cls):
        kind, optional, choices, length = _kind(hints[f.name])
        meta = f.metadata
        out.append(Declared(name=f.name, kind=kind, default=None if f.default is MISSING else f.default,
                            help=meta.get("help", ""), optional=optional, choices=choices, length=length,
                            low=meta.get("low"), high=meta.get("high"), low_open=meta.get("low_open", False),
                            high_open=meta.get("high_open", False), sequence_only=meta.get("sequence_only", False),
                            odometry_only=meta.get("odometry_only", False)))
    return out


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _in_range(value: float, d: Declared) -> bool:
    if d.low is not None and (value <= d.low if d.low_open else value < d.low):
        return False
    return not (d.high is not None and (value >= d.high if d.high_open else value > d.high))


def _problem(value: Any, d: Declared) -> str | None:
    """Why ``value`` cannot be parameter ``d``, or None when it can."""
    if value is None:
        return None if d.optional else "must be given"
    if d.kind == "bool":
        return None if isinstance(value, (bool, np.bool_)) else f"must be true or false, got {value!r}"
    if d.kind == "str":
        if d.choices and value not in d.choices:
            return f"must be one of {', '.join(d.choices)}, got {value!r}"
        return None if isinstance(value, str) else f"must be text, got {value!r}"
    if d.kind == "floats":
        if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)) \
                or (isinstance(value, np.ndarray) and value.ndim != 1) or not all(map(_is_number, value)):
            return f"must be a list of numbers, got {brief(value)}"
        if d.length is not None and len(value) != d.length:
            return f"must hold {d.length} numbers, got {len(value)}"
        if len(value) == 0:
            return "must hold at least one number"
        values = list(value)
    elif d.kind == "int":
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            return f"must be an integer, got {value!r}"
        if not INT64.min <= value <= INT64.max:  # compiled kernels take int64 (and float() of 10**400 fails)
            return f"must be a 64-bit integer (-2^63 to 2^63 - 1), got one of {len(str(abs(int(value))))} digits"
        values = [value]
    else:
        if not _is_number(value):
            return f"must be a number, got {value!r}"
        values = [value]
    if not all(math.isfinite(float(v)) for v in values):
        return f"must be finite, got {value!r}"
    if not all(_in_range(float(v), d) for v in values):
        where = d.range_text
        verb = "lie in" if where[0] in "[(" else "be"
        return f"{'every value must' if d.kind == 'floats' else 'must'} {verb} {where}, got {value!r}"
    return None


def _plain(value: Any, kind: str) -> Any:
    """A valid value as plain Python of its declared ``kind``: numpy scalars as the numbers they
    hold, a whole number given for a float as that float (``1`` as ``1.0``: a run's header says
    the same whether the value came from Python or the command line), a sequence of numbers (a
    list, a 1-D array) as a tuple of them."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(_plain(v, "float") for v in value)
    if isinstance(value, np.generic):
        value = value.item()
    return float(value) if kind == "float" and isinstance(value, int) and not isinstance(value, bool) else value


@dataclass(frozen=True)
class Parameters:
    """Base of every method's parameters: validated on construction, errors name the parameter."""

    owner: ClassVar[str] = ""  # the method's name, for error messages

    def __post_init__(self) -> None:
        for d in declared(type(self)):
            problem = _problem(getattr(self, d.name), d)
            if problem is not None:
                raise ParameterError(d.name, problem)
            object.__setattr__(self, d.name, _plain(getattr(self, d.name), d.kind))  # frozen: set once, here
        self.check()

    def check(self) -> None:
        """Rules between parameters (a subclass raises ParameterError); none by default."""

    @classmethod
    def create(cls: type[P], values: Mapping[str, Any] | None = None) -> P:
        """Parameters from a mapping; an unknown name is a ParameterError listing the valid ones."""
        values = dict(values or {})
        names = [f.name for f in fields(cls)]
        for name in values:
            if name not in names:
                owner = f" of method '{cls.owner}'" if cls.owner else ""
                raise ParameterError(name, f"not a parameter{owner} (valid: {', '.join(names) or 'none'})")
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        """The values as plain JSON-ready Python (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

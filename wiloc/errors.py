"""Errors that reach the user as one line, and the exit codes they map to."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

EXIT_OK = 0
EXIT_BAD_INPUT = 1
EXIT_USAGE = 2
EXIT_BUSY = 3
EXIT_INTERRUPTED = 130
EXIT_CLOSED_OUTPUT = 1  # the reader of stdout closed it (`| head`): rich's own code for it


def shown_name(name: str) -> str:
    """A file name as text that prints and encodes anywhere: bytes that are not UTF-8 (held by
    Python as lone surrogates) written as ``\\xff``."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _one_line_name(name: str) -> str:
    """A file name as :func:`shown_name` writes it, its line breaks written as ``\\n`` and ``\\r``."""
    return shown_name(name).replace("\n", "\\n").replace("\r", "\\r")


def _one_line_problem(text: str) -> str:
    """``text`` with its line breaks (and the spaces around them) as one space each: a library's
    message (pandas') may end in one."""
    if "\n" not in text and "\r" not in text:
        return text
    return " ".join(part.strip() for part in text.replace("\r", "\n").split("\n") if part.strip())


class WilocError(Exception):
    """A problem with the user's input: printed as one line naming the file, never a traceback
    (a problem's line breaks, as a library's message may hold, become spaces).

    ``parameter`` names the library parameter the problem came through (``where`` is then that
    name), so that a front end can name its own spelling of it (the CLI: its flag). File names
    that are not UTF-8 are shown as :func:`shown_name` writes them, so the line prints anywhere.
    """

    exit_code = EXIT_BAD_INPUT

    def __init__(self, where: str | Path | None, problem: str, *, parameter: str | None = None) -> None:
        self.where = parameter if parameter is not None else None if where is None else _one_line_name(str(where))
        self.problem = _one_line_problem(shown_name(problem))
        self.parameter = parameter
        super().__init__(f"{self.where}: {self.problem}" if self.where else self.problem)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its fields, as a worker process (or a multiprocessing pool) sends it to the
        process that re-raises it: unpickled through ``__init__``'s arguments, it was a TypeError."""
        return _unpickled, (type(self), self.args, self.__dict__)


def _unpickled(cls: type[WilocError], args: tuple[Any, ...], fields: dict[str, Any]) -> WilocError:
    """The error :meth:`WilocError.__reduce__` pickled."""
    error = cls.__new__(cls)
    Exception.__init__(error, *args)
    error.__dict__.update(fields)
    return error


class FrameError(WilocError):
    """One image could not be used (unreadable, truncated, unsupported); the frame is left out."""


class CacheBusyError(WilocError):
    """Another wiloc process holds the cache entry this one needs."""

    exit_code = EXIT_BUSY


class UsageError(WilocError):
    """An option value that cannot work (unknown name, out of range)."""

    exit_code = EXIT_USAGE


class ParameterError(UsageError):
    """A parameter value that cannot work, named by its library name (``particles``, ``bins``)."""

    def __init__(self, parameter: str, problem: str) -> None:
        super().__init__(None, problem, parameter=parameter)


def parameter_values(values: object, name: str) -> dict[str, Any]:
    """``values`` (None: none) as a dict of parameter names to values: a string or a list given
    where a mapping goes is a ParameterError naming ``name`` (``method_params``,
    ``descriptor_params``), not dict()'s ValueError about update sequences."""
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise ParameterError(name, f"must map parameter names to values (a dict), got {type(values).__name__}")
    return dict(values)


def load_problem(exc: Exception) -> str:
    """Why ``np.load(..., allow_pickle=False)`` failed, in the user's terms, never numpy's advice
    to load the file unsafely: an object array holds Python objects, not numbers; a file without
    the .npy header (text, a pickle) is no .npy array; an empty one is empty; other reasons are
    numpy's own."""
    if isinstance(exc, EOFError):
        return "the file is empty or cut short"
    if "allow_pickle" in str(exc):
        if str(exc).startswith("Object arrays"):
            return "holds Python objects, not a plain numeric array"
        return "no NumPy array header: not an .npy array (a pickle is not read)"
    return str(exc)


def interrupted(exc: BaseException | None) -> bool:
    """Whether ``exc`` is Ctrl-C or was raised while handling it (a library that turns an
    interrupted import or call into an error of its own)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False

"""Descriptor 2 (standard error) on /dev/null while image decoders print there themselves
(libjpeg's "Corrupt JPEG data: ..."; wiloc reports bad frames itself), and put back before an
error is printed: a Ctrl-C can end the quiet stretch at any point, even while it puts the
descriptor back, and the command's own "error: interrupted" must not go to /dev/null."""
from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

_devnull: int | None = None  # /dev/null, opened once quieting is wanted in this process
_held: int | None = None  # while quiet: a copy of descriptor 2 as it was


def quiet_always() -> None:
    """A worker process's decoders are always quiet (:func:`decoders_quiet`), its stderr a
    terminal or not. A forked worker starts afresh: the descriptors its parent held are not its."""
    global _devnull, _held
    _devnull, _held = os.open(os.devnull, os.O_WRONLY), None


@contextmanager
def decoders_quiet() -> Iterator[None]:
    """Descriptor 2 on /dev/null meanwhile. Always in a worker (:func:`quiet_always`), which runs
    no other thread, so nothing else is lost; in the caller's process only when stderr is no
    terminal: on a terminal other threads of the caller (a progress display) write there, so it
    is left alone. Within a quiet stretch (nested, another thread's) it changes nothing."""
    global _devnull, _held
    if _devnull is None:
        if os.isatty(2):
            yield
            return
        _devnull = os.open(os.devnull, os.O_WRONLY)
    if _held is not None:
        yield
        return
    saved = os.dup(2)
    try:
        _held = saved
        assert _devnull is not None
        os.dup2(_devnull, 2)
        yield
    finally:
        stderr_back()


def stderr_back() -> None:
    """Descriptor 2 put back where it was when :func:`decoders_quiet` holds it on /dev/null;
    whatever prints an error calls it first, since a Ctrl-C may have ended the quiet stretch
    before its own call to this ran. Safe to call again: the descriptor is put back before the
    copy is let go."""
    global _held
    held = _held
    if held is None:
        return
    os.dup2(held, 2)
    _held = None
    os.close(held)

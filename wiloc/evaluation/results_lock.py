"""A results file's lock and the refusal to replace what is no results file: a batch run, a
followed run and ``Results.save`` writing one file never overlap, and none of them replaces a file
of the user's (a frame of the query, a table of one's own) by results."""
from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from wiloc.atomic import fitting_stem, output_problem, write_error
from wiloc.cache.store import lock_file
from wiloc.errors import CacheBusyError, WilocError
from wiloc.evaluation.results_header import VERSION_KEY, starts_as_results


def lock_results(path: Path) -> int:
    """Hold an exclusive lock on the results file ``path`` (the lock file ``.NAME.lock`` beside
    it, holding the holder's pid, as the cache's locks do), without waiting: a CacheBusyError
    naming ``path`` when another run holds it, so that two runs never append to one file. A
    ``path`` that can take no file (a folder, a name over 255 bytes) is a WilocError naming it,
    not its lock, before anything is written."""
    if (problem := output_problem(path) or _other_file(path)) is not None:
        raise WilocError(path, f"cannot write the results file: {problem}")
    lock = _lock_path(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)  # as the results file's own writing does
        return lock_file(lock, time.monotonic(),
                          lambda pid: CacheBusyError(path, f"in use by another wiloc run (pid {pid})"))
    except OSError as exc:
        raise write_error(lock, "the results file's lock", exc) from None


def _other_file(path: Path) -> str | None:
    """Why the file at ``path`` is not to be replaced by results (or resumed): it holds something
    else, such as a frame of the query (``-o day_left/Image000.jpg``) or a table of one's own,
    which would be lost. None for no file, an empty one or a wiloc results file."""
    started = starts_as_results(path)  # None: no file, or none to read (output_problem and the writing say so)
    if started is not False or path.stat().st_size == 0:
        return None
    return (f"the file there is no wiloc results file (its first line is not '# {VERSION_KEY}: ...'), and "
            "writing would replace it; give another name, or remove it first")


def _lock_path(path: Path) -> Path:
    """The lock file of the results file ``path``: beside the file it names (a link resolved), so
    that every spelling of one file shares one lock; a name within 6 bytes of the longest a file
    system takes is shortened (:func:`~wiloc.atomic.fitting_stem`)."""
    real = Path(os.path.realpath(path))
    return real.with_name(f".{fitting_stem(real.name, len('..lock'))}.lock")


def unlock_results(path: Path, fd: int) -> None:
    """Let go of :func:`lock_results`' lock: its file removed while still held, then closed."""
    try:
        _lock_path(path).unlink(missing_ok=True)
    finally:
        os.close(fd)


@contextmanager
def results_lock(path: Path | None) -> Iterator[None]:
    """:func:`lock_results` held while the block runs (nothing when ``path`` is None): a batch run
    writing ``path`` and a followed run appending to it never overlap."""
    if path is None:
        yield
        return
    lock = lock_results(path)
    try:
        yield
    finally:
        unlock_results(path, lock)

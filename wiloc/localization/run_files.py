"""A run's results file: its default name, what its header says about the run, reading one
back with the bounds its method's confidences keep, and the runs the API's evaluate and compare
are given, checked."""
from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from wiloc.atomic import fitting_stem, output_problem, write_error
from wiloc.cache.store import Entry, lock_file
from wiloc.description.describing import is_stream
from wiloc.description.traversals import Describer, descriptor_label
from wiloc.errors import CacheBusyError, ParameterError, WilocError
from wiloc.evaluation.results import Results, read_results
from wiloc.evaluation.results_header import VERSION_KEY, ResultsHeader, starts_as_results
from wiloc.localization.training import Training
from wiloc.methods.registry import METHODS
from wiloc.sources.frames import text_path
from wiloc.version import __version__



def results_name(query: Path, method: str, descriptor: str, metric: str | None = None) -> str:
    """The default results file name of one query traversal (folder, matrix file, whose
    ``metric`` then names it, video file or ROS bag), descriptor and method:
    ``day_left-sad-online.csv``; a video's or bag file's suffix stays in its name
    (``day_left-mp4-sad-online.csv``), so that its run and a folder's of the same name never share a file."""
    label = descriptor_label(descriptor, metric, [query]).replace(":", "-")
    name = query.name if not query.is_file() else \
        f"{query.stem}-{query.suffix.lstrip('.').lower()}" if is_stream(query) else query.stem
    return f"{name}-{label}-{method}.csv"


def run_header(method: str, describer: Describer, query: Path | None, metric: str, reference: Path | Entry | None,
               exclude_recent: int, training: Training | None) -> ResultsHeader:
    """What a results header says about a run besides the method's parameters. A streaming run
    may not know its ``query`` (None: recorded as "") and may hold its map in memory (an
    ``Entry``: recorded by its ``folder``). Imported descriptors (a query or map that is a
    matrix file, or rows given as ``external``) are named ``external:METRIC``, with the
    parameters ``Describer.recorded_params`` gives (none for matrix files)."""
    sources = [Path(source) for source in (query, reference) if isinstance(source, (str, os.PathLike))]
    return ResultsHeader(method=method, descriptor=descriptor_label(describer.descriptor, metric, sources),
                         descriptor_params=describer.recorded_params(sources), metric=metric,
                         mode="sequence" if reference is None else "map", query="" if query is None else text_path(query),
                         map=reference.folder if isinstance(reference, Entry) else text_path(reference) if reference else "",
                         exclude_recent=exclude_recent, wiloc=__version__,
                         train_query=text_path(training.query) if training else None,
                         train_map=text_path(training.reference) if training else None)


def read_run(path: Path) -> Results:
    """The results file at ``path``, naming a registered method, its confidences checked against
    the bounds of the method that wrote it (``threshold``'s go below 0)."""
    return read_results(path, METHODS)


def results_file(run: object, parameter: str) -> Path:
    """A run that is neither a ``LocalizeRun`` nor ``Results`` as its results file's path (text or a
    path object); anything else is a ParameterError naming ``parameter`` (``run``, ``runs``)."""
    if isinstance(run, (str, os.PathLike)):
        return Path(run)
    if parameter == "run" and isinstance(run, (list, tuple)):
        raise ParameterError(parameter, f"one run is scored at a time, got a {type(run).__name__} of {len(run)}: "
                                        "score each ([api.evaluate(run, truth) for run in runs]) or compare them "
                                        "(api.compare)")
    raise ParameterError(parameter, f"a results file's path, a LocalizeRun or Results, got {type(run).__name__}")


def run_list(runs: object, alone: tuple[type, ...]) -> list:
    """The runs given to compare, as a list: one given alone (a path, or of a type in ``alone``) as
    ``[run]``, never as the characters of its name; any iterable read once. None given, or what is
    neither, is a ParameterError naming ``runs``."""
    if isinstance(runs, (str, os.PathLike, *alone)):
        return [runs]
    if not isinstance(runs, Iterable):
        raise ParameterError("runs", "one run or several: results files' paths, LocalizeRun or Results, "
                                     f"got {type(runs).__name__}")
    listed = list(runs)
    if not listed:
        raise ParameterError("runs", "no runs given")
    return listed


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

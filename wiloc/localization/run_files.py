"""A run's results file: its default name, what its header says about the run, reading one
back with the bounds its method's confidences keep, and the runs the API's evaluate and compare
are given, checked."""
from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from wiloc.cache.store import Entry
from wiloc.description.describing import is_stream
from wiloc.description.traversals import Describer, descriptor_label
from wiloc.errors import ParameterError
from wiloc.evaluation.results import Results, read_results
from wiloc.evaluation.results_header import ResultsHeader
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
    name = named_path(query).name if not query.is_file() else \
        f"{query.stem}-{query.suffix.lstrip('.').lower()}" if is_stream(query) else query.stem
    return f"{name}-{label}-{method}.csv"


def named_path(query: Path) -> Path:
    """``query`` as its traversal is named: as given, or resolved when its last part names no folder
    (``.``, ``./``, ``..``, ``x/..``), so that its results file and labels carry the folder's own
    name, not "" (a file "-sad-online.csv", read back as an option) or "..". A path that cannot be
    resolved (a symbolic link loop) stays as given; reading it says what is wrong."""
    if query.name not in ("", ".."):
        return query
    try:
        return query.resolve()
    except (OSError, RuntimeError):  # RuntimeError: a loop, before Python 3.13
        return query


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

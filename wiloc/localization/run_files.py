"""A run's results file: its default name, what its header says about the run, and reading one
back with the bounds its method's confidences keep."""
from __future__ import annotations

from pathlib import Path

from wiloc.description.describing import is_stream
from wiloc.description.traversals import Describer, descriptor_label
from wiloc.evaluation.results import Results, read_results
from wiloc.evaluation.results_header import ResultsHeader
from wiloc.localization.training import Training
from wiloc.methods.registry import lowest_confidence
from wiloc.sources.frames import text_path
from wiloc.version import __version__


def results_name(query: Path, method: str, descriptor: str, metric: str | None = None) -> str:
    """The default results file name of one query traversal (folder, matrix file, whose
    ``metric`` then names it, video file or ROS bag), descriptor and method:
    ``day_left-sad-online.csv``; a video's or bag file's suffix stays in its name
    (``day_left-mp4-sad-online.csv``), so that its run and a folder's of the same name never share a file."""
    label = descriptor_label(query, descriptor, metric).replace(":", "-")
    name = query.name if not query.is_file() else \
        f"{query.stem}-{query.suffix.lstrip('.').lower()}" if is_stream(query) else query.stem
    return f"{name}-{label}-{method}.csv"


def run_header(method: str, describer: Describer, query: Path, metric: str, reference: Path | None,
               exclude_recent: int, training: Training | None) -> ResultsHeader:
    """What a results header says about a run besides the method's parameters."""
    return ResultsHeader(method=method, descriptor=describer.label(query), descriptor_params=dict(describer.params),
                         metric=metric, mode="sequence" if reference is None else "map", query=text_path(query),
                         map=text_path(reference) if reference else "", exclude_recent=exclude_recent,
                         wiloc=__version__, train_query=str(training.query) if training else None,
                         train_map=str(training.reference) if training else None)


def read_run(path: Path) -> Results:
    """The results file at ``path``, its confidences checked against the bounds of the method
    that wrote it (``threshold``'s go below 0)."""
    return read_results(path, lowest_confidence)

"""A whole query traversal localized at once: the run session (method, map, rows), the method
stepped over the query's rows, and the results (``wiloc.localize``; ``wiloc.Localizer`` steps the
same session frame by frame)."""
from __future__ import annotations

import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wiloc.cache.store import Cache
from wiloc.description.traversals import Progress, stage
from wiloc.evaluation.results import Results, make_results, write_results
from wiloc.evaluation.results_lock import results_lock
from wiloc.localization.run_files import run_header
from wiloc.localization.session import RunSession, check_traversal
from wiloc.localization.training import Training
from wiloc.sources.video import Sampling

if TYPE_CHECKING:
    from wiloc.decisions import Decisions


@dataclass
class LocalizeRun:
    """One query traversal localized: the decisions, the results (and the file they were written
    to, when one was asked for), and the timing."""

    query: Path
    reference: Path
    method: str
    decisions: Decisions
    results: Results
    path: Path | None
    seconds: float
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (image path, why it was left out)
    replaced: bool = False  # the results file existed before and was replaced
    warnings: list[str] = field(default_factory=list)  # what makes the results doubtful (a sparse vocabulary)
    notes: list[str] = field(default_factory=list)  # worth saying: which topic of a bag was read

    def __repr__(self) -> str:
        written = f", path={str(self.path)!r}" if self.path else ""
        return (f"LocalizeRun(query={self.query.name!r}, method={self.method!r}, frames={len(self.decisions)}, "
                f"decided={int(self.decisions.decided.sum())}{written})")


def localize(query: Path, *, reference: Path | None = None, descriptor: str | None = None,
             descriptor_params: Mapping[str, Any] | None = None, metric: str | None = None,
             method: str = "online", method_params: Mapping[str, Any] | None = None,
             exclude_recent: int | None = None, training: Training | None = None,
             odometry: Path | None = None, map_odometry: Path | None = None,
             query_names_file: Path | None = None, ref_names_file: Path | None = None,
             out: Path | None = None, cache: Cache | str | os.PathLike | None = None, jobs: int | None = None,
             sampling: Sampling | None = None, progress: Progress | None = None,
             scheduler: str | None = None, topic: str | None = None, map_topic: str | None = None,
             odometry_topic: str | None = None) -> LocalizeRun:
    """Localize every frame of ``query`` (against ``reference``, or within itself) and write results.

    ``query`` and ``reference`` are image folders, or descriptor matrix files (with ``metric`` and,
    for .npy, optional ``*_names_file``; a ``descriptor``, None meaning ``sad``, only for the others). ``method`` names a registered method
    (``wiloc.methods.registry``) and ``method_params`` its parameters; the method is stepped over
    the query's difference rows, read from the cache block by block. ``odometry`` and
    ``map_odometry`` are odometry CSVs (for methods that take them); ``training`` is the labelled
    pair of the ``trained`` comparator. ``sampling`` picks the frames of video files (query, map
    and training traversals alike; default: every frame), and ``topic`` the image topic of ROS
    bags (None: each one's only one); ``map_topic`` that of a ``reference`` bag recorded with
    another topic's name (None: ``topic``); ``odometry_topic`` names their ``nav_msgs/msg/Odometry``
    topic, read as the odometry of each bag (query or map). The results are written to ``out`` when
    given (else kept in memory only: ``wiloc.api.evaluate`` takes the run itself). ``scheduler``
    (a Dask scheduler's address, or ``local``) describes and computes the differences on its workers.
    """
    started = time.perf_counter()
    check_traversal(query, "query", hint=": localize each ([api.localize(q, ...) for q in queries])")
    if reference is not None:
        check_traversal(reference, "reference", " or None for sequence mode")
    query = Path(query)
    with results_lock(None if out is None else Path(out)):  # a follower of the same file would append to a replaced one
        session = RunSession(reference, method=method, method_params=method_params, descriptor=descriptor,
                             descriptor_params=descriptor_params, metric=metric, exclude_recent=exclude_recent,
                             training=training, map_odometry=map_odometry, map_names=ref_names_file, query=query,
                             query_names=query_names_file, odometry=odometry, odometry_topic=odometry_topic,
                             sampling=sampling, cache=cache, jobs=jobs, progress=progress, scheduler=scheduler,
                             topic=topic, map_topic=map_topic)
        describer, q, R = session.describer, session.query, session.exclude_recent
        r = q if session.map is None else session.map
        rows = session.batch_rows()
        decisions = session.method.run(rows, len(q.names), odometry=session.query_steps(),
                                       progress=stage(progress, f"{method} {query.name}"),
                                       passed=session.query_passed())
        header = replace(run_header(method, describer, query, q.metric, reference, R, training), **session.recorded())
        results = make_results(decisions, query_names=q.names, ref_names=r.names, header=header)
        replaced = write_results(Path(out), results) if out is not None else False
        return LocalizeRun(query=query, reference=Path(reference) if reference else query, method=method,
                           decisions=decisions, results=results, path=None if out is None else Path(out),
                           seconds=time.perf_counter() - started, skipped=describer.skipped, replaced=replaced,
                           warnings=session.doubts(), notes=describer.notes)

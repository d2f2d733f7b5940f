"""The four verbs as plain Python functions returning data: describe, localize, evaluate, compare.

The CLI and the demo call these; so can a notebook. Nothing here prints. Long steps report through
``progress(stage, done, total)``, where ``stage`` names the step ("describe day_left", ...).
A run's setup is ``wiloc.localization.session``'s (shared with ``wiloc.Localizer``); scoring and the tables are
``wiloc.evaluation.comparison``'s, following a folder ``wiloc.localization.follow_run``'s, and importing descriptors and
building vocabularies ``wiloc.localization.inputs``'s: their public names are importable from here too.
"""
from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wiloc.cache.store import Cache
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT
from wiloc.evaluation.comparison import (DEFAULT_CUTS, RANKED_KS, TABLE1_KEYS, Comparison, Evaluation, check_once,
                                         check_precisions, comparison, method_labels, new_place_series, pr_series,
                                         reliability_series, run_names, run_subject, score, threshold_marks, threshold_series,
                                         traversal_labels)
from wiloc.description.describing import DescribeReport, check_sampling, check_topic, describe_sources, is_stream
from wiloc.description.traversals import Progress, descriptor_spec, descriptors_digest, open_cluster, stage
from wiloc.evaluation.results import Results, make_results, write_results
from wiloc.evaluation.truth_source import TruthSource
from wiloc.localization.follow_run import FollowRun, follow_folder
from wiloc.localization.inputs import import_descriptors, shared_workers, vocabulary, vocabulary_file
from wiloc.localization.run_files import read_run, results_name, run_header
from wiloc.localization.session import RunSession
from wiloc.localization.training import Training
from wiloc.sources.video import Sampling

if TYPE_CHECKING:
    from wiloc.decisions import Decisions

__all__ = ["TABLE1_KEYS", "Comparison", "Evaluation", "FollowRun", "LocalizeRun", "Sampling", "Training",
           "TruthSource", "compare", "describe", "evaluate", "follow_folder", "import_descriptors", "localize",
           "method_labels", "new_place_series", "pr_series", "reliability_series", "results_name", "run_names",
           "run_subject", "shared_workers", "threshold_marks", "threshold_series", "traversal_labels", "vocabulary",
           "vocabulary_file"]


# ----------------------------------------------------------------------------------------- describe

def describe(folders: Sequence[str | Path] | str | Path, descriptor: str = "sad", *,
             descriptor_params: Mapping[str, Any] | None = None, cache: Cache | None = None,
             jobs: int | None = None, progress: Progress | None = None,
             sampling: Sampling | None = None, scheduler: str | None = None,
             topic: str | None = None) -> list[DescribeReport]:
    """Compute (or reuse from the cache) one descriptor per image of each folder, or per frame
    of each video file or ROS bag (of its image ``topic``; None: its only one) that ``sampling``
    picks (default: every frame). ``jobs`` worker processes describe folders, or the workers of
    the Dask ``scheduler`` (an address, or ``local``: a local cluster of ``jobs`` workers); videos
    and bags are decoded and described in this process. The folders' frames form one stream over
    the workers (``wiloc.description.describing.describe_folders``). Reports come in the order of
    ``folders``; one folder given alone (not in a list) is described as ``[folder]``, never as
    the characters of its name."""
    spec = descriptor_spec(descriptor, descriptor_params)
    cache = cache or Cache()
    paths = [Path(folders)] if isinstance(folders, (str, os.PathLike)) else [Path(folder) for folder in folders]
    check_sampling(paths, sampling)
    check_topic(paths, topic)
    cluster = open_cluster(scheduler, jobs)
    return describe_sources(paths, spec, cache, jobs=jobs, sampling=sampling,
                            progress=[stage(progress, f"describe {path.name}") for path in paths],
                            cluster=cluster, topic=topic)


# ----------------------------------------------------------------------------------------- localize

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


def localize(query: Path, *, reference: Path | None = None, descriptor: str = "sad",
             descriptor_params: Mapping[str, Any] | None = None, metric: str | None = None,
             method: str = "online", method_params: Mapping[str, Any] | None = None,
             exclude_recent: int = DEFAULT_EXCLUDE_RECENT, training: Training | None = None,
             odometry: Path | None = None, map_odometry: Path | None = None,
             query_names_file: Path | None = None, ref_names_file: Path | None = None,
             out: Path | None = None, cache: Cache | None = None, jobs: int | None = None,
             sampling: Sampling | None = None, progress: Progress | None = None,
             scheduler: str | None = None, topic: str | None = None,
             odometry_topic: str | None = None) -> LocalizeRun:
    """Localize every frame of ``query`` (against ``reference``, or within itself) and write results.

    ``query`` and ``reference`` are image folders, or descriptor matrix files (with ``metric`` and,
    for .npy, optional ``*_names_file``). ``method`` names a registered method
    (``wiloc.methods.registry``) and ``method_params`` its parameters; the method is stepped over
    the query's difference rows, read from the cache block by block. ``odometry`` and
    ``map_odometry`` are odometry CSVs (for methods that take them); ``training`` is the labelled
    pair of the ``trained`` comparator. ``sampling`` picks the frames of video files (query, map
    and training traversals alike; default: every frame), and ``topic`` the image topic of ROS
    bags (None: each one's only one); ``odometry_topic`` names their ``nav_msgs/msg/Odometry``
    topic, read as the odometry of each bag (query or map). The results are written to ``out`` when
    given (else kept in memory only: ``wiloc.api.evaluate`` takes the run itself). ``scheduler``
    (a Dask scheduler's address, or ``local``) describes and computes the differences on its workers.
    """
    started = time.perf_counter()
    query = Path(query)
    session = RunSession(reference, method=method, method_params=method_params, descriptor=descriptor,
                         descriptor_params=descriptor_params, metric=metric, exclude_recent=exclude_recent,
                         training=training, map_odometry=map_odometry, map_names=ref_names_file, query=query,
                         query_names=query_names_file, odometry=odometry, odometry_topic=odometry_topic,
                         sampling=sampling, cache=cache, jobs=jobs, progress=progress, scheduler=scheduler,
                         topic=topic)
    describer, q, R = session.describer, session.query, session.exclude_recent
    r = q if session.map is None else session.map
    rows = session.batch_rows()
    decisions = session.method.run(rows, len(q.names), odometry=session.query_steps(),
                                   progress=stage(progress, f"{method} {query.name}"))
    streamed = any(is_stream(Path(source)) for source in (query, reference) if source is not None)
    evidence = session.evidence  # FAB-MAP's training data: the vocabulary's images
    header = replace(run_header(method, describer, query, q.metric, reference, R, training),
                     query_digest=descriptors_digest(q.names, q.data),
                     map_digest="" if session.sequence else descriptors_digest(r.names, r.data),
                     sampling=asdict(sampling or Sampling()) if streamed else None, topic=topic,
                     odometry_topic=odometry_topic, rows="fabmap" if evidence is not None else None,
                     fabmap_training=tuple(evidence.training_folders) if evidence is not None else None)
    results = make_results(decisions, query_names=q.names, ref_names=r.names, header=header)
    replaced = write_results(Path(out), results) if out is not None else False
    return LocalizeRun(query=query, reference=Path(reference) if reference else query, method=method,
                       decisions=decisions, results=results, path=None if out is None else Path(out),
                       seconds=time.perf_counter() - started, skipped=describer.skipped, replaced=replaced,
                       warnings=session.doubts(), notes=describer.notes)


# ----------------------------------------------------------------------------------------- evaluate

Run = Path | str | LocalizeRun | Results


def evaluate(run: Run, truth: TruthSource, cuts: Sequence[float] = DEFAULT_CUTS,
             recall_at: Sequence[int] = RANKED_KS) -> Evaluation:
    """Precision-recall metrics and calibration (with precision and recall at fixed confidence
    ``cuts``) of one run against ground truth, and of its P(new place) where the run gives one:
    a results file, or a run in memory. Recall@N for each N of ``recall_at`` when the run ranks
    the map (``wiloc.evaluation.comparison.score``)."""
    if isinstance(run, LocalizeRun):
        return score(run.path, run.results, truth, cuts, recall_at)
    if isinstance(run, Results):
        return score(None, run, truth, cuts, recall_at)
    return score(Path(run), read_run(Path(run)), truth, cuts, recall_at)


# ------------------------------------------------------------------------------------------ compare

def compare(runs: Sequence[Run], truth: TruthSource, *, precisions: Sequence[float] = (100.0, 99.0),
            global_thresholds: bool = True, cuts: Sequence[float] = DEFAULT_CUTS,
            recall_at: Sequence[int] = RANKED_KS) -> Comparison:
    """Table I (recall at 100/99/90 % precision per traversal and method), Table II and the
    calibration table with precision and recall at the fixed confidence ``cuts``, over results
    files or runs in memory. A file given twice (or a copy of one), no precision or one outside
    (0, 100] is a ParameterError: each run counts once in the tables."""
    check_precisions(precisions)
    check_once([run.path if isinstance(run, LocalizeRun) else None if isinstance(run, Results) else Path(run)
                for run in runs])
    evaluations = [evaluate(run, truth, cuts, recall_at) for run in runs]
    return comparison(evaluations, truth, precisions=precisions, global_thresholds=global_thresholds)

"""The four verbs as plain Python functions returning data: describe, localize, evaluate, compare.

The CLI and the demo call these; so can a notebook. Nothing here prints. Long steps report through
``progress(stage, done, total)``, where ``stage`` names the step ("describe day_left", ...).
A batch run is ``wiloc.localization.batch``'s (its setup, ``wiloc.localization.session``, is shared with
``wiloc.Localizer``); scoring and the tables are ``wiloc.evaluation.comparison``'s, following a folder
``wiloc.localization.follow_run``'s, and importing descriptors and building vocabularies
``wiloc.localization.inputs``'s: their public names are importable from here too.
"""
from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from wiloc.cache.store import Cache
from wiloc.description.describing import (DescribeReport, check_sampling, check_topic, describe_sources,
                                         traversal_paths)
from wiloc.description.traversals import Progress, check_progress, descriptor_spec, open_cluster, stage
from wiloc.evaluation.comparison import (DEFAULT_CUTS, RANKED_KS, TABLE1_KEYS, Comparison, Evaluation, check_cuts,
                                         check_frames, check_held_once, check_once, check_precisions, check_recall_at,
                                         comparison, method_labels, new_place_series, pr_series, reliability_series,
                                         run_names, run_subject, score, threshold_marks, threshold_series,
                                         traversal_labels)
from wiloc.evaluation.results import Results
from wiloc.evaluation.truth_source import TruthSource
from wiloc.localization.batch import LocalizeRun, localize
from wiloc.localization.follow_run import FollowRun, follow_folder
from wiloc.localization.inputs import frames, import_descriptors, shared_workers, vocabulary, vocabulary_file
from wiloc.localization.run_files import read_run, results_file, results_name, run_list
from wiloc.localization.training import Training
from wiloc.sources.video import Sampling

__all__ = ["TABLE1_KEYS", "Comparison", "Evaluation", "FollowRun", "LocalizeRun", "Sampling", "Training",
           "TruthSource", "compare", "describe", "evaluate", "follow_folder", "frames", "import_descriptors",
           "localize", "method_labels", "new_place_series", "pr_series", "reliability_series", "results_name",
           "run_names", "run_subject", "shared_workers", "threshold_marks", "threshold_series", "traversal_labels",
           "vocabulary", "vocabulary_file"]


# ----------------------------------------------------------------------------------------- describe

def describe(folders: Sequence[str | Path] | str | Path, descriptor: str = "sad", *,
             descriptor_params: Mapping[str, Any] | None = None, cache: Cache | str | os.PathLike | None = None,
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
    check_progress(progress)
    spec = descriptor_spec(descriptor, descriptor_params, images=True)
    cache = Cache.given(cache)
    paths = traversal_paths(folders, "folders")
    check_sampling(paths, sampling)
    check_topic(paths, topic)
    cluster = open_cluster(scheduler, jobs)
    return describe_sources(paths, spec, cache, jobs=jobs, sampling=sampling,
                            progress=[stage(progress, f"describe {path.name}") for path in paths],
                            cluster=cluster, topic=topic)


# ----------------------------------------------------------------------------------------- evaluate

Run = Path | str | LocalizeRun | Results


def evaluate(run: Run, truth: TruthSource, cuts: Sequence[float] = DEFAULT_CUTS,
             recall_at: Sequence[int] = RANKED_KS, *, frames: slice | str | None = None) -> Evaluation:
    """Precision-recall metrics and calibration (with precision and recall at fixed confidence
    ``cuts``) of one run against ground truth, and of its P(new place) where the run gives one:
    a results file, or a run in memory. Recall@N for each N of ``recall_at`` when the run ranks
    the map (``wiloc.evaluation.comparison.score``). ``frames`` scores a slice of the run's frames
    only, in the run's order (``slice(20, None)`` or ``"20:"``: after the first 20). Several runs
    are scored one by one, or side by side with :func:`compare`: a list is a ParameterError naming
    ``run`` and saying so."""
    frames = check_frames(frames)  # refused before any file is read
    if isinstance(run, LocalizeRun):
        return score(run.path, run.results, truth, cuts, recall_at, frames)
    if isinstance(run, Results):
        return score(None, run, truth, cuts, recall_at, frames)
    path = results_file(run, "run")
    return score(path, read_run(path), truth, cuts, recall_at, frames)


# ------------------------------------------------------------------------------------------ compare

def compare(runs: Iterable[Run] | Run, truth: TruthSource, *, precisions: Sequence[float] = (100.0, 99.0),
            global_thresholds: bool = True, cuts: Sequence[float] = DEFAULT_CUTS,
            recall_at: Sequence[int] = RANKED_KS, frames: slice | str | None = None) -> Comparison:
    """Table I (recall at 100/99/90 % precision per traversal and method), Table II and the
    calibration table with precision and recall at the fixed confidence ``cuts``, over results
    files or runs in memory. One run given alone (not in a list) is compared as ``[run]``, never
    as the characters of its name; any iterable of runs is read once. No run, a file given twice
    (or a copy of one, or a run in memory given twice), no precision or one outside (0, 100] is a
    ParameterError: each run counts once in the tables. ``frames`` scores a slice of each run's frames only, as :func:`evaluate`."""
    precisions, cuts, recall_at = check_precisions(precisions), check_cuts(cuts), check_recall_at(recall_at)
    frames = check_frames(frames)
    runs = run_list(runs, (LocalizeRun, Results))
    check_once([run.path if isinstance(run, LocalizeRun) else None if isinstance(run, Results)
                else results_file(run, "runs") for run in runs])
    check_held_once([run.results if isinstance(run, LocalizeRun) else run for run in runs  # a written run's too:
                     if isinstance(run, (Results, LocalizeRun))])  # given beside its results, it is one run
    evaluations = [evaluate(run, truth, cuts, recall_at, frames=frames) for run in runs]
    return comparison(evaluations, truth, precisions=precisions, global_thresholds=global_thresholds)

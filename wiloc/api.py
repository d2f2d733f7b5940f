"""The four verbs as plain Python functions returning data: describe, localize, evaluate, compare.

The CLI and the demo call these; so can a notebook. Nothing here prints. Long steps report through
``progress(stage, done, total)``, where ``stage`` names the step ("describe day_left", ...).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from wiloc import __version__
from wiloc.cache import Cache
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT, check_exclude_recent
from wiloc.describing import (DescribeReport, check_sampling, check_topic, describe_sources, import_matrix,
                              import_to_file, is_stream)
from wiloc.descriptors.external import recorded_metric
from wiloc.differences import candidate_blocks, run_differences
from wiloc.distances import consecutive
from wiloc.errors import ParameterError, UsageError, WilocError
from wiloc.groundtruth import Truth, TruthSource
from wiloc.fabmap.evidence import FabMapEvidence, evidence_rows
from wiloc.labels import short_names
from wiloc.methods.base import Decisions, MapContext
from wiloc.methods.registry import make_method
from wiloc.metrics import (RANKED_KS, PRCurve, Summary, correct_matches, decided_confidence, global_threshold,
                           precision_at_thresholds, summarize)
from wiloc.reliability import (DEFAULT_CUTS, NEW_PLACE_KEYS, Calibration, ReliabilityBins,
                               summarize_calibration, summarize_new_place)
from wiloc.follow import FolderWatch, Skipped, follow
from wiloc.localizer import Localizer
from wiloc.methods.base import Decision
from wiloc.reprs import short_repr
from wiloc.results import RANKING, Results, ResultsStream, make_results, read_results, write_results
from wiloc.training import Training, training_rows
from wiloc.traversals import (Describer, Progress, descriptor_label, descriptor_spec, descriptors_digest,
                              is_matrix_file, open_cluster, stage)
from wiloc.bags import Bag, is_bag
from wiloc.odometry import steps
from wiloc.video import Sampling
from wiloc.workers import keeping_pools
from wiloc.vocabulary import VocabularyParams
from wiloc.vocabulary_build import VocabularyReport, build_vocabulary, vocabulary_path

__all__ = ["Comparison", "Evaluation", "LocalizeRun", "Sampling", "Training", "TruthSource", "compare",
           "describe", "evaluate", "import_descriptors", "localize", "shared_workers"]


# ----------------------------------------------------------------------------------------- describe

def shared_workers() -> AbstractContextManager[None]:
    """Within this block, the describes of several folders share their worker processes (started
    once, stopped on leaving), as one ``wiloc describe`` call over several folders does."""
    return keeping_pools()


def describe(folders: Sequence[Path], descriptor: str = "sad", *,
             descriptor_params: Mapping[str, Any] | None = None, cache: Cache | None = None,
             jobs: int | None = None, progress: Progress | None = None,
             sampling: Sampling | None = None, scheduler: str | None = None,
             topic: str | None = None) -> list[DescribeReport]:
    """Compute (or reuse from the cache) one descriptor per image of each folder, or per frame
    of each video file or ROS bag (of its image ``topic``; None: its only one) that ``sampling``
    picks (default: every frame). ``jobs`` worker processes describe folders, or the workers of
    the Dask ``scheduler`` (an address, or ``local``: a local cluster of ``jobs`` workers); videos
    and bags are decoded and described in this process. The folders' frames form one stream over
    the workers (``wiloc.describing.describe_folders``). Reports come
    in the order of ``folders``."""
    spec = descriptor_spec(descriptor, descriptor_params)
    cache = cache or Cache()
    check_sampling([Path(folder) for folder in folders], sampling)
    check_topic([Path(folder) for folder in folders], topic)
    cluster = open_cluster(scheduler, jobs)
    return describe_sources([Path(folder) for folder in folders], spec, cache, jobs=jobs, sampling=sampling,
                            progress=[stage(progress, f"describe {Path(folder).name}") for folder in folders],
                            cluster=cluster, topic=topic)


def import_descriptors(path: Path, *, metric: str | None = None, names: Path | None = None,
                       cache: Cache | None = None, out: Path | None = None, prefix: str = "") -> DescribeReport:
    """Bring external descriptors (NetVLAD, ...) into the cache: an N x D matrix file, hloc's
    ``global-feats-*.h5``, or (with ``out``) a folder of per-image ``.npy`` vectors. With ``out``
    they are written first to that wiloc descriptor file, which records names and metric, so that
    ``localize OUT.h5 --map MAP.h5`` needs neither again; ``prefix`` keeps the frames whose names
    begin with it (hloc's ``db/``, ``query/``). ``metric``: default the file's recorded one, else l1."""
    source = Path(path)
    metric = metric or recorded_metric(source) or "l1"
    if out is not None:
        return import_to_file(source, Path(out), cache or Cache(), names, metric, prefix)
    if source.is_dir():
        raise ParameterError("out", f"{source}: a folder of .npy files is imported into a descriptor file; "
                                    "give one to write (FILE.h5)")
    if prefix:
        raise ParameterError("prefix", "keeps part of a file written to a descriptor file; give that file too")
    return import_matrix(source, cache or Cache(), names, metric)


def vocabulary(folders: Sequence[Path], params: Mapping[str, Any] | None = None, *, cache: Cache | None = None,
               progress: Progress | None = None) -> VocabularyReport:
    """Build (or reuse from the cache) the visual vocabulary of the images in ``folders``: local
    features clustered into words, for the ``bow`` descriptor and FAB-MAP (docs/fabmap.md)."""
    return build_vocabulary([Path(f) for f in folders], cache or Cache(), VocabularyParams.create(params),
                            progress=stage(progress, "vocabulary"))


def vocabulary_file(vocabulary: str | Path, cache: Cache | None = None) -> Path:
    """A vocabulary's file: ``vocabulary`` is the file, or the key of a vocabulary in the cache."""
    path = Path(vocabulary).expanduser()
    if path.is_file():
        return path
    in_cache = vocabulary_path(cache or Cache(), str(vocabulary))
    if str(vocabulary).isalnum() and in_cache.is_file():
        return in_cache
    raise WilocError(None, f"{str(vocabulary)!r} is neither a vocabulary file nor the key of one in the cache",
                     parameter="vocabulary")


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


def results_name(query: Path, method: str, descriptor: str, metric: str | None = None) -> str:
    """The default results file name of one query traversal (folder, matrix file, whose
    ``metric`` then names it, video file or ROS bag), descriptor and method:
    ``day_left-sad-online.csv``; a video's or bag file's suffix stays in its name
    (``day_left-mp4-sad-online.csv``), so that its run and a folder's of the same name never share a file."""
    label = descriptor_label(query, descriptor, metric).replace(":", "-")
    name = query.name if not query.is_file() else \
        f"{query.stem}-{query.suffix.lstrip('.').lower()}" if is_stream(query) else query.stem
    return f"{name}-{label}-{method}.csv"


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
    algo = make_method(method, method_params)
    R = check_exclude_recent(exclude_recent)
    sequence = reference is None
    bags = _odometry_bags(query, reference, odometry_topic, odometry, map_odometry)
    algo.check_inputs(sequence=sequence, training=training is not None, odometry=odometry is not None or bags[0],
                      map_odometry=map_odometry is not None or bags[1])
    check_sampling([Path(source) for source in (query, reference) if source is not None], sampling)
    pair = (training.query, training.reference) if training else ()
    check_topic([Path(source) for source in (query, reference, *pair) if source is not None], topic)
    describer = Describer(descriptor, dict(descriptor_params or {}), cache or Cache(), metric=metric, jobs=jobs,
                          progress=progress, sampling=sampling, cluster=open_cluster(scheduler, jobs), topic=topic)
    query = Path(query)
    q = describer.entry(query, query_names_file)
    r = q if sequence else describer.entry(Path(reference), ref_names_file)
    if not sequence and len(r.names) < 2:
        raise WilocError(reference, f"the map has {len(r.names)} frame(s); it needs at least 2")
    if not sequence and "map_self" in algo.needs and len(r.names) <= R + 1:
        raise WilocError(reference, f"the map has {len(r.names)} frames: with exclude_recent={R} no two "
                                    "map frames are far enough apart to learn different-place differences")
    problem = algo.query_problem(len(q.names), sequence, R)
    if problem is not None:
        raise WilocError(query, problem)
    kind = algo.row_kind(describer.descriptor)
    source = run_differences(q, r, describer.cache, R, describer.runner, progress=stage(progress, "map differences"))
    if kind == "log_ratio":  # FAB-MAP's evidence from bag-of-words descriptors
        evidence = FabMapEvidence.of(describer.spec, algo.params)
        if not sequence:
            evidence.add_places(r.data)
        rows = evidence_rows(evidence, q.data, sequence, R)
    else:
        rows = candidate_blocks(source.rows, sequence, R)
    context = MapContext(
        sequence=sequence, exclude_recent=R, n_map=0 if sequence else len(r.names), rows=kind,
        natural_max=r.natural_max, map_self=source.map_self,
        arclength=_bag_arclength(reference, odometry_topic, r.names) if bags[1] else _map_arclength(map_odometry, r.names),
        map_summary=source.map_summary, neighbours=None if sequence else lambda: consecutive(r.data, r.metric, r.scale),
        training=(lambda: training_rows(training, describer, R)) if training else None)
    algo.start(context)
    decisions = algo.run(rows, len(q.names),
                         odometry=steps(_bag_arclength(query, odometry_topic, q.names)) if bags[0]
                         else _query_steps(odometry, q.names),
                         progress=stage(progress, f"{method} {query.name}"))
    meta = _run_meta(method, describer, query, q.metric, reference, R, training)
    meta.update(query_digest=descriptors_digest(q.names, q.data),
                map_digest="" if sequence else descriptors_digest(r.names, r.data))
    if any(is_stream(Path(source)) for source in (query, reference) if source is not None):
        meta["sampling"] = asdict(sampling or Sampling())
    if topic is not None:
        meta["topic"] = topic
    if odometry_topic is not None:
        meta["odometry_topic"] = odometry_topic
    if kind == "log_ratio":  # FAB-MAP's training data: the vocabulary's images
        meta.update(rows="fabmap", fabmap_training=evidence.training_folders)
    # what holds for every result of a described query's descriptor (bow: too few words per image)
    doubts = [] if is_matrix_file(query) else describer.spec.kind.doubts(describer.spec.params)
    results = make_results(decisions, query_names=q.names, ref_names=r.names, meta=meta)
    replaced = write_results(Path(out), results) if out is not None else False
    return LocalizeRun(query=query, reference=Path(reference) if reference else query, method=method,
                       decisions=decisions, results=results, path=None if out is None else Path(out),
                       seconds=time.perf_counter() - started, skipped=describer.skipped, replaced=replaced,
                       warnings=doubts, notes=describer.notes)


def _run_meta(method: str, describer: Describer, query: Path, metric: str, reference: Path | None,
              exclude_recent: int, training: Training | None) -> dict[str, Any]:
    """What a results header says about a run besides the method's parameters."""
    meta = {"method": method, "descriptor": describer.label(query), "descriptor_params": dict(describer.params),
            "metric": metric, "mode": "sequence" if reference is None else "map", "query": str(Path(query).resolve()),
            "map": str(Path(reference).resolve()) if reference else "", "exclude_recent": exclude_recent,
            "wiloc": __version__}
    if training:
        meta.update(train_query=str(training.query), train_map=str(training.reference))
    return meta


@dataclass
class FollowRun:
    """A followed query folder: iterate it for each decision (or frame left out) as frames arrive.

    Opening it resumes a results file the same settings wrote before: the frames it lists are
    decided again, in its order, and must give the same rows (so later decisions are the ones an
    uninterrupted run makes); ``resumed`` counts them.
    """

    query: Path
    localizer: Localizer
    stream: ResultsStream
    idle: float | None
    poll: float
    resumed: int = 0

    @property
    def path(self) -> Path:
        return self.stream.path

    def __iter__(self) -> Iterator[Decision | Skipped]:
        watch = FolderWatch(self.query, done=self.stream.rows["frame"].tolist())
        try:
            for event in follow(self.localizer, watch, idle=self.idle, poll=self.poll):
                if isinstance(event, Decision):
                    self.stream.append(event)
                yield event
        finally:
            self.stream.close()


def follow_folder(query: Path, *, reference: Path | None = None, descriptor: str = "sad",
                  descriptor_params: Mapping[str, Any] | None = None, method: str = "online",
                  method_params: Mapping[str, Any] | None = None, exclude_recent: int = DEFAULT_EXCLUDE_RECENT,
                  training: Training | None = None, map_odometry: Path | None = None, out: Path | None = None,
                  cache: Cache | None = None, jobs: int | None = None, idle: float | None = None,
                  poll: float = 0.1) -> FollowRun:
    """Follow a folder that is still being filled: each frame decided as it arrives, its row
    appended to the results file at once (see :class:`FollowRun`). Ends after ``idle`` seconds
    without a new frame (None: when interrupted)."""
    query = Path(query)
    localizer = Localizer(reference, descriptor=descriptor, descriptor_params=descriptor_params, method=method,
                          exclude_recent=exclude_recent, training=training, map_odometry=map_odometry,
                          cache=cache, jobs=jobs, **dict(method_params or {}))
    meta = {**_run_meta(method, localizer.describer, query, localizer.metric, reference, localizer.exclude_recent,
                        training),
            "params": localizer.method.header(),
            "reference_frames": [] if reference is None else localizer.map_names}
    path = Path(out) if out else Path.cwd() / results_name(query, method, descriptor)
    ranked = (RANKING,) if localizer.method.ranks else ()
    stream = ResultsStream(path, meta, (*localizer.method.columns, *ranked), resume=True)
    names = stream.rows["frame"].tolist()
    for name, line in zip(names, stream.written_lines()):
        decision = localizer.observe(query / name)
        if stream.line(decision) != line:
            stream.close()
            raise WilocError(None, f"{path}: frame '{name}' decided again differs from its row: the map, the "
                                   "frames or the settings changed; give another file to start anew", parameter="out")
    return FollowRun(query=query, localizer=localizer, stream=stream, idle=idle, poll=poll, resumed=len(names))


def _map_arclength(map_odometry: Path | None, names: list[str]) -> np.ndarray | None:
    """The map's arc length per frame from its odometry CSV, when given."""
    from wiloc.odometry import read_odometry
    return read_odometry(map_odometry).arclength(names) if map_odometry else None


def _odometry_bags(query: Path, reference: Path | None, odometry_topic: str | None, odometry: Path | None,
                   map_odometry: Path | None) -> tuple[bool, bool]:
    """Whether the query's and the map's odometry come from their bags' ``odometry_topic``:
    for those that are ROS bags, when it is given. A UsageError when no traversal is a bag, or
    when a bag's odometry is also given as a CSV."""
    if odometry_topic is None:
        return False, False
    from_bag = tuple(source is not None and is_bag(Path(source)) for source in (query, reference))
    if not any(from_bag):
        raise ParameterError("odometry_topic", "applies to ROS bags only; neither the query nor the map is one")
    for used, csv, parameter in zip(from_bag, (odometry, map_odometry), ("odometry", "map_odometry")):
        if used and csv is not None:
            raise ParameterError(parameter, "give the odometry of a ROS bag once: as its CSV or by odometry_topic")
    return from_bag


def _bag_arclength(bag: Path, topic: str, names: list[str]) -> np.ndarray:
    """The distance travelled along a bag's odometry topic up to each frame of ``names``."""
    with Bag(Path(bag)) as opened:
        return opened.arclength(topic, names)


def _query_steps(odometry: Path | None, names: list[str]) -> np.ndarray | None:
    """The query's travelled distance per frame from its odometry CSV, when given."""
    from wiloc.odometry import read_odometry, steps
    return steps(read_odometry(odometry).arclength(names)) if odometry else None


# ----------------------------------------------------------------------------------------- evaluate

@short_repr
@dataclass
class Evaluation:
    """One run's results scored against ground truth; ``confidence`` is NaN for undecided frames.
    ``path`` is the results file (None for a run evaluated in memory). ``new_place`` is the
    calibration of the run's P(new place) against the frames without a true match, for methods
    that give one (None for the others)."""

    path: Path | None
    results: Results
    truth: Truth
    correct: np.ndarray
    summary: Summary
    confidence: np.ndarray
    calibration: Calibration
    new_place: Calibration | None = None

    @property
    def name(self) -> str:
        """The results file's name, or for a run in memory its query traversal and method."""
        return self.path.name if self.path else f"{Path(str(self.results.meta.get('query', ''))).name}-{self.method}"

    @property
    def traversal(self) -> str:
        return Path(str(self.results.meta.get("query") or self.name)).name

    @property
    def method(self) -> str:
        return self.results.method

    @property
    def curve(self) -> PRCurve:
        return self.summary.curve

    def calibration_row(self) -> dict[str, float | int]:
        """The calibration as a flat table row, then P(new place)'s under keys ``new_place_*``
        (:meth:`Calibration.row`) for a run that gives it."""
        extra = self.new_place.row(NEW_PLACE_KEYS) if self.new_place is not None else {}
        return {**self.calibration.row(), **extra}

    def calibration_dict(self) -> dict[str, Any]:
        """The calibration for --json, with P(new place)'s under ``new_place`` for a run that
        gives it (absent for the others)."""
        extra = {"new_place": self.new_place.as_dict()} if self.new_place is not None else {}
        return {**self.calibration.as_dict(), **extra}


Run = Path | str | LocalizeRun | Results


def evaluate(run: Run, truth: TruthSource, cuts: Sequence[float] = DEFAULT_CUTS,
             recall_at: Sequence[int] = RANKED_KS) -> Evaluation:
    """Precision-recall metrics and calibration (with precision and recall at fixed confidence
    ``cuts``) of one run against ground truth, and of its P(new place) where the run gives one:
    a results file, or a run in memory. Recall@N for each N of ``recall_at`` when the run ranks
    the map."""
    if isinstance(run, LocalizeRun):
        path, results = run.path, run.results
    elif isinstance(run, Results):
        path, results = None, run
    else:
        path = Path(run)
        results = read_results(path)
    query_names = results.frames["frame"].tolist()
    sequence = results.meta.get("mode") == "sequence"
    ref_names = results.reference_frames or query_names
    loaded = truth.load(query_names, ref_names, str(results.meta.get("query", "")), sequence,
                        int(results.meta.get("exclude_recent", 0) or 0), str(results.meta.get("map") or ""))
    match = results.match_index
    summary = summarize(match, results.confidence, loaded, results.ranking, recall_at)
    correct = correct_matches(match, loaded)
    confidence = decided_confidence(match, results.confidence)
    calibration = summarize_calibration(confidence, correct, summary.with_true_match, cuts)
    p_new = results.new_place
    new_place = None if p_new is None else summarize_new_place(p_new, loaded.has_match(), cuts)
    return Evaluation(path=path, results=results, truth=loaded, correct=correct, summary=summary,
                      confidence=confidence, calibration=calibration, new_place=new_place)


# ------------------------------------------------------------------------------------------ compare

@short_repr
@dataclass
class Comparison:
    """Methods x traversals side by side: the paper's Table I, Table II and the calibration table.

    ``labels[i]`` names the method of ``evaluations[i]`` in the tables: the method, with the
    descriptor when several are compared, and with the results file's name (and as many of its
    folders as tell two files of one name apart) when one method holds the same traversal more
    than once (say, two parameter settings). ``traversals[i]`` names its query traversal (see
    :func:`traversal_labels`). ``cut_table`` has one row per run: ECE, Brier
    score, mean confidence, share correct and precision@c, recall@c, accepted@c per cut c, and
    the same of P(new place) under ``new_place_*`` keys where a run gives it (NaN for the others).
    """

    evaluations: list[Evaluation]
    labels: list[str]
    traversals: list[str]
    table1: pd.DataFrame
    table2: pd.DataFrame
    cut_table: pd.DataFrame
    ground_truth: str = ""  # the ground truth in words, e.g. "aligned by name, +-2 frames"


def traversal_labels(evaluations: Sequence[Evaluation]) -> list[str]:
    """Each run's query traversal: its folder name, or as many trailing parts of its path as keep
    apart traversals of one name from different folders (say, two datasets' ``winter``)."""
    return short_names([str(e.results.meta.get("query") or e.name) for e in evaluations])


def method_labels(evaluations: Sequence[Evaluation]) -> list[str]:
    """One distinct table label per (method, traversal) run; see :class:`Comparison`."""
    with_descriptor = len({e.results.meta.get("descriptor") for e in evaluations}) > 1
    bases = [f"{e.method}/{e.results.meta.get('descriptor')}" if with_descriptor else e.method
             for e in evaluations]
    pairs = list(zip(bases, traversal_labels(evaluations)))
    files = [str(Path(name).with_suffix("")) if e.path else name  # as many folders as tell the files apart
             for name, e in zip(short_names([e.path or e.name for e in evaluations]), evaluations)]
    return [f"{pair[0]} [{file}]" if pairs.count(pair) > 1 else pair[0] for pair, file in zip(pairs, files)]


#: Table I's metrics per (method, traversal), as Summary names them, followed by Recall@N
#: (``recall_at_N``) for runs whose results rank the map (``Summary.as_dict`` leaves it out for the others).
TABLE1_KEYS = ("recall_at_100", "recall_at_99", "recall_at_90", "auc", "recall_at_1", "frames")


def compare(runs: Sequence[Run], truth: TruthSource, *, precisions: Sequence[float] = (100.0, 99.0),
            global_thresholds: bool = True, cuts: Sequence[float] = DEFAULT_CUTS,
            recall_at: Sequence[int] = RANKED_KS) -> Comparison:
    """Table I (recall at 100/99/90 % precision per traversal and method), Table II and the
    calibration table with precision and recall at the fixed confidence ``cuts``, over results
    files or runs in memory. A file given twice, or a precision outside (0, 100], is a
    ParameterError: each run counts once in the tables."""
    bad = [p for p in precisions if not 0.0 < float(p) <= 100.0]
    if bad:
        raise ParameterError("precisions", f"{bad[0]:g} is not a percentage in (0, 100]")
    seen: dict[Path, Path] = {}
    for run in runs:
        path = run.path if isinstance(run, LocalizeRun) else None if isinstance(run, Results) else Path(run)
        if path is not None and seen.setdefault(path.resolve(), path) is not path:
            raise ParameterError("runs", f"{path} is given twice (as {seen[path.resolve()]}); each run counts once")
    evaluations = [evaluate(run, truth, cuts, recall_at) for run in runs]
    labels = method_labels(evaluations)
    traversals = traversal_labels(evaluations)
    rows = []
    for label, traversal, e in zip(labels, traversals, evaluations):
        s = e.summary.as_dict()
        ranked = {key: value for key, value in s.items() if key.startswith("recall_at_") and key not in TABLE1_KEYS}
        rows.append({"method": label, "traversal": traversal, **{key: s[key] for key in TABLE1_KEYS}, **ranked})
    table1 = pd.DataFrame(rows)
    rows2 = []
    if global_thresholds:
        by_method: dict[str, list[tuple[str, Evaluation]]] = {}
        for label, traversal, e in zip(labels, traversals, evaluations):
            by_method.setdefault(label, []).append((traversal, e))
        for method, group in by_method.items():
            inputs = [(e.confidence, e.correct, e.summary.with_true_match) for _, e in group]
            for target in precisions:
                threshold, recalls = global_threshold(inputs, float(target) / 100.0)
                worst = int(np.argmin(recalls)) if len(recalls) else -1
                for i, ((traversal, _), recall) in enumerate(zip(group, recalls)):
                    rows2.append({"method": method, "precision": float(target), "threshold": threshold,
                                  "traversal": traversal, "recall": recall, "worst": i == worst})
    table2 = pd.DataFrame(rows2, columns=["method", "precision", "threshold", "traversal", "recall", "worst"])
    cut_table = pd.DataFrame([{"method": label, "traversal": traversal, **e.calibration_row()}
                              for label, traversal, e in zip(labels, traversals, evaluations)])
    return Comparison(evaluations=evaluations, labels=labels, traversals=traversals, table1=table1,
                      table2=table2, cut_table=cut_table, ground_truth=truth.describe())


def run_names(evaluations: Sequence[Evaluation]) -> list[str]:
    """One distinct "method traversal" name per run, as the tables label it (for plot legends)."""
    return [f"{label} {traversal}"
            for label, traversal in zip(method_labels(evaluations), traversal_labels(evaluations))]


def run_subject(evaluations: Sequence[Evaluation], truth: TruthSource) -> str:
    """What a figure of these runs shows, for its title: the dataset (the query folders' parent
    folder), the descriptor and the ground truth with its tolerance, e.g.
    ``gardens-point-walking, sad, aligned by name, +-2 frames``."""
    datasets = dict.fromkeys(Path(str(e.results.meta.get("query", ""))).parent.name or "?" for e in evaluations)
    descriptors = dict.fromkeys(str(e.results.meta.get("descriptor", "?")) for e in evaluations)
    return f"{' + '.join(datasets)}, {' + '.join(descriptors)}, {truth.describe()}"


def threshold_marks(comparison: Comparison) -> dict[str, list[tuple[float, float]]]:
    """Table II's global threshold per method label: (target precision in %, threshold)."""
    marks: dict[str, list[tuple[float, float]]] = {}
    for (method, target), group in comparison.table2.groupby(["method", "precision"], sort=False):
        marks.setdefault(str(method), []).append((float(target), float(group["threshold"].iloc[0])))
    return marks


def threshold_series(comparison: Comparison, points: int = 201) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Precision against normalised threshold per method and traversal (the paper's Figure 5)."""
    grid = np.linspace(0.0, 1.0, points)
    return {name: (grid, precision_at_thresholds(e.confidence, e.correct, grid))
            for name, e in zip(run_names(comparison.evaluations), comparison.evaluations)}


def pr_series(comparison: Comparison) -> dict[str, PRCurve]:
    """The precision-recall curve of each method and traversal, labelled as in the tables."""
    return {name: e.curve for name, e in zip(run_names(comparison.evaluations), comparison.evaluations)}


def reliability_series(evaluations: Sequence[Evaluation]) -> dict[str, ReliabilityBins]:
    """The reliability bins of each run, labelled as in the tables (for the reliability diagram)."""
    return {name: e.calibration.bins for name, e in zip(run_names(evaluations), evaluations)}


def new_place_series(evaluations: Sequence[Evaluation]) -> dict[str, ReliabilityBins]:
    """The reliability bins of P(new place) of each run that gives it and has a frame without a
    true match (else there is nothing for P(new place) to find), labelled as in the tables."""
    return {name: e.new_place.bins for name, e in zip(run_names(evaluations), evaluations)
            if e.new_place is not None and not e.truth.has_match().all()}

"""The four verbs as plain Python functions returning data: describe, localize, evaluate, compare.

The CLI and the demo call these; so can a notebook. Nothing here prints. Long steps report through
``progress(stage, done, total)``, where ``stage`` names the step ("describe day_left", ...).
"""
from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any

import numpy as np
import pandas as pd

from wiloc import __version__
from wiloc.cache import Cache, Entry
from wiloc.describing import DescribeReport, describe_folder, import_matrix
from wiloc.descriptors.registry import DescriptorSpec, get_descriptor
from wiloc.differences import DifferenceMatrix, candidate_rows, difference_matrix
from wiloc.errors import UsageError, WilocError
from wiloc.groundtruth import Truth, load_truth, restrict_sequence
from wiloc.methods.base import Decisions
from wiloc.metrics import (PRCurve, Summary, correct_matches, decided_confidence, global_threshold,
                           precision_at_thresholds, summarize)
from wiloc.reliability import DEFAULT_CUTS, Calibration, ReliabilityBins, summarize_calibration
from wiloc.results import Results, read_results, write_results

Progress = Callable[[str, int, int], None]
METHODS = ("online", "threshold", "trained", "catgraph")


def _stage(progress: Progress | None, label: str) -> Callable[[int, int], None] | None:
    """A per-step ``progress(done, total)`` callback that tags the step's label."""
    if progress is None:
        return None
    return lambda done, total: progress(label, done, total)


# ----------------------------------------------------------------------------------------- describe

def _spec(descriptor: str, descriptor_params: Mapping[str, Any] | None) -> DescriptorSpec:
    """The descriptor's spec; an unknown name or parameter is a usage error naming the choices."""
    try:
        return get_descriptor(descriptor, **dict(descriptor_params or {}))
    except ValueError as exc:
        raise UsageError("--descriptor", str(exc)) from None


def describe(folders: Sequence[Path], descriptor: str = "sad", *,
             descriptor_params: Mapping[str, Any] | None = None, cache: Cache | None = None,
             jobs: int | None = None, progress: Progress | None = None) -> list[DescribeReport]:
    """Compute (or reuse from the cache) one descriptor per image of each folder."""
    spec = _spec(descriptor, descriptor_params)
    cache = cache or Cache()
    return [describe_folder(Path(folder), spec, cache, jobs=jobs,
                            progress=_stage(progress, f"describe {Path(folder).name}"))
            for folder in folders]


def import_descriptors(path: Path, *, metric: str, names: Path | None = None,
                       cache: Cache | None = None) -> DescribeReport:
    """Bring an external N x D descriptor matrix (NetVLAD, ...) into the cache."""
    return import_matrix(Path(path), cache or Cache(), names, metric)


# ----------------------------------------------------------------------------------------- localize

@dataclass(frozen=True)
class Training:
    """A labelled traversal pair for the ``trained`` comparator."""

    query: Path
    reference: Path
    truth: "TruthSource"


@dataclass(frozen=True)
class TruthSource:
    """Which ground truth to use: a form (SPEC.md section 7) and its files and tolerances.

    ``path`` and ``ref_path`` may contain ``{query}``, replaced by the query folder's name, so that
    several query traversals can each find their own file.
    """

    kind: str = "aligned"
    path: str | None = None
    ref_path: str | None = None
    tolerance: int = 0
    radius: float | None = None
    by: str = "name"
    variable: str | None = None  # matrix form, .mat files holding several arrays: which one

    def load(self, query_names: list[str], ref_names: list[str], query_folder: str,
             sequence: bool, exclude_recent: int) -> Truth:
        """The truth matrix over these frames (sequence mode: earlier frames outside +-R only)."""
        name = Path(query_folder).name
        path = Path(self.path.format(query=name)) if self.path else None
        ref_path = Path(self.ref_path.format(query=name)) if self.ref_path else None
        truth = load_truth(self.kind, path, query_names=query_names, ref_names=ref_names,
                           tolerance=self.tolerance, radius=self.radius, ref_path=ref_path,
                           by=self.by, variable=self.variable)
        return restrict_sequence(truth, exclude_recent) if sequence else truth


@dataclass
class LocalizeRun:
    """One query traversal localized: the decisions, where they were written, and the timing."""

    query: Path
    reference: Path
    method: str
    decisions: Decisions
    results: Results
    path: Path
    seconds: float
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (image path, why it was left out)


def _entry(source: Path, descriptor: str, descriptor_params: Mapping[str, Any], metric: str | None,
           cache: Cache, jobs: int | None, progress: Progress | None, skipped: list[tuple[str, str]],
           names: Path | None = None) -> Entry:
    """Descriptors of a folder (computed on demand) or of an imported matrix file (``names``: its
    frame names, one per line, for .npy matrices).

    Frames that could not be described are appended to ``skipped`` as (path, reason).
    """
    source = Path(source)
    if source.is_file():
        if metric is None:
            raise UsageError(source, "a descriptor matrix file needs --metric")
        return import_matrix(source, cache, names, metric).entry
    spec = _spec(descriptor, descriptor_params)
    report = describe_folder(source, spec, cache, jobs=jobs, progress=_stage(progress, f"describe {source.name}"))
    skipped.extend((str(source / name), reason) for name, reason in report.failed)
    entry = report.entry
    if len(entry.names) == 0:
        raise WilocError(source, "no usable frames (every image failed to load)")
    if entry.data.dtype.kind == "f" and not np.all(np.isfinite(entry.data)):
        bad = entry.names[int(np.flatnonzero(~np.all(np.isfinite(entry.data), axis=1))[0])]
        raise WilocError(source, f"descriptor of frame '{bad}' holds NaN or infinite values")
    return entry


def _banded_rows(matrix: DifferenceMatrix, exclude_recent: int) -> Iterator[np.ndarray]:
    """Reference-against-reference rows with each frame's own +-R neighbourhood excluded."""
    for k, row in enumerate(matrix.iter_rows()):
        row[max(0, k - exclude_recent):k + exclude_recent + 1] = np.inf
        yield row


def _largest(matrix: DifferenceMatrix, block_rows: int = 1024) -> float:
    """The largest finite difference in a matrix, read block by block."""
    largest = 0.0
    for start in range(0, matrix.shape[0], block_rows):
        block = matrix.rows(start, min(start + block_rows, matrix.shape[0]))
        finite = block[np.isfinite(block)]
        largest = max(largest, float(finite.max()) if finite.size else 0.0)
    return largest


def _run_method(method: str, matrix: DifferenceMatrix, self_matrix: Callable[[], DifferenceMatrix], *,
                sequence: bool, exclude_recent: int, params: dict[str, Any], natural_max: float | None,
                training: Callable[[], tuple[Any, Any]] | None, steps: tuple[Any, Any],
                progress: Callable[[int, int], None] | None) -> Decisions:
    """Dispatch to one method with the rows it needs (the map's self-differences only on demand)."""
    n = matrix.shape[0]
    rows = candidate_rows(matrix, sequence, exclude_recent)
    if method == "online":
        from wiloc.methods.online import localize_online
        init_rows = None if sequence else _banded_rows(self_matrix(), exclude_recent)
        return localize_online(rows, n, sequence=sequence, init_rows=init_rows, progress=progress, **params)
    if method == "threshold":
        from wiloc.methods.threshold import localize_threshold
        # Without a natural maximum the map's own largest difference fixes the scale, so that one
        # normalised threshold means the same raw threshold for every query against this map.
        normaliser = natural_max if natural_max is not None else _largest(self_matrix())
        return localize_threshold(rows, n, normaliser=normaliser or None, **params)
    if method == "trained":
        from wiloc.methods.trained import localize_trained, train_model
        assert training is not None
        train_rows, labels = training()
        model_params = {k: v for k, v in params.items() if k in ("bins", "smoothing")}
        return localize_trained(rows, n, train_model(train_rows, labels, **model_params))
    if method == "catgraph":
        from wiloc.methods.catgraph import localize_catgraph
        ref_arclength, query_steps = steps
        return localize_catgraph(rows, self_matrix(), n,
                                 ref_arclength=ref_arclength, query_steps=query_steps,
                                 exclude_recent=exclude_recent, progress=progress, **params)
    raise AssertionError(f"unhandled method {method}")  # localize() checks the name first


def results_name(query: Path, method: str) -> str:
    """The default results file name of one query traversal (folder or matrix file) and method."""
    return f"{query.stem if query.is_file() else query.name}-{method}.csv"


def default_exclude_recent() -> int:
    """R, the recent-frame window (chosen by measurement, see docs/algorithm.md)."""
    from wiloc.methods.online import DEFAULT_EXCLUDE_RECENT
    return int(DEFAULT_EXCLUDE_RECENT)


def localize(query: Path, *, reference: Path | None = None, descriptor: str = "sad",
             descriptor_params: Mapping[str, Any] | None = None, metric: str | None = None,
             method: str = "online", method_params: Mapping[str, Any] | None = None,
             exclude_recent: int | None = None, training: Training | None = None,
             query_odometry: Path | None = None, ref_odometry: Path | None = None,
             query_names_file: Path | None = None, ref_names_file: Path | None = None,
             out: Path | None = None, cache: Cache | None = None, jobs: int | None = None,
             progress: Progress | None = None) -> LocalizeRun:
    """Localize every frame of ``query`` (against ``reference``, or within itself) and write results.

    ``query`` and ``reference`` are image folders, or descriptor matrix files (with ``metric`` and,
    for .npy, optional ``*_names_file``).
    """
    if method not in METHODS:
        raise UsageError("--method", f"unknown method '{method}' (choose from {', '.join(METHODS)})")
    if method == "trained" and training is None:
        raise UsageError(None, "--method trained needs --train-query, --train-map and --train-gt")
    if method == "catgraph" and reference is None:
        raise UsageError(None, "--method catgraph needs --map (a reference trajectory)")
    started = time.perf_counter()
    cache = cache or Cache()
    params = dict(method_params or {})
    dparams = dict(descriptor_params or {})
    R = default_exclude_recent() if exclude_recent is None else int(exclude_recent)
    if R < 0:
        raise UsageError("--exclude-recent", f"must be >= 0, got {R}")
    sequence = reference is None
    query = Path(query)
    skipped: list[tuple[str, str]] = []
    q = _entry(query, descriptor, dparams, metric, cache, jobs, progress, skipped, query_names_file)
    r = q if sequence else _entry(Path(reference), descriptor, dparams, metric, cache, jobs, progress,
                                  skipped, ref_names_file)
    if not sequence and len(r.names) < 2:
        raise WilocError(reference, f"the map has {len(r.names)} frame(s); it needs at least 2")
    if not sequence and method in ("online", "catgraph") and len(r.names) <= R + 1:
        raise WilocError(reference, f"the map has {len(r.names)} frames: with --exclude-recent {R} no two "
                                    "map frames are far enough apart to learn different-place differences")
    if sequence and method == "online":
        from wiloc.methods.online import DEFAULT_INIT
        init = int(params.get("init", DEFAULT_INIT))
        if init < 1:
            raise UsageError(None, f"--init must be >= 1, got {init}")
        if len(q.names) <= init + R:
            raise WilocError(query, f"has {len(q.names)} frames, too few for --init {init} "
                                    f"with --exclude-recent {R}")
    matrix = difference_matrix(q, r, cache, progress=_stage(progress, "differences"))

    @functools.cache
    def self_matrix() -> DifferenceMatrix:
        return matrix if sequence else difference_matrix(r, r, cache, progress=_stage(progress, "map differences"))

    def training_data() -> tuple[Any, Any]:
        assert training is not None
        tq = _entry(training.query, descriptor, dparams, metric, cache, jobs, progress, skipped)
        tr = _entry(training.reference, descriptor, dparams, metric, cache, jobs, progress, skipped)
        tmatrix = difference_matrix(tq, tr, cache, progress=_stage(progress, "training differences"))
        truth = training.truth.load(tq.names, tr.names, str(training.query), False, R)
        return list(candidate_rows(tmatrix, False, R)), truth.matrix

    steps = _motion(query_odometry, ref_odometry, q.names, r.names) if method == "catgraph" else (None, None)
    decisions = _run_method(method, matrix, self_matrix, sequence=sequence, exclude_recent=R,
                            params=params, natural_max=getattr(r, "natural_max", None),
                            training=training_data if training else None, steps=steps,
                            progress=_stage(progress, f"{method} {query.name}"))
    meta = {"method": method, "descriptor": descriptor if not query.is_file() else f"external:{q.metric}",
            "descriptor_params": dparams, "metric": q.metric, "mode": "sequence" if sequence else "map",
            "query": str(query.resolve()), "map": str(Path(reference).resolve()) if reference else "",
            "exclude_recent": R, "wiloc": __version__}
    if training:
        meta.update(train_query=str(training.query), train_map=str(training.reference))
    path = Path(out) if out else Path.cwd() / results_name(query, method)
    results = write_results(path, decisions, query_names=q.names, ref_names=r.names,
                            meta=meta)
    return LocalizeRun(query=query, reference=Path(reference) if reference else query, method=method,
                       decisions=decisions, results=results, path=path,
                       seconds=time.perf_counter() - started, skipped=skipped)


def _motion(query_odometry: Path | None, ref_odometry: Path | None, query_names: list[str],
            ref_names: list[str]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Reference arc length per node and query step per frame from odometry CSVs, when given."""
    from wiloc.odometry import read_odometry, steps
    ref = read_odometry(ref_odometry).arclength(ref_names) if ref_odometry else None
    query = steps(read_odometry(query_odometry).arclength(query_names)) if query_odometry else None
    return ref, query


# ----------------------------------------------------------------------------------------- evaluate

@dataclass
class Evaluation:
    """One results file scored against ground truth; ``confidence`` is NaN for undecided frames."""

    path: Path
    results: Results
    truth: Truth
    correct: np.ndarray
    summary: Summary
    confidence: np.ndarray
    calibration: Calibration

    @property
    def traversal(self) -> str:
        return Path(str(self.results.meta.get("query", self.path.stem))).name

    @property
    def method(self) -> str:
        return self.results.method

    @property
    def curve(self) -> PRCurve:
        return self.summary.curve


def evaluate(path: Path, truth: TruthSource, cuts: Sequence[float] = DEFAULT_CUTS) -> Evaluation:
    """Precision-recall metrics and calibration (with precision and recall at fixed confidence
    ``cuts``) of one results file against ground truth."""
    results = read_results(Path(path))
    query_names = results.frames["frame"].tolist()
    sequence = results.meta.get("mode") == "sequence"
    ref_names = results.reference_frames or query_names
    loaded = truth.load(query_names, ref_names, str(results.meta.get("query", "")), sequence,
                        int(results.meta.get("exclude_recent", 0) or 0))
    match = results.match_index
    summary = summarize(match, results.confidence, loaded)
    correct = correct_matches(match, loaded)
    confidence = decided_confidence(match, results.confidence)
    calibration = summarize_calibration(confidence, correct, summary.with_true_match, cuts)
    return Evaluation(path=Path(path), results=results, truth=loaded, correct=correct, summary=summary,
                      confidence=confidence, calibration=calibration)


# ------------------------------------------------------------------------------------------ compare

@dataclass
class Comparison:
    """Methods x traversals side by side: the paper's Table I, Table II and the calibration table.

    ``labels[i]`` names the method of ``evaluations[i]`` in the tables: the method, with the
    descriptor when several are compared, and with the results file's name when one method holds
    the same traversal more than once (say, two parameter settings). ``traversals[i]`` names its
    query traversal (see :func:`traversal_labels`). ``cut_table`` has one row per run: ECE, Brier
    score, mean confidence, share correct and precision@c, recall@c, accepted@c per cut c.
    """

    evaluations: list[Evaluation]
    labels: list[str]
    traversals: list[str]
    table1: pd.DataFrame
    table2: pd.DataFrame
    cut_table: pd.DataFrame


def traversal_labels(evaluations: Sequence[Evaluation]) -> list[str]:
    """Each run's query traversal: its folder name, or as many trailing parts of its path as keep
    apart traversals of one name from different folders (say, two datasets' ``winter``)."""
    paths = [PurePath(str(e.results.meta.get("query") or e.path.stem)) for e in evaluations]
    labels = [p.name for p in paths]
    for depth in range(2, max((len(p.parts) for p in paths), default=0) + 1):
        clashing = {label for label in labels
                    if len({p for p, other in zip(paths, labels) if other == label}) > 1}
        if not clashing:
            break
        labels = [str(PurePath(*p.parts[-depth:])) if label in clashing else label
                  for p, label in zip(paths, labels)]
    return labels


def method_labels(evaluations: Sequence[Evaluation]) -> list[str]:
    """One distinct table label per (method, traversal) run; see :class:`Comparison`."""
    with_descriptor = len({e.results.meta.get("descriptor") for e in evaluations}) > 1
    bases = [f"{e.method}/{e.results.meta.get('descriptor')}" if with_descriptor else e.method
             for e in evaluations]
    pairs = list(zip(bases, traversal_labels(evaluations)))
    repeated = {base for base, traversal in pairs if pairs.count((base, traversal)) > 1}
    return [f"{base} [{e.path.stem}]" if base in repeated else base for base, e in zip(bases, evaluations)]


def compare(paths: Sequence[Path], truth: TruthSource, *, precisions: Sequence[float] = (100.0, 99.0),
            global_thresholds: bool = True, cuts: Sequence[float] = DEFAULT_CUTS) -> Comparison:
    """Table I (recall at 100/99/90 % precision per traversal and method), Table II and the
    calibration table with precision and recall at the fixed confidence ``cuts``."""
    evaluations = [evaluate(Path(p), truth, cuts) for p in paths]
    labels = method_labels(evaluations)
    traversals = traversal_labels(evaluations)
    rows = []
    for label, traversal, e in zip(labels, traversals, evaluations):
        s = e.summary.as_dict()
        rows.append({"method": label, "traversal": traversal,
                     "recall@100": s["recall_at_100"], "recall@99": s["recall_at_99"],
                     "recall@90": s["recall_at_90"], "auc": s["auc"], "R@1": s["recall_at_1"],
                     "frames": s["frames"]})
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
    cut_table = pd.DataFrame([{"method": label, "traversal": traversal, **e.calibration.row()}
                              for label, traversal, e in zip(labels, traversals, evaluations)])
    return Comparison(evaluations=evaluations, labels=labels, traversals=traversals, table1=table1,
                      table2=table2, cut_table=cut_table)


def run_names(evaluations: Sequence[Evaluation]) -> list[str]:
    """One distinct "method traversal" name per run, as the tables label it (for plot legends)."""
    return [f"{label} {traversal}"
            for label, traversal in zip(method_labels(evaluations), traversal_labels(evaluations))]


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

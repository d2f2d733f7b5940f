"""Runs scored and compared: one run's metrics against ground truth, and the tables of several
side by side (the paper's Table I, Table II and the calibration table), with the series the
figures plot (precision against threshold, precision-recall, reliability), labelled as the tables.

``wiloc.api.evaluate`` and ``wiloc.api.compare`` read the runs (results files or runs in memory)
and call :func:`score` and :func:`comparison` (``DEFAULT_CUTS`` and ``RANKED_KS`` are their defaults).
"""
from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from wiloc.candidates import RANKED
from wiloc.errors import ParameterError, WilocError
from wiloc.evaluation.groundtruth import Truth, TruthMismatch
from wiloc.evaluation.metrics import (RANKED_KS, PRCurve, Summary, correct_matches, decided_confidence, global_threshold,
                                      precision_at_thresholds, summarize)
from wiloc.evaluation.reliability import (DEFAULT_CUTS, NEW_PLACE_KEYS, Calibration, ReliabilityBins,
                                          summarize_calibration, summarize_new_place)
from wiloc.evaluation.results import Results
from wiloc.evaluation.run_frames import (UNNAMED_QUERY, check_frames, frame_rows, frames_text, in_run_order,
                                          of_frames, out_of_order, run_name)
from wiloc.evaluation.truth_source import TruthSource
from wiloc.labels import short_names
from wiloc.reprs import short_repr


@short_repr
@dataclass
class Evaluation:
    """One run's results scored against ground truth; ``confidence`` is NaN for undecided frames.
    ``path`` is the results file (None for a run evaluated in memory). ``new_place`` is the
    calibration of the run's P(new place) against the frames without a true match, for methods
    that give one (None for the others). ``frame_slice`` is the slice of the run's frames scored
    (``20:``; every measure is over those frames) and ``run_frames`` how many frames the run has;
    both None when every frame is scored."""

    path: Path | None
    results: Results
    truth: Truth
    correct: np.ndarray
    summary: Summary
    confidence: np.ndarray
    calibration: Calibration
    new_place: Calibration | None = None
    frame_slice: str | None = None
    run_frames: int | None = None

    @property
    def truth_doubts(self) -> list[str]:
        """What makes its scores doubtful, one line each: its ground truth's name-matching
        warnings, and a ground truth that gives no frame a true match (every recall 0)."""
        return [*self.truth.warnings] + ([] if self.truth.has_match().any() else [
            "no frame has a true match under this ground truth, so every recall is 0, at a cut undefined "
            "(check --gt, --tolerance, --radius)"])

    @property
    def name(self) -> str:
        """The results file's name, or for a run in memory its query traversal and method
        (``day_left-online``; ``unnamed-online`` for a streaming run whose query was not given)."""
        return self.path.name if self.path else f"{self.traversal}-{self.method}"

    @property
    def first_frame(self) -> int:
        """The run's number (from 0, in the run's order) of the first frame scored: 0 for a whole
        run, a slice's start (``100:300``: 100; ``-5:`` of 200: 195), so that a figure or a page
        of a slice numbers its frames as the run does."""
        frames = check_frames(self.frame_slice)
        return 0 if frames is None or self.run_frames is None else frames.indices(self.run_frames)[0]

    @property
    def traversal(self) -> str:
        """The query traversal's folder name; for a run that records none, its results file's
        name, or :data:`UNNAMED_QUERY` for a run in memory (``Localizer.results()`` without
        ``query``): runs of one such stream share a column of Table I whatever their method."""
        query = self.results.header.query
        return Path(query).name if query else self.path.name if self.path else UNNAMED_QUERY

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


def score(path: Path | None, results: Results, truth: TruthSource, cuts: Sequence[float] = DEFAULT_CUTS,
          recall_at: Sequence[int] = RANKED_KS, frames: slice | str | None = None) -> Evaluation:
    """Precision-recall metrics and calibration (with precision and recall at fixed confidence
    ``cuts``) of one run's ``results`` (read from ``path``, None for a run in memory) against
    ground truth, and of its P(new place) where the run gives one. Recall@N for each N of
    ``recall_at`` when the run ranks the map. ``frames`` (a slice or its text, ``20:``;
    :func:`check_frames`) scores only those of the run's frames, counted in the run's order,
    against the ground truth of the whole run cut to them."""
    if not isinstance(truth, TruthSource):
        raise ParameterError("truth", f"a TruthSource (api.TruthSource(kind='aligned', tolerance=2), ...), "
                                      f"got {type(truth).__name__}")
    cuts, recall_at, frames = check_cuts(cuts), check_recall_at(recall_at), check_frames(frames)
    ordered = in_run_order(path, results)
    moved = out_of_order(path, results, ordered)
    results = ordered
    query_names = results.frames["frame"].tolist()
    header = results.header
    ref_names = results.reference_frames or query_names
    if not query_names:  # every ground truth would say it does not fit
        raise WilocError(path, "holds no rows: there is no frame to score") if path else \
            WilocError(None, f"the run {run_name(path, header)} holds no frames: there is no frame to score")
    try:
        loaded = truth.load(query_names, ref_names, header.query, header.sequence, header.exclude_recent, header.map,
                            left_out=header.reference_left_out or ())
    except TruthMismatch as exc:
        raise exc.of_run(run_name(path, header)) from None
    if moved:
        loaded.warnings.append(moved)
    if frames is not None:
        results, loaded = of_frames(results, loaded, frame_rows(frames, len(query_names), run_name(path, header)))
    match = results.match_index
    summary = summarize(match, results.confidence, loaded, results.ranking, recall_at)
    correct = correct_matches(match, loaded)
    confidence = decided_confidence(match, results.confidence)
    calibration = summarize_calibration(confidence, correct, summary.with_true_match, cuts)
    p_new = results.new_place
    new_place = None if p_new is None else summarize_new_place(p_new, loaded.has_match(), cuts)
    return Evaluation(path=path, results=results, truth=loaded, correct=correct, summary=summary,
                      confidence=confidence, calibration=calibration, new_place=new_place,
                      frame_slice=None if frames is None else frames_text(frames),
                      run_frames=None if frames is None else len(query_names))


@short_repr
@dataclass
class Comparison:
    """Methods x traversals side by side: the paper's Table I, Table II and the calibration table.

    ``labels[i]`` names the method of ``evaluations[i]`` in the tables: the method, with the
    descriptor when several are compared, and when one method holds the same traversal more than
    once (say, two parameter settings) with its results file's folder (as many folders as tell
    them apart), or where one folder holds a traversal twice with the file's name (see
    :func:`method_labels`). ``traversals[i]`` names its query traversal (see
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
    return short_names([e.results.header.query or e.traversal for e in evaluations])


def method_labels(evaluations: Sequence[Evaluation]) -> list[str]:
    """One distinct table label per (method, traversal) run; see :class:`Comparison`. A method
    that holds a traversal more than once is told apart by its results files' folders when each
    folder holds each traversal once (``online [runs/a]``, ``online [runs/b]``): every run of the
    method is, so that the runs of one folder (one setting, written by one ``localize --out``)
    share Table II's threshold; else each repeated run by its file."""
    with_descriptor = len({e.results.header.descriptor for e in evaluations}) > 1
    bases = [f"{e.method}/{e.results.header.descriptor}" if with_descriptor else e.method
             for e in evaluations]
    pairs = list(zip(bases, traversal_labels(evaluations)))
    files = [str(Path(name).with_suffix("")) if e.path else name  # as many folders as tell the files apart
             for name, e in zip(short_names([e.path or e.name for e in evaluations]), evaluations)]
    labels = [f"{pair[0]} [{file}]" if pairs.count(pair) > 1 else pair[0] for pair, file in zip(pairs, files)]
    for base in {base for base, traversal in pairs if pairs.count((base, traversal)) > 1}:
        runs = [i for i, pair in enumerate(pairs) if pair[0] == base]
        folders = [evaluations[i].path and evaluations[i].path.absolute().parent for i in runs]
        if None not in folders and len(set(zip(folders, (pairs[i][1] for i in runs)))) == len(runs):
            for i, folder in zip(runs, short_names(folders)):
                labels[i] = f"{base} [{folder}]"
    return labels


#: Table I's metrics per (method, traversal), as Summary names them, followed by Recall@N
#: (``recall_at_N``) for runs whose results rank the map (``Summary.as_dict`` leaves it out for the others).
TABLE1_KEYS = ("recall_at_100", "recall_at_99", "recall_at_90", "auc", "recall_at_1", "frames")


def _listed(values: Iterable[Any], parameter: str, wanted: str) -> list[Any]:
    """``values`` as a list (any iterable read once); text, or anything that is no iterable, is a
    ParameterError naming ``parameter`` that says what is ``wanted``."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
        raise ParameterError(parameter, f"{wanted}, got {type(values).__name__}")
    return list(values)


def check_precisions(precisions: Iterable[float]) -> list[float]:
    """Table II's target precisions, percentages in (0, 100], at least one, each once in the order
    given, as a list (any iterable read once): a ParameterError names the first that is not."""
    precisions = _listed(precisions, "precisions", "percentages such as 100,99")
    if not precisions:
        raise ParameterError("precisions", "no target precision; give percentages such as 100,99")
    bad = [p for p in precisions if isinstance(p, bool) or not isinstance(p, Real) or not 0.0 < p <= 100.0]
    if bad:
        shown = f"{bad[0]:g}" if isinstance(bad[0], Real) else repr(bad[0])
        raise ParameterError("precisions", f"{shown} is not a percentage in (0, 100]")
    return list(dict.fromkeys(float(p) for p in precisions))


def check_cuts(cuts: Iterable[float]) -> list[float]:
    """The fixed confidence cuts, numbers in [0, 1] as ``--cuts`` takes them, each once and in
    increasing order, as a list (any iterable read once; -0 is 0): a ParameterError names the first
    that is not, where the calibration's ValueError said it with a traceback."""
    cuts = _listed(cuts, "cuts", "confidences in [0, 1]")
    bad = [c for c in cuts if isinstance(c, bool) or not isinstance(c, Real) or not 0.0 <= c <= 1.0]
    if bad:
        raise ParameterError("cuts", f"confidences in [0, 1], got {bad[0]!r}")
    return sorted({float(c) + 0.0 for c in cuts})


def check_recall_at(recall_at: Iterable[int]) -> list[int]:
    """Recall@N's N, whole numbers from 1 to RANKED as ``--recall-at`` takes them, as a list (any
    iterable read once): a results file keeps that many candidates per frame, so Recall@50 would
    be Recall@20's number, and N of 90, 99 or 100 would take the key of recall at that precision.
    A ParameterError names the first that is not."""
    recall_at = _listed(recall_at, "recall_at", f"whole numbers from 1 to {RANKED}")
    bad = [n for n in recall_at if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer))
           or not 1 <= n <= RANKED]
    if bad:
        raise ParameterError("recall_at", f"whole numbers from 1 to {RANKED} (results keep the {RANKED} best "
                                          f"candidates), got {bad[0]!r}")
    return sorted({int(n) for n in recall_at})


def check_once(paths: Sequence[Path | None]) -> None:
    """Each run counts once in the tables: a ParameterError names a results file given twice (by
    any path to it) or one identical to another (a copy: the same run). None stands for a run in
    memory. A path seen before is found by its key, never by identity: a localize run written
    to a file, given twice, gives the same Path object twice."""
    seen: dict[Path, Path] = {}
    contents: dict[str, Path] = {}
    lines: dict[str, Path] = {}
    for path in paths:
        if path is None:
            continue
        if (first := seen.get(path.resolve())) is not None:
            spelling = "" if str(first) == str(path) else f" (as {first})"
            raise ParameterError("runs", f"{path} is given twice{spelling}; each run counts once")
        seen[path.resolve()] = path
        if path.is_file():
            text = path.read_bytes().removeprefix(b"\xef\xbb\xbf")  # a byte-order mark is read past
            if (first := contents.get(digest := hashlib.sha256(text).hexdigest())) is not None:
                raise ParameterError("runs", f"{path} holds the same run as {first} (identical contents); "
                                             "each run counts once")
            contents[digest] = path
            if (first := lines.get(digest := _lines_digest(text))) is not None:
                raise ParameterError("runs", f"{path} holds the same run as {first} (the same lines, in another "
                                             "order or with other line endings); each run counts once")
            lines[digest] = path


def check_held_once(held: Sequence[Results]) -> None:
    """Each run counts once in the tables: a ParameterError names a run in memory given twice
    (the same results object, as it is or inside its localize run)."""
    seen: set[int] = set()
    for results in held:
        if id(results) in seen:
            raise ParameterError("runs", f"the run of {results.header.method} on {results.header.query} in memory is "
                                         "given twice; each run counts once")
        seen.add(id(results))


def _lines_digest(text: bytes) -> str:
    """A digest of a file's non-blank lines whatever their order and line endings: a results file
    sorted in a spreadsheet, or saved again with CRLF line endings, is still the run it was."""
    kept = sorted(line.rstrip() for line in text.splitlines() if line.strip())
    return hashlib.sha256(b"\n".join(kept)).hexdigest()


def comparison(evaluations: Sequence[Evaluation], truth: TruthSource, *,
               precisions: Sequence[float] = (100.0, 99.0), global_thresholds: bool = True) -> Comparison:
    """Table I (recall at 100/99/90 % precision per traversal and method), Table II (per method,
    the one threshold reaching each of ``precisions`` over all its traversals, when
    ``global_thresholds``, True or False: text such as "no" would be true) and the calibration
    table of scored runs."""
    if not isinstance(global_thresholds, (bool, np.bool_)):
        raise ParameterError("global_thresholds", f"True or False, got {type(global_thresholds).__name__}")
    evaluations = list(evaluations)
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
                worst = int(np.argmin(recalls)) if len(recalls) and np.isfinite(threshold) else -1  # none: no worst
                for i, ((traversal, _), recall) in enumerate(zip(group, recalls)):
                    rows2.append({"method": method, "precision": float(target), "threshold": threshold,
                                  "traversal": traversal, "recall": recall, "worst": i == worst})
    table2 = pd.DataFrame(rows2, columns=["method", "precision", "threshold", "traversal", "recall", "worst"])
    cut_table = pd.DataFrame([{"method": label, "traversal": traversal, **e.calibration_row()}
                              for label, traversal, e in zip(labels, traversals, evaluations)])
    return Comparison(evaluations=evaluations, labels=labels, traversals=traversals, table1=table1,
                      table2=table2, cut_table=cut_table, ground_truth=truth.describe())


class RunName(str):
    """A run's name "method traversal" as legends show it, holding its two parts: either may
    contain spaces (a folder ``day left``, a results file in ``my runs/``), so that the figures
    read the method and traversal from here rather than split the text."""

    method: str
    traversal: str

    def __new__(cls, method: str, traversal: str) -> RunName:
        name = super().__new__(cls, f"{method} {traversal}")
        name.method, name.traversal = method, traversal
        return name

    def __getnewargs__(self) -> tuple[str, str]:  # type: ignore[override]  # copied and pickled whole
        return self.method, self.traversal


def run_names(evaluations: Sequence[Evaluation]) -> list[RunName]:
    """One distinct "method traversal" name per run, as the tables label it (for plot legends)."""
    return [RunName(label, traversal)
            for label, traversal in zip(method_labels(evaluations), traversal_labels(evaluations))]


def run_subject(evaluations: Sequence[Evaluation], truth: TruthSource | None) -> str:
    """What a figure of these runs shows, for its title: the dataset (the query folders' parent
    folder; the map's for a run that records no query, as a live run in memory), the descriptor
    and the ground truth with its tolerance (none for a figure no ground truth enters), e.g.
    ``gardens-point-walking, sad, aligned by name, +-2 frames``."""
    datasets = dict.fromkeys(Path(e.results.header.query or e.results.header.map).parent.name or "?"
                             for e in evaluations)
    descriptors = dict.fromkeys("?" if e.results.header.descriptor is None else e.results.header.descriptor
                                for e in evaluations)
    return ", ".join([" + ".join(datasets), " + ".join(descriptors), *([truth.describe()] if truth else [])])


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

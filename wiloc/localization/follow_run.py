"""A query folder followed as a camera fills it: each frame decided as it arrives by a
``Localizer``, its row appended to a results file at once; a results file the same settings
wrote before is resumed (``wiloc.api.follow_folder``)."""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from numbers import Real
from pathlib import Path
from typing import Any

from wiloc.cache.store import Cache
from wiloc.decisions import Decision
from wiloc.description.traversals import descriptor_spec
from wiloc.errors import FrameError, ParameterError, WilocError, parameter_values
from wiloc.evaluation.results import RANKING, ResultsStream
from wiloc.evaluation.results_header import ResultsHeader, read_header
from wiloc.evaluation.results_lock import lock_results, unlock_results
from wiloc.localization.follow import FolderWatch, Skipped, follow, followed_folder
from wiloc.localization.localizer import Localizer
from wiloc.localization.run_files import results_name
from wiloc.localization.training import Training
from wiloc.methods.registry import make_method


@dataclass
class FollowRun:
    """A followed query folder: iterate it for each decision (or frame left out) as frames arrive.

    Opening it resumes a results file the same settings wrote before: the frames it lists are
    decided again, in its order, and must give the same rows (so later decisions are the ones an
    uninterrupted run makes); ``resumed`` counts them. When the iteration ends (``idle``, Ctrl-C,
    the loop left), the header gets what the run learned by then, as a batch run's of the same
    frames holds it: the model, the learned parameters (catgraph's ``learned_a``) and in sequence
    mode the query's digest (:meth:`ResultsStream.finish`).
    """

    query: Path
    localizer: Localizer
    stream: ResultsStream
    idle: float | None
    poll: float
    resumed: int = 0
    warnings: list[str] = field(default_factory=list)  # what makes the decisions doubtful (a sparse vocabulary)
    lock: int | None = None  # the descriptor holding the results file's lock (:func:`lock_results`)

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
            try:
                if self.localizer.frames:
                    self.stream.finish(self.localizer.results(self.query).header)
            finally:
                self.release()

    def release(self) -> None:
        """Let go of the results file's lock (iterating to the end does so)."""
        if self.lock is not None:
            unlock_results(self.path, self.lock)
            self.lock = None


def follow_folder(query: Path, *, reference: Path | None = None, descriptor: str = "sad",
                  descriptor_params: Mapping[str, Any] | None = None, method: str = "online",
                  method_params: Mapping[str, Any] | None = None, exclude_recent: int | None = None,
                  training: Training | None = None, out: Path | None = None,
                  cache: Cache | None = None, jobs: int | None = None, idle: float | None = None,
                  poll: float = 0.1) -> FollowRun:
    """Follow a folder that is still being filled: each frame decided as it arrives, its row
    appended to the results file at once (see :class:`FollowRun`). Ends after ``idle`` seconds
    without a new frame (None: when interrupted). A query that is no folder is refused before
    the map is described or the results file written, as is an ``out`` that can take no file (a
    folder); so is a results file another run holds
    (CacheBusyError): the run holds it until iterated to its end (or :meth:`FollowRun.release`).
    ``poll`` is the seconds between looks at the folder: a whole JPEG or PNG is decided about half
    of it after it arrives (see :class:`~wiloc.localization.follow.FolderWatch`); a shorter one
    costs more CPU while frames arrive, each look then listing the folder (30 ms for 35,000 files).
    An ``idle`` or ``poll`` that is no finite number of seconds (``poll`` above 0) is a ParameterError."""
    if idle is not None:
        _check_seconds(idle, "idle", "a finite number of seconds >= 0, or None to follow until interrupted")
    _check_seconds(poll, "poll", "a finite number of seconds > 0", above_zero=True)
    query = followed_folder(query)
    path = Path(out) if out else Path.cwd() / results_name(query, method, descriptor)
    lock = lock_results(path)  # a path that can take no file refused, as a batch run's
    try:
        return _opened(query, path, lock, reference=reference, descriptor=descriptor,
                       descriptor_params=descriptor_params, method=method, method_params=method_params,
                       exclude_recent=exclude_recent, training=training, cache=cache, jobs=jobs, idle=idle,
                       poll=poll)
    except BaseException:
        unlock_results(path, lock)
        raise


def _check_seconds(value: object, parameter: str, takes: str, above_zero: bool = False) -> None:
    """A ParameterError naming ``parameter`` when ``value`` is no finite number of seconds (>= 0,
    or > 0 when ``above_zero``): a NaN ``idle`` never ended the run, a negative ``poll`` was
    ``time.sleep``'s traceback."""
    if isinstance(value, bool) or not isinstance(value, Real) or not 0 <= value < float("inf") \
            or (above_zero and value == 0):
        raise ParameterError(parameter, f"must be {takes}, got {value!r}")


def _opened(query: Path, path: Path, lock: int, *, reference: Path | None, descriptor: str,
            descriptor_params: Mapping[str, Any] | None, method: str, method_params: Mapping[str, Any] | None,
            exclude_recent: int | None, training: Training | None, cache: Cache | None,
            jobs: int | None, idle: float | None, poll: float) -> FollowRun:
    """:func:`follow_folder` once the results file ``path`` is locked (``lock``). A followed
    folder gives no odometry: a parameter read with it alone is refused, not ignored."""
    params = parameter_values(method_params, "method_params")
    make_method(method, params).check_inputs(sequence=reference is None, training=training is not None,
                                             given=tuple(params))  # before the map is described
    localizer = Localizer(reference, descriptor=descriptor, descriptor_params=descriptor_params, method=method,
                          exclude_recent=exclude_recent, training=training, cache=cache, jobs=jobs, **params)
    ranked = (RANKING,) if localizer.method.ranks else ()
    stream = ResultsStream(path, _as_written(path, localizer.header(query), localizer.describer.descriptor),
                           (*localizer.method.columns, *ranked), resume=True, learned=localizer.method.facts().keys())
    names = stream.rows["frame"].tolist()
    try:
        _check_columns(path, list(stream.rows.columns), list(stream.columns))
        for name, line in zip(names, stream.written_lines()):
            try:
                decision = localizer.observe(query / name)
            except FrameError as exc:  # removed since (a camera's folder kept as a ring buffer), or damaged
                raise WilocError(None, f"{path}: cannot resume: its frame '{name}', decided again to resume, is "
                                       f"unusable ({exc.problem}); give another file to start anew",
                                 parameter="out") from None
            if stream.line(decision) != line:
                raise WilocError(None, f"{path}: frame '{name}' decided again differs from its row: the map, the "
                                       "frames or the settings changed, or another version of wiloc wrote it; "
                                       "give another file to start anew",
                                 parameter="out")
    except BaseException:  # the stream's descriptor is closed whatever ends the replay (Ctrl-C too)
        stream.close()
        raise
    return FollowRun(query=query, localizer=localizer, stream=stream, idle=idle, poll=poll, resumed=len(names),
                     warnings=localizer.doubts, lock=lock)


def _check_columns(path: Path, found: list[str], written: list[str]) -> None:
    """A WilocError when the results file's columns (``found``) are not those the run writes
    (``written``), in that order: its rows would differ from the lines the run decides again, as
    if the settings had changed, and new rows would go under a column line naming other values."""
    if found == written:
        return
    shown = ", ".join(found), ", ".join(written)
    if sorted(found) == sorted(written):
        problem = "its columns are in another order ({}) than this run writes ({})".format(*shown)
    else:
        odd = [f"{c} missing" for c in written if c not in found] + [f"{c} extra" for c in found if c not in written]
        problem = "its columns ({}) are not those this run writes ({}): ".format(*shown) + ", ".join(odd)
    raise WilocError(None, f"{path}: cannot resume: {problem}; give another file to start anew", parameter="out")


def _as_written(path: Path, header: ResultsHeader, descriptor: str) -> ResultsHeader:
    """The run's ``header`` with the descriptor parameters the file at ``path`` records when they
    resolve to the run's: a file an older wiloc followed recorded those given (and ``sad``'s
    ``crop``), not every one, and is resumed as the same run's."""
    if not path.is_file():
        return header
    try:
        found, _ = read_header(path)
        resolved = descriptor_spec(descriptor, found.descriptor_params).params
    except WilocError:  # no results file, or parameters of another descriptor: the stream refuses it
        return header
    return replace(header, descriptor_params=found.descriptor_params) if resolved == header.descriptor_params else header

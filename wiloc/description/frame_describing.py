"""Each frame of a traversal -> its descriptor record: in this process, then also in worker
processes once the frames left would take longer than starting them; a colour descriptor's frames
decoded and described in batches; a video's or bag's frames as they are decoded. OpenCV's and the
image decoders' own warnings are kept quiet: wiloc reports bad frames itself."""
from __future__ import annotations

import itertools
import os
import queue
import socket
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from wiloc.bow.features import extract_features
from wiloc.cache.entries import FrameRecord
from wiloc.cache.features import FeatureStore
from wiloc.description.workers import UnknownToWorkers, WorkerError, borrowed_pool, can_fork, kept_pool
from wiloc.descriptors.base import ComputeError, library_versions
from wiloc.descriptors.registry import DescriptorSpec
from wiloc.errors import FrameError, ParameterError, WilocError
from wiloc.quiet import decoders_quiet, quiet_always
from wiloc.sources.frames import Fingerprint, fingerprint, jpeg_size, read_colour, read_gray

if TYPE_CHECKING:
    from wiloc.sources.bags import BagFrame
    from wiloc.sources.video import VideoFrame


@dataclass(frozen=True)
class WorkerStart:
    """What starting workers costs: `seconds` of work left above which this process hands frames
    to them, judged after timing `frames` frames of its own (the first is left out: warm-up)."""

    seconds: float
    frames: int


#: Fresh interpreters importing what describing needs: about 0.5 s for 2 (docs/formats.md).
FRESH_START = WorkerStart(seconds=0.5, frames=8)
#: Forked workers (wiloc.description.workers.can_fork): the first result comes back within 10 ms.
FORKED_START = WorkerStart(seconds=0.05, frames=2)
#: Workers kept running from the previous folder (wiloc.description.workers.keeping_pools): nothing to start;
#: two frames timed here give the median that sizes their batches.
KEPT_START = WorkerStart(seconds=0.0, frames=1)
#: Seconds of work per batch sent to a worker (by this process's median frame time; at least one
#: frame, at most MAX_CHUNK): enough that sending and answering cost little even for the fastest
#: descriptor (sad: 4-6 frames), little enough that results stream back (and are journaled)
#: promptly (gist: 1). Batches shrink below it as a folder's frames run out (`_batches`).
CHUNK_SECONDS = 0.008
MAX_CHUNK = 16
#: Frames of a colour descriptor (a network's) decoded and described together: a few network
#: batches (wiloc.descriptors.learned.BATCH), journaled as each set is in.
COLOUR_BATCH = 64
_OPENCV_ERRORS_ONLY = 2  # OpenCV's LOG_LEVEL_ERROR (the same number in every 4.x)

Task = tuple[Path, FrameRecord | None]
#: ``damaged(tag, file)``: told of a local-features file found damaged (so extracted again and
#: replaced) while settling the task tagged ``tag``.
Damaged = Callable[[int, Path], None]



def check_jobs(jobs: int | None) -> int:
    """The worker count: the cores this process may use by default, else an integer, at least 1."""
    if jobs is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)):  # '2' from a config file, 2.0
        raise ParameterError("jobs", f"must be an integer, got {jobs!r}")
    if jobs < 1:
        raise ParameterError("jobs", f"must be at least 1, got {jobs}")
    return jobs



def compute(spec: DescriptorSpec, tasks: Sequence[tuple[int, Task]], jobs: int, features: FeatureStore | None = None,
            damaged: Damaged | None = None) -> Iterator[tuple[int, FrameRecord, bool]]:
    """Settle each tagged task, yielding (tag, record, computed) as results arrive, over `jobs`
    processes. This process computes first; once the frames left would take it longer than
    starting workers (`WorkerStart`, by the median time of its frames after the first), `jobs` - 1
    workers start and take frames from the same queue while this process goes on computing.
    `features`: where the local features of a descriptor computed from them (``bow``) are kept
    and found (:func:`_describe_one`); ``damaged`` is told of each of its files found damaged, in
    this process or a worker, before that task's result is yielded."""
    if spec.colour:
        yield from _compute_colour(spec, tasks, jobs)
        return
    pending = deque(tasks)
    timed: list[float] = []
    with opencv_quiet():
        while pending and not _worth_workers(jobs, timed, len(pending)):
            started = time.perf_counter()
            result = _describe_one_tagged(spec, features, damaged, *pending.popleft())
            timed.append(time.perf_counter() - started)
            yield result
        if pending:
            chunk = min(MAX_CHUNK, max(1, round(CHUNK_SECONDS / statistics.median(timed[1:]))))
            with _opencv_threads(1):
                yield from _compute_with_workers(spec, pending, jobs - 1, chunk, features, damaged)


def _compute_with_workers(spec: DescriptorSpec, pending: deque[tuple[int, Task]], workers: int, chunk: int,
                          features: FeatureStore | None,
                          damaged: Damaged | None) -> Iterator[tuple[int, FrameRecord, bool]]:
    """The pending tagged tasks settled by this process and `workers` worker processes together:
    a helper thread feeds the workers batches from `pending` (`_batches`), two at a time each,
    and queues their results; this process computes from the same deque and yields both, first
    telling ``damaged`` of the damaged features files a worker's batch met."""
    results: queue.Queue = queue.Queue()
    # Forked from this process while it runs no other thread, else fresh interpreters; never the
    # caller's main module (wiloc.description.workers says why not multiprocessing's start methods).
    with borrowed_pool(workers, _init_worker) as pool:
        def drive() -> None:
            try:
                for batch in pool.imap_unordered(partial(_describe_tagged, spec, features),
                                                 _batches(pending, chunk, workers + 1), ahead=2):
                    results.put(batch)
                results.put(None)
            except BaseException as exc:  # raised in this process by the loop below
                results.put(exc)

        driver = threading.Thread(target=drive, name="wiloc-workers", daemon=True)
        driver.start()
        try:
            finished = False
            while not finished:
                item = _take(pending)
                if item is not None:
                    yield _describe_one_tagged(spec, features, damaged, *item)
                while not finished and (item is None or not results.empty()):  # nothing left here: wait
                    answer = results.get()
                    if isinstance(answer, BaseException):
                        raise answer
                    finished = answer is None
                    if not finished:
                        described, met = answer
                        if damaged is not None:
                            for told in met:
                                damaged(*told)
                        yield from described
        except WorkerError as exc:
            pool.kill()
            paths = [path for batch in exc.items for _, (path, _) in batch]
            folder = paths[0].parent if paths else None  # a batch may reach into the next folder
            names = ", ".join(path.name if path.parent == folder else str(path) for path in paths)
            raise WilocError(folder, f"{exc.problem} while describing {names}") from None
        except UnknownToWorkers as exc:
            pool.kill()
            raise WilocError(None, f"'{spec.name}' cannot be described in worker processes, which do not find its "
                                   f"class by name ({exc.problem}), as when the script run (__main__) registers it: "
                                   "describe with jobs 1, or register it in a module the workers can import",
                             parameter="descriptor") from None
        except BaseException:
            pool.kill()  # an interrupted run keeps what was journaled; in-flight work is lost
            raise
        finally:
            # The helper thread ends once every worker has answered or died. Only then may the
            # pipes be closed: closing one the thread waits on (epoll) would leave it waiting forever.
            driver.join()


def _batches(pending: deque[tuple[int, Task]], chunk: int, processes: int) -> Iterator[list[tuple[int, Task]]]:
    """Batches of tasks taken from `pending` as workers ask for them: `chunk` tasks, or fewer as
    the deque empties (a quarter of each process's share of what is left, at least one), so
    that at the end no process waits long for another's last batches."""
    while batch := [task for _ in range(min(chunk, max(1, len(pending) // (4 * processes))))
                    if (task := _take(pending)) is not None]:
        yield batch


def _take(pending: deque[tuple[int, Task]]) -> tuple[int, Task] | None:
    """The next task, or None when there is none left (deques pop atomically across threads)."""
    try:
        return pending.popleft()
    except IndexError:
        return None


@contextmanager
def _opencv_threads(count: int) -> Iterator[None]:
    """OpenCV's own thread count set to `count`, then restored: with several processes
    computing, each one's internal threads only compete for the same cores."""
    previous = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(previous)


def _worth_workers(jobs: int, timed: list[float], left: int) -> bool:
    """Whether `left` frames, at the median of this process's frame times so far, would take
    longer than starting `jobs` - 1 workers (KEPT_START, FORKED_START or FRESH_START)."""
    if jobs > 1 and kept_pool(jobs - 1, _init_worker):
        start = KEPT_START
    else:
        start = FORKED_START if can_fork() else FRESH_START
    if jobs == 1 or len(timed) <= start.frames:
        return False
    return statistics.median(timed[1:]) * left > start.seconds  # not np.median: its first call costs 6 ms


def describe_quietly(spec: DescriptorSpec, libraries: dict[str, str],
                     tasks: Sequence[Task]) -> list[tuple[FrameRecord, bool]]:
    """Each task's (record, computed), OpenCV's own warnings off meanwhile (a Dask worker's batch,
    from the pixels: the cache, local features too, stays the caller's; a colour descriptor's as
    one batch on the worker's cores). A worker whose libraries are not the caller's
    (``libraries``, what the caller's cache keys the rows by) refuses: its rows would be stored
    as the caller's."""
    own = library_versions(libraries)
    if own != libraries:
        theirs = ", ".join(f"{name} {version}" for name, version in own.items())
        ours = ", ".join(f"{name} {version}" for name, version in libraries.items())
        raise WilocError(f"Dask worker on {socket.gethostname()}", f"computes with {theirs} where this process has "
                                                                  f"{ours}; install the same on every worker")
    with opencv_quiet():
        if spec.colour:
            return _describe_colour(spec, tasks, check_jobs(None))
        return [_describe_one(spec, task) for task in tasks]


def _describe_tagged(spec: DescriptorSpec, features: FeatureStore | None, tasks: Sequence[tuple[int, Task]]
                     ) -> tuple[list[tuple[int, FrameRecord, bool]], list[tuple[int, Path]]]:
    """A worker process's batch: each tagged task's (tag, record, computed), and the (tag, file)
    of each damaged features file met, for the parent to report (:func:`_compute_with_workers`).
    (The worker's OpenCV warnings are off for good: :func:`_init_worker`.)"""
    met: list[tuple[int, Path]] = []
    described = [_describe_one_tagged(spec, features, lambda tag, file: met.append((tag, file)), tag, task)
                 for tag, task in tasks]
    return described, met


def _describe_one_tagged(spec: DescriptorSpec, features: FeatureStore | None, damaged: Damaged | None,
                         tag: int, task: Task) -> tuple[int, FrameRecord, bool]:
    """A tagged task's (tag, record, computed) (:func:`_describe_one`), ``damaged`` told of a
    damaged features file with the tag."""
    return (tag, *_describe_one(spec, task, features, None if damaged is None else partial(damaged, tag)))


def _init_worker() -> None:
    """Workers keep OpenCV's and libjpeg's warnings to themselves: wiloc reports bad frames itself.
    (They leave Ctrl-C to the parent, which stops them and keeps what was journaled.)"""
    _opencv_log_level(_OPENCV_ERRORS_ONLY)
    cv2.setNumThreads(1)  # the processes share out the cores already
    quiet_always()


@contextmanager
def opencv_quiet() -> Iterator[None]:
    """OpenCV's own warnings ("PNG input buffer is incomplete") off, then the previous level."""
    previous = _opencv_log_level(_OPENCV_ERRORS_ONLY)
    try:
        yield
    finally:
        _opencv_log_level(previous)


def _opencv_log_level(level: int) -> int:
    """Set OpenCV's log level and return the one before. The wheels moved the call: 4.8 to 4.11
    have ``cv2.setLogLevel`` alone, later ones ``cv2.utils.logging.setLogLevel`` alone."""
    logging = getattr(cv2.utils, "logging", None)
    return (cv2.setLogLevel if logging is None else logging.setLogLevel)(level)


def _read_gray(path: Path, min_size: tuple[int, int] | None) -> np.ndarray:
    """`read_gray`, the decoders quiet (:func:`decoders_quiet`)."""
    with decoders_quiet():
        return read_gray(path, min_size)


def _settle(task: Task, read: Callable[[Path], np.ndarray]
            ) -> tuple[FrameRecord, bool] | tuple[Fingerprint, np.ndarray]:
    """A frame's task up to its descriptor: a finished (record, False) when the stored record
    still holds (its content digest matches) or the file cannot be read or decoded, else its
    fingerprint and the image ``read`` decoded."""
    path, old = task
    try:
        fp = fingerprint(path)
    except OSError as exc:
        return FrameRecord(path.name, -1, -1, "", None, f"cannot read file ({exc.strerror or exc})"), False
    if old is not None and old.digest == fp.digest:
        return replace(old, size=fp.size, mtime_ns=fp.mtime_ns), False
    try:
        return fp, read(path)
    except FrameError as exc:
        return FrameRecord(path.name, fp.size, fp.mtime_ns, fp.digest, None, exc.problem), False


def _describe_one(spec: DescriptorSpec, task: Task, features: FeatureStore | None = None,
                  damaged: Callable[[Path], None] | None = None) -> tuple[FrameRecord, bool]:
    """One frame's record and whether its descriptor was computed (False: reused or failed).
    A frame whose content digest matches its stored record keeps that record's row or failure.
    A descriptor computed from local features (``bow``) is computed from those `features` holds
    for the image's content, which are extracted and kept there when it holds none or its file
    there is damaged (``damaged(file)`` is told: :meth:`FeatureStore.features`)."""
    settled = _settle(task, lambda path: _read_gray(path, spec.min_size))
    if not isinstance(settled[0], Fingerprint):
        return settled  # type: ignore[return-value]
    (path, _), (fp, gray) = task, settled
    if features is None:
        with _failing_on(path.name):
            row = np.asarray(spec.compute(gray), dtype=spec.dtype)
    else:
        found = features.features(fp.digest, lambda: extract_features(gray, **features.setting), damaged)
        row = np.asarray(spec.compute_from_features(found), dtype=spec.dtype)
    width, height = _full_size(path, gray)
    return FrameRecord(path.name, fp.size, fp.mtime_ns, fp.digest, row, "", width, height), True


def describe_frames(spec: DescriptorSpec, video: Fingerprint,
                     frames: Iterator[VideoFrame | BagFrame]) -> Iterator[tuple[FrameRecord, bool]]:
    """Each video (or bag) frame's record and whether it was computed, as it is decoded; a colour
    descriptor's frames COLOUR_BATCH at a time, described together."""
    if not spec.colour:
        for frame in frames:
            yield _describe_frame(spec, video, frame)
        return
    while batch := list(itertools.islice(frames, COLOUR_BATCH)):
        decoded = [frame.gray for frame in batch if frame.gray is not None]
        rows = iter(spec.compute_batch(decoded) if decoded else ())
        for frame in batch:
            yield _describe_frame(spec, video, frame, None if frame.gray is None else next(rows))


def _describe_frame(spec: DescriptorSpec, video: Fingerprint, frame: VideoFrame | BagFrame,
                    row: np.ndarray | None = None) -> tuple[FrameRecord, bool]:
    """One video (or bag) frame's record, with the file's fingerprint and the frame's timestamp,
    and whether its descriptor was computed (False for a frame without pixels); `row`: its
    descriptor when already computed (in a batch)."""
    if frame.gray is None:
        return FrameRecord(frame.name, video.size, video.mtime_ns, video.digest, None, frame.problem), False
    with _failing_on(frame.name):
        row = np.asarray(spec.compute(frame.gray) if row is None else row, dtype=spec.dtype)
    height, width = frame.gray.shape[:2]
    return FrameRecord(frame.name, video.size, video.mtime_ns, video.digest, row, "", width, height,
                       frame.timestamp_ms), True


@contextmanager
def _failing_on(frame: str) -> Iterator[None]:
    """A descriptor's code failing (a plugin's: ComputeError) said of the ``frame`` it failed on."""
    try:
        yield
    except ComputeError as exc:
        raise exc.on(frame) from None


def _describe_colour(spec: DescriptorSpec, tasks: Sequence[Task], threads: int) -> list[tuple[FrameRecord, bool]]:
    """:func:`_describe_one` for a colour descriptor's tasks, as one batch: the images decoded
    in colour on ``threads`` threads (OpenCV's decoders let go of the GIL), then described
    together (``DescriptorSpec.compute_batch``, the network's runtime on ``threads`` threads)."""
    with decoders_quiet(), ThreadPoolExecutor(max(1, threads), thread_name_prefix="wiloc-decode") as pool:
        settled = list(pool.map(lambda task: _settle(task, read_colour), tasks))
    decoded = [i for i, item in enumerate(settled) if isinstance(item[0], Fingerprint)]
    rows = spec.compute_batch([settled[i][1] for i in decoded], threads) if decoded else []
    for i, row in zip(decoded, rows):
        (path, _), (fp, image) = tasks[i], settled[i]
        height, width = image.shape[:2]
        settled[i] = FrameRecord(path.name, fp.size, fp.mtime_ns, fp.digest, np.asarray(row, dtype=spec.dtype), "",
                                 width, height), True
    return settled


def _compute_colour(spec: DescriptorSpec, tasks: Sequence[tuple[int, Task]],
                    jobs: int) -> Iterator[tuple[int, FrameRecord, bool]]:
    """A colour descriptor's tagged tasks settled in this process, COLOUR_BATCH frames at a
    time, each batch decoded and described on `jobs` threads: a network's runtime shares out
    the cores itself, and worker processes would each load the model and compete for them."""
    with opencv_quiet():
        for start in range(0, len(tasks), COLOUR_BATCH):
            batch = tasks[start:start + COLOUR_BATCH]
            for (tag, _), result in zip(batch, _describe_colour(spec, [task for _, task in batch], jobs)):
                yield (tag, *result)


def _full_size(path: Path, gray: np.ndarray) -> tuple[int, int]:
    """(width, height) of the image as shown: a JPEG's header size (its decode may be reduced),
    its sides swapped where the decode turned it upright (an EXIF orientation), else the
    decoded size."""
    head = np.fromfile(path, np.uint8, count=65536)
    is_jpeg = head.size >= 2 and head[0] == 0xFF and head[1] == 0xD8
    height, width = gray.shape[:2]
    full = jpeg_size(head) if is_jpeg else None
    if full is None:
        return width, height
    return full if (full[0] > full[1]) == (width > height) or full[0] == full[1] else (full[1], full[0])

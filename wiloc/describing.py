"""Traversal (folder, video or ROS bag) -> descriptor matrix through the cache.

A folder's unchanged frames are reused (same size and mtime, or else the same content digest);
only new or changed frames are computed, in worker processes. A video's frames are decoded in
order and described in this process. Either way each frame is journaled the moment its result
arrives, so an interrupted run resumes where it stopped. Unreadable frames are reported and left
out, never invented.
"""
from __future__ import annotations

import itertools
import os
import queue
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Container, Generator, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from wiloc.cache import (
    EXTERNAL,
    Cache,
    Entry,
    EntryHeader,
    Journal,
    FrameRecord,
    StoredEntry,
    entry_key,
)
from wiloc.descriptors.external import read_external, write_matrix
from wiloc.descriptors.registry import DescriptorSpec, get_descriptor
from wiloc.errors import FrameError, ParameterError, WilocError
from wiloc.frames import (Fingerprint, Traversal, fingerprint, jpeg_size, list_traversal, natural_key, read_colour,
                          read_gray, text_path)
from wiloc.reprs import short_repr
from wiloc.bags import Bag, bag_fingerprint, is_bag
from wiloc.video import Sampling, Video, VideoFrame, is_video, video_fingerprint
from wiloc.workers import WorkerError, borrowed_pool, can_fork, kept_pool

if TYPE_CHECKING:
    from wiloc.bags import BagFrame
    from wiloc.cluster import Cluster

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class WorkerStart:
    """What starting workers costs: `seconds` of work left above which this process hands frames
    to them, judged after timing `frames` frames of its own (the first is left out: warm-up)."""

    seconds: float
    frames: int


#: Fresh interpreters importing what describing needs: about 0.5 s for 2 (docs/formats.md).
FRESH_START = WorkerStart(seconds=0.5, frames=8)
#: Forked workers (wiloc.workers.can_fork): the first result comes back within 10 ms.
FORKED_START = WorkerStart(seconds=0.05, frames=2)
#: Workers kept running from the previous folder (wiloc.workers.keeping_pools): nothing to start;
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
_Task = tuple[Path, FrameRecord | None]
#: In a worker process: a descriptor open on /dev/null, where its image decoders' stderr goes.
_devnull: int | None = None


@short_repr
@dataclass(frozen=True)
class DescribeReport:
    """What a describe run did: counts, bad and ignored files, image sizes, speed, and the entry.
    For a video (`video` true), `failed` holds at most the frame where decoding stopped early."""

    folder: str
    descriptor: str
    shape: tuple[int, int]
    frames: int
    computed: int
    reused: int
    failed: list[tuple[str, str]]
    ignored: list[str]
    sizes: list[tuple[int, int]]
    seconds: float
    images_per_second: float
    entry: Entry
    repairs: list[str] = field(default_factory=list)  # damage found in the cache entry (Cache.repairs)
    video: bool = False
    notes: list[str] = field(default_factory=list)  # worth saying: which topic of a bag was read


def describe_source(source: Path, spec: DescriptorSpec, cache: Cache, *, jobs: int | None = None,
                    sampling: Sampling | None = None, progress: Progress | None = None,
                    cluster: Cluster | None = None, topic: str | None = None) -> DescribeReport:
    """Describe a traversal: a video file (recognised by its suffix) with `sampling`, a ROS bag's
    image `topic` with `sampling`, else a folder of images with `jobs` worker processes, or on
    `cluster`'s workers."""
    return describe_sources([source], spec, cache, jobs=jobs, sampling=sampling, progress=[progress],
                            cluster=cluster, topic=topic)[0]


def describe_sources(sources: Sequence[Path], spec: DescriptorSpec, cache: Cache, *, jobs: int | None = None,
                     sampling: Sampling | None = None, progress: Sequence[Progress | None] | None = None,
                     cluster: Cluster | None = None, topic: str | None = None) -> list[DescribeReport]:
    """:func:`describe_source` for each of several traversals (``progress``: one callback each),
    the reports in their order: the image folders together (:func:`describe_folders`), then
    each video file and ROS bag (``topic``: the bags' image topic; None: each one's only one),
    which alone ``sampling`` picks frames of (see :func:`check_sampling`)."""
    sources = [Path(source) for source in sources]
    callbacks = list(progress) if progress is not None else [None] * len(sources)
    folders = [(source, callback) for source, callback in zip(sources, callbacks) if not is_stream(source)]
    described = iter(describe_folders([f for f, _ in folders], spec, cache, jobs, [c for _, c in folders], cluster)
                     if folders else [])
    return [describe_video(source, spec, cache, sampling, callback) if is_video(source)
            else describe_bag(source, spec, cache, sampling, topic, callback) if is_bag(source) else next(described)
            for source, callback in zip(sources, callbacks)]


def is_stream(source: Path) -> bool:
    """Whether a traversal is read in order as one stream, sampled: a video file or a ROS bag."""
    return is_video(source) or is_bag(source)


def check_sampling(sources: Sequence[Path], sampling: Sampling | None) -> None:
    """ParameterError when a sampling other than every frame is given and none of ``sources`` is
    a video file or ROS bag: it applies to those only (image folders beside them take every frame)."""
    if sampling is not None and sampling != Sampling() and not any(is_stream(Path(s)) for s in sources):
        raise ParameterError("sampling", f"applies to video files and ROS bags only; {sources[0]} is neither")


def check_topic(sources: Sequence[Path], topic: str | None) -> None:
    """ParameterError when an image topic is given but no traversal is a ROS bag."""
    if topic is not None and not any(is_bag(Path(source)) for source in sources):
        raise ParameterError("topic", "applies to ROS bags only; no traversal given is one")


def describe_folder(folder: Path, spec: DescriptorSpec, cache: Cache, jobs: int | None = None,
                    progress: Progress | None = None, cluster: Cluster | None = None) -> DescribeReport:
    """Describe every image of a traversal folder with `spec`, reusing what the cache holds.

    `jobs` worker processes compute (default: all cores; 1 computes in this process), or the
    workers of a Dask `cluster` (``wiloc.cluster``; this process still journals and writes).
    `progress(done, total)` is called as frames are settled, reused ones first. Holds the
    entry's lock throughout; raises CacheBusyError if another process keeps it too long.
    """
    return describe_folders([folder], spec, cache, jobs, [progress], cluster)[0]


def describe_folders(folders: Sequence[Path], spec: DescriptorSpec, cache: Cache, jobs: int | None = None,
                     progress: Sequence[Progress | None] | None = None,
                     cluster: Cluster | None = None) -> list[DescribeReport]:
    """:func:`describe_folder` for several folders (``progress``: one callback per folder), as
    one stream of frames: the workers go on with the next folder's frames while this process
    writes the entry of the folder whose frames are all in. One folder at a time, they idled
    through each write, and the next folder started with this process timing its frames alone
    (docs/scaling.md). Every folder is listed before any frame is described, so a bad folder
    stops the run before anything is written. Each entry's lock is held from the start of the
    call until the entry is written (taken in key order, so that two runs over the same folders
    never wait on each other crosswise): another process that needs a later folder meanwhile
    waits for it, up to the cache's lock timeout. A folder given twice is described once. On a
    Dask ``cluster`` the folders are described one after the other."""
    started = time.perf_counter()
    jobs = _check_jobs(jobs)
    callbacks = list(progress) if progress is not None else [None] * len(folders)
    runs: dict[str, _Settling] = {}
    keys = []
    for folder, callback in zip(folders, callbacks):
        traversal = list_traversal(folder)
        header = _header(Path(folder), spec, spec.params)
        runs.setdefault(header.key, _Settling(header, callback, traversal))
        keys.append(header.key)
    settling = list(runs.values())
    with ExitStack() as held:
        for run in sorted(settling, key=lambda r: r.header.key):
            run.lock = held.enter_context(ExitStack())
            run.stored, run.repairs = run.lock.enter_context(_locked_entry(cache, run.header))
        for run in settling:
            run.start()
        last = started  # when the last folder was written (at first: when the call started)

        def finish(run: _Settling) -> None:
            """A report's seconds run from the folder's first result, or from the previous folder's
            end when that came first: with the stream the next folder's frames are under way
            while a folder ends, and the first folder counts from the call's start."""
            nonlocal last
            run.finish(cache, last if run.began is None else min(run.began, last))
            last = time.perf_counter()

        for run in settling:
            if not run.tasks:
                finish(run)
        tagged = [(tag, task) for tag, run in enumerate(settling) for task in run.tasks]
        if tagged:
            results = _compute(spec, tagged, jobs) if cluster is None else _on_cluster(cluster, spec, settling)
            _journal(cache, settling, results, finish)
    return [runs[key].report for key in keys]


def _on_cluster(cluster: Cluster, spec: DescriptorSpec,
                runs: Sequence[_Settling]) -> Iterator[tuple[int, FrameRecord, bool]]:
    """Each run's tasks settled on the Dask cluster, one run after the other, tagged by run."""
    for tag, run in enumerate(runs):
        if run.tasks:
            for record, fresh in cluster.in_batches(partial(describe_quietly, spec), run.tasks):
                yield tag, record, fresh


class _Settling:
    """One folder (or video) of a describe run while its frames settle: its stored entry (held
    under its lock), the frames to compute, its journal once a result arrived, and its report
    once its entry is written."""

    def __init__(self, header: EntryHeader, progress: Progress | None, traversal: Traversal | None = None,
                 stored: StoredEntry | None = None) -> None:
        self.header, self.progress, self.traversal = header, progress, traversal
        self.stored = stored if stored is not None else StoredEntry(header)
        self.lock: ExitStack | None = None  # holds the entry's lock, until the entry is written
        self.repairs: list[str] = []  # what reading the entry found damaged (Cache.repairs)
        self.tasks: list[_Task] = []
        self.removed = False
        self.done = 0  # frames settled
        self.total: int | None = None  # frames to settle (None: not known in advance, a video's)
        self.computed = 0
        self.began: float | None = None  # when the first result arrived
        self.journal: Journal | None = None
        self.report: DescribeReport | None = None

    def start(self) -> None:
        """A folder's stored frames compared with the folder: gone ones dropped, changed and new
        ones to settle, the unchanged ones reported settled."""
        traversal, records = self.traversal, self.stored.records
        assert traversal is not None
        names = set(traversal.frame_names)
        removed = [name for name in records if name not in names]
        for name in removed:
            del records[name]
        self.removed = bool(removed)
        self.tasks = _changed(traversal, records)
        self.total = len(traversal.frame_names)
        self.done = self.total - len(self.tasks)
        if self.progress is not None:
            self.progress(self.done, self.total)

    def settle(self, cache: Cache, record: FrameRecord, fresh: bool) -> bool:
        """Journal one frame's result (opening the journal on the first) and add it to the entry;
        whether that was the last frame to settle."""
        if self.journal is None:
            self.journal = cache.open_journal(self.header)
            self.began = time.perf_counter()
        self.journal.append(record)
        self.stored.records[record.name] = record
        self.computed += fresh
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, max(self.done, self.total or 0))
        return self.done == self.total

    def close(self) -> None:
        """The journal closed, if one was opened (what it holds stays until the entry is written)."""
        if self.journal is not None:
            self.journal.close()
            self.journal = None

    def finish(self, cache: Cache, since: float) -> None:
        """A folder's entry written (when anything changed), its lock released, its report made
        with the seconds ``since``."""
        self.close()
        if self.tasks or self.removed or not self.stored.complete:
            entry = cache.write_entry(self.stored, complete=True)
        else:
            entry = self.stored.entry(self.traversal.frame_names if self.traversal else None)
        if self.lock is not None:
            self.lock.close()
        ignored = [p.name for p in self.traversal.ignored] if self.traversal else []
        unusable = self.traversal.unusable if self.traversal else ()
        self.report = _report(self.stored, entry, self.computed, since, ignored=ignored, unusable=unusable,
                              repairs=self.repairs)


def describe_video(path: Path, spec: DescriptorSpec, cache: Cache, sampling: Sampling | None = None,
                   progress: Progress | None = None) -> DescribeReport:
    """Describe the frames of a video that `sampling` picks (default: all), reusing the cache.

    The entry is keyed by the video's path and fingerprint, the descriptor and the sampling.
    Frames are decoded in order and described in this process (worker processes measured
    slower: decoding is sequential and frames would have to be pickled to them). A run killed
    midway resumes, passing over the journaled frames undecoded. When decoding stops before the
    container's frame count, that frame is recorded as failed (its reason names the last good
    frame) and the frames before it are kept. Raises WilocError for a file that is not a
    readable video, before anything is written, or when the sampling picks no frame.
    """
    start = time.perf_counter()
    sampling = sampling or Sampling()
    path = Path(path)
    with _opencv_quiet(), Video(path) as video:
        video_print = video_fingerprint(path)
        params = {**spec.params, "video": video_print.digest, "sampling": asdict(sampling)}
        length = "" if video.frame_count is None else f" (it has {video.frame_count} frames)"
        stored, entry, computed, repairs = _describe_stream(
            cache, _header(path, spec, params), sampling.estimate(video.frame_count, video.rate),
            lambda skip: _describe_frames(spec, video_print, video.frames(sampling, skip=skip, colour=spec.colour)),
            WilocError(path, f"the cut ({sampling.cut}) holds no frame of this video{length}"), progress)
    return _report(stored, entry, computed, start, repairs=repairs, video=True)


def describe_bag(path: Path, spec: DescriptorSpec, cache: Cache, sampling: Sampling | None = None,
                 topic: str | None = None, progress: Progress | None = None) -> DescribeReport:
    """Describe the images of a ROS bag's `topic` (None: its only image topic) that `sampling`
    picks (default: all), reusing the cache, as :func:`describe_video` does a video's frames.

    The entry is keyed by the bag's path and fingerprint, the topic, the descriptor and the
    sampling. A frame whose image cannot be decoded is recorded as failed and left out; the
    report's ``notes`` say which topic was read when the bag chose it. Raises WilocError for a
    bag that cannot be read or has no such image topic, before anything is written, or when the
    sampling picks no frame.
    """
    start = time.perf_counter()
    sampling = sampling or Sampling()
    path = Path(path)
    if spec.colour:
        raise WilocError(path, f"'{spec.name}' descriptors take colour images, and a bag's images are read as gray "
                               "here: describe a folder or video of them instead")
    with _opencv_quiet(), Bag(path) as bag:
        bag.choose(topic)
        bag_print = bag_fingerprint(path)
        params = {**spec.params, "bag": bag_print.digest, "topic": bag.topic, "sampling": asdict(sampling)}
        stored, entry, computed, repairs = _describe_stream(
            cache, _header(path, spec, params), sampling.estimate(bag.count, bag.rate),
            lambda skip: _describe_frames(spec, bag_print, bag.frames(sampling, spec.min_size, skip=skip)),
            WilocError(path, f"the cut ({sampling.cut}) holds no image of topic {bag.topic} (it has {bag.count})"), progress)
    report = _report(stored, entry, computed, start, repairs=repairs)
    return replace(report, notes=[bag.note] if bag.note else [])


def _describe_stream(cache: Cache, header: EntryHeader, total: int | None,
                     described: Callable[[Container[str]], Iterator[tuple[FrameRecord, bool]]],
                     empty: WilocError, progress: Progress | None
                     ) -> tuple[StoredEntry, Entry, int, list[str]]:
    """A stream's entry (a video's or a bag's frames, read in order in this process): reused
    when complete, else the frames ``described(skip)`` yields journaled as they come (those of
    a killed run's journal, named in ``skip``, are passed over) and the entry written; ``empty``
    raised when no frame came. Returns the stored frames, the entry, how many were computed and
    the repairs reading the entry called for. ``total`` estimates the frames (for progress)."""
    with _locked_entry(cache, header) as (stored, repairs):
        if stored.complete:
            return stored, stored.entry(), 0, repairs
        run = _Settling(header, progress, stored=stored)
        run.total, run.done = total, len(stored.records)
        if progress is not None:
            progress(run.done, max(run.done, run.total or 0))
        _journal(cache, [run], ((0, *record) for record in described(stored.records)))
        if not stored.records:
            raise empty
        return stored, cache.write_entry(stored, complete=True), run.computed, repairs


def import_matrix(path: Path, cache: Cache, names_path: Path | None, metric: str) -> DescribeReport:
    """Bring a user's N x D descriptor matrix into the cache as an entry of its own.

    The entry is keyed by the file's resolved path, the metric and the content digests of the
    matrix file and of the names file, so an edited file makes a new entry, never a silent mix.
    """
    start = time.perf_counter()
    sources = [Path(p).resolve() for p in (path, names_path) if p is not None]
    for source in sources:
        if not source.is_file():
            raise WilocError(source, "file does not exist")
        text_path(source)
    prints = [fingerprint(source) for source in sources]
    params = {"metric": metric, "file_digest": prints[0].digest,
              "names": str(sources[1]) if names_path is not None else None,
              "names_digest": prints[1].digest if names_path is not None else None}
    key = entry_key(str(sources[0]), EXTERNAL, params)
    with cache.lock(cache.entry_name(key)):
        stored, repairs = _read_stored(cache, key)
        fresh = stored is None or not stored.complete
        if fresh:
            names, matrix = read_external(sources[0], names_path, metric)
            spec = get_descriptor(EXTERNAL, metric=metric, length=matrix.shape[1],
                                  dtype=matrix.dtype.name)
            header = EntryHeader.create(str(sources[0]), EXTERNAL, params, spec.metric,
                                        spec.scale, spec.natural_max, spec.dtype, spec.length)
            stored = StoredEntry(header, {
                name: FrameRecord(name, prints[0].size, prints[0].mtime_ns, prints[0].digest, row)
                for name, row in zip(names, matrix)})
            entry = cache.write_entry(stored, complete=True)
        else:
            entry = stored.entry()
    seconds = time.perf_counter() - start
    n = len(entry.names)
    return DescribeReport(
        folder=str(sources[0]), descriptor=EXTERNAL, shape=entry.data.shape, frames=n,
        computed=n if fresh else 0, reused=0 if fresh else n, failed=[], ignored=[], sizes=[],
        seconds=seconds, images_per_second=(n if fresh else 0) / seconds, entry=entry, repairs=repairs,
    )


def import_to_file(source: Path, out: Path, cache: Cache, names_path: Path | None, metric: str,
                   prefix: str = "") -> DescribeReport:
    """Write external descriptors (any :func:`read_external` source: a matrix file, hloc's
    global-feats-*.h5, a folder of per-image .npy vectors; ``prefix`` keeps one part of it) to a
    wiloc descriptor file ``out`` that records names and metric, and import that into the cache:
    later commands name ``out`` alone."""
    out = Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ParameterError("out", f"{out}: a descriptor file is HDF5; name it FILE.h5")
    if out.resolve() == Path(source).resolve():
        raise ParameterError("out", f"{out} is the file being imported; name another")
    names, matrix = read_external(Path(source), names_path, metric, prefix)
    write_matrix(out, names, matrix, metric)
    return import_matrix(out, cache, None, metric)


def _header(source: Path, spec: DescriptorSpec, params: dict) -> EntryHeader:
    """The header of `source`'s entry for `spec`, keyed by `params`."""
    return EntryHeader.create(text_path(source), spec.name, params, spec.metric, spec.scale, spec.natural_max,
                              spec.dtype, spec.length)


@contextmanager
def _locked_entry(cache: Cache, header: EntryHeader) -> Iterator[tuple[StoredEntry, list[str]]]:
    """Hold the entry's lock and yield what it stores (nothing when absent or made for other
    params) and the repairs reading it called for (``Cache.repairs``); a killed run's journal
    is folded into the file first."""
    with cache.lock(cache.entry_name(header.key)):
        stored, repairs = _read_stored(cache, header.key)
        if stored is None or stored.header != header:
            stored = StoredEntry(header)
        elif stored.journaled:
            cache.write_entry(stored, complete=False)
        yield stored, repairs


def _read_stored(cache: Cache, key: str) -> tuple[StoredEntry | None, list[str]]:
    """``Cache.read_stored`` and the repairs it noted (call with the entry lock held)."""
    known = len(cache.repairs)
    stored = cache.read_stored(key)
    return stored, cache.repairs[known:]


def _journal(cache: Cache, runs: Sequence[_Settling], results: Iterator[tuple[int, FrameRecord, bool]],
             finish: Callable[[_Settling], None] | None = None) -> None:
    """Journal each settled frame the moment it arrives (``(tag, record, computed)``: the frame
    of ``runs[tag]``), and ``finish`` each run whose frames are all in. A journal is opened on
    its run's first result: no result, no file. A generator `results` is closed on the way out,
    whatever ends the loop: an interrupt landing here rather than in the generator stops its
    workers now (left to the garbage collector, they were stopped only as the interpreter
    exited, where the helper thread no longer runs: a 60 s hang)."""
    try:
        for tag, record, fresh in results:
            run = runs[tag]
            if run.settle(cache, record, fresh) and finish is not None:
                finish(run)
    finally:
        if isinstance(results, Generator):
            results.close()
        for run in runs:
            run.close()


def _report(stored: StoredEntry, entry: Entry, computed: int, started: float, ignored: Sequence[str] = (),
            unusable: Sequence[tuple[str, str]] = (), repairs: Sequence[str] = (),
            video: bool = False) -> DescribeReport:
    """The report of a run that settled every frame of `stored` and wrote (or reused) `entry`;
    `unusable` image names that could not be frames (``Traversal.unusable``) count as failed."""
    records = stored.records.values()
    bad = [(r.name, r.reason) for r in records if r.row is None]
    failed = sorted([*bad, *unusable], key=lambda f: natural_key(f[0]))
    seconds = time.perf_counter() - started
    return DescribeReport(
        folder=stored.header.folder, descriptor=stored.header.descriptor, shape=entry.data.shape,
        frames=len(records) + len(unusable), computed=computed, reused=len(records) - computed - len(bad),
        failed=failed, ignored=list(ignored),
        sizes=sorted({(r.width, r.height) for r in records if r.row is not None}),
        seconds=seconds, images_per_second=computed / seconds, entry=entry, repairs=list(repairs), video=video,
    )


def _check_jobs(jobs: int | None) -> int:
    """The worker count: the cores this process may use by default, else at least 1."""
    if jobs is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if jobs < 1:
        raise ParameterError("jobs", f"must be at least 1, got {jobs}")
    return jobs


def _changed(traversal: Traversal, records: dict[str, FrameRecord]) -> list[_Task]:
    """The frames to settle: new ones, and those whose file's size or mtime differs from their
    record (the rest are reused unread). Paths are made for these only: a path per frame cost
    more than the stat that checks it."""
    prefix = os.path.join(traversal.folder, "")
    return [(traversal.folder / name, old) for name in traversal.frame_names
            if not _unchanged(prefix + name, old := records.get(name))]


def _unchanged(path: str, old: FrameRecord | None) -> bool:
    """Fast path: a stored frame whose file at `path` has the same size and mtime is reused unread."""
    if old is None:
        return False
    try:
        stat = os.stat(path)
    except OSError:
        return False
    return stat.st_size == old.size and stat.st_mtime_ns == old.mtime_ns


def _compute(spec: DescriptorSpec, tasks: Sequence[tuple[int, _Task]],
             jobs: int) -> Iterator[tuple[int, FrameRecord, bool]]:
    """Settle each tagged task, yielding (tag, record, computed) as results arrive, over `jobs`
    processes. This process computes first; once the frames left would take it longer than
    starting workers (`WorkerStart`, by the median time of its frames after the first), `jobs` - 1
    workers start and take frames from the same queue while this process goes on computing."""
    if spec.colour:
        yield from _compute_colour(spec, tasks, jobs)
        return
    pending = deque(tasks)
    timed: list[float] = []
    with _opencv_quiet():
        while pending and not _worth_workers(jobs, timed, len(pending)):
            started = time.perf_counter()
            tag, task = pending.popleft()
            record = _describe_one(spec, task)
            timed.append(time.perf_counter() - started)
            yield (tag, *record)
        if pending:
            chunk = min(MAX_CHUNK, max(1, round(CHUNK_SECONDS / statistics.median(timed[1:]))))
            with _opencv_threads(1):
                yield from _compute_with_workers(spec, pending, jobs - 1, chunk)


def _compute_with_workers(spec: DescriptorSpec, pending: deque[tuple[int, _Task]], workers: int,
                          chunk: int) -> Iterator[tuple[int, FrameRecord, bool]]:
    """The pending tagged tasks settled by this process and `workers` worker processes together:
    a helper thread feeds the workers batches from `pending` (`_batches`), two at a time each,
    and queues their results; this process computes from the same deque and yields both."""
    results: queue.Queue = queue.Queue()
    # Forked from this process while it runs no other thread, else fresh interpreters; never the
    # caller's main module (wiloc.workers says why not multiprocessing's start methods).
    with borrowed_pool(workers, _init_worker) as pool:
        def drive() -> None:
            try:
                for batch in pool.imap_unordered(partial(_describe_tagged, spec),
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
                    tag, task = item
                    yield (tag, *_describe_one(spec, task))
                while not finished and (item is None or not results.empty()):  # nothing left here: wait
                    answer = results.get()
                    if isinstance(answer, BaseException):
                        raise answer
                    finished = answer is None
                    if not finished:
                        yield from answer
        except WorkerError as exc:
            pool.kill()
            paths = [path for batch in exc.items for _, (path, _) in batch]
            folder = paths[0].parent if paths else None  # a batch may reach into the next folder
            names = ", ".join(path.name if path.parent == folder else str(path) for path in paths)
            raise WilocError(folder, f"{exc.problem} while describing {names}") from None
        except BaseException:
            pool.kill()  # an interrupted run keeps what was journaled; in-flight work is lost
            raise
        finally:
            # The helper thread ends once every worker has answered or died. Only then may the
            # pipes be closed: closing one the thread waits on (epoll) would leave it waiting forever.
            driver.join()


def _batches(pending: deque[tuple[int, _Task]], chunk: int, processes: int) -> Iterator[list[tuple[int, _Task]]]:
    """Batches of tasks taken from `pending` as workers ask for them: `chunk` tasks, or fewer as
    the deque empties (a quarter of each process's share of what is left, at least one), so
    that at the end no process waits long for another's last batches."""
    while batch := [task for _ in range(min(chunk, max(1, len(pending) // (4 * processes))))
                    if (task := _take(pending)) is not None]:
        yield batch


def _take(pending: deque[tuple[int, _Task]]) -> tuple[int, _Task] | None:
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


def describe_quietly(spec: DescriptorSpec, tasks: Sequence[_Task]) -> list[tuple[FrameRecord, bool]]:
    """Each task's (record, computed), OpenCV's own warnings off meanwhile (a Dask worker's batch;
    a colour descriptor's as one batch on the worker's cores)."""
    with _opencv_quiet():
        if spec.colour:
            return _describe_colour(spec, tasks, _check_jobs(None))
        return [_describe_one(spec, task) for task in tasks]


def _describe_tagged(spec: DescriptorSpec, tasks: Sequence[tuple[int, _Task]]) -> list[tuple[int, FrameRecord, bool]]:
    """A worker process's batch: each tagged task's (tag, record, computed)."""
    return [(tag, *result) for (tag, _), result in zip(tasks, describe_quietly(spec, [task for _, task in tasks]))]


def _init_worker() -> None:
    """Workers keep OpenCV's and libjpeg's warnings to themselves: wiloc reports bad frames itself.
    (They leave Ctrl-C to the parent, which stops them and keeps what was journaled.)"""
    global _devnull
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    cv2.setNumThreads(1)  # the processes share out the cores already
    _devnull = os.open(os.devnull, os.O_WRONLY)


@contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's own warnings ("PNG input buffer is incomplete") off, then the previous level."""
    previous = cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(previous)


@contextmanager
def _decoders_quiet() -> Iterator[None]:
    """File descriptor 2 on /dev/null meanwhile: libjpeg prints "Corrupt JPEG data: ..." there
    itself. Always in a worker, which runs no other thread, so nothing else is lost; in the
    caller's process only when stderr is no terminal: on a terminal other threads of the caller
    (a progress display) write there, so it is left alone."""
    global _devnull
    if _devnull is None:
        if os.isatty(2):
            yield
            return
        _devnull = os.open(os.devnull, os.O_WRONLY)
    saved = os.dup(2)
    os.dup2(_devnull, 2)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _read_gray(path: Path, min_size: tuple[int, int] | None) -> np.ndarray:
    """`read_gray`, the decoders quiet (:func:`_decoders_quiet`)."""
    with _decoders_quiet():
        return read_gray(path, min_size)


def _settle(task: _Task, read: Callable[[Path], np.ndarray]
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


def _describe_one(spec: DescriptorSpec, task: _Task) -> tuple[FrameRecord, bool]:
    """One frame's record and whether its descriptor was computed (False: reused or failed).
    A frame whose content digest matches its stored record keeps that record's row or failure."""
    settled = _settle(task, lambda path: _read_gray(path, spec.min_size))
    if not isinstance(settled[0], Fingerprint):
        return settled  # type: ignore[return-value]
    (path, _), (fp, gray) = task, settled
    row = np.asarray(spec.compute(gray), dtype=spec.dtype)
    width, height = _full_size(path, gray)
    return FrameRecord(path.name, fp.size, fp.mtime_ns, fp.digest, row, "", width, height), True


def _describe_frames(spec: DescriptorSpec, video: Fingerprint,
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
    row = np.asarray(spec.compute(frame.gray) if row is None else row, dtype=spec.dtype)
    height, width = frame.gray.shape[:2]
    return FrameRecord(frame.name, video.size, video.mtime_ns, video.digest, row, "", width, height,
                       frame.timestamp_ms), True


def _describe_colour(spec: DescriptorSpec, tasks: Sequence[_Task], threads: int) -> list[tuple[FrameRecord, bool]]:
    """:func:`_describe_one` for a colour descriptor's tasks, as one batch: the images decoded
    in colour on ``threads`` threads (OpenCV's decoders let go of the GIL), then described
    together (``DescriptorSpec.compute_batch``, the network's runtime on ``threads`` threads)."""
    with _decoders_quiet(), ThreadPoolExecutor(max(1, threads), thread_name_prefix="wiloc-decode") as pool:
        settled = list(pool.map(lambda task: _settle(task, read_colour), tasks))
    decoded = [i for i, item in enumerate(settled) if isinstance(item[0], Fingerprint)]
    rows = spec.compute_batch([settled[i][1] for i in decoded], threads) if decoded else []
    for i, row in zip(decoded, rows):
        (path, _), (fp, image) = tasks[i], settled[i]
        height, width = image.shape[:2]
        settled[i] = FrameRecord(path.name, fp.size, fp.mtime_ns, fp.digest, np.asarray(row, dtype=spec.dtype), "",
                                 width, height), True
    return settled


def _compute_colour(spec: DescriptorSpec, tasks: Sequence[tuple[int, _Task]],
                    jobs: int) -> Iterator[tuple[int, FrameRecord, bool]]:
    """A colour descriptor's tagged tasks settled in this process, COLOUR_BATCH frames at a
    time, each batch decoded and described on `jobs` threads: a network's runtime shares out
    the cores itself, and worker processes would each load the model and compete for them."""
    with _opencv_quiet():
        for start in range(0, len(tasks), COLOUR_BATCH):
            batch = tasks[start:start + COLOUR_BATCH]
            for (tag, _), result in zip(batch, _describe_colour(spec, [task for _, task in batch], jobs)):
                yield (tag, *result)


def _full_size(path: Path, gray: np.ndarray) -> tuple[int, int]:
    """(width, height) of the image file: a JPEG's header size (its decode may be reduced),
    else the decoded size."""
    head = np.fromfile(path, np.uint8, count=65536)
    is_jpeg = head.size >= 2 and head[0] == 0xFF and head[1] == 0xD8
    return (jpeg_size(head) if is_jpeg else None) or (gray.shape[1], gray.shape[0])

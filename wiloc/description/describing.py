"""Traversal (folder, video or ROS bag) -> descriptor matrix through the cache.

A folder's unchanged frames are reused (same size and mtime, or else the same content digest);
only new or changed frames are computed, in worker processes. A video's frames are decoded in
order and described in this process. Either way each frame is journaled the moment its result
arrives, so an interrupted run resumes where it stopped. Unreadable frames are reported and left
out, never invented.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Container, Generator, Iterable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from wiloc.cache.entries import Entry, EntryHeader, FrameRecord, StoredEntry
from wiloc.cache.features import FeatureStore, damaged_note
from wiloc.cache.store import Cache, Journal
from wiloc.description.frame_describing import Task, check_jobs, compute, describe_frames, describe_quietly, opencv_quiet
from wiloc.descriptors.registry import DescriptorSpec
from wiloc.errors import ParameterError, WilocError
from wiloc.reprs import short_repr
from wiloc.sources.bags import Bag, bag_fingerprint, is_bag
from wiloc.sources.frames import Traversal, list_traversal, text_path
from wiloc.sources.natural_order import natural_key, natural_sorted
from wiloc.sources.video import Sampling, Video, is_video, lost_frames, video_fingerprint

if TYPE_CHECKING:
    from wiloc.description.cluster import Cluster

Progress = Callable[[int, int], None]


@short_repr
@dataclass(frozen=True)
class DescribeReport:
    """What a describe run did: counts, bad and ignored files, image sizes, speed, and the entry.
    `failed` holds the frames the entry's ``/failed`` records (read, and refused); `unusable` the
    image names left out when the folder was listed (``Traversal.unusable``: a broken link, a
    FIFO, a name that is not UTF-8), which the entry cannot record: there is no file to fingerprint,
    or no UTF-8 name. For a video (`video` true), `failed` holds at most the frame where decoding
    stopped early."""

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
    repairs: list[str] = field(default_factory=list)  # damage found in the cache: entry, local features
    video: bool = False
    notes: list[str] = field(default_factory=list)  # worth saying: which topic of a bag was read
    unusable: list[tuple[str, str]] = field(default_factory=list)  # left out at listing: (name, why)

    @property
    def left_out(self) -> list[tuple[str, str]]:
        """Every frame left out, failed or unusable, in natural order: a `skipped` line each."""
        return sorted([*self.failed, *self.unusable], key=lambda f: natural_key(f[0]))


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


def traversal_paths(traversals: object, parameter: str) -> list[Path]:
    """``traversals`` as a list of paths: one given alone (text or a path object) as ``[path]``,
    never as the characters of its name; any other iterable read once. None, a number, or an
    iterable holding anything but paths is a ParameterError naming ``parameter``."""
    if isinstance(traversals, (str, os.PathLike)):
        return [Path(traversals)]
    wanted = "a traversal's path (a folder, video or ROS bag) or a list of them"
    if not isinstance(traversals, Iterable):
        raise ParameterError(parameter, f"{wanted}, got {type(traversals).__name__}")
    listed = list(traversals)
    for item in listed:
        if not isinstance(item, (str, os.PathLike)):
            raise ParameterError(parameter, f"{wanted}, got a {type(traversals).__name__} holding "
                                            f"{type(item).__name__}")
    return [Path(item) for item in listed]


def check_sampling(sources: Sequence[Path], sampling: Sampling | None) -> None:
    """ParameterError naming the sampling's first field that was set (``fps``, ...) when it keeps
    other than every frame and none of ``sources`` is a video file or ROS bag: it applies to those
    only (image folders beside them take every frame; a map held in memory, or none in sequence
    mode, has no frames to sample); anything but a Sampling is a ParameterError naming ``sampling``."""
    if sampling is not None and not isinstance(sampling, Sampling):
        raise ParameterError("sampling", f"a Sampling (Sampling(every=2), Sampling(fps=2.0, start='60s')), "
                                         f"got {type(sampling).__name__}")
    if sampling is not None and sampling != Sampling() and not any(is_stream(Path(s)) for s in sources):
        unset = Sampling()
        given = next(f.name for f in fields(Sampling) if getattr(sampling, f.name) != getattr(unset, f.name))
        neither = f"{sources[0]} is neither" if sources else "no traversal given is one"
        raise ParameterError(given, f"applies to video files and ROS bags only; {neither}")


def check_topic(sources: Sequence[Path], topic: str | None) -> None:
    """ParameterError when an image topic is given but no traversal is a ROS bag."""
    if topic is not None and not any(is_bag(Path(source)) for source in sources):
        raise ParameterError("topic", "applies to ROS bags only; no traversal given is one")


def describe_folder(folder: Path, spec: DescriptorSpec, cache: Cache, jobs: int | None = None,
                    progress: Progress | None = None, cluster: Cluster | None = None) -> DescribeReport:
    """Describe every image of a traversal folder with `spec`, reusing what the cache holds.

    `jobs` worker processes compute (default: all cores; 1 computes in this process), or the
    workers of a Dask `cluster` (``wiloc.description.cluster``; this process still journals and writes).
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
    waits for it, up to the cache's lock timeout. A folder given twice is described once. A
    damaged local-features file is extracted again and named in the repairs of the report of the
    folder whose frame met it and in ``cache.repairs`` (what ``localize`` reports). On a Dask
    ``cluster`` the folders are described one after the other (from the pixels: the workers read
    no local features)."""
    started = time.perf_counter()
    jobs = check_jobs(jobs)
    callbacks = list(progress) if progress is not None else [None] * len(folders)
    runs: dict[str, _Settling] = {}
    keys = []
    for folder, callback in zip(folders, callbacks):
        traversal = list_traversal(folder)
        header = folder_header(Path(folder), spec)
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
            def damaged(tag: int, file: Path) -> None:  # told to the folder's report and the cache's front end
                note = damaged_note(file)
                settling[tag].repairs.append(note)
                cache.repairs.append(note)

            results = compute(spec, tagged, jobs, _feature_store(spec, cache), damaged) \
                if cluster is None else _on_cluster(cluster, spec, settling)
            _journal(cache, settling, results, finish)
    return [runs[key].report for key in keys]


def _feature_store(spec: DescriptorSpec, cache: Cache) -> FeatureStore | None:
    """Where the cache keeps the local features `spec` is computed from (``bow``: those its
    vocabulary's training kept, shared with every other such descriptor); None for a descriptor
    computed from the pixels themselves."""
    setting = spec.feature_setting
    return None if setting is None else FeatureStore(cache, setting)


def _on_cluster(cluster: Cluster, spec: DescriptorSpec,
                runs: Sequence[_Settling]) -> Iterator[tuple[int, FrameRecord, bool]]:
    """Each run's tasks settled on the Dask cluster, one run after the other, tagged by run; their
    paths made absolute, as a worker started elsewhere reads a relative one from its own folder."""
    for tag, run in enumerate(runs):
        if run.tasks:
            work = partial(describe_quietly, spec, spec.cache_params["libraries"])
            for record, fresh in cluster.in_batches(work, [(path.absolute(), stored) for path, stored in run.tasks]):
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
        self.repairs: list[str] = []  # what reading the entry (Cache.repairs), and describing, found damaged
        self.tasks: list[Task] = []
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
    with opencv_quiet(), Video(path) as video:
        video_print = video_fingerprint(path)
        params = {**spec.cache_params, "video": video_print.digest, "sampling": asdict(sampling)}
        length = "" if video.frame_count is None else f" (it has {video.frame_count} frames)"
        stored, entry, computed, repairs = _describe_stream(
            cache, _header(path, spec, params), sampling.estimate(video.frame_count, video.rate),
            lambda skip: describe_frames(spec, video_print, video.frames(sampling, skip=skip, colour=spec.colour)),
            WilocError(path, f"the cut ({sampling.cut}) holds no frame of this video{length}"), progress)
    lost = lost_frames(entry.names, entry.timestamps_ms, video.rate)
    report = _report(stored, entry, computed, start, repairs=repairs, video=True)
    return replace(report, notes=[f"{path}: {lost}"] if lost else [])


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
    with opencv_quiet(), Bag(path) as bag:
        bag.choose(topic)
        bag_print = bag_fingerprint(path)
        params = {**spec.cache_params, "bag": bag_print.digest, "topic": bag.topic, "sampling": asdict(sampling)}
        stored, entry, computed, repairs = _describe_stream(
            cache, _header(path, spec, params), sampling.estimate(bag.count, bag.rate),
            lambda skip: describe_frames(spec, bag_print, bag.frames(sampling, spec.min_size, skip=skip,
                                                                       colour=spec.colour)),
            WilocError(path, f"topic {bag.topic} holds no image message" if bag.count == 0 else
                       f"the cut ({sampling.cut}) holds no image of topic {bag.topic} (it has {bag.count})"), progress)
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


def folder_header(folder: Path, spec: DescriptorSpec) -> EntryHeader:
    """The header of a folder's entry for ``spec``, keyed as :func:`describe_folders` looks it up
    (the descriptor's parameters, its code version and its libraries' versions): the one recipe
    for whoever writes such an entry itself (a benchmark's generated descriptors for placeholder
    images)."""
    return _header(folder, spec, spec.cache_params)


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
        stored, repairs = read_stored(cache, header.key)
        if stored is None or stored.header != header:
            stored = StoredEntry(header)
        elif stored.journaled:
            cache.write_entry(stored, complete=False)
        yield stored, repairs


def read_stored(cache: Cache, key: str) -> tuple[StoredEntry | None, list[str]]:
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
    """The report of a run that settled every frame of `stored` and wrote (or reused) `entry`: its
    counts those of the entry (frames = computed + reused + failed), the image names that could
    not be frames (``Traversal.unusable``) apart, as ``unusable``."""
    records = stored.records.values()
    failed = sorted(((r.name, r.reason) for r in records if r.row is None), key=lambda f: natural_key(f[0]))
    seconds = time.perf_counter() - started
    return DescribeReport(
        folder=stored.header.folder, descriptor=stored.header.descriptor, shape=entry.data.shape,
        frames=len(records), computed=computed, reused=len(records) - computed - len(failed),
        failed=failed, ignored=list(ignored), unusable=list(unusable),
        sizes=sorted({(r.width, r.height) for r in records if r.row is not None}),
        seconds=seconds, images_per_second=computed / seconds, entry=entry, repairs=list(repairs), video=video,
    )



def _changed(traversal: Traversal, records: dict[str, FrameRecord]) -> list[Task]:
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


def left_out(kept: list[str], skipped: list[str]) -> tuple[tuple[int, str], ...] | None:
    """Where the frames ``skipped`` (left out: unreadable) go among the ``kept`` frames of a
    traversal: (position, name) in the full order of all of them, the natural order a folder
    lists its frames in (a frame's position is then its own whether or not others were read);
    None when none was left out, so that such a run's results header is as before."""
    if not skipped:
        return None
    gone = set(skipped)
    return tuple((position, name) for position, name in enumerate(natural_sorted([*kept, *skipped])) if name in gone)

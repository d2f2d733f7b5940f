"""Traversals as descriptor matrices: an image folder, a video file or a ROS bag described
through the cache, a user's descriptor matrix file imported into it, or descriptors held in memory."""
from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from wiloc.cache.entries import EXTERNAL, Entry, EntryHeader
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_source
from wiloc.description.matrix_import import import_matrix
from wiloc.descriptors.external import check_frame_names, check_value_range, recorded_metric, refuse_results_file
from wiloc.descriptors.registry import DescriptorSpec, get_descriptor
from wiloc.errors import ParameterError, WilocError, parameter_values
from wiloc.sources.bags import is_bag
from wiloc.sources.frames import list_traversal, not_a_traversal
from wiloc.sources.video import Sampling, is_video

if TYPE_CHECKING:
    from wiloc.description.cluster import Cluster
    from wiloc.description.differences import BlockRunner

Progress = Callable[[str, int, int], None]


_EXTERNAL_IMAGES = (f"'{EXTERNAL}' names descriptors computed elsewhere, which are not described: import their "
                    "matrix file (api.import_descriptors), or give it to localize as it is")


def descriptor_spec(descriptor: str, params: Mapping[str, Any] | None = None, *,
                    images: bool = False) -> DescriptorSpec:
    """The descriptor's spec; an unknown name or parameter is an error naming ``descriptor``, and
    with ``images`` (to describe them) ``external``, whose rows come from a matrix file."""
    external = images and descriptor == EXTERNAL  # said after an unknown parameter's name is
    try:
        spec = get_descriptor(descriptor, **parameter_values(params, "descriptor_params"))
    except ValueError as exc:
        raise ParameterError("descriptor", _EXTERNAL_IMAGES if external else str(exc)) from None
    if external:
        raise ParameterError("descriptor", _EXTERNAL_IMAGES)
    return spec


def entry_from_array(data: np.ndarray, names: list[str], spec: DescriptorSpec, source: str = "memory") -> Entry:
    """Descriptors computed elsewhere (one row per frame, named) as an entry that is not cached:
    a map held in memory. Its digest is a hash of names and values, so a change is seen. Values
    are checked as an observed row's are (``checked_rows``): never wrapped into the descriptor's
    dtype, NaN refused; names are unique non-empty text, as an imported matrix's are."""
    if isinstance(names, str):  # list() would make each of its characters a name
        raise WilocError(source, f"names: one name per row (a list of text), got the text {names!r}")
    # numpy's text (an array of names) as plain str: results and decisions name frames by it
    data, names = np.asarray(data), [str(name) if isinstance(name, str) else name for name in names]
    check_frame_names(names, source)
    if data.ndim != 2 or data.shape[1] != spec.length or data.shape[0] != len(names):
        raise WilocError(source, f"descriptors of shape {data.shape} for {len(names)} names; "
                                 f"'{spec.name}' rows have {spec.length} values")
    data = np.array(checked_rows(data, spec.dtype, spec.metric, source), order="C")  # a copy: the caller's
    data.flags.writeable = False  # array may be reused, and the digest must stay the values'
    header = EntryHeader.create(source, spec.name, dict(spec.params), spec.metric, spec.scale, spec.natural_max,
                                spec.dtype, spec.length)
    return Entry(**asdict(header), names=list(names), data=data, digest=descriptors_digest(names, data))


#: What a cache entry's parameters hold besides its descriptor's: the versions of the computation
#: and of the libraries it ran on (``DescriptorSpec.cache_params``), a video's or bag's print, topic
#: and sampling (``describing``).
_CACHE_KEYS = ("code_version", "libraries", "video", "bag", "topic", "sampling")


def entry_params(entry: Entry) -> dict[str, Any]:
    """The parameters of the descriptor ``entry`` was described with (a cached entry's without
    what the cache keys it by besides), as a run on it describes frames with and records them;
    an imported matrix's are its storage (``external``'s), which its cache key does not hold."""
    if entry.descriptor == EXTERNAL:
        return {"metric": entry.metric, "length": entry.length, "dtype": np.dtype(entry.dtype).name}
    return {name: value for name, value in entry.params.items() if name not in _CACHE_KEYS}


def checked_rows(values: NDArray, dtype: np.dtype, metric: str, where: str) -> NDArray:
    """Descriptor values given from outside (a map's rows in memory, a row to observe) as the
    rows of ``dtype`` they are compared with: numbers and finite; for integer rows (``sad``,
    ``brisk-gist``: uint8) whole numbers within the type's range, never wrapped; for float32 rows
    (``gist``) within its range, never made infinite; small enough that no ``metric`` difference
    overflows, as an imported matrix file's (``check_value_range``). Else a WilocError naming ``where``."""
    if values.dtype.kind not in "biuf":
        raise WilocError(where, f"a descriptor of {values.dtype} values; give numbers")
    if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
        raise WilocError(where, "the descriptor holds NaN or infinite values")
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        if values.dtype.kind == "f" or (values.size and (values.min() < info.min or values.max() > info.max)):
            raise WilocError(where, f"a descriptor of {values.dtype} values; this map's rows are {dtype} "
                                    f"(integers in [{info.min}, {info.max}])")
    with np.errstate(over="ignore"):  # a float64 value beyond float32's range: refused below
        rows = values.astype(dtype, copy=False)
    if dtype.kind == "f" and not np.all(np.isfinite(rows)):
        raise WilocError(where, f"the descriptor holds values beyond the range of this map's {dtype} rows")
    check_value_range(rows, metric, where)
    return rows


def descriptors_digest(names: list[str], data: np.ndarray) -> str:
    """A hash of frame names and descriptor rows, whatever folder they came from: what a results
    header records of its traversals, so that a figure redrawn later sees whether the images
    still give the descriptors the run used."""
    return hashlib.sha256("\0".join(names).encode() + np.ascontiguousarray(data).tobytes()).hexdigest()


#: The suffixes of descriptor matrix files a traversal may be (``descriptors.external`` reads them).
MATRIX_SUFFIXES = frozenset({".npy", ".npz", ".csv", ".h5", ".hdf5"})


def is_matrix_file(source: Path) -> bool:
    """Whether a traversal is a user's descriptor matrix file (not a folder, video or ROS bag)."""
    return Path(source).is_file() and not is_video(Path(source)) and not is_bag(Path(source))


def names_matrix_file(source: Path) -> bool:
    """Whether a traversal is a descriptor matrix file, or a missing one named as such (``q.npy``):
    options are checked against the traversal meant, and reading it then says it does not exist."""
    return is_matrix_file(source) or (not Path(source).exists() and Path(source).suffix.lower() in MATRIX_SUFFIXES)


def check_query_path(query: Path) -> None:
    """Refuse, as a WilocError naming it and as a run would, a query that is no traversal: missing,
    a folder without usable image files, or a file that is no video, ROS bag or descriptor matrix
    file (a results file, an image). Nothing is described (what only reading the frames finds is
    the run's to say), so that `localize` checks every query before localizing the first."""
    query = Path(query)
    if is_matrix_file(query):
        _check_matrix_file(query)
    elif not ((is_video(query) or is_bag(query)) and query.exists()):  # a video or bag: opening it verifies
        list_traversal(query)


def _check_matrix_file(source: Path) -> None:
    """A file given as a traversal that is no video or bag: a WilocError naming it unless it is a
    descriptor matrix file (a results file, an image are said to be what they are)."""
    takes = "give a folder of images, a video or a descriptor matrix file (.npy, .npz, .csv, .h5)"
    refuse_results_file(source, f"is not a traversal: {takes}")
    if source.suffix.lower() not in MATRIX_SUFFIXES:
        raise WilocError(source, not_a_traversal(source, takes))


def check_descriptor(sources: Sequence[Path], descriptor: str | None, params: Mapping[str, Any] | None) -> None:
    """ParameterError naming ``descriptor`` (or ``descriptor_params``) when it is given and every
    one of ``sources`` is a descriptor matrix file: their rows are compared as imported, so it would
    be recorded and not used."""
    if not sources or not all(names_matrix_file(Path(s)) for s in sources):
        return
    for name, value in (("descriptor", descriptor not in (None, EXTERNAL)),
                        ("descriptor_params", bool(params) and descriptor != EXTERNAL)):  # external's: its storage
        if value:
            raise ParameterError(name, f"applies to image folders, video files and ROS bags; {sources[0]} is a "
                                       "descriptor matrix file, compared by its metric")


def check_metric(sources: Sequence[Path], metric: str | None) -> None:
    """ParameterError naming ``metric`` when it is given and none of ``sources`` is a descriptor
    matrix file: images are compared by their descriptor's own difference, so it would be recorded
    and not used."""
    if metric is not None and sources and not any(names_matrix_file(Path(s)) for s in sources):
        raise ParameterError("metric", f"applies to descriptor matrix files (.npy, .npz, .csv, .h5) only; "
                                       f"{sources[0]} is none, its frames compared by the descriptor's difference")


def descriptor_label(descriptor: str, metric: str | None, sources: Iterable[Path] = ()) -> str:
    """The descriptor of a run as results name it: ``sad``, or ``external:cosine`` for imported
    descriptors (a source that is a matrix file, or rows given as ``external``; ``metric`` None:
    the one the first matrix file records)."""
    matrices = [Path(source) for source in sources if is_matrix_file(Path(source))]
    if metric is None and matrices:
        metric = recorded_metric(matrices[0])
    return f"{EXTERNAL}:{metric}" if (descriptor == EXTERNAL or matrices) and metric else descriptor


def check_progress(progress: Progress | None) -> Progress | None:
    """``progress`` as given: a function or None. Anything else (a number, text) is a
    ParameterError naming ``progress`` before any work, not a TypeError once the first frames
    are described."""
    if progress is not None and not callable(progress):
        raise ParameterError("progress", f"a function progress(stage, done, total) or None, "
                                         f"got {type(progress).__name__}")
    return progress


def stage(progress: Progress | None, label: str) -> Callable[[int, int], None] | None:
    """A per-step ``progress(done, total)`` callback that tags the step's label (``progress`` is
    checked: :func:`check_progress`)."""
    if check_progress(progress) is None:
        return None
    return lambda done, total: progress(label, done, total)


def open_cluster(scheduler: str | None, workers: int | None = None) -> Cluster | None:
    """The Dask cluster at ``scheduler`` (an address, or ``local`` with ``workers`` processes);
    None without one. Dask is imported only here, only when asked for."""
    if scheduler is None:
        return None
    try:
        from wiloc.description.cluster import connect
    except ImportError:
        raise ParameterError("scheduler", "needs Dask: pip install 'wiloc[dask]'") from None
    return connect(scheduler, workers)


@dataclass
class Describer:
    """How traversals become descriptor matrices: one descriptor with its parameters, through one
    cache. ``metric`` is the difference of imported matrix files; ``sampling`` picks the frames of
    video files and ROS bags (default: all), ``topic`` the bags' image topic (None: each one's
    only one); ``cluster`` (``wiloc.description.cluster``) describes folders and computes differences on Dask
    workers; ``skipped`` collects the frames that could not be described, as (image path, why),
    ``notes`` what is worth saying (which topic of a bag was read)."""

    descriptor: str = "sad"
    params: Mapping[str, Any] = field(default_factory=dict)
    cache: Cache = field(default_factory=Cache)
    metric: str | None = None
    jobs: int | None = None
    progress: Progress | None = None
    skipped: list[tuple[str, str]] = field(default_factory=list)
    sampling: Sampling | None = None
    cluster: Cluster | None = None  # a Dask cluster that describes folders and computes differences
    topic: str | None = None
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        """``progress`` checked as it is given (a run's setup makes its describer before any frame
        is described)."""
        check_progress(self.progress)

    @property
    def runner(self) -> BlockRunner | None:
        """How difference blocks are computed: on the cluster, else (None) in this process."""
        return None if self.cluster is None else self.cluster.blocks

    @property
    def spec(self) -> DescriptorSpec:
        return descriptor_spec(self.descriptor, self.params)

    def recorded_params(self, sources: Iterable[Path]) -> dict[str, Any]:
        """The descriptor parameters a results header records of a run on ``sources`` (its query
        and map): every parameter of this describer's descriptor, defaults resolved, so that a run
        records the same whether made by the command line, ``wiloc.api`` or a ``Localizer`` over a
        map in memory; none where they are imported matrix files and this is no ``external``
        describer. Such a run names ``external:METRIC``; the parameters of the descriptor asked for
        (``sad``'s ``crop``) are no part of it, and the header records the metric and the
        matrices' digests apart."""
        if self.descriptor != EXTERNAL and any(is_matrix_file(Path(source)) for source in sources):
            return {}
        return dict(self.spec.params)

    def entry(self, source: Path, names: Path | None = None) -> Entry:
        """The descriptors of a folder or of a video's or bag's sampled frames (computed on demand), or of
        an imported matrix file (``names``: its frame names, one per line, for .npy matrices)."""
        source = Path(source)
        if is_matrix_file(source):
            _check_matrix_file(source)
            metric = self.metric or recorded_metric(source)
            if metric is None:
                raise ParameterError("metric", f"{source}: a descriptor matrix file needs a metric (l1, sqeuclidean, "
                                               "hamming, cosine), or an .h5 file of imported descriptors, which "
                                               "records it")
            report = import_matrix(source, self.cache, names, metric)  # a note when metric overrides the file's
        else:
            report = describe_source(source, self.spec, self.cache, jobs=self.jobs, sampling=self.sampling,
                                     progress=stage(self.progress, f"describe {source.name}"), cluster=self.cluster,
                                     topic=self.topic)
        self.skipped.extend((str(source / name), reason) for name, reason in report.left_out)
        self.notes.extend(note for note in report.notes if note not in self.notes)
        entry = report.entry
        if len(entry.names) == 0:
            raise WilocError(source, "no usable frames (every image failed to load)")
        if entry.data.dtype.kind == "f" and not np.all(np.isfinite(entry.data)):
            bad = entry.names[int(np.flatnonzero(~np.all(np.isfinite(entry.data), axis=1))[0])]
            raise WilocError(source, f"descriptor of frame '{bad}' holds NaN or infinite values")
        return entry

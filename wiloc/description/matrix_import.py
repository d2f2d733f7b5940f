"""A user's descriptor matrix -> an entry of the cache of its own (``wiloc describe --import``),
or first -> a wiloc descriptor file that records names and metric."""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from wiloc.cache.entries import EXTERNAL, EntryHeader, FrameRecord, StoredEntry, entry_key
from wiloc.cache.store import Cache
from wiloc.description.describing import DescribeReport, read_stored
from wiloc.descriptors.external import (METRIC_ATTRIBUTE, READER_VERSION, check_names_file, read_external,
                                        recorded_metric, write_matrix)
from wiloc.descriptors.registry import get_descriptor
from wiloc.errors import ParameterError, WilocError
from wiloc.sources.frames import fingerprint, text_path


def import_matrix(path: Path, cache: Cache, names_path: Path | None, metric: str) -> DescribeReport:
    """Bring a user's N x D descriptor matrix into the cache as an entry of its own.

    The entry is keyed by the file's resolved path, the metric, the reader's version and the
    content digests of the matrix file and of the names file, so an edited file (or a file read
    otherwise by a newer wiloc) makes a new entry, never a silent mix.
    """
    start = time.perf_counter()
    sources = [Path(p).resolve() for p in (path, names_path) if p is not None]
    if not sources[0].is_file():
        raise WilocError(sources[0], "file does not exist")
    if names_path is not None:
        check_names_file(sources[1])
    for source in sources:
        text_path(source)
    prints = [fingerprint(source) for source in sources]
    params = {"metric": metric, "reader": READER_VERSION, "file_digest": prints[0].digest,
              "names": str(sources[1]) if names_path is not None else None,
              "names_digest": prints[1].digest if names_path is not None else None}
    key = entry_key(str(sources[0]), EXTERNAL, params)
    with cache.lock(cache.entry_name(key)):
        stored, repairs = read_stored(cache, key)
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
        notes=_overridden_metric(sources[0], metric),
    )


def _overridden_metric(source: Path, metric: str) -> list[str]:
    """A line saying ``metric`` overrides the other metric ``source`` records (docs/descriptors.md),
    so that a --metric contradicting the file is never taken silently; none otherwise."""
    recorded = recorded_metric(source)
    if recorded is None or recorded == metric:
        return []
    return [f"{source}: records the metric {recorded}; the one given (--metric {metric}) overrides it"]


def import_to_file(source: Path, out: Path, cache: Cache, names_path: Path | None, metric: str,
                   prefix: str = "") -> DescribeReport:
    """Write external descriptors (any :func:`read_external` source: a matrix file, hloc's
    global-feats-*.h5, a folder of per-image .npy vectors; ``prefix`` keeps one part of it) to a
    wiloc descriptor file ``out`` that records names and metric, and import that into the cache:
    later commands name ``out`` alone. A file at ``out`` is replaced (and said to be) only when it
    is such a descriptor file; anything else there is a WilocError naming it, nothing written."""
    out = Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ParameterError("out", f"{out}: a descriptor file is HDF5; name it FILE.h5")
    if out.resolve() == Path(source).resolve():
        raise ParameterError("out", f"{out} is the file being imported; name another")
    if (problem := _other_file(out)) is not None:
        raise WilocError(out, problem)
    replaced = [f"replaced the existing descriptor file {out}"] if out.exists() else []
    names, matrix = read_external(Path(source), names_path, metric, prefix)
    write_matrix(out, names, matrix, metric)
    report = import_matrix(out, cache, None, metric)
    return replace(report, notes=[*_overridden_metric(Path(source), metric), *report.notes, *replaced])


def _other_file(out: Path) -> str | None:
    """Why ``out`` is not to be replaced by a descriptor file: something is there that no --out
    wrote (another tool's .h5, a text file, a folder), which would be lost. None for no file, an
    empty one or a descriptor file as :func:`write_matrix` writes it (an import redone)."""
    if not out.exists() or (out.is_file() and (out.stat().st_size == 0 or _written_by_out(out))):
        return None
    return (f"the {'folder' if out.is_dir() else 'file'} there is no wiloc descriptor file (datasets "
            f"'descriptors' and 'names', attribute '{METRIC_ATTRIBUTE}'), and writing would replace it; "
            "give another name, or remove it first")


def _written_by_out(path: Path) -> bool:
    """Whether the regular file ``path`` holds :func:`write_matrix`'s layout: the datasets
    ``descriptors`` and ``names`` alone, and the attribute ``metric``."""
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            return set(handle) == {"descriptors", "names"} and METRIC_ATTRIBUTE in handle.attrs and \
                all(isinstance(handle[name], h5py.Dataset) for name in handle)
    except OSError:  # no HDF5 file
        return False


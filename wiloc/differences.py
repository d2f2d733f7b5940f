"""Query x reference difference matrices, cached in HDF5 and read back row block by row block.

``<cache root>/differences/<query key>-<reference key>.h5`` holds dataset ``d`` (float32, query
frames x reference frames, chunked by a few rows so one row reads cheaply), datasets
``query_names`` and ``ref_names`` (datasets, not attributes: HDF5 caps an attribute at 64 KB) and
attributes ``query_digest``, ``ref_digest``, ``metric``, ``scale``, ``query_folder``,
``ref_folder`` and ``wiloc_version``. A file is reused only while both entry digests and the
metric and scale match; otherwise it is recomputed under the cache lock for its name, blockwise
(memory stays at one block of rows) and written through an atomic rename, so a killed writer
never leaves a file that looks complete. Each chunk of ``d`` carries a Fletcher-32 checksum
(HDF5's filter): a damaged chunk is a WilocError naming the file when it is read, and the file
is removed, so that the next run computes it again.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType

import h5py
import numpy as np

from wiloc import __version__
from wiloc.cache import Cache, Entry
from wiloc.distances import DifferencesTo, pairwise_blocks
from wiloc.errors import WilocError

Progress = Callable[[int, int], None]

DEFAULT_BLOCK_ROWS = 1024
_CHUNK_BYTES = 1 << 20  # target size of one HDF5 chunk of rows


class DifferenceMatrix:
    """A cached difference matrix opened for reading; use as a context manager or call close()."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._file = h5py.File(self.path, "r")
        self._d = self._file["d"]

    def __enter__(self) -> DifferenceMatrix:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the HDF5 file."""
        self._file.close()

    @property
    def shape(self) -> tuple[int, int]:
        """(query frames, reference frames)."""
        rows, cols = self._d.shape
        return int(rows), int(cols)

    @property
    def metric(self) -> str:
        return str(self._file.attrs["metric"])

    @property
    def scale(self) -> float:
        return float(self._file.attrs["scale"])

    @property
    def query_names(self) -> list[str]:
        return [str(n) for n in self._file["query_names"].asstr()[()]]

    @property
    def ref_names(self) -> list[str]:
        return [str(n) for n in self._file["ref_names"].asstr()[()]]

    def rows(self, start: int, stop: int) -> np.ndarray:
        """Rows start..stop as a float32 block read from the file; WilocError when they fail
        their checksum (the damaged file is removed: the next run computes it again)."""
        try:
            return self._d[start:stop]
        except OSError as exc:
            self.path.unlink(missing_ok=True)
            raise WilocError(self.path, f"cached differences damaged (rows {start}-{stop}: {exc}); removed it, "
                                        "run again to compute them anew") from None

    def row(self, k: int) -> np.ndarray:
        """The differences of query frame k to every reference frame, as a float64 row."""
        return self.rows(k, k + 1)[0].astype(np.float64)

    def iter_rows(self, block_rows: int = DEFAULT_BLOCK_ROWS) -> Iterator[np.ndarray]:
        """Every row in order as float64, reading the file block_rows rows at a time."""
        for start in range(0, self.shape[0], block_rows):
            yield from self.rows(start, start + block_rows).astype(np.float64)


class ComputedDifferences:
    """Differences of descriptor rows to fixed references, computed block of rows by block of rows
    when read and never stored: a row-block reader like :class:`DifferenceMatrix` without a file."""

    def __init__(self, data: np.ndarray, to: DifferencesTo) -> None:
        self._data = data
        self._to = to

    @property
    def shape(self) -> tuple[int, int]:
        return int(self._data.shape[0]), int(self._to.shape[0])

    def rows(self, start: int, stop: int) -> np.ndarray:
        """Rows start..stop as a float32 block, computed now."""
        return self._to(self._data[start:stop])


def _check_comparable(query: Entry, ref: Entry) -> None:
    """Raise WilocError naming both folders when the two entries cannot be compared."""
    problems = []
    if query.metric != ref.metric:
        problems.append(f"metric {query.metric} vs {ref.metric}")
    if query.scale != ref.scale:
        problems.append(f"scale {query.scale:g} vs {ref.scale:g}")
    if query.data.shape[1:] != ref.data.shape[1:]:
        problems.append(f"descriptor length {query.data.shape[1]} vs {ref.data.shape[1]}")
    if problems:
        raise WilocError(query.folder, f"cannot be compared with {ref.folder}: {', '.join(problems)}")


def _is_current(path: Path, query: Entry, ref: Entry) -> bool:
    """Whether the file at path holds the differences of exactly these two entries."""
    try:
        with h5py.File(path, "r") as f:
            attrs = f.attrs
            return bool(
                attrs.get("query_digest") == query.digest
                and attrs.get("ref_digest") == ref.digest
                and attrs.get("metric") == query.metric
                and attrs.get("scale") == query.scale
                and f["d"].shape == (len(query.names), len(ref.names))
                and (f["d"].fletcher32 or f["d"].chunks is None)  # written with checksums
            )
    except (OSError, KeyError):
        return False


def _write(f: h5py.File, query: Entry, ref: Entry, block_rows: int, progress: Progress | None) -> None:
    """Fill an open HDF5 file with the difference matrix, block of rows by block of rows."""
    shape = (len(query.names), len(ref.names))
    chunk_rows = max(1, min(block_rows, shape[0], _CHUNK_BYTES // (4 * max(shape[1], 1))))
    chunks = (chunk_rows, shape[1]) if all(shape) else None
    d = f.create_dataset("d", shape=shape, dtype=np.float32, chunks=chunks, fletcher32=chunks is not None)
    f.create_dataset("query_names", data=query.names, dtype=h5py.string_dtype())
    f.create_dataset("ref_names", data=ref.names, dtype=h5py.string_dtype())
    f.attrs.update(
        query_digest=query.digest, ref_digest=ref.digest, metric=query.metric, scale=query.scale,
        query_folder=query.folder, ref_folder=ref.folder, wiloc_version=__version__,
    )
    for start, stop, block in pairwise_blocks(query.data, ref.data, query.metric, query.scale, block_rows):
        d[start:stop] = block
        if progress is not None:
            progress(stop, shape[0])


def difference_matrix(
    query: Entry, ref: Entry, cache: Cache, progress: Progress | None = None, block_rows: int = DEFAULT_BLOCK_ROWS
) -> DifferenceMatrix:
    """The len(query) x len(ref) float32 difference matrix, reused from the cache or computed into it.

    ``progress(done, total)`` counts query rows while computing; it is not called on reuse.
    """
    _check_comparable(query, ref)
    name = f"differences/{query.key}-{ref.key}.h5"
    path = cache.root / name
    if not _is_current(path, query, ref):
        with cache.lock(name):
            if not _is_current(path, query, ref):  # another process may have written it meanwhile
                with cache.atomic_h5(path) as f:
                    _write(f, query, ref, block_rows, progress)
    return DifferenceMatrix(path)


def candidate_rows(matrix: DifferenceMatrix, sequence: bool, exclude_recent: int) -> Iterator[np.ndarray]:
    """Difference rows over the candidate frames, float64, np.inf where a frame is no candidate.

    Map mode: the rows as they are. Sequence mode (the matrix is the traversal against itself):
    row k keeps only frames i < k - exclude_recent.
    """
    if exclude_recent < 0:
        raise ValueError(f"exclude_recent must be >= 0, got {exclude_recent}")
    if sequence and matrix.shape[0] != matrix.shape[1]:
        raise ValueError(f"sequence mode needs a square matrix, got {matrix.shape}")
    for k, row in enumerate(matrix.iter_rows()):
        if sequence:
            row[max(0, k - exclude_recent) :] = np.inf
        yield row

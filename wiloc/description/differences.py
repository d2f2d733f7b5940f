"""A run's difference rows, computed block of rows by block of rows and never stored; the map's
self-difference summary, small, cached.

Nothing N x N is kept: at N = 35,000 the SAD kernel computes the query x map rows in about the
time HDF5 reads them back from a cache, and in a fraction of the time it takes to write them
(4.9 GB per matrix; docs/kernels.md gives the measurements). What methods learn from the map's
differences to itself is small and is cached: each map frame's smallest difference outside its
+-R (``online``) and the largest difference (``threshold`` without a natural maximum), in
``<cache root>/differences/<map key>-self-r<R>.h5``: datasets ``minima`` (float64, one per map
frame, inf where a frame has no difference outside +-R) and ``largest`` (float64, one element),
attributes ``ref_digest``, ``metric``, ``scale``, ``exclude_recent``, ``differences_version``,
``ref_folder`` and ``wiloc_version``. Both datasets carry HDF5's Fletcher-32 checksum: a value
kept in an attribute has none, and a flipped bit in ``largest`` (threshold's d_max) changed every
confidence silently. A summary is reused only while the map's entry digest, metric, scale, R and
the difference functions' version (``distances.DIFFERENCES_VERSION``) match, it has both datasets
(one written before ``largest`` had its checksum is not current) and their checksums hold;
otherwise it is recomputed under the cache lock for its name and written through an atomic rename.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from numpy.typing import NDArray

from wiloc.ahead import computed_ahead
from wiloc.cache.store import Cache, Entry
from wiloc.description.distances import DIFFERENCES_VERSION, DifferencesTo, band_extremes
from wiloc.errors import WilocError
from wiloc.recycled import RecycledArrays
from wiloc.rows import MapSummary, RowBlocks
from wiloc.version import __version__

Progress = Callable[[int, int], None]

DEFAULT_BLOCK_ROWS = 1024
"""Query rows per block: the blocks the kernels computed when matrices were stored, so that
BLAS-based metrics give the same last digits as before."""
EXACT_BLOCK_ROWS = 256
"""Query rows per block where the kernel's sums are exact integers (uint8 rows: SAD, Hamming),
so that any blocks give the same values: four of the kernel's 64-row panels. Blocks in flight
are fresh memory at first, and its pages cost faults: at N = 35,000, zeroing four 1,024-row
blocks took the kernel's threads about 0.9 CPU-s in a cold catgraph run (docs/scaling.md)."""


#: Computes blocks of query rows against fixed references and yields them in order: the query
#: rows, the references prepared for the kernel, and (start, stop) of each block.
BlockRunner = Callable[[NDArray, DifferencesTo, list[tuple[int, int]]], Iterator[NDArray[np.float32]]]


def prefetched_blocks(data: NDArray, to: DifferencesTo, ranges: list[tuple[int, int]]) -> Iterator[NDArray[np.float32]]:
    """The blocks in order, each computed in a helper thread while the caller works on the one
    before (the kernels release the GIL), so a method's steps and the kernel overlap; the
    memory of blocks the caller has let go is used again (``wiloc.recycled``)."""
    blocks = RecycledArrays(np.float32)
    return computed_ahead(to(data[start:end], blocks.take((end - start, to.shape[0]))) for start, end in ranges)


class ComputedDifferences:
    """Differences of descriptor rows to fixed references, computed block of rows by block of
    rows when read and never stored. ``runner`` computes the blocks of :meth:`iter_rows` (default:
    in this process, one block ahead; ``wiloc.description.cluster`` runs them on a Dask cluster)."""

    def __init__(self, data: NDArray, to: DifferencesTo, runner: BlockRunner | None = None) -> None:
        self._data = data
        self._to = to
        self._runner = runner or prefetched_blocks

    @property
    def shape(self) -> tuple[int, int]:
        return int(self._data.shape[0]), int(self._to.shape[0])

    def rows(self, start: int, stop: int) -> NDArray[np.float32]:
        """Rows start..stop as a float32 block, computed now."""
        return self._to(self._data[start:stop])

    @property
    def block_rows(self) -> int:
        """Query rows per block unless told: :data:`EXACT_BLOCK_ROWS` for exact kernels, else
        :data:`DEFAULT_BLOCK_ROWS`."""
        return EXACT_BLOCK_ROWS if self._to.exact else DEFAULT_BLOCK_ROWS

    def blocks(self, block_rows: int | None = None) -> Iterator[tuple[int, NDArray[np.float32]]]:
        """(first row, float32 block) over every row in order, computed by the runner."""
        block_rows = block_rows or self.block_rows
        ranges = [(start, min(start + block_rows, self.shape[0])) for start in range(0, self.shape[0], block_rows)]
        for (start, _), block in zip(ranges, self._runner(self._data, self._to, ranges)):
            yield start, block

    def iter_rows(self, block_rows: int | None = None) -> Iterator[NDArray[np.float64]]:
        """Every row in order as float64 (converted one at a time: a block stays float32)."""
        for _, block in self.blocks(block_rows):
            for row in block:
                yield row.astype(np.float64)


def _sweep(matrix: RowBlocks) -> Iterator[tuple[int, NDArray[np.floating]]]:
    """(first row, block) over every row of ``matrix``; a computed one computes ahead."""
    if isinstance(matrix, ComputedDifferences):
        yield from matrix.blocks()
        return
    block_rows = DEFAULT_BLOCK_ROWS
    for start in range(0, matrix.shape[0], block_rows):
        yield start, matrix.rows(start, min(start + block_rows, matrix.shape[0]))


def summarize(matrix: RowBlocks, exclude_recent: int, progress: Progress | None = None) -> MapSummary:
    """The summary of a square self-difference matrix, swept once block by block; non-finite
    values count as no difference."""
    n_rows = matrix.shape[0]
    minima = np.full(n_rows, np.inf)
    largest = np.zeros(n_rows)
    for start, block in _sweep(matrix):
        stop = start + block.shape[0]
        band_extremes(np.ascontiguousarray(block, dtype=np.float32), start, exclude_recent,
                      minima[start:stop], largest[start:stop])
        if progress is not None:
            progress(stop, n_rows)
    return MapSummary(minima=minima, largest=float(largest.max(initial=0.0)))


def check_comparable(query: Entry, ref: Entry) -> None:
    """Raise WilocError naming both folders when the two entries cannot be compared."""
    problems = []
    if query.descriptor != ref.descriptor:  # say first what the scale or length below follow from
        problems.append(f"descriptor {query.descriptor} vs {ref.descriptor} (describe both alike)")
    if query.metric != ref.metric:
        problems.append(f"metric {query.metric} vs {ref.metric}")
    if query.scale != ref.scale:
        problems.append(f"scale {query.scale:g} vs {ref.scale:g}")
    if query.data.shape[1:] != ref.data.shape[1:]:
        problems.append(f"descriptor length {query.data.shape[1]} vs {ref.data.shape[1]}")
    if problems:
        raise WilocError(query.folder, f"cannot be compared with {ref.folder}: {', '.join(problems)}")


def differences(query: Entry, ref: Entry, runner: BlockRunner | None = None) -> ComputedDifferences:
    """The query x reference differences as a row-block reader, computed as read."""
    check_comparable(query, ref)
    return ComputedDifferences(query.data, DifferencesTo(ref.data, ref.metric, ref.scale), runner)


def _summary_attrs(ref: Entry, exclude_recent: int) -> dict[str, object]:
    return {"ref_digest": ref.digest, "metric": ref.metric, "scale": ref.scale, "exclude_recent": exclude_recent,
            "differences_version": DIFFERENCES_VERSION}


def _read_summary(path: Path, ref: Entry, exclude_recent: int, repairs: list[str] | None = None) -> MapSummary | None:
    """The summary stored at ``path`` if it is the one of exactly this map and R, else None; a
    file there that cannot be read (damaged: its checksum failed) is noted in ``repairs``."""
    try:
        with h5py.File(path, "r") as f:
            current = all(f.attrs.get(k) == v for k, v in _summary_attrs(ref, exclude_recent).items())
            largest = f.get("largest")  # None in a file of the old layout, where it was an attribute
            if not current or largest is None or largest.shape != (1,) or f["minima"].shape != (len(ref.names),):
                return None
            return MapSummary(minima=f["minima"][()], largest=float(largest[0]))
    except (OSError, KeyError) as exc:
        if repairs is not None and path.exists():
            repairs.append(f"{path}: unreadable map summary ({exc}); computed again")
        return None


def map_summary(ref: Entry, cache: Cache, exclude_recent: int, runner: BlockRunner | None = None,
                progress: Progress | None = None) -> MapSummary:
    """The map's self-difference summary, reused from the cache or computed (``progress(done,
    total)`` counts map rows then; the N x N differences are swept once and never stored)."""
    name = f"differences/{ref.key}-self-r{exclude_recent}.h5"
    path = cache.root / name
    summary = _read_summary(path, ref, exclude_recent)
    if summary is not None:
        return summary
    with cache.lock(name):
        summary = _read_summary(path, ref, exclude_recent, cache.repairs)  # another process may have written it
        if summary is None:
            summary = summarize(differences(ref, ref, runner), exclude_recent, progress)
            with cache.atomic_h5(path) as f:
                f.create_dataset("minima", data=summary.minima, fletcher32=True)
                f.create_dataset("largest", data=[summary.largest], dtype=np.float64, fletcher32=True)
                f.attrs.update(ref_folder=ref.folder, wiloc_version=__version__, **_summary_attrs(ref, exclude_recent))
    return summary


def candidate_blocks(matrix: ComputedDifferences, sequence: bool,
                     exclude_recent: int) -> Iterator[NDArray[np.float32]]:
    """Blocks of consecutive difference rows over the candidate frames, float32 as the kernels
    give them, inf where a frame is no candidate.

    Map mode: the rows as they are. Sequence mode (the traversal against itself): row k keeps
    only frames i < k - exclude_recent.
    """
    if exclude_recent < 0:
        raise ValueError(f"exclude_recent must be >= 0, got {exclude_recent}")
    if sequence and matrix.shape[0] != matrix.shape[1]:
        raise ValueError(f"sequence mode needs a square matrix, got {matrix.shape}")
    for start, block in matrix.blocks():
        if sequence:
            for k, row in enumerate(block, start):
                row[max(0, k - exclude_recent):] = np.inf
        yield block


def candidate_rows(matrix: ComputedDifferences, sequence: bool, exclude_recent: int) -> Iterator[NDArray[np.float64]]:
    """The rows of :func:`candidate_blocks` one by one, float64."""
    for block in candidate_blocks(matrix, sequence, exclude_recent):
        for row in block:
            yield row.astype(np.float64)


@dataclass(frozen=True)
class RunDifferences:
    """Where a run's differences come from: its query rows (against the map, or in sequence mode
    against the traversal itself) and the cached summary of the map's differences to itself."""

    rows: ComputedDifferences
    map_summary: Callable[[], MapSummary]


def run_differences(query: Entry, ref: Entry, cache: Cache, exclude_recent: int, runner: BlockRunner | None = None,
                    progress: Progress | None = None) -> RunDifferences:
    """The row-block readers of a run of ``query`` against ``ref`` (the same entry in sequence
    mode), computed as read; the map's summary is read from ``cache`` or computed into it on
    first use (``progress`` counts its map rows)."""
    return RunDifferences(rows=differences(query, ref, runner),
                          map_summary=lambda: map_summary(ref, cache, exclude_recent, runner, progress))

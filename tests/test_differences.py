"""Difference rows computed block by block; the map summary: values, cache reuse, invalidation,
errors, crash safety."""
from __future__ import annotations

import dataclasses
import struct
import threading
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import make_entry

from wiloc.cache.store import Cache, Entry
from wiloc.description.differences import candidate_rows, differences, map_summary, prefetched_blocks, summarize
from wiloc.description.distances import pairwise
from wiloc.errors import WilocError
from wiloc.rows import ArrayRows, MapSummary


class Counter:
    """A progress callback that records its calls."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, int]] = []

    def __call__(self, done: int, total: int) -> None:
        self.calls.append((done, total))


@pytest.fixture
def cache(tmp_path: Path) -> Cache:
    return Cache(tmp_path / "cache")


def brute_summary(entry: Entry, exclude: int) -> MapSummary:
    """The summary the slow way: the whole matrix in float64, the band masked."""
    d = pairwise(entry.data, entry.data, entry.metric, entry.scale).astype(np.float64)
    n = d.shape[0]
    band = np.abs(np.arange(n)[:, None] - np.arange(n)[None, :]) <= exclude
    return MapSummary(minima=np.where(band, np.inf, d).min(axis=1, initial=np.inf), largest=float(d.max(initial=0.0)))


def test_rows_are_the_kernels_differences_in_any_block_size() -> None:
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    m = differences(query, ref)
    expected = pairwise(query.data, ref.data, "l1", 0.5)
    assert m.shape == (10, 7)
    np.testing.assert_array_equal(m.rows(2, 5), expected[2:5])
    for block_rows in (1, 3, 4, 10, 64):
        rows = list(m.iter_rows(block_rows))
        assert len(rows) == 10 and all(r.dtype == np.float64 for r in rows)
        np.testing.assert_array_equal(np.stack(rows), expected)


def test_empty_query_has_no_rows() -> None:
    m = differences(make_entry("q", 0, 1), make_entry("r", 5, 2))
    assert m.shape == (0, 5)
    assert list(m.iter_rows()) == []


class FailingKernel:
    """Differences to one reference row: the query value itself, failing on a row of value 3."""

    shape = (1, 1)

    def __call__(self, rows: np.ndarray, out: np.ndarray) -> np.ndarray:
        if rows[0, 0] == 3:
            raise RuntimeError("kernel failed")
        out[:] = rows
        return out


def test_prefetching_hands_a_kernel_error_to_the_reader() -> None:
    data = np.arange(6, dtype=np.float32)[:, None]
    blocks = prefetched_blocks(data, FailingKernel(), [(0, 2), (2, 3), (3, 6)])  # type: ignore[arg-type]
    assert next(blocks).tolist() == [[0.0], [1.0]]
    assert next(blocks).tolist() == [[2.0]]
    with pytest.raises(RuntimeError, match="kernel failed"):
        next(blocks)


def test_a_reader_that_stops_early_stops_the_helper_thread() -> None:
    query, ref = make_entry("q", 50, 1), make_entry("r", 7, 2)
    before = threading.active_count()
    rows = differences(query, ref).iter_rows(block_rows=2)
    next(rows)
    rows.close()
    assert threading.active_count() == before


@pytest.mark.parametrize("exclude", [0, 2, 30])
def test_summary_is_the_band_masked_minimum_and_the_largest_value(exclude: int) -> None:
    entry = make_entry("r", 23, 3)
    got = summarize(differences(entry, entry), exclude)
    want = brute_summary(entry, exclude)
    np.testing.assert_array_equal(got.minima, want.minima)
    assert got.largest == want.largest
    from_array = summarize(ArrayRows(pairwise(entry.data, entry.data, "l1", 0.5)), exclude)
    np.testing.assert_array_equal(from_array.minima, want.minima)
    assert from_array.largest == want.largest
    assert np.isinf(got.minima).all() == (exclude >= 22)


def test_summary_ignores_values_that_are_not_finite() -> None:
    s = summarize(ArrayRows(np.array([[0, np.nan, 5], [np.inf, 0, 2], [4, 1, 0]], np.float32)), 0)
    np.testing.assert_array_equal(s.minima, [5.0, 2.0, 1.0])
    assert s.largest == 5.0


def test_map_summary_is_cached_and_reused(cache: Cache) -> None:
    ref = make_entry("r", 12, 2)
    first, second = Counter(), Counter()
    s1 = map_summary(ref, cache, 2, progress=first)
    path = cache.root / "differences" / "r-self-r2.h5"
    stamp = path.stat().st_mtime_ns
    s2 = map_summary(ref, cache, 2, progress=second)
    assert first.calls[-1] == (12, 12) and not second.calls
    assert path.stat().st_mtime_ns == stamp
    np.testing.assert_array_equal(s1.minima, s2.minima)
    assert s1.largest == s2.largest == brute_summary(ref, 2).largest
    with h5py.File(path, "r") as f:
        assert f.attrs["ref_digest"] == ref.digest and f.attrs["exclude_recent"] == 2
        assert "wiloc_version" in f.attrs
    assert path.stat().st_size < 20_000  # no N x N matrix in the cache


@pytest.mark.parametrize("change", ["ref", "metric", "scale"])
def test_changed_map_recomputes_its_summary(cache: Cache, change: str) -> None:
    ref = make_entry("r", 12, 2)
    map_summary(ref, cache, 2)
    if change == "ref":
        ref = make_entry("r", 12, 4)
    else:
        ref = dataclasses.replace(ref, **({"metric": "hamming"} if change == "metric" else {"scale": 0.25}))
    counter = Counter()
    got = map_summary(ref, cache, 2, progress=counter)
    assert counter.calls
    np.testing.assert_array_equal(got.minima, brute_summary(ref, 2).minima)


def test_another_recent_window_is_another_summary(cache: Cache) -> None:
    ref = make_entry("r", 12, 2)
    wide, narrow = map_summary(ref, cache, 5), map_summary(ref, cache, 1)
    np.testing.assert_array_equal(wide.minima, brute_summary(ref, 5).minima)
    np.testing.assert_array_equal(narrow.minima, brute_summary(ref, 1).minima)
    assert {p.name for p in (cache.root / "differences").glob("*.h5")} == {"r-self-r5.h5", "r-self-r1.h5"}


def test_candidate_rows_mask_recent_frames_in_sequence_mode() -> None:
    route = make_entry("s", 9, 5)
    exclude = 2
    m = differences(route, route)
    full = m.rows(0, 9).astype(np.float64)
    seq = list(candidate_rows(m, sequence=True, exclude_recent=exclude))
    mapped = list(candidate_rows(m, sequence=False, exclude_recent=exclude))
    for k, row in enumerate(seq):
        candidates = np.arange(9) < k - exclude
        assert np.all(np.isinf(row[~candidates]))
        np.testing.assert_array_equal(row[candidates], full[k, candidates])
    np.testing.assert_array_equal(np.stack(mapped), full)


def test_candidate_rows_reject_bad_requests() -> None:
    m = differences(make_entry("q", 4, 1), make_entry("r", 3, 2))
    with pytest.raises(ValueError, match="square"):
        next(candidate_rows(m, sequence=True, exclude_recent=0))
    with pytest.raises(ValueError, match="exclude_recent"):
        next(candidate_rows(m, sequence=False, exclude_recent=-1))


@pytest.mark.parametrize(
    ("ref_change", "problem"),
    [
        ({"metric": "hamming"}, "metric l1 vs hamming"),
        ({"scale": 1.0}, "scale 0.5 vs 1"),
        ({"length": 40}, "length 48 vs 40"),
    ],
)
def test_incompatible_entries_name_both_folders(ref_change: dict, problem: str) -> None:
    query, ref = make_entry("q", 4, 1), make_entry("r", 3, 2, **ref_change)
    with pytest.raises(WilocError) as caught:
        differences(query, ref)
    message = str(caught.value)
    assert query.folder in message and ref.folder in message and problem in message
    assert "\n" not in message


_KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from helpers import make_entry
from wiloc.cache.store import Cache
from wiloc.description.differences import map_summary

def die(done, total):
    if done == total:
        os.kill(os.getpid(), signal.SIGKILL)

map_summary(make_entry("r", 10, 2), Cache({root!r}), 2, progress=die)
"""


def test_killed_summary_writer_leaves_no_file(cache: Cache) -> None:
    script = _KILLED_WRITER.format(tests=str(Path(__file__).parent), root=str(cache.root))
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == -9, result.stderr[-2000:]
    assert not (cache.root / "differences" / "r-self-r2.h5").exists()
    ref = make_entry("r", 10, 2)
    np.testing.assert_array_equal(map_summary(ref, cache, 2).minima, brute_summary(ref, 2).minima)


def test_a_damaged_summary_is_computed_again(cache: Cache) -> None:
    ref = make_entry("r", 12, 2)
    map_summary(ref, cache, 2)
    path = cache.root / "differences" / "r-self-r2.h5"
    with h5py.File(path, "r") as f:
        offset = f["minima"].id.get_offset() if f["minima"].chunks is None else \
            f["minima"].id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset:offset + 16] = bytes(16)  # zero the first values: the checksum no longer holds
    path.write_bytes(bytes(data))
    counter = Counter()
    got = map_summary(ref, cache, 2, progress=counter)
    assert counter.calls
    np.testing.assert_array_equal(got.minima, brute_summary(ref, 2).minima)


def test_recycled_blocks_give_the_same_rows_as_fresh_ones() -> None:
    query, ref = make_entry("q", 50, 1), make_entry("r", 7, 2)
    computed = differences(query, ref)
    kept = [block.copy() for _, block in computed.blocks(block_rows=8)]
    rows = list(computed.iter_rows(block_rows=8))
    np.testing.assert_array_equal(np.vstack(kept), computed.rows(0, 50))
    np.testing.assert_array_equal(np.vstack(rows), computed.rows(0, 50))


def test_a_damaged_largest_difference_is_noticed_and_computed_again(cache: Cache) -> None:
    """``largest`` is threshold's d_max without a natural maximum: a flipped bit in it changed every
    confidence silently; it is kept under a checksum, so the damage is noted and recomputed."""
    ref = make_entry("r", 12, 2)
    clean = map_summary(ref, cache, 2)
    path = cache.root / "differences" / "r-self-r2.h5"
    data = bytearray(path.read_bytes())
    stored = struct.pack("<d", clean.largest)
    offset = data.find(stored)
    assert offset >= 0 and data.find(stored, offset + 1) < 0  # the value is stored once, as is
    data[offset + 6] ^= 0x01  # one bit of the mantissa, as a bad disk would flip it
    path.write_bytes(bytes(data))
    counter = Counter()
    got = map_summary(ref, cache, 2, progress=counter)
    assert counter.calls and got.largest == clean.largest
    assert [line.split(" (")[0] for line in cache.repairs] == [f"{path}: unreadable map summary"]


def test_a_summary_of_the_old_layout_is_computed_again_without_a_note(cache: Cache) -> None:
    """Summaries written before ``largest`` had its checksum are not current: recomputed, not damaged."""
    ref = make_entry("r", 12, 2)
    clean = map_summary(ref, cache, 2)
    path = cache.root / "differences" / "r-self-r2.h5"
    with h5py.File(path, "r+") as f:  # the old layout: the value as an unchecked attribute only
        del f["largest"]
        f.attrs["largest"] = clean.largest
    counter = Counter()
    got = map_summary(ref, cache, 2, progress=counter)
    assert counter.calls and got.largest == clean.largest and not cache.repairs
    with h5py.File(path, "r") as f:
        assert f["largest"].fletcher32 and "largest" not in f.attrs

"""Cached difference matrices: reuse, invalidation, blockwise reading, masking, errors, crash safety."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from wiloc.cache import Cache, Entry
from wiloc.differences import DifferenceMatrix, candidate_rows, difference_matrix
from wiloc.distances import pairwise
from wiloc.errors import WilocError


def make_entry(key: str, rows: int, seed: int, metric: str = "l1", scale: float = 0.5, length: int = 48) -> Entry:
    """A small uint8 entry whose digest follows its content, as the cache's digests do."""
    data = np.random.default_rng(seed).integers(0, 256, (rows, length), dtype=np.uint8)
    return Entry(
        key=key, folder=f"/routes/{key}", descriptor="sad", params={}, metric=metric, scale=scale,
        natural_max=None, dtype=data.dtype.str, length=length,
        names=[f"{key}{i:04d}.png" for i in range(rows)], data=data,
        digest=f"{key}-{seed}-{rows}-{length}",
    )


class Counter:
    """A progress callback that records its calls."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, int]] = []

    def __call__(self, done: int, total: int) -> None:
        self.calls.append((done, total))


@pytest.fixture
def cache(tmp_path: Path) -> Cache:
    return Cache(tmp_path / "cache")


def test_matrix_holds_the_differences(cache: Cache) -> None:
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    with difference_matrix(query, ref, cache) as m:
        assert m.shape == (10, 7)
        assert m.path == cache.root / "differences" / "q-r.h5"
        assert m.metric == "l1" and m.scale == 0.5
        assert m.query_names == query.names and m.ref_names == ref.names
        expected = pairwise(query.data, ref.data, "l1", 0.5)
        block = m.rows(2, 5)
        assert block.dtype == np.float32
        np.testing.assert_array_equal(block, expected[2:5])
        assert m.row(4).dtype == np.float64
        np.testing.assert_array_equal(m.row(4), expected[4])
    with h5py.File(m.path, "r") as f:
        assert f.attrs["query_digest"] == query.digest and f.attrs["ref_digest"] == ref.digest
        assert "wiloc_version" in f.attrs


def test_second_call_reuses_the_file(cache: Cache) -> None:
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    first, second = Counter(), Counter()
    with difference_matrix(query, ref, cache, progress=first) as m:
        stamp = m.path.stat().st_mtime_ns
    with difference_matrix(query, ref, cache, progress=second) as m:
        assert m.path.stat().st_mtime_ns == stamp
    assert first.calls and not second.calls


@pytest.mark.parametrize("change", ["query", "ref", "metric"])
def test_changed_entry_recomputes(cache: Cache, change: str) -> None:
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    difference_matrix(query, ref, cache).close()
    if change == "query":
        query = make_entry("q", 12, 3)
    elif change == "ref":
        ref = make_entry("r", 7, 4)
    else:
        query = dataclasses.replace(query, metric="hamming")
        ref = dataclasses.replace(ref, metric="hamming")
    counter = Counter()
    with difference_matrix(query, ref, cache, progress=counter) as m:
        np.testing.assert_array_equal(m.rows(0, m.shape[0]), pairwise(query.data, ref.data, query.metric, 0.5))
    assert counter.calls


def test_small_blocks_write_and_read_everything(cache: Cache) -> None:
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    counter = Counter()
    with difference_matrix(query, ref, cache, progress=counter, block_rows=3) as m:
        assert counter.calls == [(3, 10), (6, 10), (9, 10), (10, 10)]
        rows = list(m.iter_rows(block_rows=4))
    expected = pairwise(query.data, ref.data, "l1", 0.5)
    assert len(rows) == 10 and all(r.dtype == np.float64 for r in rows)
    np.testing.assert_array_equal(np.stack(rows), expected)


def test_empty_query(cache: Cache) -> None:
    with difference_matrix(make_entry("q", 0, 1), make_entry("r", 5, 2), cache) as m:
        assert m.shape == (0, 5)
        assert list(m.iter_rows()) == []


def test_candidate_rows_mask_recent_frames_in_sequence_mode(cache: Cache) -> None:
    route = make_entry("s", 9, 5)
    exclude = 2
    with difference_matrix(route, route, cache) as m:
        full = m.rows(0, 9).astype(np.float64)
        seq = list(candidate_rows(m, sequence=True, exclude_recent=exclude))
        mapped = list(candidate_rows(m, sequence=False, exclude_recent=exclude))
    for k, row in enumerate(seq):
        candidates = np.arange(9) < k - exclude
        assert np.all(np.isinf(row[~candidates]))
        np.testing.assert_array_equal(row[candidates], full[k, candidates])
    np.testing.assert_array_equal(np.stack(mapped), full)


def test_candidate_rows_reject_bad_requests(cache: Cache) -> None:
    with difference_matrix(make_entry("q", 4, 1), make_entry("r", 3, 2), cache) as m:
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
def test_incompatible_entries_name_both_folders(cache: Cache, ref_change: dict, problem: str) -> None:
    query, ref = make_entry("q", 4, 1), make_entry("r", 3, 2, **ref_change)
    with pytest.raises(WilocError) as caught:
        difference_matrix(query, ref, cache)
    message = str(caught.value)
    assert query.folder in message and ref.folder in message and problem in message
    assert "\n" not in message
    assert not (cache.root / "differences" / "q-r.h5").exists()


_KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from test_differences import make_entry
from wiloc.cache import Cache
from wiloc.differences import difference_matrix

def die(done, total):
    os.kill(os.getpid(), signal.SIGKILL)

difference_matrix(make_entry("q", 10, 1), make_entry("r", 7, 2), Cache({root!r}), progress=die, block_rows=3)
"""


def test_killed_writer_leaves_no_complete_looking_file(cache: Cache) -> None:
    script = _KILLED_WRITER.format(tests=str(Path(__file__).parent), root=str(cache.root))
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == -9, result.stderr[-2000:]
    final = cache.root / "differences" / "q-r.h5"
    assert not final.exists()
    assert any(p.name.startswith(".q-r.h5") for p in final.parent.iterdir())  # the abandoned temp file
    query, ref = make_entry("q", 10, 1), make_entry("r", 7, 2)
    with difference_matrix(query, ref, cache) as m:
        np.testing.assert_array_equal(m.rows(0, 10), pairwise(query.data, ref.data, "l1", 0.5))


def test_matrix_file_closes(cache: Cache) -> None:
    m = difference_matrix(make_entry("q", 3, 1), make_entry("r", 3, 2), cache)
    assert isinstance(m, DifferenceMatrix)
    m.close()
    with pytest.raises((ValueError, RuntimeError, KeyError, OSError)):
        m.rows(0, 1)
    os.remove(m.path)  # closed: the file can go

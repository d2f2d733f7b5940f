"""The cache's primitives: atomic HDF5 writes, temp-file cleanup, the lock, the journal."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from wiloc.cache.entries import EntryHeader, FrameRecord, StoredEntry, checksum
from wiloc.cache.features import FeatureStore
from wiloc.cache.store import TEMP_SUFFIX, Cache
from wiloc.errors import WilocError


def _header(folder: str = "/data/route", length: int = 4) -> EntryHeader:
    return EntryHeader.create(folder, "fake", {"k": (1, 2)}, "l1", 2.0, None, np.float32, length)


def _record(name: str, value: float, length: int = 4) -> FrameRecord:
    return FrameRecord(name, 10, 20, f"digest-{name}", np.full(length, value, np.float32), "", 64, 48)


def test_default_root_is_wiloc_cache_env(cache_dir: Path) -> None:
    assert Cache().root == cache_dir.resolve()


def test_atomic_h5_replaces_on_success_and_keeps_old_file_on_error(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    target = cache.root / "sub" / "m.h5"
    with cache.atomic_h5(target) as f:
        f["x"] = np.arange(3)
    with pytest.raises(RuntimeError), cache.atomic_h5(target) as f:
        f["x"] = np.arange(5)
        raise RuntimeError("fail mid-write")
    with h5py.File(target, "r") as f:
        np.testing.assert_array_equal(f["x"][()], np.arange(3))
    assert sorted(p.name for p in target.parent.iterdir()) == ["m.h5"]


def test_clean_temp_files_removes_only_orphans(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    folder = tmp_path / "c" / "differences"
    folder.mkdir(parents=True)
    orphan = folder / f".m.h5.{dead.stdout.strip()}.ab12{TEMP_SUFFIX}"
    live = folder / f".m.h5.{os.getpid()}.cd34{TEMP_SUFFIX}"
    orphan.write_bytes(b"half")
    live.write_bytes(b"half")
    cache = Cache(tmp_path / "c")
    assert orphan.exists()  # construction does no work
    with cache.atomic_h5(folder / "other.h5") as f:  # the first write sweeps
        f["x"] = np.arange(2)
    assert not orphan.exists()
    assert live.exists()


def test_construction_creates_nothing(tmp_path: Path) -> None:
    Cache(tmp_path / "new")
    assert not (tmp_path / "new").exists()


def test_lock_times_out_in_another_process_naming_the_holder(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    code = (
        "import sys; from pathlib import Path; from wiloc.cache.store import Cache\n"
        "from wiloc.errors import CacheBusyError\n"
        "try:\n"
        f"    with Cache(Path({str(cache.root)!r})).lock('descriptors/k.h5', timeout=0.2): pass\n"
        "except CacheBusyError as e: print(e); sys.exit(3)\n"
    )
    with cache.lock("descriptors/k.h5"), cache.lock("descriptors/k.h5", timeout=0):  # re-entrant
        busy = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert busy.returncode == 3
    assert f"(pid {os.getpid()})" in busy.stdout
    assert str(cache.root / "descriptors" / "k.h5") in busy.stdout
    free = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert free.returncode == 0, free.stderr


def test_lock_rejects_names_outside_the_cache(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    for name in ("../x", "/etc/x", ""):
        with pytest.raises(ValueError), cache.lock(name):
            pass


def _journal(cache: Cache, header: EntryHeader, frames: int) -> Path:
    """A journal of ``frames`` records (f0.png, f1.png, ...), as a run killed after them leaves it."""
    journal = cache.open_journal(header)
    for i in range(frames):
        journal.append(_record(f"f{i}.png", i))
    journal.close()
    return cache.journal_path(header.key)


def test_journal_survives_a_torn_record_and_folds_into_the_entry(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    header = _header()
    path = _journal(cache, header, 3)
    whole = path.stat().st_size
    with open(path, "ab") as f:  # a kill in the middle of the fourth record
        f.write(b"WJR1\x40\x00\x00\x00garbage")
    stored = cache.read_stored(header.key)
    assert stored is not None and stored.journaled and not stored.complete
    assert sorted(stored.records) == ["f0.png", "f1.png", "f2.png"]
    assert cache.repairs == []  # a record cut short by a kill is expected, not damage
    [info] = cache.list_entries()
    assert (info.frames, info.complete, info.key) == (3, False, header.key)

    journal = cache.open_journal(header)  # truncates the torn tail before appending
    assert path.stat().st_size == whole
    journal.append(_record("f3.png", 3))
    journal.close()
    stored = cache.read_stored(header.key)
    entry = cache.write_entry(stored, complete=True)
    assert not path.exists()
    assert entry.names == ["f0.png", "f1.png", "f2.png", "f3.png"]
    np.testing.assert_array_equal(entry.data[:, 0], [0, 1, 2, 3])
    again = cache.read_entry(header.key)
    assert again.digest == entry.digest
    np.testing.assert_array_equal(again.data, entry.data)
    assert again.params == {"k": [1, 2]}


def test_entry_file_layout_is_plain_h5py(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    header = _header()
    stored = StoredEntry(header, {
        "a10.png": _record("a10.png", 1.0),
        "a2.png": _record("a2.png", 2.0),
        "bad.png": FrameRecord("bad.png", 0, 5, "d", None, "empty file (0 bytes)"),
    })
    cache.write_entry(stored, complete=True)
    with h5py.File(cache.entry_path(header.key), "r") as f:
        assert f.attrs["complete"] and f.attrs["descriptor"] == "fake"
        assert [n.decode() for n in f["frames/name"][()]] == ["a2.png", "a10.png"]
        assert f["descriptors"].shape == (2, 4) and f["descriptors"].dtype == np.float32
        assert [r.decode() for r in f["failed/reason"][()]] == ["empty file (0 bytes)"]
        for attr in ("folder", "params", "metric", "scale", "dtype", "wiloc_version", "created",
                     "updated", "digest"):
            assert attr in f.attrs


def test_entry_digest_follows_content_not_mtime(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    base = StoredEntry(_header(), {"a.png": _record("a.png", 1.0)})
    touched = StoredEntry(_header(), {"a.png": FrameRecord("a.png", 10, 99, "digest-a.png",
                                                           np.full(4, 1.0, np.float32))})
    edited = StoredEntry(_header(), {"a.png": FrameRecord("a.png", 10, 20, "other",
                                                          np.full(4, 1.0, np.float32))})
    assert base.entry().digest == touched.entry().digest != edited.entry().digest
    assert cache.list_entries() == []


def test_external_entry_keeps_the_file_row_order(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    names = ["zeta", "alpha", "mid10", "mid2", "beta"]  # time order, not name order
    header = EntryHeader.create("/data/m.npy", "external", {}, "l1", 1.0, None, np.float32, 4)
    stored = StoredEntry(header, {name: _record(name, i) for i, name in enumerate(names)})
    assert stored.entry().names == names
    cache.write_entry(stored, complete=True)
    again = cache.read_entry(header.key)
    assert again.names == names
    np.testing.assert_array_equal(again.data[:, 0], np.arange(5))
    folder = StoredEntry(_header(), {name: _record(name, i) for i, name in enumerate(names)})
    assert folder.entry().names == ["alpha", "beta", "mid2", "mid10", "zeta"]


def test_ordered_takes_a_listing_for_the_sort() -> None:
    names = ["a10.png", "A2.png", "a02.png", "b.png", "bad.png"]
    stored = StoredEntry(_header(), {name: _record(name, i) for i, name in enumerate(names)})
    stored.records["bad.png"] = FrameRecord("bad.png", 0, 5, "d", None, "empty file (0 bytes)")
    listed = ["A2.png", "a02.png", "a10.png", "b.png", "bad.png"]  # natural order, as listed
    assert [r.name for r in stored.ordered()] == listed
    assert stored.ordered(listed) == stored.ordered()
    by_sort, by_listing = stored.entry(), stored.entry(listed)
    assert by_sort.names == listed[:4]
    assert (by_listing.names, by_listing.digest) == (by_sort.names, by_sort.digest)
    np.testing.assert_array_equal(by_listing.data, by_sort.data)


def _json_checksum(record: FrameRecord, dtype: str) -> int:
    """The checksum as entry files have always stored it: CRC-32 of json.dumps of the fields,
    then the row bytes."""
    if record.row is None:
        fields = [record.name, record.size, record.mtime_ns, record.digest, record.reason]
        row = b""
    else:
        fields = [record.name, record.size, record.mtime_ns, record.digest, record.width, record.height,
                  record.timestamp_ms]
        row = np.ascontiguousarray(record.row, np.dtype(dtype)).tobytes()
    return zlib.crc32(json.dumps(fields).encode() + row)


_AWKWARD = ["img1.png", "Ünïcødé 東京 🚗.jpg", 'say "cheese".png', "back\\slash\\.jpg", "tab\tnew\nline.png",
            "ctl\x00\x01\x1f\x7f.png", "sep\u2028\u2029.png", "bad byte \udcff.jpg", "/", ""]


@pytest.mark.parametrize("name", _AWKWARD)
def test_checksum_is_that_of_its_json_definition(name: str) -> None:
    """Checksums written by earlier versions must still verify: the same CRC for every record."""
    row = np.array([0.5, -0.0, np.nan, 1e30], np.float32)
    for stamp in (None, 0.0, 66.733, -0.0, 1 / 3, 1e16, 5e-324, float("nan"), float("inf"), float("-inf"),
                  np.float64(33.4)):
        for size, mtime in ((1234, 1_733_000_000_123_456_789), (-1, -1), (0, 2**70)):
            record = FrameRecord(name, size, mtime, f"{name}-digest", row, "", 640, 480, stamp)
            assert checksum(record, "<f4") == _json_checksum(record, "<f4"), (stamp, size)
            failed = FrameRecord(name, size, mtime, "", None, f"cannot read {name!r} ({name})")
            assert checksum(failed, "<f4") == _json_checksum(failed, "<f4")
    odd = FrameRecord(name, 1, 2, "d", row.astype(np.float64), "", True, 3, None)  # json writes a bool its way
    assert checksum(odd, "<f4") == _json_checksum(odd, "<f4")


@pytest.mark.parametrize("content", ["garbage", "empty-h5", "garbage+journal"])
def test_list_entries_shows_an_unreadable_entry(tmp_path: Path, content: str) -> None:
    cache = Cache(tmp_path / "c")
    good = StoredEntry(_header(), {"a.png": _record("a.png", 1.0)})
    cache.write_entry(good, complete=True)
    bad = cache.entry_path("0badbadbadbadbadbadbadba")
    if content == "empty-h5":
        with h5py.File(bad, "w") as f:
            f["x"] = 1
    else:
        bad.write_bytes(b"this is not an HDF5 file" * 10)
    if content.endswith("journal"):
        header = _header("/d")
        cache.open_journal(header).close()
        cache.journal_path(header.key).rename(cache.journal_path("0badbadbadbadbadbadbadba"))
    infos = {info.key: info for info in cache.list_entries()}
    assert infos[good.header.key].complete and infos[good.header.key].problem == ""
    info = infos["0badbadbadbadbadbadbadba"]
    assert (info.descriptor, info.complete, info.frames, info.size > 0) == ("unreadable", False, 0, True)
    assert info.problem.startswith(f"{bad}: unreadable cache entry")
    assert "\n" not in info.problem


def test_list_entries_shows_an_entry_whose_journal_cannot_be_read(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A folder where an entry's journal belongs (or one without permission) ended the whole
    listing in its OSError: the entry is listed as unreadable, naming the journal, and the others too."""
    cache = Cache(tmp_path / "c")
    good = StoredEntry(_header(), {"a.png": _record("a.png", 1.0)})
    cache.write_entry(good, complete=True)
    other = StoredEntry(_header("/d"), {"a.png": _record("a.png", 1.0)})
    cache.write_entry(other, complete=True)
    cache.journal_path(other.header.key).mkdir()
    infos = {info.key: info for info in cache.list_entries()}
    assert infos[good.header.key].complete and infos[good.header.key].problem == ""
    info = infos[other.header.key]
    assert info.descriptor == "unreadable" and not info.complete
    assert info.problem == f"{cache.journal_path(other.header.key)}: a folder where a cache file belongs; remove it"
    cache.journal_path(other.header.key).rmdir()
    cache.open_journal(other.header).close()
    journal = cache.journal_path(other.header.key)

    def refused(path: Path) -> object:  # as for a user without permission (tests run as root)
        raise PermissionError(13, "Permission denied", str(path))

    from wiloc.cache import store
    monkeypatch.setattr(store, "scan_journal", refused)
    info = {i.key: i for i in cache.list_entries()}[other.header.key]
    assert info.descriptor == "unreadable" and info.problem == f"{journal}: unreadable (Permission denied)"


def test_a_journal_damaged_in_its_middle_is_noted_and_its_later_frames_described_again(tmp_path: Path) -> None:
    """Bytes overwritten inside the journal (not a record cut short at its end): the records
    before the damage are used, the rest left to be described again, with a line that says so."""
    cache = Cache(tmp_path / "c")
    header = _header()
    path = _journal(cache, header, 5)
    blob = bytearray(path.read_bytes())
    blob[len(blob) * 3 // 5] ^= 0xFF  # inside the fourth record or so
    path.write_bytes(bytes(blob))
    stored = cache.read_stored(header.key)
    assert stored is not None and not stored.complete and 0 < len(stored.records) < 5
    assert cache.repairs == [f"{path}: a record after the first {len(stored.records)} frame(s) failed its checksum "
                             "(the file is damaged); the frames after it described again"]


def test_a_journal_whose_header_record_is_damaged_is_noted(tmp_path: Path) -> None:
    """A byte flipped in the journal's first record (the entry's header) dropped every frame it
    held without a line, where damage in a later record was noted."""
    cache = Cache(tmp_path / "c")
    header = _header()
    path = _journal(cache, header, 5)
    blob = bytearray(path.read_bytes())
    blob[40] ^= 4
    path.write_bytes(bytes(blob))
    assert cache.read_stored(header.key) is None
    assert cache.repairs == [(f"{path}: its first record (the header) failed its checksum (the file is damaged); "
                              "the frames after it described again")]


def test_an_entry_whose_digest_attribute_is_damaged_is_described_again(tmp_path: Path) -> None:
    """The digest an entry file records was never read back: damaged, it stayed in the file for
    good (and a reader of the file, as docs/formats.md shows, read it) while the entry was reused."""
    cache = Cache(tmp_path / "c")
    written = cache.write_entry(StoredEntry(_header(), {f"f{i}.png": _record(f"f{i}.png", i) for i in range(3)}),
                                complete=True)
    path = cache.entry_path(_header().key)
    assert cache.read_stored(_header().key) is not None and cache.repairs == []
    with h5py.File(path, "r+") as f:
        f.attrs["digest"] = written.digest[:-1] + ("0" if written.digest[-1] != "0" else "1")
    assert cache.read_stored(_header().key) is None
    assert cache.repairs == [(f"{path}: unreadable cache entry (its digest attribute does not match its frames); "
                              "described again")]


def test_timestamps_round_trip_through_journal_and_file(tmp_path: Path) -> None:
    from dataclasses import replace

    cache = Cache(tmp_path / "c")
    header = _header("/data/route.avi")
    journal = cache.open_journal(header)
    journal.append(replace(_record("000000", 0.0), timestamp_ms=0.0))
    journal.append(replace(_record("000002", 2.0), timestamp_ms=66.733))
    journal.close()
    stored = cache.read_stored(header.key)
    assert [r.timestamp_ms for r in stored.ordered()] == [0.0, 66.733]
    entry = cache.write_entry(stored, complete=True)
    np.testing.assert_array_equal(entry.timestamps_ms, [0.0, 66.733])
    np.testing.assert_array_equal(cache.read_entry(header.key).timestamps_ms, [0.0, 66.733])
    images = StoredEntry(_header(), {"a.png": _record("a.png", 1.0)})
    cache.write_entry(images, complete=True)
    with h5py.File(cache.entry_path(images.header.key), "r") as f:
        assert np.isnan(f["frames/timestamp_ms"][()]).all()


def test_list_entries_skips_a_journal_a_run_has_only_just_opened(tmp_path: Path) -> None:
    """A describe run creates its journal before writing the header: a listing at that moment
    neither fails nor shows an entry."""
    cache = Cache(tmp_path / "c")
    good = StoredEntry(_header(), {"a.png": _record("a.png", 1.0)})
    cache.write_entry(good, complete=True)
    cache.journal_path("0newnewnewnewnewnewnewne").write_bytes(b"")
    assert [info.key for info in cache.list_entries()] == [good.header.key]


def test_an_entry_read_back_is_its_rows_in_frame_order_copied_only_when_they_changed(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    records = {f"f{i}.png": _record(f"f{i}.png", float(i)) for i in (10, 2, 1)}
    cache.write_entry(StoredEntry(_header(), records), complete=True)
    stored = cache.read_stored(_header().key)
    want = np.array([[1.0] * 4, [2.0] * 4, [10.0] * 4], np.float32)  # natural order: f1, f2, f10
    read = stored.entry()
    np.testing.assert_array_equal(read.data, want)
    assert read.names == ["f1.png", "f2.png", "f10.png"]
    assert read.data is stored.read_matrix[0]  # the rows as read, in order: no copy
    stored.records["f2.png"] = _record("f2.png", 7.0)  # a changed frame: its new row is used
    changed = stored.entry()
    np.testing.assert_array_equal(changed.data, np.array([[1.0] * 4, [7.0] * 4, [10.0] * 4], np.float32))
    assert changed.data is not stored.read_matrix[0]
    del stored.records["f1.png"]
    np.testing.assert_array_equal(stored.entry().data, np.array([[7.0] * 4, [10.0] * 4], np.float32))


_KILLED_FEATURES = """
import os, sys, time
import numpy as np
from wiloc.cache.features import FeatureStore
from wiloc.cache.store import Cache

def stop_here(fd):  # the file is written beside its place, not yet renamed onto it
    open(sys.argv[1], "w").write("now")
    time.sleep(120)

os.fsync = stop_here
FeatureStore(Cache(), {"feature": "sift", "max_features": 50, "max_side": 320}).write("d1", np.ones((3, 128), np.float32))
"""


def test_local_features_killed_while_written_are_absent_and_kept_by_the_next_run(tmp_path: Path) -> None:
    marker = tmp_path / "marker"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_FEATURES, str(marker)],
                            env={**os.environ, "WILOC_CACHE": str(tmp_path / "c")})
    try:
        deadline = time.monotonic() + 60
        while not marker.exists():
            assert proc.poll() is None, "the write ended before the kill"
            assert time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    store = FeatureStore(Cache(tmp_path / "c"), {"feature": "sift", "max_features": 50, "max_side": 320})
    assert [p.name.endswith(TEMP_SUFFIX) for p in store.folder.iterdir()] == [True]
    assert store.read("d1") is None
    fresh = np.full((2, 128), 7, np.float32)
    np.testing.assert_array_equal(store.features("d1", lambda: fresh), fresh)
    np.testing.assert_array_equal(store.read("d1"), fresh)
    assert [p.name for p in store.folder.iterdir()] == ["d1.h5"]  # the dead writer's file swept
    empty = np.zeros((0, 128), np.float32)  # a featureless image's features are kept too
    store.write("d2", empty)
    assert store.read("d2").shape == (0, 128)


@pytest.mark.parametrize("features, stored", [
    (np.array([[0.0, 17.0, 255.0], [3.0, 0.0, 128.0]], np.float32), np.uint8),  # SIFT's whole numbers: bytes
    (np.array([[0.5, 17.0, 255.0]], np.float32), np.float32),  # a fraction: kept as it is
    (np.array([[256.0, 1.0, 2.0]], np.float32), np.float32),  # beyond a byte
    (np.array([[-0.0, 1.0, 2.0]], np.float32), np.float32),  # -0.0 reads back as 0.0 from a byte
    (np.array([[np.nan, 1.0, 2.0]], np.float32), np.float32),
    (np.array([[9, 200, 3]], np.uint8), np.uint8),  # ORB's bytes
])
def test_local_features_are_stored_as_bytes_only_when_they_read_back_bit_for_bit(
        tmp_path: Path, features: np.ndarray, stored: type) -> None:
    store = FeatureStore(Cache(tmp_path / "c"), {"feature": "sift", "max_features": 50, "max_side": 320})
    store.write("d1", features)
    with h5py.File(store.path("d1"), "r") as f:
        assert f["features"].dtype == np.dtype(stored)
    back = store.read("d1")
    assert back is not None and back.dtype == features.dtype and back.tobytes() == features.tobytes()


def test_a_file_where_the_cache_keeps_a_folder_is_named(tmp_path: Path) -> None:
    """A regular file named ``descriptors`` in the cache was "<cache>: cannot create the cache
    folder (File exists)", naming the folder that was fine."""
    cache = Cache(tmp_path / "c")
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "descriptors").write_text("x")
    with pytest.raises(WilocError) as err:
        cache.open_journal(_header())
    assert str(err.value) == f"{tmp_path / 'c' / 'descriptors'}: a file where a cache folder belongs; remove it"

"""A damaged cache never gives a silently different result: frames failing their checksum are
described again, a damaged map summary is computed anew; cache files are never
written through a symbolic link; lock files do not pile up and still exclude each other."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import FakeSpec, write_images

from wiloc import api
from wiloc.cache.features import FeatureStore
from wiloc.cache.store import Cache, lock_file
from wiloc.description.describing import describe_folder
from wiloc.description.differences import map_summary


def _overwrite(path: Path, offset: int, data: bytes = b"\xde\xad\xbe\xef") -> None:
    """Bytes overwritten in place, as a bad disk or a stray write would."""
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(data)


def _data_offset(path: Path, dataset: str, element: int = 0) -> int:
    """The file offset of ``element`` of a contiguous dataset, or inside the first chunk of a chunked one."""
    with h5py.File(path, "r") as f:
        d = f[dataset]
        if d.chunks is None:
            return d.id.get_offset() + element * d.dtype.itemsize * int(np.prod(d.shape[1:]))
        return d.id.get_chunk_info(0).byte_offset + 16


@pytest.mark.parametrize("dataset", ["descriptors", "frames/size", "frames/crc32"])
def test_a_damaged_frame_is_described_again_and_reported(tmp_path: Path, dataset: str) -> None:
    folder = tmp_path / "route"
    write_images(folder, 8)
    first = describe_folder(folder, FakeSpec(), Cache(tmp_path / "c"), jobs=1)
    entry_file = Cache(tmp_path / "c").entry_path(first.entry.key)
    _overwrite(entry_file, _data_offset(entry_file, dataset, element=3))
    cache = Cache(tmp_path / "c")
    again = describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert again.computed == 1  # only the damaged frame
    np.testing.assert_array_equal(again.entry.data, first.entry.data)
    assert again.entry.digest == first.entry.digest
    assert cache.repairs == [f"{entry_file}: 1 frame(s) failed their checksum (the file is damaged); described again"]
    assert Cache(tmp_path / "c").read_stored(first.entry.key).dropped == 0  # repaired on disk


def test_an_unreadable_or_unchecked_entry_file_is_described_anew(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    write_images(folder, 5)
    first = describe_folder(folder, FakeSpec(), Cache(tmp_path / "c"), jobs=1)
    entry_file = Cache(tmp_path / "c").entry_path(first.entry.key)
    with h5py.File(entry_file, "r+") as f:
        f.attrs["format_version"] = 1  # written before frames carried checksums
    cache = Cache(tmp_path / "c")
    assert describe_folder(folder, FakeSpec(), cache, jobs=1).computed == 5
    assert "written without checksums" in cache.repairs[0]
    entry_file.write_bytes(b"not an HDF5 file" * 64)
    cache = Cache(tmp_path / "c")
    again = describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert again.computed == 5 and again.entry.digest == first.entry.digest
    assert "unreadable cache entry" in cache.repairs[0]


@pytest.mark.parametrize(("dataset", "kept"), [("descriptors", 3), ("frames/width", 4), ("failed/reason", 1)])
def test_an_entry_whose_datasets_disagree_in_length_is_described_anew(tmp_path: Path, dataset: str,
                                                                       kept: int) -> None:
    """Datasets of one frame each cut to other lengths (a repair tool's or a hand's damage) read
    other frames' values or ran past the end, an IndexError traceback on every run: now an
    unreadable entry, said and described again."""
    folder = tmp_path / "route"
    write_images(folder, 5)
    (folder / "broken.png").write_bytes(b"not an image")  # a failed frame: the failed group has a row
    first = describe_folder(folder, FakeSpec(), Cache(tmp_path / "c"), jobs=1)
    entry_file = Cache(tmp_path / "c").entry_path(first.entry.key)
    with h5py.File(entry_file, "r+") as f:
        values = f[dataset][()]
        del f[dataset]
        f[dataset] = values[:kept] if kept < len(values) else np.concatenate([values, values[:1]])
    cache = Cache(tmp_path / "c")
    again = describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert again.computed == 5 and again.entry.digest == first.entry.digest
    assert cache.repairs and "unreadable cache entry" in cache.repairs[0] and f"{dataset} holds" in cache.repairs[0]


def test_a_cache_folder_that_cannot_be_written_is_one_error_naming_it(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Entries are locked while read: in a cache folder the user may not write (shared read-only)
    the lock was an OSError naming a .lock file; now one line names the cache folder and why."""
    import errno

    from wiloc.cache import store
    from wiloc.errors import WilocError

    def refused(path: Path, *args: object) -> int:
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(store, "lock_file", refused)
    cache = Cache(tmp_path / "c")
    with pytest.raises(WilocError, match=r"cannot lock descriptors/x\.h5 \(Permission denied\): the cache folder "
                                         r"must be writable") as err:
        with cache.lock("descriptors/x.h5"):
            pass
    assert err.value.where == str(tmp_path / "c")


@pytest.mark.parametrize("which", ["entry", "journal"])
@pytest.mark.parametrize("kind, said", [("folder", "a folder where a cache file belongs; remove it"),
                                        ("fifo", "not a regular file .* where a cache file belongs; remove it")])
def test_no_regular_file_in_place_of_a_cache_file_is_refused_before_describing(tmp_path: Path, which: str, kind: str,
                                                                                said: str) -> None:
    """An entry file replaced by a folder had every frame described, then the writing failed (and
    so on every run); one replaced by a FIFO (or its journal) blocked every command, --list too,
    in the opening of it for ever. Either is named before any frame is described, and the list
    tells it as the entry's problem."""
    from wiloc.errors import WilocError

    folder = tmp_path / "route"
    write_images(folder, 5)
    key = describe_folder(folder, FakeSpec(), Cache(tmp_path / "c"), jobs=1).entry.key
    cache = Cache(tmp_path / "c")
    path = cache.entry_path(key) if which == "entry" else cache.journal_path(key)
    path.unlink(missing_ok=True)
    if kind == "folder":
        path.mkdir()
    else:
        os.mkfifo(path)
    with pytest.raises(WilocError, match=said) as err:
        describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert err.value.where == str(path)
    [info] = cache.list_entries()
    assert re.match(f"{re.escape(str(path))}: {said}", info.problem)


def test_an_entry_flagged_complete_by_damage_is_not_taken_for_whole(tmp_path: Path) -> None:
    """The complete flag had no check: flipped on disk, a video's partial entry was taken for the
    whole video (its other frames never described, no note). It is checked against its key and
    frame counts, and such a file is described again, said so."""
    folder = tmp_path / "route"
    write_images(folder, 5)
    key = describe_folder(folder, FakeSpec(), Cache(tmp_path / "c"), jobs=1).entry.key
    cache = Cache(tmp_path / "c")
    with cache.lock(cache.entry_name(key)):
        cache.write_entry(cache.read_stored(key), complete=False)  # as a killed video's resumed run leaves it
    assert cache.read_stored(key).complete is False
    with h5py.File(cache.entry_path(key), "r+") as f:
        f.attrs.modify("complete", True)
    again = Cache(tmp_path / "c")
    assert again.read_stored(key) is None
    assert again.repairs == [f"{cache.entry_path(key)}: unreadable cache entry (its complete attribute does not "
                             "match its check); described again"]


def test_a_file_in_place_of_the_descriptors_folder_is_said_by_the_list_too(tmp_path: Path) -> None:
    """describe --list gave an empty list, as of an emptied cache, where describing said what is wrong."""
    from wiloc.errors import WilocError

    cache = Cache(tmp_path / "c")
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "descriptors").write_text("x")
    with pytest.raises(WilocError, match="a file where a cache folder belongs; remove it") as err:
        cache.list_entries()
    assert err.value.where == str(tmp_path / "c" / "descriptors")


def test_a_damaged_map_summary_is_computed_anew(tmp_path: Path) -> None:
    write_images(tmp_path / "r", 20, seed=2)
    cache = Cache(tmp_path / "c")
    r = describe_folder(tmp_path / "r", FakeSpec(), cache, jobs=1).entry
    clean = map_summary(r, cache, 2)
    path = cache.root / "differences" / f"{r.key}-self-r2.h5"
    _overwrite(path, _data_offset(path, "minima"))
    calls = []
    again = map_summary(r, cache, 2, progress=lambda done, total: calls.append(done))
    assert calls  # the damaged file was not used, and that is said once (it was said nowhere)
    assert [line.split(" (")[0] for line in cache.repairs] == [f"{path}: unreadable map summary"]
    assert cache.repairs[0].endswith("; computed again")
    np.testing.assert_array_equal(again.minima, clean.minima)
    assert again.largest == clean.largest


def test_cache_writes_never_follow_symbolic_links(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    names = write_images(folder, 6)
    cache = Cache(tmp_path / "c")
    key = describe_folder(folder, FakeSpec(), cache, jobs=1).entry.key
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    for path in (cache.journal_path(key), cache.entry_path(key).with_name(f"{key}.h5.lock")):
        path.symlink_to(victim)
    (folder / names[0]).write_bytes((folder / names[1]).read_bytes())  # a changed frame: journaled
    describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert victim.read_text() == "keep me\n"
    assert not cache.journal_path(key).exists()  # folded into the entry, and the link is gone


def test_lock_files_do_not_pile_up(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "c")
    for folder in ("a", "b"):
        write_images(tmp_path / folder, 4, seed=len(folder))
    report = api.describe([tmp_path / "a", tmp_path / "b"], "sad", cache=cache, jobs=1)
    map_summary(report[1].entry, cache, 1)
    leftovers = sorted(p.name for p in cache.root.rglob("*") if p.suffix in (".lock", ".owner"))
    assert leftovers == []


def test_the_lock_excludes_other_processes_while_lock_files_come_and_go(tmp_path: Path) -> None:
    counter = tmp_path / "counter"
    counter.write_text("0")
    code = (
        "import sys; from pathlib import Path; from wiloc.cache.store import Cache\n"
        f"cache, counter = Cache(Path({str(tmp_path / 'c')!r})), Path({str(counter)!r})\n"
        "for _ in range(40):\n"
        "    with cache.lock('descriptors/k.h5'):\n"
        "        value = int(counter.read_text()); counter.write_text(str(value + 1))\n"
    )
    workers = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(3)]
    assert [w.wait(timeout=120) for w in workers] == [0, 0, 0]
    assert counter.read_text() == "120"  # no increment lost: never two holders at once
    assert not (tmp_path / "c" / "descriptors" / "k.h5.lock").exists()


_SLOW_HOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX)
open(sys.argv[2], "w").write("locked")
time.sleep(0.3)  # locked, its pid not written yet
os.pwrite(fd, f"{os.getpid()}\\n".encode(), 0)
time.sleep(30)
"""


def test_a_busy_lock_names_its_holder_even_before_the_holder_wrote_its_pid(tmp_path: Path) -> None:
    """A run refused a lock at once (a results file another run follows) names the holder's pid,
    which the holder writes just after it locks, never "unknown" for that moment."""
    lock, marker = tmp_path / "r.lock", tmp_path / "marker"
    holder = subprocess.Popen([sys.executable, "-c", _SLOW_HOLDER, str(lock), str(marker)])
    try:
        deadline = time.monotonic() + 60
        while not marker.exists():
            assert holder.poll() is None and time.monotonic() < deadline
            time.sleep(0.01)
        with pytest.raises(RuntimeError, match=f"^held by {holder.pid}$"):
            lock_file(lock, time.monotonic(), lambda pid: RuntimeError(f"held by {pid}"))
    finally:
        holder.kill()
        holder.wait()


SIFT = {"feature": "sift", "max_features": 50, "max_side": 320}


@pytest.mark.parametrize("damage", ["features", "checksum", "cut short", "other setting"])
def test_damaged_local_features_are_extracted_again(tmp_path: Path, damage: str) -> None:
    """Local features kept in the cache whose bytes, checksum or file no longer hold, or that were
    extracted otherwise, are never used: they are extracted again and the file replaced."""
    store = FeatureStore(Cache(tmp_path / "c"), SIFT)
    kept = np.arange(3 * 128, dtype=np.float32).reshape(3, 128)
    store.write("0123abcd", kept)
    np.testing.assert_array_equal(store.read("0123abcd"), kept)
    path = store.path("0123abcd")
    if damage == "features":
        _overwrite(path, _data_offset(path, "features", element=1))
    elif damage == "checksum":
        with h5py.File(path, "r+") as f:
            f.attrs["crc32"] = int(f.attrs["crc32"]) ^ 1
    elif damage == "cut short":  # as a write in place, killed, would leave it
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    else:
        store = FeatureStore(Cache(tmp_path / "c"), {**SIFT, "max_features": 60})
        store.path("0123abcd").parent.mkdir(parents=True)
        path.rename(store.path("0123abcd"))
    assert store.read("0123abcd") is None
    fresh = kept + 1
    np.testing.assert_array_equal(store.features("0123abcd", lambda: fresh), fresh)
    np.testing.assert_array_equal(store.read("0123abcd"), fresh)

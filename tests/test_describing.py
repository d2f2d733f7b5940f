"""describe_folder through the cache: reuse, incremental updates, bad frames, crashes, locking."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import FakeSpec, interrupt_after_six_frames, write_images

from wiloc.cache.entries import EntryHeader
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folder
from wiloc.description.matrix_import import import_matrix
from wiloc.errors import WilocError
from wiloc.sources.frames import read_gray


@dataclass(frozen=True)
class PidSpec(FakeSpec):
    """Rows that hold the id of the process that computed them, after `seconds` of work."""

    seconds: float = 0.0

    def compute(self, gray: np.ndarray) -> np.ndarray:
        time.sleep(self.seconds)
        return np.full(self.length, os.getpid(), dtype=np.float32)


@dataclass(frozen=True)
class SlowSpec(FakeSpec):
    """FakeSpec's rows after `seconds` of work."""

    seconds: float = 0.0

    def compute(self, gray: np.ndarray) -> np.ndarray:
        time.sleep(self.seconds)
        return super().compute(gray)


def expected_rows(folder: Path, names: list[str], spec: FakeSpec) -> np.ndarray:
    return np.stack([spec.compute(read_gray(folder / n, spec.min_size)) for n in names])


def test_round_trip_and_incremental_updates(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    names = write_images(folder, 12)
    (folder / "notes.txt").write_text("not an image")
    cache = Cache(tmp_path / "cache")
    spec = FakeSpec()
    calls: list[tuple[int, int]] = []

    first = describe_folder(folder, spec, cache, jobs=2, progress=lambda d, t: calls.append((d, t)))
    assert (first.computed, first.reused, first.failed, first.frames) == (12, 0, [], 12)
    assert first.entry.names == names  # natural order: img2 before img10
    assert first.shape == (12, 16) and first.entry.data.dtype == np.float32
    np.testing.assert_array_equal(first.entry.data, expected_rows(folder, names, spec))
    assert first.ignored == ["notes.txt"] and first.sizes == [(64, 48)]
    assert calls[-1] == (12, 12) and [d for d, _ in calls] == sorted(d for d, _ in calls)

    second = describe_folder(folder, spec, cache, jobs=1)
    assert (second.computed, second.reused) == (0, 12)
    assert second.entry.digest == first.entry.digest

    os.utime(folder / names[3], ns=(1, 1))  # same content, new mtime: digest says reuse
    touched = describe_folder(folder, spec, cache, jobs=1)
    assert (touched.computed, touched.reused) == (0, 12)
    assert touched.entry.digest == first.entry.digest

    write_images(tmp_path / "other", 1, seed=7)
    os.replace(tmp_path / "other" / "img0.jpg", folder / names[4])  # new content
    changed = describe_folder(folder, spec, cache, jobs=1)
    assert (changed.computed, changed.reused) == (1, 11)
    assert changed.entry.digest != first.entry.digest
    np.testing.assert_array_equal(changed.entry.data, expected_rows(folder, names, spec))

    write_images(tmp_path / "more", 13, seed=3)
    os.replace(tmp_path / "more" / "img12.jpg", folder / "img12.jpg")
    added = describe_folder(folder, spec, cache, jobs=1)
    assert (added.computed, added.reused, added.shape) == (1, 12, (13, 16))
    assert added.entry.names[-1] == "img12.jpg"

    (folder / names[0]).unlink()
    removed = describe_folder(folder, spec, cache, jobs=1)
    assert (removed.computed, removed.shape) == (0, (12, 16))
    assert names[0] not in removed.entry.names

    other = describe_folder(folder, FakeSpec(params={"side": 2}), cache, jobs=1)
    assert (other.computed, other.shape) == (12, (12, 4))
    infos = cache.list_entries()
    assert len(infos) == 2 and all(i.complete and i.frames == 12 for i in infos)
    assert sorted(i.params["side"] for i in infos) == [2, 4]
    assert describe_folder(folder, spec, cache, jobs=1).entry.digest == removed.entry.digest


def test_a_frame_whose_size_or_mtime_changed_is_checked_again(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    names = write_images(folder, 3)
    cache = Cache(tmp_path / "cache")
    first = describe_folder(folder, FakeSpec(), cache, jobs=1)
    os.utime(folder / names[1], ns=(1, 1))  # same content: reused, its new mtime recorded
    grown = folder / names[2]
    before = grown.stat()
    with open(grown, "ab") as f:
        f.write(b"\0")  # a byte past the end of the image: new content, same mtime
    os.utime(grown, ns=(before.st_atime_ns, before.st_mtime_ns))
    again = describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert (again.computed, again.reused) == (1, 2)
    records = cache.read_stored(first.entry.key).records
    assert records[names[1]].mtime_ns == 1
    assert records[names[2]].size == before.st_size + 1


def test_bad_frames_are_reported_and_left_out(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    names = write_images(folder, 4)
    (folder / "img10.png").write_bytes(b"")
    whole = (folder / "img0.jpg").read_bytes()
    (folder / "img11.jpg").write_bytes(whole[: len(whole) // 2])
    cache = Cache(tmp_path / "cache")
    report = describe_folder(folder, FakeSpec(), cache, jobs=2)
    assert [name for name, _ in report.failed] == ["img10.png", "img11.jpg"]
    assert all(reason for _, reason in report.failed)
    assert report.entry.names == names
    assert (report.computed, report.shape, report.frames) == (4, (4, 16), 6)
    again = describe_folder(folder, FakeSpec(), cache, jobs=1)
    assert again.failed == report.failed and again.computed == 0


def test_names_left_out_at_listing_are_not_counted_as_the_entry_s_failed_frames(tmp_path: Path) -> None:
    """The report's failed frames are the entry's /failed (docs/formats.md: files read and refused,
    with their size, time and digest); a dangling link, left out when the folder is listed, has
    none of these and is reported apart (it was counted failed, where /failed did not hold it)."""
    folder = tmp_path / "route"
    names = write_images(folder, 3)
    (folder / "img10.png").write_bytes(b"")
    (folder / "img11.png").symlink_to("nowhere.png")
    cache = Cache(tmp_path / "cache")
    report = describe_folder(folder, FakeSpec(), cache, jobs=1)
    with h5py.File(next((tmp_path / "cache").rglob(f"{report.entry.key}.h5")), "r") as f:
        assert [name for name, _ in report.failed] == f["failed/name"].asstr()[()].tolist() == ["img10.png"]
    assert report.unusable == [("img11.png", "broken symbolic link")]
    assert report.entry.names == names
    assert (report.frames, report.computed, report.reused) == (4, 3, 0)


def test_mixed_sizes_are_reported(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    write_images(folder, 2)
    write_images(tmp_path / "big", 1, size=(96, 40))
    os.replace(tmp_path / "big" / "img0.jpg", folder / "img5.jpg")
    report = describe_folder(folder, FakeSpec(), Cache(tmp_path / "cache"), jobs=1)
    assert report.sizes == [(64, 48), (96, 40)]
    assert report.shape == (3, 16)


_RUN = """
import sys
from pathlib import Path
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folder
from wiloc.descriptors.registry import get_descriptor
describe_folder(Path(sys.argv[1]), get_descriptor("gist"), Cache(Path(sys.argv[2])), jobs=int(sys.argv[3]))
"""


def test_short_work_stays_in_this_process_and_long_work_goes_to_workers(tmp_path: Path) -> None:
    # 10 quick frames: 7 left after the 3 timed, which would need over 7 ms each (FORKED_START's
    # 0.05 s) to be worth a worker; they take about 0.2 ms, a margin that load on the machine keeps
    write_images(tmp_path / "few", 10)
    short = describe_folder(tmp_path / "few", PidSpec(params={"side": 1}), Cache(tmp_path / "a"), jobs=2)
    assert set(short.entry.data[:, 0].astype(int).tolist()) == {os.getpid()}  # less work than starting workers
    write_images(tmp_path / "route", 60)
    long = describe_folder(tmp_path / "route", PidSpec(params={"side": 1}, seconds=0.08), Cache(tmp_path / "b"),
                           jobs=2)
    pids = long.entry.data[:, 0].astype(int).tolist()
    assert set(pids[:3]) == {os.getpid()}  # timed here first; then 57 x 0.08 s left: one forked worker joins
    assert os.getpid() in pids[3:] and len(set(pids[3:]) - {os.getpid()}) == 1


def test_describe_keeps_decoder_warnings_off_stderr(tmp_path: Path) -> None:
    folder = tmp_path / "route"
    names = write_images(folder, 4, size=(160, 120))
    png = (folder / names[1]).read_bytes()
    damaged = bytearray(png)
    damaged[len(png) // 2] ^= 0xFF
    (folder / "img4.png").write_bytes(bytes(damaged))  # libpng: "libpng error: IDAT: CRC error"
    (folder / "img6.png").write_bytes(png[: len(png) * 2 // 3])  # cut: refused before decoding
    jpeg = (folder / names[0]).read_bytes()
    (folder / "img5.jpg").write_bytes(jpeg[: len(jpeg) // 2] + b"\xff\xd9")  # libjpeg: "Corrupt JPEG"
    code = (
        "import sys, cv2; from pathlib import Path; from wiloc.cache.store import Cache\n"
        "from wiloc.descriptors.registry import get_descriptor; from wiloc.description.describing import describe_folder\n"
        "log = getattr(cv2.utils, 'logging', cv2)  # where the wheel has it: OpenCV 4.8-4.11 cv2, later cv2.utils.logging\n"
        "level = log.getLogLevel()\n"
        "r = describe_folder(Path(sys.argv[1]), get_descriptor('sad'), Cache(Path(sys.argv[2])), jobs=int(sys.argv[3]))\n"
        "assert log.getLogLevel() == level\n"
        "print(r.computed, len(r.failed))\n"
    )
    for jobs in (2, 1):
        args = [sys.executable, "-c", code, str(folder), str(tmp_path / f"cache{jobs}"), str(jobs)]
        run = subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)
        assert run.returncode == 0, run.stderr
        assert run.stdout.split() == ["5", "2"]  # the damaged and the cut PNG fail; the patched JPEG decodes
        assert "WARN" not in run.stderr
        assert run.stderr == ""  # libpng's and libjpeg's own messages too: stderr is no terminal


@pytest.mark.parametrize("moment", ["moved", "put back"])
def test_ctrl_c_at_either_end_of_the_decoders_quiet_stretch_leaves_stderr_where_it_was(
        moment: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C raised just as descriptor 2 has been moved to /dev/null (the libjpeg messages'
    silencer) or as the stretch's end puts it back, before it is back: the command's "error:
    interrupted" must reach the user. The first the stretch puts back itself; the second
    stderr_back, which every error printer calls first (the line was lost now and then: exit code
    130 and an empty stderr)."""
    from wiloc import quiet
    from wiloc.description import frame_describing

    image = tmp_path / write_images(tmp_path, 1)[0]
    original = os.fstat(2)
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    null = os.fstat(devnull)
    dup2 = os.dup2
    interrupted: list[int] = []

    def interrupting(fd: int, fd2: int) -> int:
        if moment == "put back" and fd != devnull and not interrupted:  # cut short before it moves
            interrupted.append(fd)
            raise KeyboardInterrupt
        result = dup2(fd, fd2)
        if moment == "moved" and fd == devnull:
            interrupted.append(fd)
            raise KeyboardInterrupt
        return result

    monkeypatch.setattr(quiet, "_devnull", devnull)
    monkeypatch.setattr(quiet.os, "dup2", interrupting)
    try:
        with pytest.raises(KeyboardInterrupt):
            frame_describing._read_gray(image, None)
        stretch_ended = os.fstat(2)
        quiet.stderr_back()
        quiet.stderr_back()  # a second call changes nothing
        now = os.fstat(2)
    finally:
        dup2(saved, 2)  # for the tests after this one, whatever happened
        os.close(saved)
        os.close(devnull)
    left = original if moment == "moved" else null
    assert interrupted and (stretch_ended.st_dev, stretch_ended.st_ino) == (left.st_dev, left.st_ino)
    assert (now.st_dev, now.st_ino) == (original.st_dev, original.st_ino)


def test_a_new_version_of_a_descriptors_code_describes_afresh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An entry's key holds the version of its descriptor's computation: rows an earlier version
    computed are never reused once the version is raised; the same version reuses them."""
    from wiloc.descriptors.registry import get_descriptor
    from wiloc.descriptors.sad import Sad

    folder = tmp_path / "route"
    write_images(folder, 3)
    cache = Cache(tmp_path / "cache")
    first = describe_folder(folder, get_descriptor("sad"), cache, jobs=1)
    assert describe_folder(folder, get_descriptor("sad"), cache, jobs=1).computed == 0
    monkeypatch.setattr(Sad, "version", Sad.version + 1)
    again = describe_folder(folder, get_descriptor("sad"), cache, jobs=1)
    assert (first.computed, again.computed) == (3, 3) and again.entry.key != first.entry.key
    assert np.array_equal(again.entry.data, first.entry.data)
    assert sorted(i.params["code_version"] for i in cache.list_entries()) == [Sad.version - 1, Sad.version]


def test_describe_in_another_process_reports_a_busy_entry(tmp_path: Path) -> None:
    from wiloc.descriptors.registry import get_descriptor

    folder = tmp_path / "route"
    write_images(folder, 2)
    cache = Cache(tmp_path / "cache")
    spec = get_descriptor("gist")
    key = EntryHeader.create(str(folder.resolve()), spec.name, spec.cache_params, spec.metric, spec.scale,
                             spec.natural_max, spec.dtype, spec.length).key
    code = _RUN.replace("Cache(Path(sys.argv[2]))", "Cache(Path(sys.argv[2]), lock_timeout=0.3)")
    with cache.lock(cache.entry_name(key)):
        busy = subprocess.run([sys.executable, "-c", code, str(folder), str(cache.root), "1"],
                              capture_output=True, text=True, check=False)
    assert busy.returncode != 0
    problem = f"in use by another wiloc process (pid {os.getpid()})"
    assert f"CacheBusyError: {cache.entry_path(key)}: {problem}" in busy.stderr
    assert cache.list_entries() == []


def test_missing_folder_and_bad_jobs_are_user_errors(tmp_path: Path) -> None:
    cache = Cache(tmp_path / "cache")
    with pytest.raises(WilocError, match="does not exist"):
        describe_folder(tmp_path / "nope", FakeSpec(), cache)
    write_images(tmp_path / "route", 1)
    with pytest.raises(WilocError, match="at least 1"):
        describe_folder(tmp_path / "route", FakeSpec(), cache, jobs=0)




@pytest.mark.parametrize(("sig", "jobs"), [(signal.SIGKILL, 1), (signal.SIGINT, 2)])
def test_interrupted_describe_resumes(tmp_path: Path, sig: signal.Signals, jobs: int) -> None:
    from wiloc.descriptors.registry import get_descriptor

    folder = tmp_path / "route"
    count = 160  # enough work left after the sixth frame for the signal to land before the end, even on a busy machine
    write_images(folder, count)
    cache = Cache(tmp_path / "cache")
    run = interrupt_after_six_frames([_RUN, str(folder), str(cache.root), str(jobs)], cache, sig)
    assert run.returncode != 0

    for path in cache.root.rglob("*.h5"):
        with h5py.File(path, "r"):
            pass
    [info] = cache.list_entries()
    assert not info.complete and 6 <= info.frames < count
    resumed = describe_folder(folder, get_descriptor("gist"), cache, jobs=jobs)
    assert resumed.computed == count - info.frames
    assert resumed.reused == info.frames
    clean = describe_folder(folder, get_descriptor("gist"), Cache(tmp_path / "clean"), jobs=2)
    assert resumed.entry.names == clean.entry.names
    # gist itself varies in the last float32 bit between calls (OpenCV's SIMD DFT), so rows are
    # compared to a few ulp; the frame bookkeeping above and the digest below are exact.
    np.testing.assert_allclose(resumed.entry.data, clean.entry.data, rtol=1e-5, atol=1e-7)
    assert resumed.entry.digest == clean.entry.digest
    assert not list(cache.root.rglob("*.wiloc-tmp")) and not list(cache.root.rglob("*.journal"))


def test_import_matrix_is_cached_and_follows_the_file(tmp_path: Path) -> None:
    matrix = np.random.default_rng(1).random((5, 3)).astype(np.float32)
    path = tmp_path / "netvlad.npy"
    np.save(path, matrix)
    names_path = tmp_path / "names.txt"
    names_path.write_text("".join(f"f{i}.png\n" for i in range(5)))
    cache = Cache(tmp_path / "cache")
    first = import_matrix(path, cache, names_path, "cosine")
    assert (first.computed, first.shape, first.entry.metric) == (5, (5, 3), "cosine")
    assert first.entry.names == [f"f{i}.png" for i in range(5)]
    [info] = cache.list_entries()
    assert (info.descriptor, info.frames, info.complete) == ("external", 5, True)
    np.testing.assert_array_equal(first.entry.data, matrix)
    second = import_matrix(path, cache, names_path, "cosine")
    assert (second.computed, second.reused) == (0, 5)
    assert second.entry.digest == first.entry.digest
    np.save(path, matrix * 2)
    third = import_matrix(path, cache, names_path, "cosine")
    assert third.computed == 5 and third.entry.digest != first.entry.digest
    np.testing.assert_array_equal(third.entry.data, matrix * 2)
    with pytest.raises(WilocError, match="does not exist"):
        import_matrix(tmp_path / "missing.npy", cache, None, "cosine")


def test_import_matrix_keeps_the_file_row_order(tmp_path: Path) -> None:
    names = ["zeta", "alpha", "mid10", "mid2", "beta"]  # time order, not name order
    matrix = np.arange(1, 16, dtype=np.float32).reshape(5, 3)
    path = tmp_path / "seq.npy"
    np.save(path, matrix)
    names_path = tmp_path / "names.txt"
    names_path.write_text("\n".join(names))
    cache = Cache(tmp_path / "cache")
    for report in (import_matrix(path, cache, names_path, "l1"), import_matrix(path, cache, names_path, "l1")):
        assert report.entry.names == names
        np.testing.assert_array_equal(report.entry.data, matrix)
    assert report.reused == 5


@pytest.mark.realdata
def test_gardens_point_day_left_with_sad(data_root: Path, tmp_path: Path) -> None:
    from wiloc.descriptors.registry import get_descriptor

    folder = data_root / "gardens-point-walking" / "day_left"
    cache = Cache(tmp_path / "cache")
    first = describe_folder(folder, get_descriptor("sad"), cache)
    assert first.failed == [] and first.computed == first.frames == 200
    assert first.shape == (200, 1152) and first.entry.data.dtype == np.uint8
    assert len(first.sizes) == 1  # one camera: one image size, read from the JPEG headers
    again = describe_folder(folder, get_descriptor("sad"), cache)
    assert (again.computed, again.reused, again.entry.digest) == (0, 200, first.entry.digest)


def test_folders_described_in_one_block_share_their_workers(tmp_path: Path) -> None:
    from wiloc.description.workers import keeping_pools

    for name in ("a", "b"):
        write_images(tmp_path / name, 24)
    spec = PidSpec(params={"side": 1}, seconds=0.05)
    with keeping_pools():
        reports = [describe_folder(tmp_path / name, spec, Cache(tmp_path / "cache"), jobs=2) for name in ("a", "b")]
    workers = [set(r.entry.data[:, 0].astype(int).tolist()) - {os.getpid()} for r in reports]
    assert len(workers[0]) == 1 and workers[1] == workers[0]  # started once, for both folders
    assert [r.computed for r in reports] == [24, 24]


def test_folders_described_in_one_stream_match_one_at_a_time(tmp_path: Path) -> None:
    """Folders whose frames share their names, described together with a worker: each frame's
    row goes to its own folder's entry, and a folder given twice is described once."""
    from wiloc.description.describing import describe_folders

    folders = [tmp_path / name for name in ("a", "b", "c")]
    for seed, folder in enumerate(folders):
        write_images(folder, 30, seed=seed)  # img0 .. img29 in each
    spec = SlowSpec(seconds=0.01)  # 90 frames: worth a worker, even a fresh interpreter
    alone = [describe_folder(folder, spec, Cache(tmp_path / f"alone-{folder.name}"), jobs=1) for folder in folders]
    calls: dict[str, list[tuple[int, int]]] = {f.name: [] for f in folders}
    progress = [lambda d, t, n=f.name: calls[n].append((d, t)) for f in folders] + [None]
    together = describe_folders([*folders, folders[0]], spec, Cache(tmp_path / "together"), jobs=2, progress=progress)
    assert [Path(r.folder).name for r in together] == ["a", "b", "c", "a"] and together[3] is together[0]
    for one, both, folder in zip(alone, together, folders):
        assert both.entry.digest == one.entry.digest and both.computed == 30
        np.testing.assert_array_equal(both.entry.data, expected_rows(folder, [f"img{i}" + (".png" if i % 2 else ".jpg")
                                                                           for i in range(30)], spec))
        assert calls[folder.name][0] == (0, 30) and calls[folder.name][-1] == (30, 30)
    pids = describe_folders(folders, PidSpec(params={"side": 1}, seconds=0.05), Cache(tmp_path / "pids"), jobs=2)
    by_worker = [set(r.entry.data[:, 0].astype(int).tolist()) - {os.getpid()} for r in pids]
    # one worker, started once, took frames of several folders (of all three when forked; a fresh
    # interpreter, where this process runs other threads, starts a few frames later: on a busy
    # machine over a second later, so each folder's frames take 1.5 s here)
    assert len(set().union(*by_worker)) == 1 and sum(bool(worker) for worker in by_worker) >= 2


def test_a_bad_folder_among_several_stops_the_run_before_anything_is_written(tmp_path: Path) -> None:
    from wiloc.description.describing import describe_folders

    write_images(tmp_path / "good", 4)
    (tmp_path / "empty").mkdir()
    cache = Cache(tmp_path / "cache")
    with pytest.raises(WilocError, match="empty"):
        describe_folders([tmp_path / "good", tmp_path / "empty"], FakeSpec(), cache, jobs=1)
    assert cache.list_entries() == []


def test_query_and_map_frames_of_another_shape_are_warned_of(tmp_path: Path, cache_dir: Path) -> None:
    """A query of 4:3 frames against a map of 16:9 ones (another camera, a crop) gets one warning
    line naming both sizes; the same shape at another size (a camera's other resolution) none."""
    from wiloc import api

    write_images(tmp_path / "map", 6, seed=1, size=(96, 54))
    write_images(tmp_path / "wide", 6, seed=2, size=(192, 108))
    write_images(tmp_path / "square", 6, seed=3, size=(80, 60))
    cache = Cache(cache_dir)
    same_shape = api.localize(tmp_path / "wide", reference=tmp_path / "map", method="threshold", cache=cache)
    assert same_shape.warnings == []
    other_shape = api.localize(tmp_path / "square", reference=tmp_path / "map", method="threshold", cache=cache)
    [line] = other_shape.warnings
    assert f"{(tmp_path / 'square').resolve()}: frames of 80 x 60 pixels against the map's 96 x 54" in line


def test_query_frames_of_another_shape_among_others_are_warned_of_with_their_count(tmp_path: Path,
                                                                                cache_dir: Path) -> None:
    """A query whose frames are mostly of the map's shape, a few turned upright: the few are warned
    of (the most common size alone was looked at, so a minority of another shape never was), and
    describing names the sizes."""
    from typer.testing import CliRunner

    from wiloc import api
    from wiloc.cli import app

    write_images(tmp_path / "map", 6, seed=1, size=(96, 54))
    write_images(tmp_path / "mixed", 6, seed=2, size=(96, 54))
    write_images(tmp_path / "upright", 2, seed=3, size=(54, 96))
    for k, image in enumerate(sorted((tmp_path / "upright").iterdir())):
        image.replace(tmp_path / "mixed" / f"zz{k}{image.suffix}")
    run = api.localize(tmp_path / "mixed", reference=tmp_path / "map", method="threshold", cache=Cache(cache_dir))
    [line] = run.warnings
    assert f"{(tmp_path / 'mixed').resolve()}: 2 of 8 frames of 54 x 96 pixels against the map's 96 x 54" in line
    said = CliRunner().invoke(app, ["describe", str(tmp_path / "mixed")])
    assert said.exit_code == 0 and "images of 2 different sizes (54 x 96, 96 x 54)" in said.stderr


def test_a_jpeg_turned_upright_by_its_exif_orientation_has_the_shape_it_is_shown_in(tmp_path: Path,
                                                                                  cache_dir: Path) -> None:
    """A phone's portrait JPEG is stored landscape with an EXIF orientation that the decoder
    applies: its frame size is the upright one, so a landscape map warns of another shape."""
    from PIL import Image

    from wiloc import api

    write_images(tmp_path / "map", 6, seed=1, size=(96, 54))
    (tmp_path / "portrait").mkdir()
    for png in sorted((tmp_path / "map").iterdir()):
        image = Image.open(png)
        exif = image.getexif()
        exif[0x0112] = 6  # rotate 90 degrees clockwise to show
        image.convert("L").save(tmp_path / "portrait" / f"{png.stem}.jpg", exif=exif.tobytes())
    run = api.localize(tmp_path / "portrait", reference=tmp_path / "map", method="threshold", cache=Cache(cache_dir))
    [line] = run.warnings
    assert f"{(tmp_path / 'portrait').resolve()}: frames of 54 x 96 pixels against the map's 96 x 54" in line

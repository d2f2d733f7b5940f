"""Video files as traversals: names, timestamps, sampling, fingerprints, resume, damaged files."""
from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from helpers import FakeSpec, ends_in_one_error, interrupt_after_six_frames
from typer.testing import CliRunner

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.description.describing import describe_folder, describe_video
from wiloc.description.traversals import Describer, descriptor_label
from wiloc.errors import ParameterError, WilocError
from wiloc.sources.frames import list_traversal, read_gray
from wiloc.sources.video import Sampling, frame_name, is_video, lost_frames, video_fingerprint


def write_video(path: Path, count: int, *, fps: float = 10.0, size: tuple[int, int] = (64, 48),
                seed: int = 0, fourcc: str = "MJPG") -> Path:
    """`count` smooth random frames; MJPG in .avi is written by every opencv-python build."""
    rng = np.random.default_rng(seed)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size)
    assert writer.isOpened()
    for _ in range(count):
        writer.write(cv2.GaussianBlur(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8), (5, 5), 0))
    writer.release()
    return path


def decoded_gray(path: Path) -> list[np.ndarray]:
    """Every frame of a video as OpenCV decodes it, in grayscale."""
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    frames = []
    while (read := capture.read())[0]:
        frames.append(cv2.cvtColor(read[1], cv2.COLOR_BGR2GRAY))
    capture.release()
    return frames


def names(indices: range | list[int]) -> list[str]:
    return [frame_name(i) for i in indices]


def test_frames_are_named_by_index_with_timestamps(tmp_path: Path) -> None:
    video = write_video(tmp_path / "route.avi", 25)
    cache = Cache(tmp_path / "cache")
    spec = FakeSpec()
    first = describe_video(video, spec, cache)
    assert first.video and (first.frames, first.computed, first.reused, first.failed) == (25, 25, 0, [])
    assert first.entry.names == [f"{i:06d}" for i in range(25)]
    np.testing.assert_allclose(first.entry.timestamps_ms, np.arange(25) * 100.0, atol=1e-6)
    np.testing.assert_array_equal(first.entry.data, np.stack([spec.compute(g) for g in decoded_gray(video)]))
    assert first.sizes == [(64, 48)] and first.folder == str(video.resolve())
    with h5py.File(cache.entry_path(first.entry.key), "r") as f:
        np.testing.assert_allclose(f["frames/timestamp_ms"][()], first.entry.timestamps_ms)
        assert json.loads(f.attrs["params"])["sampling"] == {"every": 1, "fps": None, "start": 0, "stop": None}
    again = describe_video(video, spec, cache)
    assert (again.computed, again.reused, again.entry.digest) == (0, 25, first.entry.digest)
    [info] = cache.list_entries()
    assert (info.folder, info.frames, info.complete) == (str(video.resolve()), 25, True)


def test_folders_keep_nan_timestamps(tmp_path: Path) -> None:
    from helpers import write_images

    write_images(tmp_path / "route", 3)
    report = describe_folder(tmp_path / "route", FakeSpec(), Cache(tmp_path / "cache"), jobs=1)
    assert report.entry.timestamps_ms.shape == (3,) and np.isnan(report.entry.timestamps_ms).all()


@pytest.mark.parametrize(("sampling", "expected"), [
    (Sampling(every=3), list(range(0, 30, 3))),
    (Sampling(fps=2.5), list(range(0, 30, 4))),
    (Sampling(fps=25), list(range(30))),
    (Sampling(start=5, stop=12), list(range(5, 12))),
    (Sampling(start="1s", stop="2.05s"), list(range(10, 21))),
    (Sampling(every=4, start=3, stop="2s"), [3, 7, 11, 15, 19]),
    (Sampling(fps=3, start="0.5s"), [5, 9, 12, 15, 19, 22, 25, 29]),
])
def test_sampling_picks_and_keeps_the_video_indices(tmp_path: Path, sampling: Sampling, expected: list[int]) -> None:
    video = write_video(tmp_path / "route.avi", 30)
    report = describe_video(video, FakeSpec(), Cache(tmp_path / "cache"), sampling)
    assert report.entry.names == names(expected)
    np.testing.assert_allclose(report.entry.timestamps_ms, np.array(expected) * 100.0, atol=1e-6)
    all_rows = describe_video(video, FakeSpec(), Cache(tmp_path / "all")).entry.data
    np.testing.assert_array_equal(report.entry.data, all_rows[expected])


def test_sampling_rule_on_timestamps() -> None:
    ntsc = [(i, i * 1000 / 29.97) for i in range(300)]  # 29.97 frames/s, float timestamps
    assert [i for i, _ in Sampling(fps=10).pick(ntsc)] == list(range(0, 300, 3))
    ragged = [(0, 0.0), (1, 40.0), (2, 99.7), (3, 130.0), (4, 260.0), (5, 299.99999), (6, 420.0)]
    assert [i for i, _ in Sampling(fps=10).pick(ragged)] == [0, 2, 4, 5, 6]  # one per 100 ms slot

    def endless():
        index = 0
        while True:
            yield index, index * 100.0
            index += 1
    assert [i for i, _ in Sampling(stop="1s").pick(endless())] == list(range(10))  # stops drawing
    assert Sampling(every=3).estimate(30, 10.0) == 10
    assert Sampling(fps=2.5, start="1s").estimate(30, 10.0) == 5
    assert Sampling().estimate(None, 0.0) is None


@pytest.mark.parametrize(("kwargs", "parameter"), [
    ({"every": 0}, "every"), ({"every": 1.5}, "every"), ({"every": True}, "every"),
    ({"fps": 0}, "fps"), ({"fps": float("nan")}, "fps"), ({"fps": True}, "fps"), ({"fps": 5, "every": 2}, "fps"),
    ({"start": -1}, "start"), ({"start": "x"}, "start"), ({"start": "-2s"}, "start"),
    ({"start": 2.5}, "start"), ({"stop": "inf s"}, "stop"), ({"start": 10, "stop": 10}, "stop"),
    ({"start": "3s", "stop": "1.5s"}, "stop"),
])
def test_sampling_checks_name_the_parameter(kwargs: dict, parameter: str) -> None:
    with pytest.raises(ParameterError) as caught:
        Sampling(**kwargs)
    assert caught.value.parameter == parameter and "\n" not in str(caught.value)
    assert str(caught.value).startswith(f"{parameter}: ")


def test_sampling_normalises_positions() -> None:
    assert Sampling(start="12", stop="1.50s") == Sampling(start=12, stop="1.5s")
    assert Sampling(start=" 90s ").start == "90s"
    assert Sampling(start=np.int64(4)).start == 4
    assert Sampling(start="2s", stop=5) != Sampling()  # mixed units are checked by the video


def test_resume_passes_over_journaled_frames_undecoded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    video = write_video(tmp_path / "route.avi", 20)
    cache = Cache(tmp_path / "cache")
    spec = FakeSpec()
    clean = describe_video(video, spec, Cache(tmp_path / "clean"), Sampling(every=2))
    stored = Cache(tmp_path / "clean").read_stored(clean.entry.key)
    journal = cache.open_journal(stored.header)  # a run killed after its first four frames
    for name in names([0, 2, 4, 6]):
        journal.append(stored.records[name])
    journal.close()
    retrieved = []
    real = cv2.VideoCapture

    class Counting:  # a wrapper: a Python subclass of cv2.VideoCapture can crash the interpreter
        def __init__(self, *args: object) -> None:
            self.capture = real(*args)

        def __getattr__(self, name: str) -> object:
            return getattr(self.capture, name)

        def retrieve(self) -> tuple[bool, np.ndarray]:  # converts the frame grabbed last
            retrieved.append(int(self.capture.get(cv2.CAP_PROP_POS_FRAMES)) - 1)
            return self.capture.retrieve()
    monkeypatch.setattr(cv2, "VideoCapture", Counting)
    resumed = describe_video(video, spec, cache, Sampling(every=2))
    assert (resumed.computed, resumed.reused) == (6, 4)
    assert retrieved == [8, 10, 12, 14, 16, 18]
    assert resumed.entry.digest == clean.entry.digest
    np.testing.assert_array_equal(resumed.entry.data, clean.entry.data)
    np.testing.assert_array_equal(resumed.entry.timestamps_ms, clean.entry.timestamps_ms)


_RUN = """
import sys
from pathlib import Path
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_video
from wiloc.descriptors.registry import get_descriptor
from wiloc.sources.video import Sampling
describe_video(Path(sys.argv[1]), get_descriptor("gist"), Cache(Path(sys.argv[2])), Sampling(every=2))
"""


def test_killed_describe_resumes_with_what_is_missing(tmp_path: Path) -> None:
    from wiloc.descriptors.registry import get_descriptor

    video = write_video(tmp_path / "route.avi", 96, size=(160, 120))
    count = 48
    cache = Cache(tmp_path / "cache")
    run = interrupt_after_six_frames([_RUN, str(video), str(cache.root)], cache, signal.SIGKILL)
    assert run.returncode == -signal.SIGKILL
    [info] = cache.list_entries()
    assert not info.complete and 6 <= info.frames < count
    resumed = describe_video(video, get_descriptor("gist"), cache, Sampling(every=2))
    assert (resumed.computed, resumed.reused, resumed.frames) == (count - info.frames, info.frames, count)
    clean = describe_video(video, get_descriptor("gist"), Cache(tmp_path / "clean"), Sampling(every=2))
    assert resumed.entry.names == clean.entry.names == names(range(0, 96, 2))
    np.testing.assert_array_equal(resumed.entry.timestamps_ms, clean.entry.timestamps_ms)
    np.testing.assert_allclose(resumed.entry.data, clean.entry.data, rtol=1e-5, atol=1e-7)  # gist: a few ulp
    assert resumed.entry.digest == clean.entry.digest
    assert not list(cache.root.rglob("*.wiloc-tmp")) and not list(cache.root.rglob("*.journal"))


def test_cut_video_keeps_its_good_frames(tmp_path: Path) -> None:
    whole = write_video(tmp_path / "whole.avi", 50)
    cut = tmp_path / "cut.avi"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    good = len(decoded_gray(cut))
    assert 0 < good < 50
    cache = Cache(tmp_path / "cache")
    report = describe_video(cut, FakeSpec(), cache)
    assert report.entry.names == names(range(good))
    [(name, reason)] = report.failed
    assert name == frame_name(good)
    assert f"cannot decode frame {frame_name(good)} of 50" in reason
    assert f"the last good frame is {frame_name(good - 1)}" in reason
    again = describe_video(cut, FakeSpec(), cache)
    assert (again.computed, again.reused, again.failed) == (0, good, report.failed)
    stopped = describe_video(cut, FakeSpec(), cache, Sampling(stop=good))  # the cut ends before the damage
    assert stopped.failed == [] and stopped.entry.names == names(range(good))


def test_a_damaged_stored_frame_of_a_video_is_described_again(tmp_path: Path) -> None:
    """A video's entry with a frame failing its checksum said "described again" and was reused
    without the frame on every run: the frame was missing from every later localize."""
    video = write_video(tmp_path / "v.avi", 12)
    cache = Cache(tmp_path / "cache")
    first = describe_video(video, FakeSpec(), cache)
    entry_file = cache.entry_path(first.entry.key)
    with h5py.File(entry_file, "r+") as f:
        row = f["descriptors"][5]
        row[0] += 1.0
        f["descriptors"][5] = row
    damaged = Cache(tmp_path / "cache")
    again = describe_video(video, FakeSpec(), damaged)
    assert "1 frame(s) failed their checksum" in damaged.repairs[0]
    assert (again.computed, again.reused) == (1, 11)
    assert again.entry.names == first.entry.names and again.entry.digest == first.entry.digest
    assert describe_video(video, FakeSpec(), Cache(tmp_path / "cache")).computed == 0  # repaired on disk


def test_a_video_whose_first_frame_is_damaged_says_so(tmp_path: Path) -> None:
    """It said "no frame of this video can be decoded" where every frame but the first decodes."""
    video = write_video(tmp_path / "v.avi", 20)
    data = bytearray(video.read_bytes())
    first = data.index(b"\xff\xd8\xff")  # the first frame's JPEG, half of it zeroed
    size = data.index(b"\xff\xd8\xff", first + 3) - first
    data[first:first + size // 2] = bytes(size // 2)
    damaged = tmp_path / "first.avi"
    damaged.write_bytes(bytes(data))
    capture = cv2.VideoCapture(str(damaged), cv2.CAP_FFMPEG)
    assert [capture.read()[0] for _ in range(20)] == [False] + [True] * 19
    with pytest.raises(WilocError, match="cannot decode frame 000000 \\(the file is damaged there\\)"):
        describe_video(damaged, FakeSpec(), Cache(tmp_path / "cache"))


def longer_duration(path: Path, duration_ms: float) -> Path:
    """A Matroska file's header duration set to `duration_ms`, its frames untouched: what a video
    of variable frame rate looks like to OpenCV, whose frame count is the duration times the
    nominal rate (a phone's 1 fps stretch counts 10 frames a second at a nominal 10 fps)."""
    data = bytearray(path.read_bytes())
    header = data[:data.index(b"\x1f\x43\xb6\x75")]  # up to the first cluster: no frame bytes
    at = header.index(b"\x44\x89\x88") + 3  # Info's Duration, a float64 in ms
    data[at:at + 8] = struct.pack(">d", duration_ms)
    path.write_bytes(bytes(data))
    return path


def test_a_frame_count_beyond_the_frames_at_the_end_of_the_duration_is_no_cut(tmp_path: Path) -> None:
    video = longer_duration(write_video(tmp_path / "vfr.mkv", 20, fourcc="FFV1"), 2500.0)  # frames at 0-1.9 s
    capture = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    assert capture.get(cv2.CAP_PROP_FRAME_COUNT) == 25 and len(decoded_gray(video)) == 20
    report = describe_video(video, FakeSpec(), Cache(tmp_path / "cache"))
    assert report.failed == [] and report.entry.names == names(range(20))
    cut = longer_duration(write_video(tmp_path / "cut.mkv", 20, fourcc="FFV1"), 5000.0)  # 3 s of frames missing
    [(name, reason)] = describe_video(cut, FakeSpec(), Cache(tmp_path / "cache")).failed
    assert name == frame_name(20) and "cannot decode frame 000020 of 50 (the file is cut or damaged there)" in reason


def later_start(path: Path, offset_ms: int) -> Path:
    """A Matroska file's frames moved `offset_ms` later in the container's time (each cluster's
    timecode, widened in place over its CRC-32 element): a recording cut out of a longer one,
    whose first frame is not at 0."""
    data = bytearray(path.read_bytes())
    at = 0
    while (at := data.find(b"\x1f\x43\xb6\x75", at + 1)) > 0:  # a cluster: CRC-32, then its timecode
        crc = data.index(b"\xbf\x84", at)
        assert crc < at + 12 and data[crc + 6] == 0xE7
        size = data[crc + 7] & 0x7F
        value = int.from_bytes(data[crc + 8:crc + 8 + size], "big") + offset_ms
        pad = size - 1  # a Void element where the CRC-32 was, the timecode in 4 bytes
        data[crc:crc + 8 + size] = b"\xec" + bytes([0x80 | pad]) + bytes(pad) + b"\xe7\x84" + value.to_bytes(4, "big")
    path.write_bytes(bytes(data))
    return path


@pytest.mark.skipif(not hasattr(cv2, "CAP_PROP_PTS"), reason="this OpenCV gives no presentation stamps")
def test_a_video_starting_after_0_is_no_cut(tmp_path: Path) -> None:
    """Its container's duration counts from 0: frames at 5-6.9 s of a 7 s video were taken for a
    cut at frame 20 of 70, an error naming a frame that does not exist."""
    video = longer_duration(later_start(write_video(tmp_path / "late.mkv", 20, fourcc="FFV1"), 5000), 7000.0)
    capture = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    assert capture.get(cv2.CAP_PROP_FRAME_COUNT) == 70 and len(decoded_gray(video)) == 20
    report = describe_video(video, FakeSpec(), Cache(tmp_path / "cache"))
    assert report.failed == [] and report.entry.names == names(range(20))
    assert report.entry.timestamps_ms[0] == 0.0
    cut = longer_duration(later_start(write_video(tmp_path / "cut.mkv", 20, fourcc="FFV1"), 5000), 10000.0)
    [(name, reason)] = describe_video(cut, FakeSpec(), Cache(tmp_path / "cache")).failed
    assert name == frame_name(20) and "cannot decode frame 000020 of 100 (the file is cut or damaged there)" in reason


def test_frames_a_damaged_file_loses_without_an_error_are_noted(tmp_path: Path) -> None:
    """FFmpeg passes over the frames of a damaged stretch of some files without an error: the
    frames after it were named as if none were missing, silently pairing the wrong frames."""
    video = write_video(tmp_path / "whole.mkv", 60, fourcc="FFV1")
    data = bytearray(video.read_bytes())
    data[len(data) // 2:len(data) // 2 + 6000] = bytes(6000)
    damaged = tmp_path / "damaged.mkv"
    damaged.write_bytes(bytes(data))
    report = describe_video(damaged, FakeSpec(), Cache(tmp_path / "cache"))
    assert 30 < len(report.entry.names) < 60 and report.failed == []
    [note] = report.notes
    lost = 60 - len(report.entry.names)
    assert f"{damaged}: its timestamps say {lost} frame(s) are missing, the first after frame" in note
    assert describe_video(damaged, FakeSpec(), Cache(tmp_path / "cache")).notes == [note]  # said again when reused
    assert describe_video(video, FakeSpec(), Cache(tmp_path / "cache")).notes == []
    sampled = describe_video(damaged, FakeSpec(), Cache(tmp_path / "cache"), Sampling(every=3))
    assert "frame(s) are missing" in sampled.notes[0]


def test_lost_frames_judges_videos_of_constant_rate_only() -> None:
    names = [frame_name(i) for i in range(20)]
    steady = np.arange(20) * 100.0
    assert lost_frames(names, steady, 10.0) == ""
    gap = np.r_[steady[:10], steady[10:] + 300.0]
    assert "3 frame(s) are missing, the first after frame 000009 (400 ms to the next at 10 frames/s)" in \
        lost_frames(names, gap, 10.0)
    varying = np.cumsum(np.random.default_rng(0).uniform(50.0, 600.0, 20))  # a phone's variable rate
    assert lost_frames(names, varying, 10.0) == ""
    assert lost_frames(names, gap, 0.0) == ""  # no rate: nothing to judge by


def _cli(*args: str, cache: Path) -> subprocess.CompletedProcess:
    """The command line in a fresh process, where the CLI sets FFmpeg's log level before cv2 loads."""
    code = "import sys; from wiloc.cli import app; sys.argv[0] = 'wiloc'; app()"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "WILOC_CACHE": str(cache), "COLUMNS": "200"}, check=False)


def test_cli_reports_a_cut_video_as_one_error_line(tmp_path: Path) -> None:
    whole = write_video(tmp_path / "whole.mkv", 50, fourcc="FFV1")
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])
    good = len(decoded_gray(cut))
    run = _cli("describe", str(cut), "--json", cache=tmp_path / "cache")
    assert run.returncode == 1
    assert run.stderr.splitlines() == [
        f"error: {cut.resolve()}: cannot decode frame {frame_name(good)} of 50 (the file is cut or damaged "
        f"there); the last good frame is {frame_name(good - 1)}, and the frames up to it are kept"]
    [row] = json.loads(run.stdout)["results"]
    assert (row["frames"], row["computed"], row["failed"]) == (good + 1, good, 1)
    [info] = Cache(tmp_path / "cache").list_entries()
    assert info.complete and info.frames == good
    past = _cli("describe", str(cut), "--start", str(good + 5), cache=tmp_path / "cache2")  # the cut after the damage
    assert past.returncode == 1
    assert past.stderr.splitlines() == [
        f"error: {cut.resolve()}: cannot decode frame {frame_name(good)} of 50 (the file is cut or damaged "
        "there); the frames before it are not in the cut: no frame of the cut can be decoded"]


def test_a_file_that_is_no_video_is_one_error_line(tmp_path: Path) -> None:
    fake = tmp_path / "x.mp4"
    fake.write_text("not a video\n" * 100)
    with pytest.raises(WilocError, match="not a video"):
        describe_video(fake, FakeSpec(), Cache(tmp_path / "cache"))
    run = _cli("describe", str(fake), cache=tmp_path / "cache")
    assert run.returncode == 1
    assert run.stderr.splitlines() == [
        f"error: {fake}: not a video wiloc can read (no video stream found; an MP4 or MOV cut before "
        "its index cannot be opened either)"]
    assert not (tmp_path / "cache").exists()
    with pytest.raises(WilocError, match="does not exist"):
        describe_video(tmp_path / "missing.avi", FakeSpec(), Cache(tmp_path / "cache"))


def test_an_edited_video_makes_a_new_entry(tmp_path: Path) -> None:
    video = write_video(tmp_path / "route.avi", 12)
    cache = Cache(tmp_path / "cache")
    first = describe_video(video, FakeSpec(), cache)
    stat = video.stat()
    os.utime(video, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # touched: same entry
    assert describe_video(video, FakeSpec(), cache).computed == 0
    write_video(video, 12, seed=1)
    edited = describe_video(video, FakeSpec(), cache)
    assert edited.computed == 12 and edited.entry.key != first.entry.key
    assert edited.entry.digest != first.entry.digest
    assert not np.array_equal(edited.entry.data, first.entry.data)
    assert len(cache.list_entries()) == 2
    other = describe_video(video, FakeSpec(), cache, Sampling(every=2))  # another sampling: its own entry
    assert other.computed == 6 and len(cache.list_entries()) == 3


def test_fingerprint_reads_ends_and_samples_of_a_large_file(tmp_path: Path) -> None:
    path = tmp_path / "big.mp4"
    data = bytearray(np.random.default_rng(0).integers(0, 256, 8 << 20, dtype=np.uint8).tobytes())
    path.write_bytes(data)
    base = video_fingerprint(path)
    assert base.size == len(data)
    for offset in (10, len(data) - 10, len(data) * 4 // 9 + 3):  # head, tail, a middle block
        changed = bytearray(data)
        changed[offset] ^= 0xFF
        path.write_bytes(changed)
        assert video_fingerprint(path).digest != base.digest, offset
    path.write_bytes(data + b"\0")
    assert video_fingerprint(path).digest != base.digest


def test_api_describe_and_describer_take_videos(tmp_path: Path) -> None:
    video = write_video(tmp_path / "route.avi", 20, size=(96, 64))
    cache = Cache(tmp_path / "cache")
    [report] = api.describe([video], "sad", cache=cache, sampling=Sampling(every=5))
    assert report.entry.names == names([0, 5, 10, 15]) and report.shape == (4, 1152)
    describer = Describer("sad", cache=cache, sampling=Sampling(every=5))
    assert describer.entry(video).digest == report.entry.digest and describer.skipped == []
    assert descriptor_label("sad", None, [video]) == "sad"  # a video is described, not imported
    assert Describer("sad", cache=cache).entry(video).names == names(range(20))
    folder = tmp_path / "frames"
    folder.mkdir()
    with pytest.raises(ParameterError, match="^fps: applies to video files and ROS bags only"):  # the field set
        api.describe([folder], "sad", cache=cache, sampling=Sampling(fps=2))  # no video: nothing to sample
    for i, gray in enumerate(decoded_gray(video)[:3]):
        cv2.imwrite(str(folder / f"Image{i:03d}.png"), gray)
    on_video, on_folder = api.describe([video, folder], "sad", cache=cache, sampling=Sampling(every=5))
    assert on_video.entry.names == names([0, 5, 10, 15]) and on_folder.entry.names == [f"Image{i:03d}.png" for i in range(3)]
    assert is_video(video) and not is_video(folder) and not is_video(tmp_path / "x.npy")


def test_cli_describe_samples_videos(tmp_path: Path, cache_dir: Path) -> None:
    video = write_video(tmp_path / "route.avi", 30)
    result = CliRunner().invoke(app, ["describe", str(video), "--start", "1s", "--every", "5", "--json"])
    assert result.exit_code == 0, result.output
    [row] = json.loads(result.stdout)["results"]
    assert (row["frames"], row["computed"], row["failed"]) == (4, 4, 0)
    bad = CliRunner().invoke(app, ["describe", str(video), "--fps", "0"])
    assert bad.exit_code == 2 and "--fps" in bad.output
    for command in (["describe", str(video)], ["localize", str(video), "--map", str(video)]):
        both = CliRunner().invoke(app, [*command, "--every", "2", "--fps", "3"])  # named as typed, not as `every`
        ends_in_one_error(both, 2, "--fps: does not go with --every (got --every 2)")
    none = CliRunner().invoke(app, ["describe", str(video), "--start", "40"])
    assert none.exit_code == 1 and "the cut (start 40) holds no frame of this video (it has 30 frames)" in none.output
    folder = tmp_path / "frames"
    folder.mkdir()
    alone = CliRunner().invoke(app, ["describe", str(folder), "--every", "2"])
    assert alone.exit_code == 2
    assert f"--every: applies to video files and ROS bags only; {folder} is neither" in alone.output


@pytest.fixture(scope="module")
def nordland(data_root: Path, tmp_path_factory: pytest.TempPathFactory,
             real_data_cache: Path) -> tuple[dict[str, Path], Cache]:
    """Each Nordland season written once as a lossless video of its 3576 frames, and the cache the
    tests share (the session's real-data one: the folders' descriptors and differences are in it
    when other tests made them; the second test describes nothing the first did not)."""
    root = data_root / "nordland-summer-winter-64x32"
    tmp = tmp_path_factory.mktemp("nordland")
    videos = {}
    for season in ("summer", "winter"):
        videos[season] = tmp / f"{season}.mkv"
        writer = cv2.VideoWriter(str(videos[season]), cv2.VideoWriter_fourcc(*"FFV1"), 10.0, (64, 32))  # lossless
        for path in list_traversal(root / season).frames:
            writer.write(cv2.cvtColor(read_gray(path), cv2.COLOR_GRAY2BGR))
        writer.release()
    return videos, Cache(real_data_cache)


@pytest.mark.realdata
@pytest.mark.parametrize("season", ["summer", "winter"])
def test_nordland_as_a_lossless_video_gives_the_folder_descriptors(data_root: Path, season: str,
                                                                  nordland: tuple[dict[str, Path], Cache]) -> None:
    from wiloc.descriptors.registry import get_descriptor

    videos, cache = nordland
    folder = data_root / "nordland-summer-winter-64x32" / season
    frames = list_traversal(folder).frames
    spec = get_descriptor("sad")
    from_video = describe_video(videos[season], spec, cache)
    from_folder = describe_folder(folder, spec, cache, jobs=1)
    assert from_video.failed == [] and from_video.entry.names == names(range(len(frames)))
    assert from_folder.entry.names == [p.name for p in frames]
    np.testing.assert_array_equal(from_video.entry.data, from_folder.entry.data)


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_nordland_videos_localize_as_the_folders_do(data_root: Path, method: str,
                                                    nordland: tuple[dict[str, Path], Cache]) -> None:
    from wiloc import api

    root = data_root / "nordland-summer-winter-64x32"
    videos, cache = nordland
    on_video = api.localize(videos["winter"], reference=videos["summer"], method=method, cache=cache)
    on_folder = api.localize(root / "winter", reference=root / "summer", method=method, cache=cache)
    for got, want in [(on_video.decisions.match, on_folder.decisions.match),
                      (on_video.decisions.confidence, on_folder.decisions.confidence),
                      (on_video.decisions.difference, on_folder.decisions.difference)]:
        np.testing.assert_array_equal(got, want)
    assert on_video.results.header.descriptor == "sad" and on_video.results.header.sampling["every"] == 1


def test_a_video_against_a_folder_of_its_frames_samples_the_video_and_aligns_by_position(tmp_path: Path,
                                                                                       cache_dir: Path) -> None:
    """Sampling options apply to the video side (the folder map takes every frame); the results
    file keeps the video's suffix in its name, apart from a folder run of the same name; aligned
    ground truth matches the video's frames (named by index) with the folder's by position. In
    this process: the error lines are only searched, FFmpeg's log lines would not matter."""
    video = write_video(tmp_path / "route.mkv", 30, fourcc="FFV1")
    folder = tmp_path / "route"
    folder.mkdir()
    for i, gray in enumerate(decoded_gray(video)):
        cv2.imwrite(str(folder / f"Image{i:03d}.png"), gray)
    runner, out = CliRunner(env={"COLUMNS": "200"}), tmp_path / "runs"
    run = runner.invoke(app, ["localize", str(video), "--map", str(folder), "--method", "catgraph", "--out", str(out)])
    assert run.exit_code == 0, run.output
    written = out / "route-mkv-sad-catgraph.csv"
    assert written.is_file() and api.results_name(folder, "catgraph", "sad") == "route-sad-catgraph.csv"
    by_name = runner.invoke(app, ["evaluate", str(written), "--gt", "aligned"])
    assert by_name.exit_code == 1 and "aligned:index" in by_name.stderr
    by_index = runner.invoke(app, ["evaluate", str(written), "--gt", "aligned:index", "--json"])
    assert by_index.exit_code == 0, by_index.output
    [row] = json.loads(by_index.stdout)["runs"]
    assert row["frames"] == 30 and row["recall_at_1"] >= 0.9
    sampled = runner.invoke(app, ["localize", str(video), "--map", str(folder), "--every", "2",
                                  "--out", str(tmp_path / "every2.csv"), "--json"])
    assert sampled.exit_code == 0, sampled.output
    assert json.loads(sampled.stdout)["runs"][0]["frames"] == 15
    refused = runner.invoke(app, ["localize", str(folder), "--map", str(folder), "--every", "2"])
    assert refused.exit_code == 2 and "applies to video files and ROS bags only" in refused.stderr

"""`wiloc localize --follow`: a folder filled while wiloc runs gives the batch decisions, row by row,
and a killed follower resumes to the same file."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from wiloc import api, demo
from wiloc.decisions import Decision
from wiloc.errors import WilocError
from wiloc.evaluation.results import read_results
from wiloc.localization.follow import SETTLE_SECONDS, FolderWatch, Skipped, follow
from wiloc.localization.localizer import Localizer
from wiloc.sources.natural_order import natural_sorted

CLI = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"

# Copies the frames into a folder one by one, each written in two halves with a pause between,
# as a camera writing files would.
FEEDER = """
import sys, time
from pathlib import Path
src, dst, pause = Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3])
for path in sorted(src.iterdir(), key=lambda p: p.name):
    data = path.read_bytes()
    with open(dst / path.name, "wb") as out:
        out.write(data[: len(data) // 2]); out.flush(); time.sleep(pause / 2)
        out.write(data[len(data) // 2:])
    time.sleep(pause / 2)
"""


def _rows(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)


def _live_folder(tmp_path: Path, frames: list[Path]) -> Path:
    """A folder ``live`` holding copies of ``frames``, as a camera has written them."""
    live = tmp_path / "live"
    live.mkdir()
    for path in frames:
        (live / path.name).write_bytes(path.read_bytes())
    return live


def _follower(folder: Path, ref: Path | None, out: Path, method: str, idle: float) -> subprocess.Popen:
    """``wiloc localize FOLDER --follow`` against ``ref`` (None: sequence mode) in a new process."""
    args = ["localize", str(folder), *(["--map", str(ref)] if ref is not None else []), "--method", method,
            "--follow", "--idle", str(idle), "--out", str(out)]
    return subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def test_watch_hands_out_stable_files_in_natural_order(tmp_path: Path) -> None:
    for name in ("f10.png", "f2.png", "notes.txt", ".hidden.png"):
        (tmp_path / name).write_bytes(b"x" * 10)
    watch = FolderWatch(tmp_path)
    assert watch.poll() == []  # first sight: not yet known to be stable
    assert [p.name for p in watch.poll()] == ["f2.png", "f10.png"]
    (tmp_path / "f11.png").write_bytes(b"half")
    assert watch.poll() == []
    with open(tmp_path / "f11.png", "ab") as grow:
        grow.write(b" and the rest")
    assert watch.poll() == []  # it grew since the last poll
    assert [p.name for p in watch.poll()] == ["f11.png"]
    assert watch.poll() == []


def _encoded(suffix: str) -> bytes:
    """A small gray image encoded as ``suffix`` (``.jpg``, ``.png``, ``.bmp``, ``.tif``) gives it."""
    import cv2

    return cv2.imencode(suffix, np.arange(64, dtype=np.uint8).reshape(8, 8))[1].tobytes()


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_whole_jpeg_or_png_is_handed_out_by_the_first_poll_that_finds_it(suffix: str, tmp_path: Path) -> None:
    """The reader refuses a JPEG or PNG cut short, so one need not be seen twice: written in place,
    renamed into place or linked to, it is handed out at first sight (not known stable), once."""
    outside = tmp_path / "elsewhere"
    live = tmp_path / "live"
    outside.mkdir()
    live.mkdir()
    (live / f"f1{suffix}").write_bytes(_encoded(suffix))
    watch = FolderWatch(live)
    assert watch.poll() == [live / f"f1{suffix}"] and not watch.stable(live / f"f1{suffix}")
    (live / ".f2.tmp").write_bytes(_encoded(suffix))
    os.replace(live / ".f2.tmp", live / f"f2{suffix}")
    (outside / f"f3{suffix}").write_bytes(_encoded(suffix))
    (live / f"f3{suffix}").symlink_to(outside / f"f3{suffix}")
    assert watch.poll() == [live / f"f2{suffix}", live / f"f3{suffix}"]
    assert watch.poll() == [] and watch.rewritten == []


@pytest.mark.parametrize("name, data", [
    ("f1.bmp", _encoded(".bmp")),
    ("f1.tif", _encoded(".tif")),
    ("f1.jpg", _encoded(".bmp")),  # named a JPEG, read as the BMP it is
    ("f1.jpg", b""),  # just created: its format not known yet
    ("f1.png", _encoded(".png")[:5]),  # too short to tell
], ids=["bmp", "tiff", "bmp-named-jpg", "empty", "short"])
def test_a_file_whose_cut_the_reader_cannot_tell_is_handed_out_once_seen_twice(name: str, data: bytes,
                                                                                 tmp_path: Path) -> None:
    """A BMP or TIFF cut short may decode, its missing part made up: it waits for a second sighting
    with the same size and time, as do files whose first bytes do not show a JPEG or PNG."""
    (tmp_path / name).write_bytes(data)
    watch = FolderWatch(tmp_path)
    assert watch.poll() == []
    assert watch.poll() == [tmp_path / name] and watch.stable(tmp_path / name)


def test_files_found_together_are_handed_out_in_natural_order_whatever_their_format(tmp_path: Path) -> None:
    """A PNG found with a BMP that sorts before it waits for the BMP's second sighting, so a folder's
    frames already there are decided in the batch run's order; one found alone is not held back."""
    for name in ("f1.bmp", "f2.png", "f3.jpg"):
        (tmp_path / name).write_bytes(_encoded(Path(name).suffix))
    (tmp_path / "f0.png").write_bytes(_encoded(".png"))
    watch = FolderWatch(tmp_path)
    assert watch.poll() == [tmp_path / "f0.png"]
    assert [p.name for p in watch.poll()] == ["f1.bmp", "f2.png", "f3.jpg"]
    (tmp_path / "f4.png").write_bytes(_encoded(".png"))
    assert watch.poll() == [tmp_path / "f4.png"]


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_frame_handed_out_while_cut_and_read_once_whole_is_not_said_written_again(suffix: str,
                                                                                   tmp_path: Path) -> None:
    """A file handed out at first sight whose writer finishes it before it is read: the size and
    time it was read with, not those it was handed out with, tell a later rewrite."""
    whole = _encoded(suffix)
    frame = tmp_path / f"f1{suffix}"
    frame.write_bytes(whole[: len(whole) // 2])
    watch = FolderWatch(tmp_path)
    assert watch.poll() == [frame]
    frame.write_bytes(whole)  # finished before the follower reads it
    os.utime(frame, ns=(10**18, 10**18))
    watch.taken(frame)
    for _ in range(3):
        assert watch.poll() == []
    assert watch.rewritten == []
    frame.write_bytes(whole[::-1])  # written again
    watch.poll()
    assert watch.rewritten == [frame]


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_frame_written_in_steps_is_decided_once_by_the_first_poll_that_finds_it_whole(
        demo_route: demo.DemoRoute, suffix: str, tmp_path: Path, cache_dir: Path) -> None:
    """A JPEG or PNG written in thirds, each seen by polls (read at first sight, refused cut short):
    decided once, from the whole file, by the poll that finds it whole, not one poll later."""
    import cv2

    whole = cv2.imencode(suffix, cv2.imread(str(min(demo_route.queries[0].iterdir()))))[1].tobytes()
    frame = tmp_path / f"frame001{suffix}"
    frame.write_bytes(whole[: len(whole) // 3])
    steps = {0.6: whole[: 2 * len(whole) // 3], 1.2: whole}  # when the writer writes on, and what the file then holds
    now, sizes = [0.0], set()

    def sleep(seconds: float) -> None:
        sizes.add(frame.stat().st_size)
        now[0] = round(now[0] + seconds, 6)
        if now[0] in steps:
            frame.write_bytes(steps[now[0]])

    observe = Localizer.observe
    read: list[int] = []

    def observed(self: Localizer, path: Path) -> Decision:
        read.append(path.stat().st_size)
        return observe(self, path)

    decided = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Localizer, "observe", observed)
        for event in follow(Localizer(demo_route.reference, method="threshold"), FolderWatch(tmp_path), idle=1.0,
                            poll=0.2, clock=lambda: now[0], sleep=sleep):
            assert not isinstance(event, Skipped), event
            decided.append((event.frame, now[0]))
    assert decided == [(frame.name, 1.2)]
    assert sizes >= {len(whole) // 3, 2 * len(whole) // 3} and set(read) == sizes | {len(whole)}


@pytest.mark.parametrize("names", [
    [f"scene1.{i}.png" for i in range(1, 12)],  # numbered: each dotted run keeps its value
    ["1614000000.1.png", "1614000000.15.png", "1614000000.2.png", "1614000000.25.png"],  # decimals
])
def test_a_followed_folder_is_handed_out_in_the_batch_runs_order(names: list[str], tmp_path: Path) -> None:
    for name in names:
        (tmp_path / name).write_bytes(b"x" * 10)
    watch = FolderWatch(tmp_path)
    watch.poll()
    assert [p.name for p in watch.poll()] == natural_sorted(names)


def test_a_poll_orders_its_names_as_numbered_once_earlier_names_showed_it(tmp_path: Path) -> None:
    """scene1.2 and scene1.11 alone could be decimals; scene1.1 and scene1.10, decided earlier
    (or in a run resumed), showed the folder numbered."""
    names = [f"scene1.{i}.png" for i in range(1, 12)]
    watch = FolderWatch(tmp_path, done=["scene1.1.png", "scene1.10.png"])
    for name in names:
        (tmp_path / name).write_bytes(b"x" * 10)
    watch.poll()
    assert [p.name for p in watch.poll()] == [n for n in natural_sorted(names) if n not in ("scene1.1.png", "scene1.10.png")]


def test_an_undecodable_frame_is_retried_then_left_out(demo_route: demo.DemoRoute, tmp_path: Path,
                                                       cache_dir: Path) -> None:
    good = sorted(demo_route.queries[0].iterdir())[:3]
    for path in good:
        (tmp_path / path.name).write_bytes(path.read_bytes())
    (tmp_path / "frame001.jpg").write_bytes(good[1].read_bytes()[:500])  # truncated for good
    now = [0.0]
    events = list(follow(Localizer(demo_route.reference, method="threshold"), FolderWatch(tmp_path), idle=1.0, poll=0.5,
                         clock=lambda: now[0], sleep=lambda s: now.__setitem__(0, now[0] + s)))
    skipped = [e for e in events if isinstance(e, Skipped)]
    assert [e.frame for e in events if not isinstance(e, Skipped)] == [good[0].name, good[2].name]
    assert len(skipped) == 1 and skipped[0].path.name == "frame001.jpg" and "truncated" in skipped[0].reason
    assert now[0] >= SETTLE_SECONDS


def test_a_skipped_frame_completed_later_is_a_note_not_a_decided_file_written_again(
        demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    """A JPEG cut short is skipped after SETTLE_SECONDS; its writer finishing it later was warned
    of as 'written again after it was decided', though it never was."""
    from wiloc.localization.follow import COMPLETED

    good = sorted(demo_route.queries[0].iterdir())[:2]
    cut = tmp_path / "g6.jpg"
    cut.write_bytes(good[1].read_bytes()[:500])
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds
        if SETTLE_SECONDS + 1.0 <= now[0] < SETTLE_SECONDS + 1.0 + seconds:  # skipped by now: the writer finishes
            cut.write_bytes(good[1].read_bytes())
            os.utime(cut, ns=(int(now[0] * 1e9), int(now[0] * 1e9)))

    events = list(follow(Localizer(demo_route.reference, method="threshold"), FolderWatch(tmp_path), idle=3.0,
                         poll=0.5, clock=lambda: now[0], sleep=sleep))
    assert [(e.path, e.kind) for e in events] == [(cut, "skipped"), (cut, "note")]
    assert "truncated" in events[0].reason and events[1].reason == COMPLETED
    assert str(events[1]).startswith(f"{cut}: completed after it was skipped")


@pytest.mark.parametrize("name", ["frame001.jpg", "frame001.png"])
def test_a_frame_whose_writer_pauses_halfway_is_waited_for(demo_route: demo.DemoRoute, name: str, tmp_path: Path,
                                                           cache_dir: Path) -> None:
    """Half a file, unchanged over several polls, reads as cut short: it is retried, not left out,
    and decided once the writer finishes it (within :data:`SETTLE_SECONDS`)."""
    import cv2

    frames = sorted(demo_route.queries[0].iterdir())[:3]
    for path in (frames[0], frames[2]):
        (tmp_path / path.name).write_bytes(path.read_bytes())
    whole = cv2.imencode(Path(name).suffix, cv2.imread(str(frames[1])))[1].tobytes()
    (tmp_path / name).write_bytes(whole[: len(whole) // 2])
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds
        if now[0] >= SETTLE_SECONDS / 2 and (tmp_path / name).stat().st_size < len(whole):
            (tmp_path / name).write_bytes(whole)  # the writer goes on

    decided = {}  # frame -> when it was decided
    for event in follow(Localizer(demo_route.reference, method="threshold"), FolderWatch(tmp_path), idle=1.0, poll=0.2,
                        clock=lambda: now[0], sleep=sleep):
        assert not isinstance(event, Skipped), event
        decided[event.frame] = now[0]
    assert sorted(decided) == sorted([frames[0].name, name, frames[2].name])
    assert decided[name] >= SETTLE_SECONDS / 2  # from the whole file, not from its first half


def _killed_and_resumed(query: Path, reference: Path | None, method: str, tmp_path: Path) -> None:
    """Feed ``query`` into a folder, kill the follower halfway, resume: the batch rows (``reference``
    None: sequence mode)."""
    batch = api.localize(query, reference=reference, method=method, out=tmp_path / "batch.csv")
    live = tmp_path / "live"
    live.mkdir()
    out = tmp_path / "follow.csv"
    feeder = subprocess.Popen([sys.executable, "-c", FEEDER, str(query), str(live), "0.01"])
    follower = _follower(live, reference, out, method, idle=60)
    n = len(batch.results.frames)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(_rows(out)) < n // 2):
        time.sleep(0.05)
    follower.send_signal(signal.SIGKILL)
    follower.wait()
    halfway = len(_rows(out))
    assert 0 < halfway < n
    feeder.wait(timeout=120)
    resumed = _follower(live, reference, out, method, idle=2)
    stdout, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr
    header, *lines, end = stdout.splitlines()  # the header, one plain line per frame decided after the resume
    assert header == "frame\tmatch\tconfidence\tP(new place)\tstage" and len(lines) == n - halfway
    assert end == (f"# ended: no new frame for 2 s; {n - halfway} frames decided ({halfway} resumed before), "
                   f"0 left out; results in {out}")
    expected, got = _rows(batch.path), _rows(out)
    assert got.columns.tolist() == expected.columns.tolist()
    pd.testing.assert_frame_equal(got, expected)


@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_a_filling_folder_gives_the_batch_rows_and_a_killed_follower_resumes(
        demo_route: demo.DemoRoute, method: str, tmp_path: Path, cache_dir: Path) -> None:
    # the detour: a stretch off the map
    _killed_and_resumed(demo_route.queries[2], demo_route.reference, method, tmp_path)


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_gardens_point_follower_killed_halfway_resumes_identically(data_root: Path, method: str, tmp_path: Path,
                                                                   cache_dir: Path) -> None:
    gp = data_root / "gardens-point-walking"
    _killed_and_resumed(gp / "day_left", gp / "day_right", method, tmp_path)


@pytest.mark.realdata
def test_a_loop_followed_without_a_map_resumes_to_the_batch_rows(data_root: Path, tmp_path: Path,
                                                                 cache_dir: Path) -> None:
    """catgraph in sequence mode (loop closure within one traversal): GP day_right then day_left as
    one traversal of 400 frames, followed live, killed halfway and resumed, decides as the batch."""
    gp = data_root / "gardens-point-walking"
    loop = tmp_path / "loop"
    loop.mkdir()
    walks = [sorted((gp / walk).glob("*.jpg")) for walk in ("day_right", "day_left")]
    for k, image in enumerate(walks[0] + walks[1]):
        (loop / f"f{k:04d}.jpg").symlink_to(image)
    _killed_and_resumed(loop, None, "catgraph", tmp_path)


def test_follow_refuses_what_it_cannot_follow(demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    from typer.testing import CliRunner

    from wiloc.cli import app
    runner = CliRunner()
    result = runner.invoke(app, ["localize", str(demo_route.queries[0]), str(demo_route.queries[1]), "--map",
                                 str(demo_route.reference), "--follow"])
    assert result.exit_code == 2 and "--follow: takes one query folder" in result.stderr
    result = runner.invoke(app, ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference),
                                 "--idle", "3"])
    assert result.exit_code == 2 and "--idle: applies to --follow only" in result.stderr
    out = tmp_path / "r.csv"
    first = runner.invoke(app, ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference), "--follow",
                                "--idle", "0.5", "--out", str(out)])
    assert first.exit_code == 0, first.output
    other = runner.invoke(app, ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference), "--follow",
                                "--idle", "0.5", "--out", str(out), "--method", "threshold"])
    assert other.exit_code == 1 and "holds a run with other settings" in other.stderr
    batch = tmp_path / "batch.csv"  # a batch run's file, same settings: it was "other settings" too
    assert runner.invoke(app, ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference), "--out",
                               str(batch)]).exit_code == 0
    again = runner.invoke(app, ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference), "--follow",
                                "--idle", "0.5", "--out", str(batch)])
    assert again.exit_code == 1 and "holds a batch run's rows, which a followed run cannot resume" in again.stderr
    with pytest.raises(WilocError) as err:  # the API given a folder as out: as a batch run, before any work
        api.follow_folder(demo_route.queries[0], reference=demo_route.reference, out=tmp_path)
    assert str(err.value) == (f"{tmp_path}: cannot write the results file: it is not a regular file (a device, a "
                              "pipe or a folder), which writing would replace")


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_gardens_point_fed_frame_by_frame_equals_batch(data_root: Path, method: str, tmp_path: Path,
                                                       cache_dir: Path) -> None:
    gp = data_root / "gardens-point-walking"
    batch = api.localize(gp / "day_left", reference=gp / "day_right", method=method, out=tmp_path / "batch.csv")
    live = tmp_path / "day_left"
    live.mkdir()
    feeder = subprocess.Popen([sys.executable, "-c", FEEDER, str(gp / "day_left"), str(live), "0.01"])
    follower = _follower(live, gp / "day_right", tmp_path / "follow.csv", method, idle=3)
    feeder.wait(timeout=300)
    _, stderr = follower.communicate(timeout=300)
    assert follower.returncode == 0, stderr
    pd.testing.assert_frame_equal(_rows(tmp_path / "follow.csv"), _rows(batch.path))
    assert np.all(_rows(batch.path)["frame"].to_numpy() == sorted(p.name for p in live.iterdir()))
    assert os.environ.get("WILOC_CACHE") == str(cache_dir)


@pytest.mark.parametrize("how", ["overwritten", "renamed onto"])
def test_a_decided_file_written_again_is_said_once_not_decided_again(demo_route: demo.DemoRoute, how: str,
                                                                      tmp_path: Path, cache_dir: Path) -> None:
    """A camera writing one fixed name (``latest.jpg``) again and again: the first image is decided,
    the rewrite is a warning, once, and not decided again (results hold one row per name)."""
    from wiloc.localization.follow import REWRITTEN

    frames = sorted(demo_route.queries[0].iterdir())[:3]
    latest = tmp_path / "latest.jpg"
    latest.write_bytes(frames[0].read_bytes())
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds
        if 1.0 <= now[0] < 1.0 + seconds or 1.5 <= now[0] < 1.5 + seconds:  # the camera writes twice more
            image = frames[1 if now[0] < 1.5 else 2].read_bytes()
            if how == "overwritten":
                latest.write_bytes(image)
            else:
                (tmp_path / ".latest.tmp").write_bytes(image)
                os.replace(tmp_path / ".latest.tmp", latest)
            os.utime(latest, ns=(int(now[0] * 1e9), int(now[0] * 1e9)))

    events = list(follow(Localizer(demo_route.reference, method="threshold"), FolderWatch(tmp_path), idle=2.0,
                         poll=0.2, clock=lambda: now[0], sleep=sleep))
    assert [e.frame for e in events if not isinstance(e, Skipped)] == ["latest.jpg"]
    warned = [e for e in events if isinstance(e, Skipped)]
    assert [(e.path, e.reason, e.kind) for e in warned] == [(latest, REWRITTEN, "warning")]
    assert str(warned[0]).startswith(f"{latest}: written again after it was decided")


def test_a_decided_file_in_a_large_folder_written_again_is_noticed(tmp_path: Path) -> None:
    """Each poll stats only a few of the files handed out, in turn: a rewrite is still noticed."""
    from wiloc.localization.follow import CHECKS_PER_POLL

    for k in range(3 * CHECKS_PER_POLL):
        (tmp_path / f"f{k:04d}.png").write_bytes(b"x")
    watch = FolderWatch(tmp_path)
    watch.poll()
    assert len(watch.poll()) == 3 * CHECKS_PER_POLL
    with open(tmp_path / "f0100.png", "ab") as grow:
        grow.write(b"more")
    for _ in range(4):
        assert watch.poll() == []
    assert watch.rewritten == [tmp_path / "f0100.png"]


def _listings(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Counts the folder listings ``FolderWatch`` makes (one entry per ``os.scandir`` call)."""
    import wiloc.localization.follow as follow_module

    calls: list[str] = []
    scandir = os.scandir

    def counted(path):  # unannotated: os.scandir's own signature
        calls.append(str(path))
        return scandir(path)

    monkeypatch.setattr(follow_module.os, "scandir", counted)
    return calls


def _set_folder_time(folder: Path, ns: int) -> None:
    os.utime(folder, ns=(ns, ns))


def test_an_idle_folder_is_not_listed_again_until_it_changes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A follower of a large folder waits cheaply: a folder whose time has not moved since a listing
    made well after it is not listed again; a new file moves it and is handed out."""
    listings = _listings(monkeypatch)
    for k in range(5):
        (tmp_path / f"f{k}.png").write_bytes(b"x")
    _set_folder_time(tmp_path, time.time_ns() - 60 * 10**9)  # the camera wrote a minute ago
    watch = FolderWatch(tmp_path)
    watch.poll()
    assert len(watch.poll()) == 5
    before = len(listings)
    for _ in range(10):
        assert watch.poll() == []
    assert len(listings) == before  # idle: no listing
    (tmp_path / "f5.png").write_bytes(b"x")
    watch.poll()
    assert [p.name for p in watch.poll()] == ["f5.png"]
    assert len(listings) > before


def test_a_file_added_within_the_folders_clock_tick_is_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A file added without moving the folder's time (the same tick of a coarse clock) is still
    found: at the next poll while the folder changed recently, after LISTING_SECONDS otherwise."""
    from wiloc.localization.follow import LISTING_SECONDS

    (tmp_path / "f0.png").write_bytes(b"x")
    recent = time.time_ns() - 10**8
    _set_folder_time(tmp_path, recent)
    watch = FolderWatch(tmp_path)
    watch.poll()
    assert [p.name for p in watch.poll()] == ["f0.png"]
    (tmp_path / "f1.png").write_bytes(b"x")
    _set_folder_time(tmp_path, recent)  # the same tick: the folder's time unchanged
    watch.poll()
    assert [p.name for p in watch.poll()] == ["f1.png"]

    now = [0.0]
    old = time.time_ns() - 60 * 10**9
    _set_folder_time(tmp_path, old)
    watch = FolderWatch(tmp_path, done=["f0.png", "f1.png"], clock=lambda: now[0])
    assert watch.poll() == []
    listings = _listings(monkeypatch)
    (tmp_path / "f2.png").write_bytes(b"x")
    _set_folder_time(tmp_path, old)  # a file system whose folder time lags
    now[0] = LISTING_SECONDS / 2
    assert watch.poll() == [] and listings == []
    now[0] = LISTING_SECONDS
    watch.poll()
    now[0] = LISTING_SECONDS + 0.2
    assert [p.name for p in watch.poll()] == ["f2.png"]
    assert len(listings) == 1


def test_two_followers_of_one_results_file_one_ends_busy(demo_route: demo.DemoRoute, tmp_path: Path,
                                                         cache_dir: Path) -> None:
    """Two runs started at once on the same --out: the second ends at once with exit 3 (busy), before
    deciding anything; the file holds each frame once."""
    frames = sorted(demo_route.queries[0].iterdir())[:6]
    live = _live_folder(tmp_path, frames)
    out = tmp_path / "r.csv"
    api.localize(live, reference=demo_route.reference, method="threshold", out=tmp_path / "warm.csv")  # the map described
    runs = [_follower(live, demo_route.reference, out, "threshold", idle=3) for _ in range(2)]
    ended = [run.communicate(timeout=120) for run in runs]
    codes = [run.returncode for run in runs]
    assert sorted(codes) == [0, 3], ended
    busy = ended[codes.index(3)]
    assert busy[0] == "" and busy[1].strip().splitlines() == [
        f"error: {out}: in use by another wiloc run (pid {runs[codes.index(0)].pid})"]
    assert _rows(out)["frame"].tolist() == [p.name for p in frames]
    assert not (tmp_path / ".r.csv.lock").exists()


def test_a_batch_run_leaves_a_followed_results_file_alone(demo_route: demo.DemoRoute, tmp_path: Path,
                                                          cache_dir: Path) -> None:
    """A batch run given the --out a follower appends to ends busy (exit 3) rather than replacing the
    file under it (the follower's later rows would go to the replaced file, lost); once the
    follower has ended, the batch run writes it."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    run = api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.0)
    try:
        batch = subprocess.run([sys.executable, "-c", CLI, "localize", str(live), "--map", str(demo_route.reference),
                                "--method", "threshold", "--out", str(out)], capture_output=True, text=True,
                               timeout=300, check=False)
    finally:
        run.release()
    assert (batch.returncode, batch.stderr.strip().splitlines()[-1:]) == (
        3, [f"error: {out}: in use by another wiloc run (pid {os.getpid()})"])
    assert not out.exists() or _rows(out).empty  # the follower's file, not the batch run's
    api.localize(live, reference=demo_route.reference, method="threshold", out=out)
    assert len(_rows(out)) == 4
    assert not (tmp_path / ".r.csv.lock").exists()


def _followed_to_the_end(frames: list[Path], live: Path, out: Path, method: str,
                         reference: Path | None = None) -> tuple[int, int]:
    """``frames`` copied into the followed folder ``live`` (those not there yet), then followed
    into ``out`` until idle: (frames resumed from the file, frames decided now)."""
    for path in frames:
        if not (live / path.name).exists():
            (live / path.name).write_bytes(path.read_bytes())
    run = api.follow_folder(live, reference=reference, method=method, out=out, idle=0.5, poll=0.05)
    return run.resumed, sum(1 for _ in run)


@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_a_followed_file_ends_with_what_the_run_learned_and_resumes(demo_route: demo.DemoRoute, method: str,
                                                                    tmp_path: Path, cache_dir: Path) -> None:
    """A followed run's header ends as the batch run's of the same frames: the learned model, the
    learned parameters (catgraph's learned_a) and the map's digest (it started with the prior's, and without the
    digest). Such a file resumes, and so does one an older version wrote (no digest, no model):
    the run goes on and ends with the batch header of all its frames."""
    from wiloc.evaluation.results_header import read_header

    frames = sorted(demo_route.queries[0].iterdir())
    live, out = tmp_path / "live", tmp_path / "follow.csv"
    live.mkdir()

    def follow_to_the_end(count: int) -> tuple[int, int]:
        return _followed_to_the_end(frames[:count], live, out, method, demo_route.reference)

    def assert_batch_header(count: int) -> None:
        batch = api.localize(live, reference=demo_route.reference, method=method, out=tmp_path / f"batch{count}.csv")
        (got, _), (expected, _) = read_header(out), read_header(batch.path)
        assert got.follow and got.frames is None and got.query_digest is None
        assert got.model == expected.model and (got.model is not None) == (method == "online")
        assert got.params == expected.params
        assert got.map_digest == expected.map_digest and got.map_digest
        pd.testing.assert_frame_equal(_rows(out), _rows(batch.path))

    assert follow_to_the_end(20) == (0, 20)
    assert_batch_header(20)
    assert follow_to_the_end(26) == (20, 6)  # a finished file resumed: its learned values are not settings
    assert_batch_header(26)
    lines = out.read_text().splitlines(keepends=True)
    out.write_text("".join(line for line in lines if not line.startswith(("# map_digest:", "# model:"))))
    assert follow_to_the_end(30) == (26, 4)  # an older version's file
    assert_batch_header(30)


@pytest.mark.parametrize("method", ["threshold", "catgraph"])
def test_a_finished_followed_run_without_a_map_resumes(demo_route: demo.DemoRoute, method: str, tmp_path: Path,
                                                       cache_dir: Path) -> None:
    """A followed run without a map (sequence mode) ends with every frame it saw as its reference
    frames, which it started without: rerunning the command resumes it (no "other settings"),
    and it ends as the batch run of all its frames."""
    frames = sorted(demo_route.queries[0].iterdir())
    live, out = tmp_path / "live", tmp_path / "follow.csv"
    live.mkdir()

    def follow_to_the_end(count: int) -> tuple[int, int]:
        return _followed_to_the_end(frames[:count], live, out, method)

    assert follow_to_the_end(80) == (0, 80)
    assert follow_to_the_end(80) == (80, 0)  # nothing new: resumed, nothing decided
    assert follow_to_the_end(86) == (80, 6)
    batch = api.localize(live, method=method, out=tmp_path / "batch.csv")
    pd.testing.assert_frame_equal(_rows(out), _rows(batch.path))


def test_frames_of_another_shape_than_the_maps_are_warned_of_once(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                  cache_dir: Path) -> None:
    """A camera whose frames are of another shape than the map's (a crop) is warned of once, by
    the Localizer (``doubts``) and by a followed folder (a warning after its first such frame), as
    a batch run warns of such a query; frames of the map's shape, other sizes too, are not."""
    import cv2

    frames = sorted(demo_route.queries[0].iterdir())
    loc = Localizer(demo_route.reference, method="threshold")
    image = cv2.imread(str(frames[0]))
    loc.observe(cv2.resize(image, None, fx=2, fy=2))  # another size, the same shape
    assert loc.frame_doubts == [] and loc.doubts == []
    height, width = image.shape[:2]
    for k in (1, 2):
        loc.observe(image[:, : width // 2])
    [line] = loc.frame_doubts
    assert line.startswith(f"observe: images of {width // 2} x {height} pixels against the map's {width} x {height}, "
                           "another shape") and loc.doubts == [line]
    live = tmp_path / "live"
    live.mkdir()
    for k, path in enumerate(frames[:3]):
        cv2.imwrite(str(live / path.name), cv2.imread(str(path))[:, : width // 2] if k else cv2.imread(str(path)))
    run = api.follow_folder(live, reference=demo_route.reference, method="threshold", out=tmp_path / "r.csv",
                            idle=0.5, poll=0.05)
    events = list(run)
    warnings = [e for e in events if isinstance(e, Skipped)]
    assert [e.kind for e in warnings] == ["warning"] and warnings[0].path.name == frames[1].name
    assert "another shape" in str(warnings[0]) and sum(not isinstance(e, Skipped) for e in events) == 3


def test_a_results_name_near_the_longest_is_written_and_a_longer_one_named(demo_route: demo.DemoRoute,
                                                                          tmp_path: Path, cache_dir: Path) -> None:
    """A results file named within 6 bytes of the 255 a file system takes is written, batch and
    followed (its lock file's name was too long); a longer name is refused naming the results file,
    not its lock file, and nothing is left beside it."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    runs = {"batch": lambda out: api.localize(live, reference=demo_route.reference, method="threshold", out=out),
            "followed": lambda out: list(api.follow_folder(live, reference=demo_route.reference, method="threshold",
                                                           out=out, idle=0.5))}
    for how, run in runs.items():
        out = tmp_path / ("r" * (251 - len(how)) + how + ".csv")
        run(out)
        assert _rows(out)["frame"].tolist() == sorted(p.name for p in live.iterdir()), how
        too_long = tmp_path / ("r" * 260 + ".csv")
        with pytest.raises(WilocError) as error:
            run(too_long)
        assert error.value.where == str(too_long) and "cannot write the results file: no file can have this name" \
            in error.value.problem, how
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_a_run_whose_decided_frame_is_gone_cannot_resume_and_says_why(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                       cache_dir: Path) -> None:
    """A folder trimmed as it fills (its oldest frames removed): resuming decides the file's frames
    again, and the error named the missing image alone, not the results file nor what to do."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3))
    gone = min(live.iterdir())
    gone.unlink()
    with pytest.raises(WilocError) as error:
        api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3)
    assert error.value.where == "out" and error.value.problem.startswith(f"{out}: cannot resume: its frame '{gone.name}'")
    assert "give another file to start anew" in error.value.problem
    assert not (tmp_path / ".r.csv.lock").exists() and len(_rows(out)) == 4


def test_a_resume_interrupted_while_it_replays_closes_the_results_file(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                       cache_dir: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C (or any error but the two a replay names) while a resumed run decides its file's frames
    again left the file's descriptor open; the lock is given back as well."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3))

    def interrupted(self: Localizer, frame: object, *args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    def open_on(path: Path) -> int:
        return sum(os.path.realpath(f"/proc/self/fd/{fd}") == str(path.resolve()) for fd in os.listdir("/proc/self/fd"))

    monkeypatch.setattr(Localizer, "observe", interrupted)
    with pytest.raises(KeyboardInterrupt):
        api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3)
    assert open_on(out) == 0
    assert not (tmp_path / ".r.csv.lock").exists() and len(_rows(out)) == 4


def test_a_frame_whose_name_starts_like_a_header_line_keeps_its_row(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                    cache_dir: Path) -> None:
    """The header rewritten as the run ends dropped every line starting with '# ', the row of a frame
    named '# 2.jpg' too; names with a comma, a quote or a line break keep theirs as well."""
    live = tmp_path / "live"
    live.mkdir()
    names = ["# 2.jpg", "a,b.jpg", 'q"uote.jpg', "line\nbreak.jpg"]
    for name, path in zip(names, sorted(demo_route.queries[0].iterdir())):
        (live / name).write_bytes(path.read_bytes())
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3))
    assert sorted(read_results(out).frames["frame"]) == sorted(names)


def test_idle_zero_decides_the_frames_there_then_ends(demo_route: demo.DemoRoute, tmp_path: Path,
                                                      cache_dir: Path) -> None:
    """--idle 0 ended at the first poll, which only notes each file's size: every frame was left
    out as still being written."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    events = list(api.follow_folder(live, reference=demo_route.reference, method="threshold",
                                    out=tmp_path / "r.csv", idle=0))
    assert [e.frame for e in events if not isinstance(e, Skipped)] == sorted(p.name for p in live.iterdir())
    assert [e for e in events if isinstance(e, Skipped)] == []


def test_a_followed_file_recording_the_parameters_given_resumes(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                cache_dir: Path) -> None:
    """Results headers record every descriptor parameter now; a followed file of an older wiloc
    recorded those given (and sad's crop) and is the same run's: it resumes, and a file whose
    parameters resolve otherwise is still refused."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3))
    text = out.read_text()
    line = '# descriptor_params: {"crop": "none", "patch": 8, "storage": "uint8"}\n'
    assert text.count(line) == 1
    out.write_text(text.replace(line, '# descriptor_params: {"crop": "none"}\n'))
    run = api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3)
    assert run.resumed == 4
    list(run)
    out.write_text(text.replace(line, '# descriptor_params: {"crop": "top-half"}\n'))
    with pytest.raises(WilocError, match="holds a run with other settings"):
        api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3)


def test_a_followed_file_of_a_version_without_a_later_method_parameter_resumes(
        demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    """A method parameter added since (online's ``confidence``, whose default is what earlier
    versions did) is missing from an older followed file's params: the file is the same run's and
    resumes. Given otherwise than its default, the rows decided again differ, and the file is
    refused for them."""
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="online", out=out, idle=0.3))
    text = out.read_text()
    assert text.count(', "confidence": "filter"') == 1
    out.write_text(text.replace(', "confidence": "filter"', ""))
    run = api.follow_folder(live, reference=demo_route.reference, method="online", out=out, idle=0.3)
    assert run.resumed == 4
    list(run)
    out.write_text(text.replace(', "confidence": "filter"', ""))
    with pytest.raises(WilocError, match="decided again differs from its row: the map, the frames or the settings "
                                         "changed"):
        list(api.follow_folder(live, reference=demo_route.reference, method="online", out=out, idle=0.3,
                               method_params={"confidence": "appendix"}))


WRITTEN = "frame, match, difference, confidence, stage, ranking"  # the columns a threshold run writes


@pytest.mark.parametrize("table, problem", [
    (lambda rows: rows[["frame", "match", "confidence", "difference", "stage", "ranking"]],
     f"its columns are in another order (frame, match, confidence, difference, stage, ranking) than this run "
     f"writes ({WRITTEN})"),
    (lambda rows: rows.iloc[:0][["frame", "match", "confidence", "difference", "stage", "ranking"]],
     f"its columns are in another order (frame, match, confidence, difference, stage, ranking) than this run "
     f"writes ({WRITTEN})"),
    (lambda rows: rows.drop(columns="ranking"),
     f"its columns (frame, match, difference, confidence, stage) are not those this run writes ({WRITTEN}): "
     "ranking missing"),
    (lambda rows: rows.assign(note="x")[["frame", "note", "match", "difference", "confidence", "stage"]],
     f"its columns (frame, note, match, difference, confidence, stage) are not those this run writes ({WRITTEN}): "
     "ranking missing, note extra"),
], ids=["reordered", "reordered-no-rows", "missing", "missing-and-extra"])
def test_a_followed_file_with_other_columns_is_refused_for_them_not_the_settings(
        demo_route: demo.DemoRoute, table: object, problem: str, tmp_path: Path, cache_dir: Path) -> None:
    """A followed file re-saved with its columns moved was refused as if the map, the frames or the
    settings had changed (a user then changes settings that were right), and one holding the column
    line alone was resumed, its new rows appended in the run's order under the file's. The refusal
    names the columns found and those the run writes; the file is left as it was."""
    from typer.testing import CliRunner

    from wiloc.cli import app
    live = _live_folder(tmp_path, sorted(demo_route.queries[0].iterdir())[:4])
    out = tmp_path / "r.csv"
    list(api.follow_folder(live, reference=demo_route.reference, method="threshold", out=out, idle=0.3))
    header = "".join(line for line in out.read_text().splitlines(keepends=True) if line.startswith("# "))
    out.write_text(header + table(_rows(out)).to_csv(index=False))
    edited = out.read_bytes()
    result = CliRunner().invoke(app, ["localize", str(live), "--map", str(demo_route.reference), "--method",
                                      "threshold", "--follow", "--idle", "0.3", "--out", str(out)])
    assert result.exit_code == 1 and result.stdout == ""
    assert result.stderr.splitlines() == [f"error: --out: {out}: cannot resume: {problem}; give another file to "
                                          "start anew"]
    assert out.read_bytes() == edited and not (tmp_path / ".r.csv.lock").exists()


@pytest.mark.parametrize(("given", "parameter"), [({"idle": float("nan")}, "idle"), ({"idle": -5.0}, "idle"),
                                                  ({"idle": "5"}, "idle"), ({"poll": -0.5}, "poll"),
                                                  ({"poll": float("nan")}, "poll"), ({"poll": 0.0}, "poll"),
                                                  ({"poll": float("inf")}, "poll")])
def test_idle_and_poll_are_checked_before_the_results_file_is_locked(given: dict, parameter: str,
                                                                      demo_route: demo.DemoRoute, tmp_path: Path) -> None:
    """idle=nan never ended (its lock file left behind), idle=-5 was taken, and a negative or NaN
    poll ended in time.sleep's ValueError: each a ParameterError naming it, before any work."""
    from wiloc.errors import ParameterError

    out = tmp_path / "r.csv"
    with pytest.raises(ParameterError) as err:
        api.follow_folder(demo_route.queries[0], reference=demo_route.reference, out=out, **given)
    assert err.value.parameter == parameter and "seconds" in err.value.problem
    assert list(tmp_path.iterdir()) == []

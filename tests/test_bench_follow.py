"""benchmarks/bench_follow.py: its frames/s, where the run on the empty folder, subtracted from the
full folder's, does the same fixed work and a rate that would come out negative, or one of a run
that left a frame of the folder without a row, is refused; its
latency, which counts every row a run wrote, those written as it ended too, and refuses a run that
left a fed frame without a row; and its command line, where bad options, missing data or a method
that cannot run end it with one error line and an exit code."""
from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from types import SimpleNamespace

import pytest
from helpers import BENCHMARKS, benchmark_module


@pytest.fixture()
def bench():
    with benchmark_module("bench_follow") as module:
        yield module


def write_results(out: Path, frames: Iterable[str]) -> None:
    """A stand-in run's followed results file, as wiloc reads it: a row (undecided) for each of ``frames``."""
    out.write_text('# wiloc-results: 1\n# method: catgraph\n# reference_frames: ["m.png"]\n# follow: True\n'
                   "frame,match,difference,confidence,stage\n" + "".join(f"{name},,,,\n" for name in frames),
                   encoding="utf-8")


def test_a_full_run_no_longer_than_the_empty_one_gives_no_rate(bench) -> None:
    # A run's timings: the empty folder's had described the map, the full folder's read it from the cache.
    with pytest.raises(bench.BrokenMeasure, match="no longer than the empty folder's"):
        bench.frames_per_second(3576, full=7.2, empty=9.47)
    with pytest.raises(bench.BrokenMeasure):
        bench.frames_per_second(3576, full=2.7, empty=2.7)
    assert bench.frames_per_second(3576, full=7.2, empty=2.7) == pytest.approx(3576 / (7.2 - 2.7))


def test_neither_timed_run_pays_for_describing_the_map(bench, tmp_path: Path, monkeypatch) -> None:
    """Stand-in runs on a stand-in clock: each costs a start-up, its idle wait, a time per frame, and
    describing the map when no run has described it before."""
    winter = tmp_path / "winter"
    winter.mkdir()
    for k in range(40):
        (winter / f"{k:05d}.png").write_bytes(b"")
    per_frame, clock, described = 0.25, SimpleNamespace(now=0.0), set()

    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        frames = sorted(folder.iterdir())
        clock.now += 1.5 + idle + per_frame * len(frames) + (30.0 if summer not in described else 0.0)
        described.add(summer)
        write_results(out, (p.name for p in frames))
        return SimpleNamespace(wait=lambda: 0)

    monkeypatch.setattr(bench, "follow", follow)
    monkeypatch.setattr(bench, "time", SimpleNamespace(perf_counter=lambda: clock.now))
    work = tmp_path / "work"
    work.mkdir()
    assert bench.throughput(winter, tmp_path / "summer", "catgraph", work) == pytest.approx(1 / per_frame)


def a_users_winter(folder: Path) -> list[str]:
    """A winter folder as a user's may be: frames whose natural order is not their text order, a
    text file and a subfolder beside them. Returns the frames' names, in natural order."""
    folder.mkdir()
    (folder / "a-notes.txt").write_text("taken in December\n", encoding="utf-8")
    (folder / "b-sub").mkdir()
    names = [f"images-{k}.png" for k in (9, 10, 11)]
    for name in names:
        (folder / name).write_bytes(b"")
    return names


def folder_run(skips: str = "") -> Callable[..., SimpleNamespace]:
    """A stand-in for `bench_follow.follow`: a run that decides every frame of its folder, but for
    the one named ``skips``, and ends well."""
    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        write_results(out, (p.name for p in sorted(folder.iterdir()) if p.name != skips))
        return SimpleNamespace(wait=lambda: 0)
    return follow


def test_the_full_folder_holds_the_frames_alone(bench, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    names = a_users_winter(tmp_path / "winter")
    monkeypatch.setattr(bench, "follow", folder_run())
    monkeypatch.setattr(bench, "frames_per_second", lambda *_: 1.0)
    bench.throughput(tmp_path / "winter", tmp_path / "summer", "catgraph", tmp_path)
    assert sorted(path.name for path in (tmp_path / "full-catgraph").iterdir()) == sorted(names)


def test_a_full_folder_run_that_leaves_a_frame_without_a_row_gives_no_rate(bench, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The run ends well (exit code 0) having decided 2 of the folder's 3 frames: a rate over its
    time would be one of a run that decided them all."""
    a_users_winter(tmp_path / "winter")
    monkeypatch.setattr(bench, "follow", folder_run(skips="images-10.png"))
    with pytest.raises(SystemExit) as ended:
        bench.throughput(tmp_path / "winter", tmp_path / "summer", "catgraph", tmp_path)
    assert ended.value.code == ("error: wiloc localize --follow --method catgraph decided 2 of the 3 frames in the "
                                "folder; the first without a row: images-10.png")


def test_the_feeder_feeds_the_frames_alone_in_their_order(bench, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A stand-in run that decides each file as soon as it is in its folder."""
    names = a_users_winter(tmp_path / "winter")

    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        def poll() -> None:
            write_results(out, (p.name for p in folder.iterdir() if not p.name.startswith(".")))
        poll()
        return SimpleNamespace(poll=poll, wait=lambda: 0)

    copied: list[str] = []
    copyfile = bench.shutil.copyfile
    monkeypatch.setattr(bench, "follow", follow)
    monkeypatch.setattr(bench.shutil, "copyfile", lambda source, target: (copied.append(Path(source).name),
                                                                          copyfile(source, target)))
    waits = bench.latency(tmp_path / "winter", tmp_path / "summer", "catgraph", tmp_path, rate=1000.0, frames=3)
    assert copied == names and len(waits) == 3


@pytest.mark.parametrize(("args", "code", "line"), [
    (["--frames", "0"], 2, "error: --frames must be at least 1, got 0"),
    (["--rate", "0"], 2, "error: --rate must exceed one frame per 3 s (the followed run stops after 3 s without "
                         "a new frame), got 0"),
    (["--rate", "0.25"], 2, "error: --rate must exceed one frame per 3 s (the followed run stops after 3 s without "
                            "a new frame), got 0.25"),
    (["--rate", "nan"], 2, "error: --rate must exceed one frame per 3 s (the followed run stops after 3 s without "
                           "a new frame), got nan"),
    (["--methods", "catgraph,nosuch"], 2, "error: --methods: unknown method 'nosuch' (choose from"),
    ([], 1, "nordland-summer-winter-64x32/winter: folder does not exist"),
])
def test_bad_options_and_missing_data_are_one_line(bench, args: list[str], code: int, line: str, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_follow.py", str(tmp_path / "no-data"), *args])
    monkeypatch.setattr(bench, "follow", lambda *_: pytest.fail("a run was started"))
    with pytest.raises(SystemExit) as ended:
        bench.main()
    captured = capsys.readouterr()
    assert ended.value.code == code and line in captured.err.strip().splitlines()[-1]
    assert "Traceback" not in captured.err and not captured.out


@pytest.mark.parametrize(("failing", "said"), [
    ("warm", "ended with exit code 3 describing the map; it said: exit status 3"),
    ("full", "ended with exit code 3 on the full folder; it said: exit status 3"),
])
def test_a_run_that_fails_ends_the_benchmark_with_its_exit_code(bench, failing: str, said: str, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The first run fails where the method cannot run on this map; a timed run that fails gives no rate."""
    (tmp_path / "winter").mkdir()
    (tmp_path / "winter" / "images-00000.png").write_bytes(b"")
    monkeypatch.setattr(bench, "follow", lambda folder, summer, out, method, idle: SimpleNamespace(
        wait=lambda: 3 if out.name.startswith(failing) else 0))
    with pytest.raises(SystemExit) as ended:
        bench.throughput(tmp_path / "winter", tmp_path / "summer", "fabmap", tmp_path)
    assert ended.value.code == f"error: wiloc localize --follow --method fabmap {said}"


def test_a_run_that_fails_before_its_results_file_ends_the_benchmark_with_its_error(tmp_path: Path) -> None:
    """A real followed run that refuses its options (threshold's --normaliser below 0) ends before it
    writes its results file, which the latency run waits for: the benchmark ends with its error
    line rather than waiting on (the timeout only stops a benchmark that would wait for ever)."""
    for folder in ("winter", "summer"):
        (tmp_path / folder).mkdir()
    refusing = ("import sys; from wiloc.cli import app; "
                "sys.exit(app(args=sys.argv[1:] + ['--normaliser', '-1'], prog_name='wiloc'))")
    driver = (f"import sys; sys.path.insert(0, {str(BENCHMARKS)!r}); from pathlib import Path; import bench_follow; "
              f"bench_follow.CLI = {refusing!r}; root = Path({str(tmp_path)!r}); "
              "bench_follow.latency(root / 'winter', root / 'summer', 'threshold', root, rate=20.0, frames=2)")
    done = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, timeout=120, check=False)
    assert (done.returncode, done.stderr.strip().splitlines()) == (1, [
        "error: wiloc localize --follow --method threshold ended with exit code 2 before writing its results "
        "file; it said: error: --normaliser: must be > 0, got -1.0"])


def test_a_feed_that_fails_ends_the_benchmark_and_its_run(bench, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The feeder cannot write the second frame: the run, which would follow the folder on, is
    stopped, and the benchmark ends with the feeder's error."""
    winter = tmp_path / "winter"
    winter.mkdir()
    for k in range(3):
        (winter / f"images-{k:05d}.png").write_bytes(b"")
    run = SimpleNamespace(polls=0, stopped=False)

    def poll() -> int | None:
        run.polls += 1  # a run following on, which a stand-in cannot do for ever
        return 0 if run.stopped or run.polls > 5000 else None

    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        write_results(out, [])
        return SimpleNamespace(poll=poll, wait=poll, terminate=lambda: setattr(run, "stopped", True))

    copied: list[Path] = []

    def copyfile(source: Path, target: Path) -> None:
        if copied:
            raise OSError(28, "No space left on device")
        copied.append(source)
        target.write_bytes(b"")

    monkeypatch.setattr(bench, "follow", follow)
    monkeypatch.setattr(bench.shutil, "copyfile", copyfile)
    with pytest.raises(SystemExit) as ended:
        bench.latency(winter, tmp_path / "summer", "catgraph", tmp_path, rate=1000.0, frames=3)
    assert ended.value.code == (f"error: feeding {winter}/images-00001.png to wiloc localize --follow --method "
                                "catgraph: [Errno 28] No space left on device")
    assert run.stopped


@pytest.mark.parametrize(("code", "said"), [
    (0, "decided none of the 2 frames fed before 3 s without a new frame ended it"),
    (3, "ended with exit code 3 after deciding 0 of the 2 frames fed; it said: exit status 3"),
])
def test_a_run_that_decides_no_frame_fed_is_one_error_line(bench, code: int, said: str, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The latency run's process ends (idle, or failing) before any row: no latency to take a median of."""
    for season in ("winter", "summer"):
        folder = tmp_path / "nordland-summer-winter-64x32" / season
        folder.mkdir(parents=True)
        for k in range(2):
            (folder / f"images-{k:05d}.png").write_bytes(b"")

    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        write_results(out, [])  # started, then ended without a row

        def poll() -> int | None:  # ended once both frames are in; its error output: none
            return code if len([p for p in folder.iterdir() if not p.name.startswith(".")]) == 2 else None
        return SimpleNamespace(poll=poll, wait=poll)

    monkeypatch.setattr(sys, "argv", ["bench_follow.py", str(tmp_path), "--methods", "threshold", "--frames", "2"])
    monkeypatch.setattr(bench, "throughput", lambda *_: 100.0)
    monkeypatch.setattr(bench, "follow", follow)
    with pytest.raises(SystemExit) as ended:
        bench.main()
    assert ended.value.code == f"error: wiloc localize --follow --method threshold {said}"


def traversal_of(folder: Path, count: int) -> list[str]:
    """A traversal's folder of ``count`` (empty) frames; their names, in order."""
    folder.mkdir(parents=True)
    names = [f"images-{k:05d}.png" for k in range(count)]
    for name in names:
        (folder / name).write_bytes(b"")
    return names


def ending_run(decides: int) -> Callable[..., SimpleNamespace]:
    """A stand-in for `bench_follow.follow`: a run that writes its results file at once, then, as
    it ends (once the feeder has put 3 frames in its folder), a row for the first ``decides`` of
    them: rows no poll of the run's results file can see while it runs."""
    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        write_results(out, [])

        def poll() -> int | None:
            fed = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
            if len(fed) < 3:
                return None
            write_results(out, fed[:decides])
            return 0
        return SimpleNamespace(poll=poll, wait=lambda: 0)
    return follow


def test_rows_written_as_the_run_ends_are_counted(bench, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    traversal_of(tmp_path / "winter", 3)
    monkeypatch.setattr(bench, "follow", ending_run(decides=3))
    waits = bench.latency(tmp_path / "winter", tmp_path / "summer", "catgraph", tmp_path, rate=1000.0, frames=3)
    assert len(waits) == 3 and min(waits) >= 0


def deciding_run(skips: str) -> Callable[..., SimpleNamespace]:
    """A stand-in for `bench_follow.follow`: a run that writes each frame's row as soon as the frame
    is in its folder, but for the frame named ``skips``, and ends once the feeder has put 3 in."""
    def follow(folder: Path, summer: Path, out: Path, method: str, idle: float) -> SimpleNamespace:
        def poll() -> int | None:
            fed = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
            write_results(out, [name for name in fed if name != skips])
            return 0 if len(fed) == 3 else None
        poll()
        return SimpleNamespace(poll=poll, wait=lambda: 0)
    return follow


@pytest.mark.parametrize("run", [ending_run(decides=2), deciding_run(skips="images-00002.png")],
                         ids=["rows as it ends", "rows while it runs"])
def test_a_run_that_leaves_a_fed_frame_without_a_row_is_one_error_line(bench, run: Callable[..., SimpleNamespace],
                                                                       tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The run ends well (exit code 0) having decided 2 of the 3 frames fed: their latencies alone
    are no measure of the run's."""
    for season in ("winter", "summer"):
        traversal_of(tmp_path / "nordland-summer-winter-64x32" / season, 3)
    monkeypatch.setattr(sys, "argv", ["bench_follow.py", str(tmp_path), "--methods", "threshold", "--frames", "3"])
    monkeypatch.setattr(bench, "throughput", lambda *_: 100.0)
    monkeypatch.setattr(bench, "follow", run)
    with pytest.raises(SystemExit) as ended:
        bench.main()
    assert ended.value.code == ("error: wiloc localize --follow --method threshold decided 2 of the 3 frames fed; "
                                "the first without a row: images-00002.png")

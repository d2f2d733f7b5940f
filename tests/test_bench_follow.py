"""benchmarks/bench_follow.py: its frames/s, where the run on the empty folder, subtracted from the
full folder's, does the same fixed work and a rate that would come out negative is refused; and
its command line, where bad options, missing data or a method that cannot run end it with one
error line and an exit code."""
from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from helpers import benchmark_module


@pytest.fixture()
def bench():
    with benchmark_module("bench_follow") as module:
        yield module


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
        out.write_text("# wiloc results\nframe,node\n" + "".join(f"{p.name},0\n" for p in frames), encoding="utf-8")
        return SimpleNamespace(wait=lambda: 0)

    monkeypatch.setattr(bench, "follow", follow)
    monkeypatch.setattr(bench, "time", SimpleNamespace(perf_counter=lambda: clock.now))
    work = tmp_path / "work"
    work.mkdir()
    assert bench.throughput(winter, tmp_path / "summer", "catgraph", work) == pytest.approx(1 / per_frame)


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


def test_a_method_that_cannot_run_ends_the_benchmark_with_its_exit_code(bench, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "winter").mkdir()
    monkeypatch.setattr(bench, "follow", lambda *_: SimpleNamespace(wait=lambda: 3))
    with pytest.raises(SystemExit, match="--method fabmap ended with exit code 3"):
        bench.throughput(tmp_path / "winter", tmp_path / "summer", "fabmap", tmp_path)


@pytest.mark.parametrize(("code", "said"), [
    (0, "decided none of the 2 frames fed before 3 s without a new frame ended it"),
    (3, "decided none of the 2 frames fed and ended with exit code 3"),
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
        out.write_text("# wiloc results\nframe,node\n", encoding="utf-8")  # started, then ended without a row
        return SimpleNamespace(poll=lambda: code, wait=lambda: code)

    monkeypatch.setattr(sys, "argv", ["bench_follow.py", str(tmp_path), "--methods", "threshold", "--frames", "2"])
    monkeypatch.setattr(bench, "throughput", lambda *_: 100.0)
    monkeypatch.setattr(bench, "follow", follow)
    with pytest.raises(SystemExit) as ended:
        bench.main()
    assert ended.value.code == f"error: wiloc localize --follow --method threshold {said}"

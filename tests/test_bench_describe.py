"""benchmarks/bench_describe.py's command line: missing data or a --repeat below 1 end it with
one error line and an exit code before anything is decoded or described, never a traceback."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "code", "line"), [
    ([], 1, "gardens-point-walking/day_left: folder does not exist"),
    (["--repeat", "0"], 2, "error: --repeat must be at least 1, got 0"),
])
def test_bad_options_and_missing_data_are_one_line(args: list[str], code: int, line: str, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_describe.py", str(tmp_path / "no-data"), *args])
    with benchmark_module("bench_describe") as bench, pytest.raises(SystemExit) as ended:
        bench.main()
    captured = capsys.readouterr()
    assert ended.value.code == code and line in captured.err.strip().splitlines()[-1]
    assert "Traceback" not in captured.err and not captured.out


def test_the_describe_benchmarks_list_the_same_gardens_point_frames(tmp_path: Path) -> None:
    """bench_scale's describe table times the frames bench_describe lists, by its listing."""
    expected = []
    for traversal in ("day_left", "day_right", "night_right"):
        folder = tmp_path / "gardens-point-walking" / traversal
        folder.mkdir(parents=True)
        for k in (10, 9):  # listed in natural order: Image9 before Image10
            (folder / f"Image{k}.jpg").touch()
        (folder / "notes.txt").touch()
        expected += [folder / "Image9.jpg", folder / "Image10.jpg"]
    with benchmark_module("bench_describe") as describe, benchmark_module("bench_scale") as scale:
        assert describe.gardens_point_frames(tmp_path) == expected
        assert scale.gardens_point_frames is describe.gardens_point_frames

"""benchmarks/bench_scale.py: the folders it fills the cache for are found described, so that a
small size runs end to end."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from helpers import benchmark_module

from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folders


@pytest.fixture(scope="module")
def bench():
    with benchmark_module("bench_scale") as module:
        yield module


def test_seeded_folders_are_reused_from_the_cache(bench, tmp_path: Path) -> None:
    bench.make_case(tmp_path, 50)
    folders = [tmp_path / name for name in ("map", "query", "train")]
    reports = describe_folders(folders, bench.SPEC, Cache(tmp_path / "cache"), jobs=1)
    # the placeholder images are empty files: any frame described afresh would fail to load
    assert [(r.computed, r.failed, r.reused) for r in reports] == [(0, [], r.frames) for r in reports]
    assert [r.frames for r in reports] == [50, 50, 25]


def test_a_small_size_runs_end_to_end(bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--sizes", "50", "--repeat", "1", "--methods", "threshold", "--work", str(tmp_path)])
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert [row[:2] for row in rows if row and row[0] == "50"] == [["50", "threshold"]]
    assert not any(tmp_path.iterdir())  # its scratch folder removed


@pytest.mark.parametrize(("args", "line"), [
    (["--work", "{tmp}/missing"], "error: --work {tmp}/missing: folder does not exist"),
    (["--work", "{tmp}/file"], "error: --work {tmp}/file: not a folder"),
    (["--repeat", "0"], "error: --repeat must be at least 1, got 0"),
    (["--sizes", "50,-5"], "error: --sizes must be at least 0, got -5"),
    (["--sizes", "50,many"], "error: --sizes must be whole numbers, comma-separated, got '50,many'"),
    (["--methods", "online,nosuch"], "error: --methods: unknown method 'nosuch' (choose from online, threshold, "
                                     "trained, catgraph)"),
    (["--describe", "--descriptors", "sad,nosuch"], "error: --descriptors: unknown descriptor 'nosuch'"),
])
def test_a_bad_option_is_one_error_line(bench, args: list[str], line: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").touch()
    with pytest.raises(SystemExit) as ended:
        bench.main(["--sizes", "50", *(arg.format(tmp=tmp_path) for arg in args)])
    out, err = capsys.readouterr()
    assert ended.value.code == 2 and out == "" and "Traceback" not in err
    assert line.format(tmp=tmp_path) in err.strip().splitlines()[-1]
    assert sorted(path.name for path in tmp_path.iterdir()) == ["file"]  # nothing made


def test_missing_data_for_the_describe_table_is_one_error_line_before_any_run(
        bench, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ended:
        bench.main(["--sizes", "50", "--describe", "--data", str(tmp_path / "no-data"), "--work", str(tmp_path)])
    out, err = capsys.readouterr()
    assert ended.value.code == 1 and out == "" and "Traceback" not in err
    assert err.strip().splitlines() == [f"error: {tmp_path}/no-data/gardens-point-walking/day_left: folder does not exist"]
    assert not any(tmp_path.iterdir())  # no size was run


@pytest.mark.realdata
def test_the_describe_table_runs_on_gardens_point(bench, data_root: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--sizes", "0", "--describe", "--repeat", "1", "--descriptors", "sad", "--data", str(data_root)])
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert [row[:2] for row in rows if row and row[0] == "sad"] == [["sad", "1"], ["sad", "2"]]
    assert ["cv2.imread", "full", "size"] in [row[:3] for row in rows]


def test_a_failed_child_run_ends_the_benchmark_with_its_error(bench, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as ended:
        bench.run_child("--child", "localize", "--root", str(tmp_path), "--method", "threshold")
    assert ended.value.code == (f"error: --child localize --root {tmp_path} --method threshold: "
                                f"wiloc.errors.WilocError: {tmp_path}/query: folder does not exist")


def test_the_describe_table_shows_each_label_whole_and_its_figures_under_their_headers(
        bench, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench, "plain_decode_rate", lambda frames: 306.3)
    monkeypatch.setattr(bench, "run_child", lambda *argv: {"rate": 744.4 if argv[-1] == "1" else 765.8})
    header, *lines = bench.describe_rows(tmp_path, [], 1, ["sad", "brisk-gist"], None)
    labels = ["cv2.imread full size", "sad", "sad", "brisk-gist", "brisk-gist"]
    assert [line[:len(label) + 1] for line, label in zip(lines, labels)] == [f"{label} " for label in labels]
    assert len(lines) == len(labels)
    for column in ("images/s", "/decode"):  # right-aligned: each figure ends where its header does
        end = header.index(column) + len(column)
        assert all(re.fullmatch(r"\d+\.\d+", line[:end].split()[-1]) and line[end] == " " for line in lines), lines

"""benchmarks/bench_scale.py: the folders it fills the cache for are found described, so that a
small size runs end to end."""
from __future__ import annotations

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


@pytest.mark.parametrize(("work", "problem"), [("missing", "folder does not exist"), ("file", "not a folder")])
def test_a_work_folder_that_is_none_is_one_error_line(bench, work: str, problem: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").touch()
    with pytest.raises(SystemExit) as ended:
        bench.main(["--sizes", "50", "--work", str(tmp_path / work)])
    out, err = capsys.readouterr()
    assert ended.value.code == 2 and out == "" and "Traceback" not in err
    assert err.strip().splitlines()[-1].endswith(f"error: --work {tmp_path / work}: {problem}")


@pytest.mark.realdata
def test_the_describe_table_runs_on_gardens_point(bench, data_root: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--sizes", "0", "--describe", "--repeat", "1", "--descriptors", "sad", "--data", str(data_root)])
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert [row[:2] for row in rows if row and row[0] == "sad"] == [["sad", "1"], ["sad", "2"]]
    assert ["cv2.imread", "full", "size"] in [row[:3] for row in rows]

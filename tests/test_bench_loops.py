"""benchmarks/bench_loops.py's command line: a bad option or missing data ends it with one error
line and an exit code before any loop is described, never a traceback."""
from __future__ import annotations

from pathlib import Path

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "code", "line"), [
    (["--descriptors", "sad,nosuch"], 2, "error: --descriptors: unknown descriptor 'nosuch'"),
    (["--param", "online.nosuch=1"], 2, "error: --param online.nosuch: not a parameter of method 'online'"),
    (["--param", "online.init=0"], 2, "error: --param online.init: must be >= 1, got 0"),
    (["--odometry", "-0.1"], 2, "error: --odometry -0.1: give a noise of 0 (exact) or more"),
    ([], 1, "gardens-point-walking/day_right: folder does not exist"),
    (["--methods", "online,bogus"], 2, "error: --methods: unknown method 'bogus' (choose from "),
    (["--json", "{tmp}/missing/rows.json"], 2,
     "error: --json {tmp}/missing/rows.json: folder {tmp}/missing does not exist"),
    (["--json", "{tmp}/file/rows.json"], 2, "error: --json {tmp}/file/rows.json: {tmp}/file is not a folder"),
])
def test_bad_options_and_missing_data_are_one_line(args: list[str], code: int, line: str, tmp_path: Path,
                                                   cache_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").touch()
    with benchmark_module("bench_loops") as bench, pytest.raises(SystemExit) as ended:
        bench.main([str(tmp_path / "no-data"), "--loops", "dr+dl", "--methods", "online",
                    *(arg.format(tmp=tmp_path) for arg in args)])
    stderr = capsys.readouterr().err
    assert ended.value.code == code and line.format(tmp=tmp_path) in stderr.strip().splitlines()[-1]
    assert "Traceback" not in stderr
    assert not cache_dir.exists()  # nothing described

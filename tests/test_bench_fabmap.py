"""benchmarks/bench_fabmap.py's command line: a data folder without Gardens Point ends it with one
error line naming the missing folder, exit 1, before any vocabulary is built."""
from __future__ import annotations

from pathlib import Path

import pytest
from helpers import benchmark_module


def test_missing_data_is_one_error_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    with benchmark_module("bench_fabmap") as bench:
        monkeypatch.setattr(bench, "build_vocabulary", lambda *_: pytest.fail("a vocabulary was built"))
        with pytest.raises(SystemExit) as ended:
            bench.main([str(tmp_path / "no-data")])
    out, err = capsys.readouterr()
    assert ended.value.code == 1 and not out and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith(f"error: {tmp_path}/no-data/gardens-point-walking/")
    assert err.strip().endswith("folder does not exist")

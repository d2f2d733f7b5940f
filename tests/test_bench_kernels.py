"""benchmarks/bench_kernels.py's command line: a count of frames or rows below 1 ends it with one
error line naming the option, exit 2, before any frame is made."""
from __future__ import annotations

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "line"), [
    (["--n", "0"], "error: --n must be at least 1, got 0"),
    (["--n", "-5"], "error: --n must be at least 1, got -5"),
    (["--baseline-rows", "0"], "error: --baseline-rows must be at least 1, got 0"),
    (["--block-rows", "0"], "error: --block-rows must be at least 1, got 0"),
])
def test_a_count_below_one_is_one_error_line(args: list[str], line: str, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    with benchmark_module("bench_kernels") as bench:
        monkeypatch.setattr(bench, "make_frames", lambda *_: pytest.fail("frames were made"))
        with pytest.raises(SystemExit) as ended:
            bench.main(args)
    out, err = capsys.readouterr()
    assert ended.value.code == 2 and line in err.strip().splitlines()[-1]
    assert "Traceback" not in err and not out

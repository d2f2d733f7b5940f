"""benchmarks/bench_step.py's command line: too few frames to leave any timed after the warm-up
end it with one error line naming --frames and the least it takes, exit 2, before any map is made."""
from __future__ import annotations

import sys

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "line"), [
    (["--frames", "20"], "error: --frames must be at least --warmup + 2 = 22 (the first 20 are not timed), got 20"),
    (["--frames", "6", "--warmup", "5"], "error: --frames must be at least --warmup + 2 = 7"),
    (["--warmup", "-1"], "error: --warmup must be at least 0, got -1"),
])
def test_too_few_frames_are_one_error_line(args: list[str], line: str, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_step.py", "--sizes", "1000", *args])
    with benchmark_module("bench_step") as bench:
        monkeypatch.setattr(bench, "rows_and_context", lambda *_: pytest.fail("a map was made"))
        with pytest.raises(SystemExit) as ended:
            bench.main()
    captured = capsys.readouterr()
    assert ended.value.code == 2 and line in captured.err.strip().splitlines()[-1]
    assert "Traceback" not in captured.err and not captured.out

"""benchmarks/bench_step.py's command line: too few frames to leave any timed after the warm-up,
more than the query can follow on the smallest map, a size that is no whole number of 1 or more, or
a method (to run or to profile) not known end it with one error line naming the option, exit 2,
before any map is made."""
from __future__ import annotations

import sys

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "line"), [
    (["--frames", "20"], "error: --frames must be at least --warmup + 2 = 22 (the first 20 are not timed), got 20"),
    (["--frames", "6", "--warmup", "5"], "error: --frames must be at least --warmup + 2 = 7"),
    (["--warmup", "-1"], "error: --warmup must be at least 0, got -1"),
    (["--frames", "901"],
     "error: --frames must be at most 900 for a map of 1000 frames (the query starts at its 10 % mark), got 901"),
    (["--sizes", "1000,2000", "--frames", "950"], "error: --frames must be at most 900 for a map of 1000 frames"),
    (["--sizes", "1000,10k"], "error: --sizes must be whole numbers, comma-separated, got '1000,10k'"),
    (["--sizes", "1000,-5"], "error: --sizes must be at least 1, got -5"),
    (["--methods", "onlne"], "error: --methods: unknown method 'onlne' (choose from "),
    (["--profile", "bogus"], "error: --profile: unknown method 'bogus' (choose from catgraph, online)"),
])
def test_bad_options_are_one_error_line(args: list[str], line: str, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_step.py", "--sizes", "1000", *args])
    with benchmark_module("bench_step") as bench:
        monkeypatch.setattr(bench, "rows_and_context", lambda *_: pytest.fail("a map was made"))
        with pytest.raises(SystemExit) as ended:
            bench.main()
    captured = capsys.readouterr()
    assert ended.value.code == 2 and line in captured.err.strip().splitlines()[-1]
    assert "Traceback" not in captured.err and not captured.out

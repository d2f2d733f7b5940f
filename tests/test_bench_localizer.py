"""benchmarks/bench_localizer.py's command line: an unknown method, a size or a frame count that is
no whole number of 1 or more end it with one error line naming the option, exit 2, before any map
is made."""
from __future__ import annotations

import pytest
from helpers import benchmark_module


@pytest.mark.parametrize(("args", "line"), [
    (["--methods", "onlne"], "error: --methods: unknown method 'onlne' (choose from "),
    (["--sizes", "1k"], "error: --sizes must be whole numbers, comma-separated, got '1k'"),
    (["--sizes", "1000,-5"], "error: --sizes must be at least 1, got -5"),
    (["--frames", "0"], "error: --frames must be at least 1, got 0"),
])
def test_a_bad_option_is_one_error_line(args: list[str], line: str, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    with benchmark_module("bench_localizer") as bench:
        monkeypatch.setattr(bench, "measure", lambda *_: pytest.fail("a map was made"))
        with pytest.raises(SystemExit) as ended:
            bench.main(["--sizes", "1000", "--frames", "5", *args])
    out, err = capsys.readouterr()
    assert ended.value.code == 2 and line in err.strip().splitlines()[-1]
    assert "Traceback" not in err and not out


def test_a_table_printed_to_a_pipe_shows_its_labels_whole(monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    figures = dict.fromkeys(("startup_s", "excluded_wall", "excluded_cpu", "included_wall", "included_cpu",
                             "batch_wall", "batch_cpu", "sequence_wall", "sequence_cpu"), 1.0)
    with benchmark_module("bench_localizer") as bench:
        monkeypatch.setattr(bench, "measure", lambda *_: figures)
        bench.main(["--sizes", "1000", "--frames", "5", "--methods", "threshold"])
    assert "descriptor excluded" in capsys.readouterr().out

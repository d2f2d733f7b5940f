"""The benchmark scripts' ``--help``: each shows its docstring's whole first paragraph, the summary
of what it measures, never a line of it cut mid-sentence."""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import BENCHMARKS

SCRIPTS = sorted(path for path in BENCHMARKS.glob("*.py") if 'if __name__ == "__main__":' in path.read_text())


def test_every_benchmark_script_is_checked() -> None:
    assert {path.stem for path in SCRIPTS} >= {"bench_describe", "bench_follow", "bench_step", "bench_pace"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: path.stem)
def test_help_shows_the_whole_summary(script: Path) -> None:
    summary = (ast.get_docstring(ast.parse(script.read_text()), clean=False) or "").split("\n\n")[0]
    shown = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, check=True,
                           cwd=BENCHMARKS, env={**os.environ, "COLUMNS": "1000"}).stdout
    assert summary and " ".join(summary.split()) in " ".join(shown.split())

"""The rich consoles of the example and benchmark scripts print text as given, as wiloc's own do:
a path holding ':name:' (a folder ``a:smile:b``) is printed as typed, not with an emoji."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import benchmark_module

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = sorted([*REPO.glob("benchmarks/*.py"), *REPO.glob("examples/*.py")])


def test_an_examples_error_line_names_a_folder_as_typed(tmp_path: Path) -> None:
    data = tmp_path / "a:smile:b"
    data.mkdir()
    done = subprocess.run([sys.executable, str(REPO / "examples" / "gardens_point.py"), str(data),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True, cwd=tmp_path, check=False)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.splitlines() == [f"error: {data}/gardens-point-walking/day_right: dataset folder not found "
                                        "(pass the data folder or set WILOC_DATA)"]


def test_a_benchmarks_console_prints_a_file_name_as_typed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "a:smile:b.json"
    with benchmark_module("bench_common") as common:
        common.write_json(path, [{"method": "online"}], common.plain_console(width=1000))
    assert capsys.readouterr().out == f"wrote {path}\n"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: f"{path.parent.name}/{path.name}")
def test_no_script_makes_a_console_of_its_own(script: Path) -> None:
    """The benchmarks make theirs with bench_common.plain_console, the examples print with wiloc's."""
    made = [node.lineno for node in ast.walk(ast.parse(script.read_text(encoding="utf-8")))
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "Console"]
    assert len(made) == (script.name == "bench_common.py"), f"{script.name}: Console( on lines {made}"

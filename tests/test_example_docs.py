"""The example scripts' docstrings: ``--help`` shows each one's first line as its description.

Each script passes ``__doc__.splitlines()[0]`` to argparse, so that line must be the whole
summary: a first paragraph wrapped onto a second line shows in ``--help`` cut mid-sentence.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(path for path in EXAMPLES.glob("*.py") if "__doc__.splitlines()[0]" in path.read_text())


def test_every_script_with_a_help_text_is_checked() -> None:
    assert {path.stem for path in SCRIPTS} >= {"gardens_point", "nordland", "table1", "loop_closure", "live"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: path.stem)
def test_docstring_summary_is_one_line(script: Path) -> None:
    docstring = ast.get_docstring(ast.parse(script.read_text()), clean=False) or ""
    lines = docstring.splitlines()
    assert len(lines) >= 2 and lines[1] == "", (
        f"{script.name}: the docstring's first paragraph runs onto a second line ({lines[1]!r}), "
        "so --help shows its first line cut short")


def test_help_shows_the_whole_summary() -> None:
    script = EXAMPLES / "table1.py"
    shown = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, check=True,
                           cwd=EXAMPLES).stdout
    summary = ast.get_docstring(ast.parse(script.read_text()), clean=False).splitlines()[0]
    assert " ".join(summary.split()) in " ".join(shown.split())
    assert summary.rstrip().endswith(".")

"""The example scripts on the real datasets, and the numbers docs/results.md quotes from them.

Each example runs once (descriptor ``sad``, the scripts' default, which is what docs/results.md
checks) in a subprocess with a private cache; the markdown tables that
``examples/protocol.render_markdown`` makes from its ``summary.json`` must equal the example's
block in docs/results.md and appear in what the script printed.
"""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = ("gardens_point", "nordland")
METHODS = ("online", "threshold", "trained", "catgraph")
QUERIES = {"gardens_point": {"day_left", "night_right"}, "nordland": {"winter"}}

pytestmark = pytest.mark.realdata


def _protocol() -> ModuleType:
    spec = importlib.util.spec_from_file_location("protocol", REPO / "examples" / "protocol.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def runs(data_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[dict, str]]:
    """Each example's summary.json and printed output (one cache shared by both runs)."""
    tmp = tmp_path_factory.mktemp("examples")
    env = {**os.environ, "WILOC_CACHE": str(tmp / "cache"), "COLUMNS": "200"}
    done = {}
    for name in EXAMPLES:
        out = tmp / name
        proc = subprocess.run([sys.executable, str(REPO / "examples" / f"{name}.py"), str(data_root),
                               "--out", str(out)], capture_output=True, text=True, env=env, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        done[name] = (json.loads((out / "summary.json").read_text(encoding="utf-8")), proc.stdout)
    return done


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_covers_every_method_and_query(runs: dict[str, tuple[dict, str]], name: str) -> None:
    summary, stdout = runs[name]
    pairs = {(row["method"], row["traversal"]) for row in summary["table1"]}
    assert pairs == {(m, q) for m in METHODS for q in QUERIES[name]}
    for row in summary["table1"]:
        assert 0.0 <= row["recall_at_100"] <= row["recall_at_99"] <= row["recall_at_90"] <= 1.0
    worst = [row for row in summary["table2"] if row["worst"]]
    assert len(worst) == 2 * len(METHODS)  # one per method and target precision (100, 99)
    assert f"trained: {summary['trained_on']}" in stdout
    assert "summary.json" in stdout


@pytest.mark.parametrize("name", EXAMPLES)
def test_results_doc_quotes_the_examples(runs: dict[str, tuple[dict, str]], name: str) -> None:
    summary, stdout = runs[name]
    protocol = _protocol()
    tables = protocol.render_markdown(summary)
    assert tables in stdout
    quoted = protocol.block_in((REPO / "docs" / "results.md").read_text(encoding="utf-8"), name)
    assert quoted == tables, f"docs/results.md is out of date: run examples/{name}.py --update-docs"


@pytest.fixture(scope="module")
def table1(data_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, str]:
    """examples/table1.py's summary.json and printed output, on a private cache."""
    tmp = tmp_path_factory.mktemp("table1")
    env = {**os.environ, "WILOC_CACHE": str(tmp / "cache"), "COLUMNS": "200"}
    proc = subprocess.run([sys.executable, str(REPO / "examples" / "table1.py"), str(data_root), "--out",
                           str(tmp / "out")], capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads((tmp / "out" / "summary.json").read_text(encoding="utf-8")), proc.stdout


def test_table1_trains_vocabularies_on_the_other_query_and_the_doc_quotes_it(table1: tuple[dict, str]) -> None:
    summary, stdout = table1
    assert {q: v["trained_on"] for q, v in summary["vocabularies"].items()} == \
        {"day_left": "night_right", "night_right": "day_left"}
    assert len(summary["table"]) == 10 and all(row["ms_per_frame"] > 0 for row in summary["table"])
    spec = importlib.util.spec_from_file_location("table1", REPO / "examples" / "table1.py")
    assert spec is not None and spec.loader is not None
    sys.path.insert(0, str(REPO / "examples"))
    try:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(REPO / "examples"))
    tables = module.render(summary)
    assert tables in stdout
    quoted = _protocol().block_in((REPO / "docs" / "results.md").read_text(encoding="utf-8"), "table1")
    assert quoted == tables, "docs/results.md is out of date: run examples/table1.py --update-docs"

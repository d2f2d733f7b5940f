"""benchmarks/bench_common.py: the --json file is written whole or not at all, so that a run killed
while writing never leaves a truncated file that looks complete."""
from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from helpers import benchmark_module
from rich.console import Console


def test_json_is_replaced_whole_or_left_as_it_was(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "rows.json"
    out.write_text("[1]\n")
    with benchmark_module("bench_common") as common:
        def killed(*_: object) -> None:
            raise KeyboardInterrupt

        monkeypatch.setattr(common.os, "replace", killed)
        with pytest.raises(KeyboardInterrupt):
            common.write_json(out, [{"r1": 0.5}] * 1000, Console(file=io.StringIO()))
        assert out.read_text() == "[1]\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["rows.json"]  # no temporary file left
        monkeypatch.undo()
        common.write_json(out, [{"r1": float("nan")}], Console(file=io.StringIO()))
    assert json.loads(out.read_text()) == [{"r1": None}]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rows.json"]

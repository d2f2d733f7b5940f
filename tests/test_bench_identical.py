"""benchmarks/check_identical.py: a bad option or missing data ends it with one error line before
any worktree is made or command run, and a comparison in which a command failed (on either side)
never passes: it exits 1 and says which commands failed and why."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import BENCHMARKS, benchmark_module

SCRIPT = BENCHMARKS / "check_identical.py"


@pytest.mark.parametrize(("args", "code", "line"), [
    (["--base", "nosuchrev"], 2, "error: --base nosuchrev: not a commit"),
    (["--frames", "-5"], 2, "error: --frames must be at least 1, got -5"),
    (["--descriptors", "nosuch"], 2, "error: --descriptors: unknown descriptor 'nosuch' (choose from "),
    (["--datasets", "nosuch"], 2, "error: --datasets: unknown dataset 'nosuch' (choose from gp, nordland)"),
    (["--datasets", "nordland"], 1, "error: {data}/nordland-summer-winter-64x32/summer: folder does not exist"),
    (["--datasets", "gp"], 1, "error: {data}/gardens-point-walking/day_left: folder does not exist"),
])
def test_a_bad_option_or_missing_data_is_one_error_line(args: list[str], code: int, line: str,
                                                        tmp_path: Path) -> None:
    data = tmp_path / "no-data"
    done = subprocess.run([sys.executable, str(SCRIPT), "--methods", "online", "--descriptors", "sad", *args],
                          capture_output=True, text=True, env={**os.environ, "WILOC_DATA": str(data)}, timeout=60, check=False)
    assert done.returncode == code and "Traceback" not in done.stderr
    assert line.format(data=data) in done.stderr.strip().splitlines()[-1]
    assert "base:" not in done.stdout  # no commit was run


def fake_run(failing: dict[str, str]):
    """A stand-in for run_commit writing one localize log, failed (its stderr ``failing[label]``)
    in the runs named in ``failing``."""
    def run(code: Path, work: Path, *_: object) -> None:
        (work / "results").mkdir(parents=True)
        (work / "logs").mkdir()
        said = failing.get(code.name, "")
        stem = work / "logs" / "001-gp-sad-onlin"
        for suffix, text in ((".args", "localize x --json\n"), (".rc", f"{2 if said else 0}\n"),
                             (".out", ""), (".err", f"Usage: wiloc localize\n{said}\n" if said else "")):
            stem.with_suffix(suffix).write_text(text)
    return run


@pytest.mark.parametrize("failing", [{"base-code": "Error: unknown method 'onlin'", "main": "Error: nope"},
                                     {"main": "Error: unknown method 'onlin'"}])
def test_a_failed_command_fails_the_check_and_is_named(failing: dict[str, str], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    for folder in ("day_left", "day_right", "night_right"):
        (tmp_path / "gardens-point-walking" / folder).mkdir(parents=True)
    monkeypatch.setenv("WILOC_DATA", str(tmp_path))
    with benchmark_module("check_identical") as check:
        monkeypatch.setattr(check, "worktree", lambda rev, folder: folder)
        monkeypatch.setattr(check, "run_commit", fake_run(failing))
        code = check.main(["--methods", "onlin", "--descriptors", "sad", "--datasets", "gp"])
    out = capsys.readouterr().out
    assert code == 1
    for side, label in (("base", "base-code"), ("head", "main")):
        named = f"failed on {side}: 001-gp-sad-onlin (exit 2): {failing.get(label)}" in out
        assert named == (label in failing)

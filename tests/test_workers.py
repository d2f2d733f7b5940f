"""Worker processes: they import the installed wiloc whatever the current folder, never rerun the
caller's main module, and a worker that dies or raises ends the run at once."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc.workers import WorkerError, WorkerPool

TIMEOUT = 120  # seconds; a hang fails the test instead of the suite


def _folder(path: Path, n: int = 12) -> Path:
    rng = np.random.default_rng(0)
    path.mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(path / f"img{i:02d}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    return path


def _console_script() -> Path:
    script = Path(sys.executable).parent / "wiloc"
    if not script.exists():
        pytest.skip("the wiloc console script is not installed beside this interpreter")
    return script


@pytest.mark.parametrize("shadow", ["package", "namespace"])
def test_a_wiloc_folder_in_the_current_folder_is_never_imported(tmp_path: Path, cache_dir: Path,
                                                                 shadow: str) -> None:
    images = _folder(tmp_path / "images")
    here = tmp_path / "project"
    (here / "wiloc").mkdir(parents=True)
    marker = tmp_path / "shadow-imported"
    if shadow == "package":
        (here / "wiloc" / "__init__.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    result = subprocess.run([str(_console_script()), "describe", str(images), "--jobs", "2", "--json"],
                            cwd=here, capture_output=True, text=True, timeout=TIMEOUT)
    assert result.returncode == 0, result.stderr
    assert '"computed": 12' in result.stdout
    assert not marker.exists()
    assert "Traceback" not in result.stderr


def test_a_script_without_main_guard_describes_once(tmp_path: Path, cache_dir: Path) -> None:
    images = _folder(tmp_path / "images")
    log = tmp_path / "runs.log"
    script = tmp_path / "script.py"
    script.write_text(
        "from pathlib import Path\n"
        "import wiloc\n"
        f"with open({str(log)!r}, 'a') as f:\n"
        "    f.write('run\\n')\n"
        f"print(wiloc.describe([Path({str(images)!r})], 'sad', jobs=2)[0].computed)\n")
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                            timeout=TIMEOUT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "12"
    assert log.read_text() == "run\n"  # the workers never ran the script again
    assert "Traceback" not in result.stderr


def test_results_come_back_from_every_item() -> None:
    pool = WorkerPool(2)
    try:
        assert sorted(pool.imap_unordered(abs, range(-20, 0), chunksize=3)) == list(range(1, 21))
    finally:
        pool.close()
        pool.join()


def test_an_exception_in_a_worker_is_raised_in_the_caller() -> None:
    pool = WorkerPool(2)
    try:
        with pytest.raises(ValueError, match="invalid literal"):
            list(pool.imap_unordered(int, ["1", "2", "x"], chunksize=1))
    finally:
        pool.terminate()


def test_a_worker_that_dies_ends_the_run_naming_its_items() -> None:
    pool = WorkerPool(1)
    try:
        with pytest.raises(WorkerError, match="exit code 3") as caught:
            list(pool.imap_unordered(os._exit, [3], chunksize=1))
    finally:
        pool.terminate()
    assert caught.value.items == [3]

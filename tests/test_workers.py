"""Worker processes, forked or fresh interpreters: they run the installed wiloc whatever the
current folder, never rerun the caller's main module, and a worker that dies or raises ends the
run at once."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc.workers import WorkerError, WorkerPool, can_fork

TIMEOUT = 120  # seconds; a hang fails the test instead of the suite


def _folder(path: Path, n: int = 12) -> Path:
    rng = np.random.default_rng(0)
    path.mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(path / f"img{i:02d}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    return path


@pytest.fixture(params=["forked", "fresh"])
def start(request: pytest.FixtureRequest) -> str:
    """How the pools of a test start their workers."""
    return request.param


def _pool(processes: int, start: str) -> WorkerPool:
    pool = WorkerPool(processes, fork=start == "forked")
    assert pool.forked == (start == "forked")
    return pool


def test_workers_are_forked_only_while_no_other_thread_runs() -> None:
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not can_fork()
        pool = WorkerPool(1)
        try:
            assert not pool.forked
            assert list(pool.imap_unordered(abs, [-2])) == [2]
        finally:
            pool.terminate()
    finally:
        stop.set()
        other.join()


#: Prepended to the scripts below: the caller runs another thread, so its workers are fresh
#: interpreters.
_THREAD = "import threading; threading.Thread(target=threading.Event().wait, daemon=True).start()\n"


def _console_script() -> Path:
    script = Path(sys.executable).parent / "wiloc"
    if not script.exists():
        pytest.skip("the wiloc console script is not installed beside this interpreter")
    return script


@pytest.mark.parametrize("shadow", ["package", "namespace"])
@pytest.mark.parametrize("caller", ["command", "threaded script"])
def test_a_wiloc_folder_in_the_current_folder_is_never_imported(tmp_path: Path, cache_dir: Path,
                                                                 shadow: str, caller: str) -> None:
    images = _folder(tmp_path / "images")
    here = tmp_path / "project"
    (here / "wiloc").mkdir(parents=True)
    marker = tmp_path / "shadow-imported"
    if shadow == "package":
        (here / "wiloc" / "__init__.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    if caller == "command":
        args = [str(_console_script()), "describe", str(images), "--jobs", "2", "--json"]
    else:  # a script elsewhere (its folder, not the current one, is on its path) with a thread
        script = tmp_path / "script.py"
        script.write_text(_THREAD + "from pathlib import Path\nimport wiloc\n"
                          f"print('\"computed\": %d' % wiloc.describe([Path({str(images)!r})], 'sad', "
                          "jobs=2)[0].computed)\n")
        args = [sys.executable, str(script)]
    result = subprocess.run(args, cwd=here, capture_output=True, text=True, timeout=TIMEOUT)
    assert result.returncode == 0, result.stderr
    assert '"computed": 12' in result.stdout
    assert not marker.exists()
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("thread", [False, True])
def test_a_script_without_main_guard_describes_once(tmp_path: Path, cache_dir: Path, thread: bool) -> None:
    images = _folder(tmp_path / "images")
    log = tmp_path / "runs.log"
    script = tmp_path / "script.py"
    script.write_text(
        (_THREAD if thread else "") +
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


def test_results_come_back_from_every_item(start: str) -> None:
    pool = _pool(2, start)
    try:
        assert sorted(pool.imap_unordered(abs, range(-20, 0), chunksize=3)) == list(range(1, 21))
    finally:
        pool.close()
        pool.join()


def test_an_exception_in_a_worker_is_raised_in_the_caller(start: str) -> None:
    pool = _pool(2, start)
    try:
        with pytest.raises(ValueError, match="invalid literal"):
            list(pool.imap_unordered(int, ["1", "2", "x"], chunksize=1))
    finally:
        pool.terminate()


def test_a_worker_that_dies_ends_the_run_naming_its_items(start: str) -> None:
    pool = _pool(1, start)
    try:
        with pytest.raises(WorkerError, match="exit code 3") as caught:
            list(pool.imap_unordered(os._exit, [3], chunksize=1))
    finally:
        pool.terminate()
    assert caught.value.items == [3]


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc")
def test_a_forked_worker_keeps_only_its_pipes_and_stderr(tmp_path: Path) -> None:
    with open(tmp_path / "held", "wb"):  # a descriptor of the caller's, such as a cache lock
        pool = _pool(1, "forked")
        try:
            assert list(pool.imap_unordered(abs, [-1])) == [1]  # the worker has set itself up
            [worker] = pool._workers
            fds = os.listdir(f"/proc/{worker.pid}/fd")
            assert sorted(fds) == ["0", "1", "2", "3", "4"]  # /dev/null, stderr, its 2 pipes
            assert not any(os.readlink(f"/proc/{worker.pid}/fd/{fd}").endswith("held") for fd in fds)
        finally:
            pool.close()
            pool.join()

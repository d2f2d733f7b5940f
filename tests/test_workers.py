"""Worker processes, forked or fresh interpreters: they run the installed wiloc whatever the
current folder, never rerun the caller's main module, and a worker that dies or raises ends the
run at once."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from wiloc.description.workers import WorkerError, WorkerPool, borrowed_pool, can_fork, kept_pool, keeping_pools

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
    result = subprocess.run(args, cwd=here, capture_output=True, text=True, timeout=TIMEOUT, check=False)
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
                            timeout=TIMEOUT, check=False)
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


def _within(seconds: float, job: Callable[[], Any]) -> Any:
    """``job()``'s result, failing the test (not hanging the suite) if it takes longer."""
    done: list[Any] = []
    thread = threading.Thread(target=lambda: done.append(job()), daemon=True)
    thread.start()
    thread.join(seconds)
    assert done, f"no result within {seconds} s"
    return done[0]


def test_workers_holding_two_chunks_answer_every_item(start: str) -> None:
    pool = _pool(2, start)
    try:  # answers of tiny chunks arrive back to back: none may wait unread behind another
        assert _within(TIMEOUT, lambda: sorted(pool.imap_unordered(abs, range(-500, 0), ahead=2))) == \
            list(range(1, 501))
    finally:
        pool.close()
        pool.join()


def test_large_chunks_and_answers_do_not_block_each_other(start: str) -> None:
    pool = _pool(1, start)
    big = [bytes([i]) * 300_000 for i in range(6)]  # each over any pipe's buffer
    try:
        assert _within(TIMEOUT, lambda: sorted(pool.imap_unordered(bytes, big, ahead=2))) == big
    finally:
        pool.close()
        pool.join()


def test_a_worker_that_dies_holding_two_chunks_names_both(start: str) -> None:
    pool = _pool(1, start)
    try:
        with pytest.raises(WorkerError, match="exit code 3") as caught:
            list(pool.imap_unordered(os._exit, [3, 4, 5], chunksize=1, ahead=2))
    finally:
        pool.terminate()
    assert caught.value.items == [3, 4]


def test_kept_pools_serve_several_jobs_and_stop_with_the_block() -> None:
    with keeping_pools():
        assert not kept_pool(2)
        with borrowed_pool(2) as pool:
            first = pool
        assert kept_pool(2)
        with borrowed_pool(2) as pool:
            assert pool is first
        with pytest.raises(ValueError), borrowed_pool(2) as pool:  # a job that fails: not kept
            raise ValueError
        assert not kept_pool(2)
        with borrowed_pool(2) as pool:
            assert pool is not first
            last = pool
    assert all(worker.poll() is not None for worker in last._workers)  # stopped with the block
    with borrowed_pool(1) as pool:  # outside a block: stopped after the job
        alone = pool
    assert all(worker.poll() is not None for worker in alone._workers)

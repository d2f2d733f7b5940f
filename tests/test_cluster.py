"""Describe and localize on a Dask cluster (2 worker processes): the same cache entries and results
as a local run, and a worker killed mid-run costs nothing but time."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest

pytest.importorskip("distributed")
from distributed import LocalCluster

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.description.cluster import connect, disconnect
from wiloc.description.differences import ComputedDifferences
from wiloc.description.distances import DifferencesTo
from wiloc.errors import ParameterError, WilocError

TRAVERSALS = ("day_right", "day_left", "night_right")
VOLATILE = {"created", "updated"}  # times of writing: the only attributes allowed to differ


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """The address of a local cluster of 2 worker processes (each restarted by its nanny). Its
    nannies set variables in this process for the workers (one BLAS thread, ...), which later
    tests' child processes must not inherit."""
    environ = dict(os.environ)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        yield cluster.scheduler_address
        disconnect(cluster.scheduler_address)
    os.environ.clear()
    os.environ.update(environ)


def kill_a_worker(address: str) -> None:
    """SIGKILL one worker process (its nanny starts a new one)."""
    pids = connect(address).client.run(os.getpid)
    os.kill(min(pids.values()), signal.SIGKILL)


def dataset_bytes(item: h5py.Dataset) -> bytes:
    """A dataset's values as bytes: its raw buffer, or its strings joined."""
    if item.dtype.kind == "O":
        return "\0".join(item.asstr()[()]).encode()
    return item[()].tobytes()


def entry_contents(path: Path) -> dict[str, bytes | str]:
    """Every dataset's bytes and every attribute but the write times of one HDF5 file."""
    contents: dict[str, bytes | str] = {}
    with h5py.File(path, "r") as f:
        contents.update({f"@{k}": repr(v) for k, v in f.attrs.items() if k not in VOLATILE})
        f.visititems(lambda name, item: contents.__setitem__(name, dataset_bytes(item))
                     if isinstance(item, h5py.Dataset) else None)
    return contents


def cache_contents(root: Path) -> dict[str, dict[str, bytes | str]]:
    return {p.name: entry_contents(p) for p in sorted(root.rglob("*.h5"))}


def test_blocks_on_the_cluster_are_the_local_blocks_despite_a_killed_worker(scheduler: str) -> None:
    rng = np.random.default_rng(0)
    query = rng.integers(0, 256, (200, 1152), dtype=np.uint8)
    to = DifferencesTo(rng.integers(0, 256, (300, 1152), dtype=np.uint8), "l1", 1 / 1152)
    cluster = connect(scheduler)
    remote = ComputedDifferences(query, to, cluster.blocks).blocks(block_rows=16)
    first = [next(remote)]
    kill_a_worker(scheduler)
    got = np.concatenate([block for _, block in first + list(remote)])
    assert got.tobytes() == to(query).tobytes()


def test_a_local_cluster_leaves_the_environment_alone() -> None:
    before = dict(os.environ)
    connect("local", 1)
    disconnect("local", 1)
    assert dict(os.environ) == before


def test_without_a_scheduler_nothing_imports_dask(tmp_path: Path) -> None:
    code = ("import sys, wiloc.api, wiloc.cli; "
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))))")
    run = subprocess.run([sys.executable, "-c", "import json; " + code], capture_output=True, text=True, check=True)
    assert json.loads(run.stdout) == []


def test_an_unreachable_scheduler_is_one_error_line(tmp_path: Path) -> None:
    code = ("import dask, sys; from wiloc.cli import app; dask.config.set({'distributed.comm.timeouts.connect': '2s'}); "
            "sys.argv = ['wiloc', 'describe', sys.argv[1], '--scheduler', 'tcp://127.0.0.1:9']; app()")
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "WILOC_CACHE": str(tmp_path / "cache")}, check=False)
    assert run.returncode == 1, run.stderr
    assert run.stderr.count("error:") == 1 and "tcp://127.0.0.1:9: cannot reach the Dask scheduler" in run.stderr


@pytest.mark.parametrize("answer", ["nothing", "a banner"])
def test_another_service_at_the_scheduler_address_is_one_error_line(answer: str, tmp_path: Path) -> None:
    """A service that accepts the connection and never answers (a web server waits for a request)
    kept Dask's handshake waiting for ever; one that writes first (an SSH server's banner) ended
    in a MemoryError traceback, its bytes read as a message's length. In a process of its own, as
    a failed client leaves Dask's event loop unusable to others."""
    code = "\n".join([
        "import socket, sys, threading", "from wiloc.cli import app", "from wiloc.description import cluster",
        "cluster.CONNECT_WAIT = 3", "server = socket.create_server(('127.0.0.1', 0))", "held = []",
        "def serve():", "    while True:", "        peer = server.accept()[0]", "        held.append(peer)",
        f"        {'peer.sendall(bytes(range(256)) * 4)' if answer == 'a banner' else 'pass'}",
        "threading.Thread(target=serve, daemon=True).start()",
        "sys.argv = ['wiloc', 'describe', sys.argv[1], '--scheduler', f'tcp://127.0.0.1:{server.getsockname()[1]}']",
        "app()"])
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "WILOC_CACHE": str(tmp_path / "cache")}, check=False)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 1 and len(lines) == 1, run.stderr[-2000:]
    assert lines[0].endswith("no answer as a Dask scheduler in 3 s: is another service listening there?"
                             if answer == "nothing" else "answered, but not as a Dask scheduler: another service "
                                                         "listens there"), lines


@pytest.mark.parametrize("address", ["http://127.0.0.1:8787", "127.0.0.1"])
def test_a_malformed_scheduler_address_is_a_usage_error(address: str, tmp_path: Path) -> None:
    """In a process of its own: a client that failed to start leaves Dask's shared event loop
    unusable for the other tests' clients."""
    code = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"
    env = {**os.environ, "WILOC_CACHE": str(tmp_path / "cache")}
    run = subprocess.run([sys.executable, "-c", code, "describe", str(tmp_path), "--scheduler", address],
                         capture_output=True, text=True, timeout=120, env=env, check=False)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert lines[0].startswith("error: --scheduler:") and "is no Dask scheduler address" in lines[0] \
        and "tcp://HOST:8786" in lines[0], lines


@pytest.mark.parametrize(("address", "said"), [
    ("tcp://127.0.0.1:99999", "port 99999 is outside 1-65535"),
    ("tcp://127.0.0.1:0", "port 0 is outside 1-65535"),
    ("local:3", "local takes no count: jobs sets its workers (local, with jobs 3)"),
    ("inproc://x", "inproc:// names a scheduler inside this same process, and this process runs none"),
    ("tls://127.0.0.1:1", "tls:// needs Dask's TLS settings"),
    ("wss://127.0.0.1:1", "wss:// needs Dask's TLS settings"),
    ("ucx://127.0.0.1:8786", "this installation's Dask cannot connect by ucx://")])
@pytest.mark.parametrize("command", ["describe", "localize"])
def test_an_address_that_can_never_work_is_a_usage_error_at_once(address: str, said: str, command: str,
                                                                 tmp_path: Path) -> None:
    """A port out of range and ``local:3`` waited for Dask's 30 s connect timeout (``local:3`` as
    the host ``local``); inproc:// said Python's unpacking error; tls:// without TLS settings and
    ucx:// (a transport this Dask has not) ended in a traceback. Given by WILOC_SCHEDULER for
    localize. In a process of its own, as test_a_malformed_scheduler_address_is_a_usage_error."""
    code = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"
    env = {**os.environ, "WILOC_CACHE": str(tmp_path / "cache"), "WILOC_SCHEDULER": address}
    args = ["describe", str(tmp_path), "--scheduler", address] if command == "describe" else \
        ["localize", str(tmp_path), "--method", "online"]
    run = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=20, env=env,
                         check=False, cwd=tmp_path)  # localize's results file (and its lock) would go there
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr[-2000:]
    assert lines[0].startswith(f"error: --scheduler: '{address}'") and said in lines[0], lines
    assert "local" in lines[0] and ("tcp://HOST:8786" in lines[0] or address.startswith("local")), lines


def test_an_in_process_scheduler_is_an_address(monkeypatch: pytest.MonkeyPatch) -> None:
    """inproc:// is refused only where this process runs no scheduler of that address."""
    from distributed.comm.inproc import global_manager

    from wiloc.description.cluster import Cluster, _check_address

    listener = Cluster  # any object a weak reference can hold, as the listeners' registry does
    monkeypatch.setitem(global_manager.listeners, "198.51.100.1/1/1", listener)
    _check_address("inproc://198.51.100.1/1/1")
    with pytest.raises(ParameterError, match="this process runs none"):
        _check_address("inproc://198.51.100.1/1/2")


def test_tls_settings_that_cannot_be_loaded_are_a_usage_error(tmp_path: Path) -> None:
    """A CA file Dask's configuration names but that is not there ended in ``error: [Errno 2] No
    such file or directory``, naming neither --scheduler nor the settings."""
    import dask

    from wiloc.description.cluster import _check_address

    with dask.config.set({"distributed.comm.tls.ca-file": str(tmp_path / "none.pem"),
                          "distributed.comm.tls.client.cert": str(tmp_path / "none.pem")}), \
            pytest.raises(ParameterError, match=r"^scheduler: 'tls://127\.0\.0\.1:1': Dask's TLS settings "
                                                r"\(distributed\.comm\.tls\.\* in its configuration\) cannot be "
                                                r"loaded \(\[Errno 2\]"):
        _check_address("tls://127.0.0.1:1")


def test_any_failure_to_make_the_client_is_one_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever Dask raises while making the client (seen: a transport's TypeError) is one error
    saying it cannot reach the scheduler, not a traceback."""
    from wiloc.description import cluster

    def failing(address: str) -> None:
        raise TypeError("no such connector")

    monkeypatch.setattr(cluster, "Client", failing)
    with pytest.raises(WilocError, match=r"^tcp://127\.0\.0\.1:9: cannot reach the Dask scheduler \(TypeError: no "
                                         r"such connector\)$") as caught:
        cluster.Cluster("tcp://127.0.0.1:9")
    assert not isinstance(caught.value, ParameterError)


def error_in_a_process(workers: int, work: str, then: str = "", wait: float = 1) -> str:
    """The WilocError line of a describe-like run of ``work`` over batches on a local cluster of
    ``workers`` workers (``local``), with ``then`` done once its first result is in and the run
    ending when no worker is there for ``wait`` seconds, run in a
    process of its own: a cluster lost or starved under a client leaves Dask's shared event loop
    unusable for the other tests' clients."""
    code = "\n".join([
        "import os, time", "from distributed import LocalCluster", "from wiloc.description import cluster",
        "from wiloc.errors import WilocError", f"cluster.WORKER_WAIT, cluster.POLL = {wait}, 0.2",
        f"local = LocalCluster(n_workers={workers}, threads_per_worker=1, processes=True, dashboard_address=':0')",
        "try:",
        f"    results = cluster.connect(local.scheduler_address).in_batches({work}, list(range(64)))",
        *(["    assert next(results) in range(64)", f"    {then}"] if then else []),
        "    list(results)",
        "except WilocError as exc:", "    print(exc)"])
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180, check=False)
    assert run.returncode == 0, run.stderr
    return run.stdout.strip()


SLOW_BATCH = "lambda b: time.sleep(0.2) or b"


def test_a_scheduler_without_workers_is_one_error_not_a_wait() -> None:
    line = error_in_a_process(0, SLOW_BATCH)
    assert line.endswith(": no worker joined the Dask scheduler in 1 s; start some (the dask worker command, one "
                         "thread each)"), line


def test_a_lost_scheduler_ends_the_run_in_one_error() -> None:
    line = error_in_a_process(1, SLOW_BATCH, "local.close()")
    assert line.endswith(": the Dask cluster failed during the run (the connection was lost); the frames described so "
                         "far are kept in the cache; run again to resume"), line


def test_a_run_whose_workers_all_left_ends_in_one_error() -> None:
    line = error_in_a_process(1, SLOW_BATCH, "local.scale(0)  # the only worker retires, none comes back")
    assert line.endswith(": the Dask cluster failed during the run (no worker for 1 s); the frames described so far "
                         "are kept in the cache; run again to resume"), line


def test_a_task_that_kills_its_workers_is_one_error() -> None:
    assert "a task's worker died each time it ran" in error_in_a_process(1, "lambda b: os._exit(1)", wait=60)


def stalled_in_a_process(stuck: str, *run: str) -> str:
    """What ``run`` (lines that print how a run on ``local``, a local cluster of 2 workers, ended)
    prints, or the run's WilocError line; with ``stuck`` (code that makes Dask lose track of tasks,
    as it rarely does after a worker died) run first and the stall bound at 1 s, in a process of
    its own, as error_in_a_process's."""
    code = "\n".join([
        "import asyncio, numpy as np", "from distributed import Client, LocalCluster",
        "from wiloc.description import cluster", "from wiloc.description.distances import DifferencesTo",
        "from wiloc.errors import WilocError", "cluster.POLL, cluster.STALL = 0.2, 1", stuck,
        "local = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0')",
        "try:", *(f"    {line}" for line in run),
        "except WilocError as exc:", "    print(exc)"])
    process = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert process.returncode == 0, process.stderr
    return process.stdout.strip()


def blocks_in_a_process(stuck: str) -> str:
    """How a run of difference blocks ends (stalled_in_a_process): ``same`` (its blocks are the
    local ones) or its WilocError line."""
    return stalled_in_a_process(
        stuck, "rng = np.random.default_rng(0)", "query = rng.integers(0, 256, (64, 1152), dtype=np.uint8)",
        "to = DifferencesTo(rng.integers(0, 256, (300, 1152), dtype=np.uint8), 'l1', 1 / 1152)",
        "ranges = [(start, start + 16) for start in range(0, 64, 16)]",
        "blocks = cluster.connect(local.scheduler_address).blocks(query, to, ranges)",
        "print('same' if np.concatenate(list(blocks)).tobytes() == to(query).tobytes() else 'differ')")


def never_received(nth: int) -> str:
    """Code by which the ``nth`` result asked for is never received, though its task finished."""
    return "\n".join([
        "gather, asked = Client._gather, []",
        "async def _gather(self, *args, **kwargs):",
        "    asked.append(args)",
        f"    return await (asyncio.Event().wait() if len(asked) == {nth} else gather(self, *args, **kwargs))",
        "Client._gather = _gather"])


SLOW = "\n".join([  # each task computes for 1.5 s, where a stall (none allowed) is 1 s without progress
    "import time", "cluster.RESENDS = 0", "submit = Client.submit",
    "def slow(work, *args):", "    time.sleep(1.5)", "    return work(*args)",
    "Client.submit = lambda self, work, *args, **kwargs: submit(self, slow, work, *args, **kwargs)"])
NEVER_RUN = "\n".join([  # every task waits for a resource no worker has, with the workers idle
    "cluster.RESENDS = 1", "submit = Client.submit",
    "Client.submit = lambda self, *args, **kwargs: submit(self, *args, resources={'none': 1}, **kwargs)"])


def test_a_block_whose_result_never_arrives_is_sent_again() -> None:
    assert blocks_in_a_process(never_received(1)) == "same"


def test_a_block_slower_than_the_stall_bound_is_no_stall() -> None:
    assert blocks_in_a_process(SLOW) == "same"


def test_blocks_that_never_run_end_in_one_error() -> None:
    line = blocks_in_a_process(NEVER_RUN)
    assert line.endswith(": the Dask cluster failed during the run (a block made no progress in 1 s, 2 times); run "
                         "again"), line


def batches_in_a_process(stuck: str) -> str:
    """How a describe-like run of 64 items in batches ends (stalled_in_a_process): ``once`` (every
    item's result, each yielded once), the results it yielded otherwise, or its WilocError line."""
    return stalled_in_a_process(
        stuck, "results = list(cluster.connect(local.scheduler_address).in_batches(lambda b: b, list(range(64))))",
        "print('once' if sorted(results) == list(range(64)) else results)")


def test_a_batch_whose_result_never_arrives_is_sent_again_and_its_results_come_once() -> None:
    assert batches_in_a_process(never_received(2)) == "once"  # after the first batch's results: not sent again


def test_a_batch_slower_than_the_stall_bound_is_no_stall() -> None:
    assert batches_in_a_process(SLOW) == "once"


def test_batches_that_never_run_end_in_one_error() -> None:
    line = batches_in_a_process(NEVER_RUN)
    assert line.endswith(": the Dask cluster failed during the run (a batch made no progress in 1 s, 2 times); the "
                         "frames described so far are kept in the cache; run again to resume"), line


def _pretend_opencv(version: str | None) -> None:
    """On a worker: report OpenCV as ``version`` (None: as it is)."""
    from wiloc.descriptors import base

    saved = vars(base).setdefault("_real_library_version", base.library_version)
    base.library_version = saved if version is None else (lambda name: version)


def test_a_worker_with_another_opencv_is_refused_and_nothing_is_cached(scheduler: str, demo_route,
                                                                        tmp_path: Path) -> None:
    """The cache keys rows by the caller's OpenCV: a worker computing with another one would store
    its rows as the caller's, so it refuses, in one error naming it and both versions."""
    client = connect(scheduler).client
    client.run(_pretend_opencv, "0.0.1")
    try:
        with pytest.raises(WilocError, match=r"computes with opencv 0\.0\.1 where this process has opencv \d"):
            api.describe([demo_route.reference], "sad", cache=Cache(tmp_path / "cache"), scheduler=scheduler)
    finally:
        client.run(_pretend_opencv, None)
    assert not list((tmp_path / "cache").rglob("*.h5"))


def test_a_local_cluster_of_no_workers_is_refused_at_once(demo_route, tmp_path: Path) -> None:
    """--jobs -1 with --scheduler local started a cluster of none and waited 30 s for a worker."""
    with pytest.raises(ParameterError, match="jobs: must be at least 1, got -1"):
        api.describe([demo_route.reference], "sad", cache=Cache(tmp_path / "cache"), scheduler="local", jobs=-1)


def test_a_folder_given_by_a_relative_path_is_described_by_workers_started_elsewhere(
        scheduler: str, demo_route, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The workers started in another folder than the caller's: a relative path sent as given
    was read from theirs, and every frame was skipped as unreadable."""
    monkeypatch.chdir(demo_route.reference.parent)
    [report] = api.describe([Path(demo_route.reference.name)], "sad", cache=Cache(tmp_path / "cache"),
                            scheduler=scheduler)
    [local] = api.describe([demo_route.reference], "sad", cache=Cache(tmp_path / "local"))
    assert report.failed == [] and np.array_equal(report.entry.data, local.entry.data)


@pytest.mark.realdata
@pytest.mark.slow
def test_describe_and_localize_on_a_cluster_match_the_local_run(scheduler: str, data_root: Path,
                                                                tmp_path: Path) -> None:
    folders = [data_root / "gardens-point-walking" / t for t in TRAVERSALS]
    runs = {}
    for where in ("local", "cluster"):
        cache = Cache(tmp_path / where / "cache")
        kill = {"done": False}

        def progress(stage: str, done: int, total: int) -> None:
            # called during this iteration's describe, so where and kill are this iteration's
            if where == "cluster" and not kill["done"] and stage.startswith("describe day_left") and done >= total // 3:  # noqa: B023
                kill["done"] = True  # noqa: B023
                kill_a_worker(scheduler)  # mid-run: its batches are run again elsewhere

        reports = api.describe(folders, "sad", cache=cache, jobs=2, progress=progress,
                               scheduler=scheduler if where == "cluster" else None)
        assert [r.computed for r in reports] == [200, 200, 200]
        assert kill["done"] == (where == "cluster")
        for method in ("online", "threshold", "catgraph"):
            api.localize(folders[1], reference=folders[0], method=method, cache=cache, jobs=2,
                         out=tmp_path / where / f"{method}.csv", scheduler=scheduler if where == "cluster" else None)
        runs[where] = cache_contents(cache.root), {p.name: p.read_bytes() for p in (tmp_path / where).glob("*.csv")}
    local, cluster = runs["local"], runs["cluster"]
    assert len(local[0]) == 4 and local[0] == cluster[0]  # 3 descriptor entries and the map's summary
    assert len(local[1]) == 3 and local[1] == cluster[1]

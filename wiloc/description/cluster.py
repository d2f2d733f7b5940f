"""Running describe batches and difference blocks on a Dask cluster (``wiloc[dask]``).

Only imported when a scheduler is asked for (``--scheduler``, ``WILOC_SCHEDULER``): without one
nothing imports dask. The cache stays the calling process's alone: workers get image paths (and
the stored record of a frame, to reuse a row whose content is unchanged) or blocks of descriptor
rows, and return records or arrays; the caller journals and writes, exactly as a local run does,
so the entries are the same. A task whose worker dies is run again elsewhere by Dask.
docs/scaling.md tells how to start a scheduler and workers.
"""
from __future__ import annotations

import asyncio
import atexit
import concurrent.futures
import logging
import os
import pickle
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
from distributed import Client, Future, KilledWorker, LocalCluster, wait
from distributed.comm.addressing import parse_address
from distributed.comm.core import CommClosedError
from distributed.comm.inproc import global_manager
from distributed.comm.registry import get_backend
from distributed.protocol import pickle as dask_pickle
from distributed.security import Security
from numpy.typing import NDArray

from wiloc.description.distances import DifferencesTo
from wiloc.description.frame_describing import check_jobs
from wiloc.descriptors.registry import plugin_named
from wiloc.errors import ParameterError, WilocError

LOCAL = "local"
#: Items per batch task (frames, for describe): enough that a task's round trip costs little next
#: to its work.
BATCH = 16
#: Seconds a scheduler may be without a worker, before a run and during one: without one, tasks
#: would wait for ever.
WORKER_WAIT = 30
#: Seconds an address may take to answer as a Dask scheduler: Dask's own connect timeout (30 s)
#: covers reaching it, not its answer, for which it waited for ever where another service listened.
CONNECT_WAIT = 45
#: Seconds between looks at the scheduler's workers while waiting for a task.
POLL = 2
#: Seconds the oldest difference block, or describe's batches, may make no progress before the
#: tasks in flight are sent again: Dask can lose track of a task after a worker died (seen: a
#: block in memory on a live worker whose result the client never received; blocks waiting on
#: their worker for scattered references the scheduler thought it held) and would then wait for
#: ever. No progress is measured where a slow task cannot be mistaken for it: while the tasks
#: waited for are unfinished, no worker computing any task or fetching its data (a slow task keeps
#: its worker computing, a busy shared cluster its workers; a task the scheduler counts as
#: processing may be waiting on its worker for data lost with a dead worker); once one finished,
#: its result not arriving in STALL s plus one per TRANSFER bytes.
STALL = 60
#: Bytes a second a finished task's result is sure to arrive at, from a live worker.
TRANSFER = 10_000_000
#: Stalls in a row the tasks in flight are sent again after, before the run ends in an error.
RESENDS = 2
#: What a describe that lost its cluster, or a task that kept killing workers, leaves behind.
RESUME = "the frames described so far are kept in the cache; run again to resume"
#: What a wait that runs out raises: Python 3.10's asyncio and concurrent.futures each have their
#: own (Dask's waits raise theirs); from 3.11 all three are the builtin TimeoutError.
TIMEOUTS = (TimeoutError, asyncio.TimeoutError, concurrent.futures.TimeoutError)
T = TypeVar("T")
R = TypeVar("R")


def _block(to: DifferencesTo, rows: NDArray) -> NDArray[np.float32]:
    """On a worker: one block of differences."""
    return to(rows)


def _check_address(scheduler: str) -> None:
    """A ParameterError, at once, for an address no client could ever connect to, where Dask waited
    its 30 s connect timeout (a port out of range; ``local:3``, read as the host ``local``), said a
    Python error (inproc://) or ended in a traceback (tls:// without TLS settings, ucx://). What
    Dask cannot parse (no scheme it knows, no port) it refuses itself, as Cluster says."""
    again = "give tcp://HOST:8786, or local"
    if scheduler.lower().startswith(LOCAL + ":"):
        count = scheduler[len(LOCAL) + 1:]
        raise ParameterError("scheduler", f"{scheduler!r}: local takes no count: jobs sets its workers"
                                          + (f" (local, with jobs {count})" if count.isdigit() else ""))
    try:
        scheme, loc = parse_address(scheduler)
        backend = get_backend(scheme)
    except ValueError:
        return  # Dask's own words, as Cluster says them
    if (port := re.search(r":(-?\d+)$", loc)) and not 1 <= int(port[1]) <= 65535:
        raise ParameterError("scheduler", f"{scheduler!r} is no Dask scheduler address (port {int(port[1])} is "
                                          f"outside 1-65535); {again}")
    if scheme == "inproc" and loc not in global_manager.listeners:
        raise ParameterError("scheduler", f"{scheduler!r}: inproc:// names a scheduler inside this same process, "
                                          f"and this process runs none (a command-line run never does); {again}")
    if scheme in ("tls", "wss"):
        try:
            tls = Security().get_connection_args("client")["ssl_context"]
        except (OSError, ValueError) as exc:  # a file they name missing, or no certificate
            raise ParameterError("scheduler", f"{scheduler!r}: Dask's TLS settings (distributed.comm.tls.* in its "
                                              f"configuration) cannot be loaded ({exc})") from None
        if tls is None:
            raise ParameterError("scheduler", f"{scheduler!r}: {scheme}:// needs Dask's TLS settings (distributed."
                                              "comm.tls.ca-file and client.cert, with client.key, in its "
                                              "configuration), and they are not set; wiloc takes none of its own: "
                                              f"set them there, or {again}")
    try:
        backend.get_connector()
    except Exception as exc:  # ucx://: Dask moved its transport to another package
        raise ParameterError("scheduler", f"{scheduler!r}: this installation's Dask cannot connect by {scheme}:// "
                                          f"({type(exc).__name__}: {exc}); {again}") from None


def _connect(scheduler: str) -> Client:
    """A client of the scheduler at ``scheduler``, connected in a thread that is given up after
    :data:`CONNECT_WAIT` seconds: a service that accepts and never answers as Dask does (a web
    server) kept Dask's handshake waiting for ever. Dask's own errors are raised as they came."""
    got: dict[str, Any] = {}

    def attempt() -> None:
        try:
            got["client"] = Client(scheduler)
        except BaseException as exc:  # handed to the caller's thread
            got["error"] = exc

    thread = threading.Thread(target=attempt, name="wiloc-dask-connect", daemon=True)
    thread.start()
    thread.join(CONNECT_WAIT)
    if thread.is_alive():
        raise WilocError(scheduler, f"no answer as a Dask scheduler in {CONNECT_WAIT} s: is another service "
                                    "listening there?")
    if "error" in got:
        raise got["error"]
    return got["client"]


class Cluster:
    """A connection to a Dask scheduler (or a local cluster of worker processes it started)."""

    def __init__(self, scheduler: str, workers: int | None = None) -> None:
        self.scheduler = scheduler
        self._local: LocalCluster | None = None
        if scheduler != LOCAL:
            _check_address(scheduler)
        try:
            if scheduler == LOCAL:
                count = check_jobs(workers)  # --jobs -1 waited for workers that never came
                environ = dict(os.environ)
                # its workers' and nannies' log lines (a heartbeat missed on a busy machine, a task
                # cancelled by Ctrl-C) are not the user's: what fails the run is said in one line
                try:
                    self._local = LocalCluster(n_workers=count, threads_per_worker=1, processes=True,
                                               dashboard_address=":0", silence_logs=logging.CRITICAL)
                except RuntimeError as exc:  # "Nanny failed to start.": the workers' own tracebacks say why
                    raise WilocError(LOCAL, f"the local Dask cluster's workers failed to start ("
                                            f"{str(exc).rstrip('.')}); a script that starts one must do so under "
                                            "if __name__ == '__main__': (its workers, started by multiprocessing's "
                                            "spawn, run the script again)") from None
                finally:
                    _restore(environ)
                self.client = Client(self._local)
            else:
                self.client = _connect(scheduler)
        except ValueError as exc:  # no scheme Dask knows (http://, the dashboard's), no port
            raise ParameterError("scheduler", f"{scheduler!r} is no Dask scheduler address ({exc}); give "
                                              "tcp://HOST:8786, or local") from None
        except (OSError, *TIMEOUTS) as exc:
            raise WilocError(scheduler, f"cannot reach the Dask scheduler ({exc})") from None
        except MemoryError:  # another protocol's first bytes read as the length of a Dask message
            raise WilocError(scheduler, "answered, but not as a Dask scheduler: another service listens "
                                        "there") from None
        except WilocError:
            raise
        except Exception as exc:  # any other failure to make an address's client: one line, not a traceback
            if scheduler == LOCAL:
                raise
            raise WilocError(scheduler, f"cannot reach the Dask scheduler ({type(exc).__name__}: {exc})") from None
        try:
            self.client.wait_for_workers(1, timeout=WORKER_WAIT)
        except TIMEOUTS:
            self.close()
            raise WilocError(scheduler, f"no worker joined the Dask scheduler in {WORKER_WAIT} s; start some "
                                        "(the dask worker command, one thread each)") from None

    @property
    def workers(self) -> int:
        """Workers connected now (at least 1, for sizing how much work is sent ahead)."""
        return max(1, len(self.client.scheduler_info(n_workers=-1)["workers"]))

    def in_batches(self, work: Callable[[list[T]], list[R]], items: Sequence[T]) -> Iterator[R]:
        """``work`` (a module-level function, or a partial of one: the workers import it) over
        batches of ``BATCH`` items on the workers; each item's result as its batch finishes, in
        any order (describe: ``frame_describing.describe_quietly`` over frame tasks). Once they
        stall (see STALL) the batches not yet received are sent again: ``work`` is a pure function
        of its items, so a batch run twice costs only time, and its results are yielded once."""

        def send(batches: Iterable[list[T]]) -> dict[Future, list[T]]:
            return {self.client.submit(work, batch, pure=False): batch for batch in batches}

        with self._failures(RESUME):
            self._check_loadable(work)
        sent = send(list(items[i:i + BATCH]) for i in range(0, len(items), BATCH))
        stalls = 0
        try:
            with self._failures(RESUME):
                while sent:
                    try:
                        for future, results in self._results(list(sent)):
                            del sent[future]
                            stalls = 0
                            yield from results
                    except _Stalled:
                        stalls = _stalled(stalls, "a batch")
                        self.client.cancel(list(sent))
                        sent = send(sent.values())
        finally:
            self._cancel(list(sent))

    def _check_loadable(self, work: Callable[..., Any]) -> None:
        """A WilocError naming the descriptor plugin (else pickle's words) when the scheduler or a
        worker cannot unpickle ``work``, before any task is sent: a scheduler without the plugin
        failed the run in Dask's chained tracebacks, and a worker without it left the cluster."""
        payload = dask_pickle.dumps(work)  # as Dask pickles a task: by value where it must (__main__)
        try:
            self.client.run_on_scheduler(dask_pickle.loads, payload)
            self.client.run(dask_pickle.loads, payload)
        except (AttributeError, ImportError, pickle.UnpicklingError) as exc:
            plugin = plugin_named(str(exc))
            raise WilocError(self.scheduler, f"descriptor plugin '{plugin}' is not installed on the Dask scheduler "
                                             "or its workers; install it there and restart them" if plugin else
                                             f"the Dask scheduler or its workers cannot load this run's tasks "
                                             f"({type(exc).__name__}: {exc}); install the same packages there "
                                             "as here") from None

    def blocks(self, data: NDArray, to: DifferencesTo, ranges: list[tuple[int, int]]) -> Iterator[NDArray[np.float32]]:
        """A ``wiloc.description.differences.BlockRunner``: the blocks in order, a few per worker in flight;
        the prepared references go to every worker once (again, with the blocks in flight, if a
        dying worker took the last copy with it or the oldest block stalled: see STALL)."""
        with self._failures("run again"):
            shared = self.client.scatter(to, broadcast=True)
        ahead = 2 * self.workers
        todo = deque(ranges)
        pending: deque[tuple[tuple[int, int], Future]] = deque()
        stalls = 0

        def fill() -> None:
            while todo and len(pending) < ahead:
                start, stop = todo.popleft()
                pending.append(((start, stop), self.client.submit(_block, shared, data[start:stop], pure=False)))

        def resend() -> None:
            """Send the blocks in flight again, with fresh references (a new key: the scheduler's
            record of the old ones may be what went wrong)."""
            nonlocal shared
            todo.extendleft(reversed([s for s, _ in pending]))
            self.client.cancel([f for _, f in pending] + [shared])
            pending.clear()
            shared = self.client.scatter(to, broadcast=True, hash=False)
            fill()

        try:
            with self._failures("run again"):
                fill()
                while pending:
                    (start, stop), future = pending[0]
                    nbytes = (stop - start) * to.shape[0] * np.dtype(np.float32).itemsize
                    try:
                        _, block = next(self._results([future], nbytes))
                    except CancelledError as exc:  # lost dependencies: the references went with a worker
                        if _lost(exc):
                            raise
                        resend()
                        continue
                    except _Stalled:
                        stalls = _stalled(stalls, "a block")
                        resend()
                        continue
                    stalls = 0
                    pending.popleft()
                    fill()
                    yield block
        finally:
            self._cancel([f for _, f in pending] + [shared])

    def _results(self, futures: list[Future], nbytes: int = 0) -> Iterator[tuple[Future, Any]]:
        """``futures`` with their results (``nbytes`` long at most; describe's records are a
        descriptor row each, small) as they finish; a _Stalled once they made no progress (see
        STALL), a finished one's result not received in time included."""
        for future in self._finished(futures):
            try:
                result = future.result(timeout=STALL + nbytes / TRANSFER)
            except TIMEOUTS:
                raise _Stalled() from None
            yield future, result

    def _finished(self, futures: list[Future]) -> Iterator[Future]:
        """``futures`` as they finish; a TimeoutError once the scheduler has had no worker for
        WORKER_WAIT s (every worker gone mid-run, none restarted), where Dask waits for ever; a
        _Stalled once its workers have all been idle (see _busy) for STALL s while these are
        unfinished (tasks Dask lost track of)."""
        pending, alone_since, idle_since = set(futures), None, None
        while pending:
            try:
                done, pending = wait(pending, timeout=POLL, return_when="FIRST_COMPLETED")
            except TIMEOUTS:
                now = time.monotonic()
                workers = self.client.scheduler_info(n_workers=-1)["workers"]
                if not workers:
                    idle_since = None
                    if now - (alone_since := alone_since or now) > WORKER_WAIT:
                        raise TimeoutError(f"no worker for {WORKER_WAIT} s") from None
                else:
                    alone_since = None
                    if any(map(_busy, workers.values())):
                        idle_since = None
                    elif now - (idle_since := idle_since or now) > STALL:
                        raise _Stalled()
                continue
            yield from done

    @contextmanager
    def _failures(self, then: str) -> Iterator[None]:
        """What Dask raises when the cluster fails under a run, as one WilocError naming the
        scheduler and ending with ``then`` (what to do): the connection lost, no worker left, a
        task whose workers kept dying (a task's own error, a WilocError of a worker, passes as
        it is)."""
        try:
            yield
        except KilledWorker:
            raise WilocError(self.scheduler, "a task's worker died each time it ran (out of memory, or killed); "
                                             f"{then}") from None
        except (CancelledError, CommClosedError, *TIMEOUTS) as exc:
            lonely = type(exc) in TIMEOUTS and str(exc)  # no worker: Dask's words, or _finished's
            detail = str(exc).splitlines()[0].lower() if lonely else "the connection was lost"
            logging.getLogger("distributed.client").setLevel(logging.CRITICAL)  # its reconnect attempts: said here
            raise WilocError(self.scheduler, f"the Dask cluster failed during the run ({detail}); {then}") from None

    def _cancel(self, futures: list[Future]) -> None:
        """Cancel what is left of a run's tasks, unless the client has lost its scheduler."""
        if self.client.status == "running":
            self.client.cancel(futures)

    def close(self) -> None:
        self.client.close()
        if self._local is not None:
            self._local.close()


def _busy(worker: dict) -> bool:
    """Whether a worker (as ``scheduler_info`` describes it, as of its last heartbeat) is computing
    a task or fetching a task's data. Not the scheduler's "processing": seen, tasks processing there
    for ever on a worker that waited for scattered references the scheduler wrongly thought it had."""
    counts = worker.get("metrics", {}).get("task_counts", {})
    return bool(counts.get("executing") or counts.get("flight"))


class _Stalled(Exception):
    """Tasks that made no progress for STALL s (``Cluster.blocks`` and ``Cluster.in_batches`` send
    them again)."""


def _stalled(stalls: int, what: str) -> int:
    """The stalls in a row of a run's tasks with one more of ``what`` (a block, a batch); past
    RESENDS, a TimeoutError that ends the run in one error line saying so."""
    stalls += 1
    if stalls > RESENDS:
        raise TimeoutError(f"{what} made no progress in {STALL} s, {stalls} times")
    return stalls


def _lost(exc: CancelledError) -> bool:
    """Whether a task was cancelled because the client lost its scheduler (not a dependency)."""
    return "connection" in str(getattr(exc, "reason", "") or "")


def _restore(environ: dict[str, str]) -> None:
    """Put back this process's environment: starting workers sets variables for them here (one
    BLAS thread, a hash seed) that later child processes of the caller must not inherit."""
    os.environ.clear()
    os.environ.update(environ)


_open: dict[tuple[str, int | None], Cluster] = {}


def connect(scheduler: str, workers: int | None = None) -> Cluster:
    """The cluster at ``scheduler`` (an address such as ``tcp://host:8786``, or ``local``: a
    local cluster of ``workers`` processes, default one per core), one per process, closed at
    exit or by :func:`disconnect`."""
    key = (scheduler, workers if scheduler == LOCAL else None)
    if key not in _open:
        _open[key] = Cluster(scheduler, workers)
        atexit.register(disconnect, scheduler, workers)
    return _open[key]


def disconnect(scheduler: str, workers: int | None = None) -> None:
    """Close the connection :func:`connect` made (and a local cluster it started), if open."""
    cluster = _open.pop((scheduler, workers if scheduler == LOCAL else None), None)
    if cluster is not None:
        cluster.close()

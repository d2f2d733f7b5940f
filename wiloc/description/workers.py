"""Worker processes that run the wiloc the caller imported, whatever the current folder, and
never run the caller's main module.

multiprocessing's ``spawn`` and ``forkserver`` methods run the caller's main script again in
every worker (a script without an ``if __name__ == "__main__":`` guard then starts workers from
its workers, and hangs), and the fork server resolves imports against the current folder (a
folder named ``wiloc`` there was imported instead of the installed package, and hung the pool).
``fork`` avoids both but copies a parent that may run threads (a progress display, the caller's
own), whose locks then stay held in the child. So a :class:`WorkerPool` forks its workers only
while the calling process runs no other thread: a forked worker has everything imported already
and answers within milliseconds. Otherwise it starts each worker as a fresh ``python -c BOOT``
(about 0.25 CPU-s of imports): BOOT sets the module search path to the caller's, loads the
``wiloc`` package from the very folder the caller loaded it from, and runs :func:`serve`. Either
way a worker ignores Ctrl-C (the parent stops the workers) and answers calls sent over a pair
of pipes as length-prefixed pickles; a worker that dies makes the pool raise at once.
"""
from __future__ import annotations

import io
import os
import pickle
import selectors
import signal
import struct
import subprocess
import sys
import threading
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from itertools import chain, islice
from typing import Any, BinaryIO, Protocol

import wiloc
from wiloc.errors import WilocError

_LENGTH = struct.Struct("<Q")
#: The pools :func:`keeping_pools` keeps, by worker count and initializer (None: outside one).
_kept: ContextVar[dict[tuple[int, Callable[[], None] | None], WorkerPool] | None] = ContextVar("wiloc_kept_pools",
                                                                                             default=None)
#: Largest message sent to a worker that still holds a chunk: two such messages unread fit in any
#: pipe's buffer (16 KiB at least), so that sending never blocks while the worker, blocked on
#: sending its own answer, waits for this process to read it.
_AHEAD_BYTES = 8192
_BOOT = """\
import importlib.util, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.path[:] = {path!r}
spec = importlib.util.spec_from_file_location("wiloc", {init!r}, submodule_search_locations=[{package!r}])
sys.modules["wiloc"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sys.modules["wiloc"])
from wiloc.description.workers import serve
serve()
"""


class WorkerError(WilocError):
    """A worker process ended without answering (killed, crashed, or its imports failed) while
    it held ``items``."""

    def __init__(self, problem: str, items: list[Any]) -> None:
        super().__init__(None, problem)
        self.items = items


class UnknownToWorkers(WilocError):
    """A worker process could not find by name what it was sent to run (``problem``: pickle's
    words): a class the caller's main script defines, which a fresh worker never runs."""

    def __init__(self, problem: str) -> None:
        super().__init__(None, problem)


def _pack(message: Any) -> bytes:
    """A message as sent: its pickle, prefixed by the pickle's length."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return _LENGTH.pack(len(data)) + data


def _send(stream: BinaryIO, message: Any) -> None:
    _write(stream, _pack(message))


def _write(stream: BinaryIO, packed: bytes) -> None:
    stream.write(packed)
    stream.flush()


def _receive(stream: BinaryIO) -> Any:
    """The next message, or raise EOFError when the other side closed the pipe. From a raw
    (unbuffered) stream too, which may return fewer bytes than asked for at a time."""
    (length,) = _LENGTH.unpack(_read_exactly(stream, _LENGTH.size))
    return pickle.loads(_read_exactly(stream, length))


def _read_exactly(stream: BinaryIO, size: int) -> bytes:
    """`size` bytes from `stream`, or EOFError when it ends first."""
    parts = []
    while size:
        part = stream.read(size)
        if not part:
            raise EOFError
        parts.append(part)
        size -= len(part)
    return b"".join(parts)


def serve() -> None:
    """A worker's loop: run the initializer it is sent first, then answer each ``(func, items)``
    with ``(True, [func(item) ...])`` or ``(False, exception)`` (:class:`UnknownToWorkers` when
    it names what this process cannot find), until its stdin closes. The
    pipes are moved off descriptors 0 and 1 first, so that whatever prints goes to stderr."""
    inbox = os.fdopen(os.dup(0), "rb")
    outbox = os.fdopen(os.dup(1), "wb")
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.close(devnull)
    os.dup2(2, 1)
    try:
        initializer = _receive(inbox)
        if initializer is not None:
            initializer()
        while True:
            try:
                func, items = _receive(inbox)
            except (AttributeError, ImportError, pickle.UnpicklingError) as exc:  # read whole: the next one follows
                _send(outbox, (False, UnknownToWorkers(str(exc))))
                continue
            try:
                answer: tuple[bool, Any] = (True, [func(item) for item in items])
            except Exception as exc:  # noqa: BLE001 - the parent re-raises it
                answer = (False, exc)
            try:
                _send(outbox, answer)
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                _send(outbox, (False, RuntimeError(f"a worker's answer could not be sent back: {exc!r}")))
    except EOFError:
        pass


class _Worker(Protocol):
    """What the pool uses of a worker process (a ``subprocess.Popen`` or a :class:`_Forked`)."""

    stdin: BinaryIO
    stdout: io.BufferedReader

    def wait(self) -> int: ...

    def poll(self) -> int | None: ...

    def kill(self) -> None: ...


class _Forked:
    """A worker forked from this process, with the parts of ``subprocess.Popen`` the pool uses.
    The child keeps only its two pipes (on descriptors 0 and 1) and stderr, ignores Ctrl-C, runs
    :func:`serve` and leaves with ``os._exit``: none of the parent's exit handlers, finalizers
    or buffered output run in it."""

    def __init__(self) -> None:
        down_read, down_write = os.pipe()
        up_read, up_write = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # nothing buffered here is written twice
            if stream is not None:
                stream.flush()
        with warnings.catch_warnings():  # Python 3.12+ warns of native threads too (can_fork)
            warnings.filterwarnings("ignore", r".*use of fork\(\) may lead to deadlocks", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # pragma: no cover - the child process
            code = 1
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                os.dup2(down_read, 0)
                os.dup2(up_write, 1)
                os.closerange(3, os.sysconf("SC_OPEN_MAX"))  # other workers' pipes, the cache's locks
                serve()
                code = 0
            finally:
                os._exit(code)
        os.close(down_read)
        os.close(up_write)
        self.pid = pid
        self.returncode: int | None = None
        self.stdin = os.fdopen(down_write, "wb")
        self.stdout = os.fdopen(up_read, "rb")

    def wait(self) -> int:
        """The exit code, negative for a signal (as ``Popen.wait``), once the child has ended."""
        if self.returncode is None:
            _, status = os.waitpid(self.pid, 0)
            self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def poll(self) -> int | None:
        """The exit code once the child has ended, else None (as ``Popen.poll``)."""
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def kill(self) -> None:
        """SIGKILL, unless the child has been waited for already."""
        if self.returncode is None:
            os.kill(self.pid, signal.SIGKILL)


class WorkerPool:
    """``processes`` worker processes, each started with ``initializer()``; the calls of
    multiprocessing's Pool that wiloc uses (imap_unordered, close, join, terminate), and kill.
    The workers are forked when ``fork`` says so, by default when :func:`can_fork` (:attr:`forked`),
    else fresh interpreters."""

    def __init__(self, processes: int, initializer: Callable[[], None] | None = None,
                 fork: bool | None = None) -> None:
        self.forked = can_fork() if fork is None else fork
        boot = _BOOT.format(path=[os.path.abspath(p) for p in sys.path], init=wiloc.__file__,
                            package=wiloc.__path__[0])
        self._workers: list[_Worker] = []
        try:
            for _ in range(processes):
                worker: _Worker = _Forked() if self.forked else subprocess.Popen(
                    [sys.executable, "-c", boot], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                self._workers.append(worker)
                self._post(worker, initializer, [])
        except BaseException:
            self.terminate()
            raise

    @staticmethod
    def _post(worker: _Worker, message: Any, items: list[Any]) -> None:
        WorkerPool._post_packed(worker, _pack(message), items)

    @staticmethod
    def _post_packed(worker: _Worker, packed: bytes, items: list[Any]) -> None:
        try:
            _write(worker.stdin, packed)
        except BrokenPipeError:
            raise WorkerError(f"a worker process ended ({_how(worker.wait())})", items) from None

    def imap_unordered(self, func: Callable[[Any], Any], items: Iterable[Any], chunksize: int = 1,
                       ahead: int = 1) -> Iterator[Any]:
        """``func(item)`` for every item, computed in chunks of ``chunksize`` by the workers and
        yielded as the chunks come back. Each worker holds up to ``ahead`` chunks: with 2, its next
        chunk waits in its pipe while it computes, so it never idles through a round trip to this
        process (a chunk over _AHEAD_BYTES waits here until the worker holds none). A worker's
        exception is raised here; a worker that ends without answering raises WorkerError."""
        pending = iter(items)
        sent: dict[_Worker, deque[list[Any]]] = {worker: deque() for worker in self._workers}
        held: dict[_Worker, tuple[bytes, list[Any]]] = {}
        with selectors.DefaultSelector() as selector:
            def feed(worker: _Worker) -> None:
                while len(sent[worker]) < ahead:
                    if worker in held:
                        packed, chunk = held.pop(worker)
                    else:
                        chunk = list(islice(pending, chunksize))
                        if not chunk:
                            return
                        packed = _pack((func, chunk))
                    if sent[worker] and len(packed) > _AHEAD_BYTES:
                        held[worker] = packed, chunk
                        return
                    self._post_packed(worker, packed, [*chain.from_iterable(sent[worker]), *chunk])
                    if not sent[worker]:
                        selector.register(worker.stdout, selectors.EVENT_READ, worker)
                    sent[worker].append(chunk)

            for worker in self._workers:
                feed(worker)
            while any(sent.values()):
                for key, _ in selector.select():
                    worker = key.data
                    try:  # past the buffer, which may take in an answer the selector would not report
                        ok, answer = _receive(worker.stdout.raw)
                    except EOFError:
                        raise WorkerError(f"a worker process ended without answering ({_how(worker.wait())})",
                                          [*chain.from_iterable(sent[worker])]) from None
                    if not ok:
                        raise answer
                    sent[worker].popleft()
                    if not sent[worker]:
                        selector.unregister(worker.stdout)
                    feed(worker)
                    yield from answer

    def alive(self) -> bool:
        """Whether every worker still runs (one that ended between jobs cannot take the next)."""
        return all(worker.poll() is None for worker in self._workers)

    def close(self) -> None:
        """No more work: each worker's stdin is closed, and it exits."""
        for worker in self._workers:
            if not worker.stdin.closed:
                worker.stdin.close()

    def join(self) -> None:
        """Wait for the workers to exit (after :meth:`close` or :meth:`terminate`)."""
        for worker in self._workers:
            worker.wait()
            worker.stdout.close()

    def kill(self) -> None:
        """SIGKILL every worker; their pipes stay open, so that a thread waiting on them in
        :meth:`imap_unordered` sees them end (and raises WorkerError). Then :meth:`close` and
        :meth:`join`."""
        for worker in self._workers:
            worker.kill()

    def terminate(self) -> None:
        """Stop the workers now (from the thread that reads them, or with none reading); work in
        flight is lost."""
        self.kill()
        self.close()
        self.join()


@contextmanager
def keeping_pools() -> Iterator[None]:
    """Within this block, the pools of :func:`borrowed_pool` outlive each job: the next job
    asking for as many workers with the same initializer gets the same workers (started once, by
    the first job: for several folders of one ``describe`` call), and all are stopped on leaving
    the block. Blocks nest: the outermost keeps."""
    if _kept.get() is not None:
        yield
        return
    kept: dict[tuple[int, Callable[[], None] | None], WorkerPool] = {}
    token = _kept.set(kept)
    try:
        yield
    finally:
        _kept.reset(token)
        for pool in kept.values():
            pool.close()
            pool.join()


def kept_pool(processes: int, initializer: Callable[[], None] | None = None) -> bool:
    """Whether :func:`borrowed_pool` would lend running workers, kept from an earlier job."""
    pool = (_kept.get() or {}).get((processes, initializer))
    return pool is not None and pool.alive()


@contextmanager
def borrowed_pool(processes: int, initializer: Callable[[], None] | None = None) -> Iterator[WorkerPool]:
    """A pool of ``processes`` workers for one job: the one an enclosing :func:`keeping_pools`
    block keeps (started now if it keeps none alive), else a new pool stopped after the job. A
    job that raises leaves the pool killed (by the job, with its helper threads done) and not
    kept."""
    kept = _kept.get()
    key = (processes, initializer)
    pool = kept.pop(key, None) if kept is not None else None
    if pool is not None and not pool.alive():
        pool.terminate()
        pool = None
    pool = pool or WorkerPool(processes, initializer)
    try:
        yield pool
    except BaseException:
        pool.terminate()
        raise
    if kept is None:
        pool.close()
        pool.join()
    else:
        kept[key] = pool


def can_fork() -> bool:
    """Whether workers can be forked safely: on Linux (macOS's system libraries are not fork-safe),
    while this process runs no Python thread but the calling one (another thread may hold a lock
    the child would wait on forever). Native threads of numpy's BLAS and OpenCV are idle there:
    OpenBLAS stops its own at a fork, OpenCV runs on one thread while workers run."""
    return sys.platform == "linux" and threading.active_count() == 1


def _how(code: int) -> str:
    """A worker's exit status in words."""
    return f"killed by signal {-code}" if code < 0 else f"exit code {code}"

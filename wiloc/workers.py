"""Worker processes that import the wiloc the caller imported, whatever the current folder, and
never run the caller's main module.

multiprocessing's ``spawn`` and ``forkserver`` methods run the caller's main script again in
every worker (a script without an ``if __name__ == "__main__":`` guard then starts workers from
its workers, and hangs), and the fork server resolves imports against the current folder (a
folder named ``wiloc`` there was imported instead of the installed package, and hung the pool).
``fork`` avoids both but copies a parent that may run threads (a progress display, the caller's
own), whose locks then stay held in the child. A :class:`WorkerPool` starts each worker as a
fresh ``python -c BOOT``: BOOT ignores Ctrl-C (the parent stops the workers), sets the module
search path to the caller's, loads the ``wiloc`` package from the very folder the caller loaded
it from, and runs :func:`serve`, which answers calls sent over the worker's stdin and stdout as
length-prefixed pickles. A worker that dies makes the pool raise at once.
"""
from __future__ import annotations

import os
import pickle
import selectors
import struct
import subprocess
import sys
from collections.abc import Callable, Iterable, Iterator
from itertools import islice
from typing import Any, BinaryIO

import wiloc
from wiloc.errors import WilocError

_LENGTH = struct.Struct("<Q")
_BOOT = """\
import importlib.util, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.path[:] = {path!r}
spec = importlib.util.spec_from_file_location("wiloc", {init!r}, submodule_search_locations=[{package!r}])
sys.modules["wiloc"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sys.modules["wiloc"])
from wiloc.workers import serve
serve()
"""


class WorkerError(WilocError):
    """A worker process ended without answering (killed, crashed, or its imports failed) while
    it held ``items``."""

    def __init__(self, problem: str, items: list[Any]) -> None:
        super().__init__(None, problem)
        self.items = items


def _send(stream: BinaryIO, message: Any) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LENGTH.pack(len(data)) + data)
    stream.flush()


def _receive(stream: BinaryIO) -> Any:
    """The next message, or raise EOFError when the other side closed the pipe."""
    head = stream.read(_LENGTH.size)
    if len(head) < _LENGTH.size:
        raise EOFError
    data = stream.read(_LENGTH.unpack(head)[0])
    return pickle.loads(data)


def serve() -> None:
    """A worker's loop: run the initializer it is sent first, then answer each ``(func, items)``
    with ``(True, [func(item) ...])`` or ``(False, exception)``, until its stdin closes. The
    pipes are moved off descriptors 0 and 1 first, so that whatever prints goes to stderr."""
    inbox = os.fdopen(os.dup(0), "rb")
    outbox = os.fdopen(os.dup(1), "wb")
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    os.dup2(2, 1)
    try:
        initializer = _receive(inbox)
        if initializer is not None:
            initializer()
        while True:
            func, items = _receive(inbox)
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


class WorkerPool:
    """``processes`` worker processes, each started with ``initializer()``; the calls of
    multiprocessing's Pool that wiloc uses (imap_unordered, close, join, terminate)."""

    def __init__(self, processes: int, initializer: Callable[[], None] | None = None) -> None:
        boot = _BOOT.format(path=[os.path.abspath(p) for p in sys.path], init=wiloc.__file__,
                            package=wiloc.__path__[0])
        self._workers: list[subprocess.Popen[bytes]] = []
        try:
            for _ in range(processes):
                worker = subprocess.Popen([sys.executable, "-c", boot], stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE)
                self._workers.append(worker)
                self._post(worker, initializer, [])
        except BaseException:
            self.terminate()
            raise

    @staticmethod
    def _post(worker: subprocess.Popen[bytes], message: Any, items: list[Any]) -> None:
        try:
            _send(worker.stdin, message)
        except BrokenPipeError:
            raise WorkerError(f"a worker process ended ({_how(worker.wait())})", items) from None

    def imap_unordered(self, func: Callable[[Any], Any], items: Iterable[Any], chunksize: int = 1) -> Iterator[Any]:
        """``func(item)`` for every item, computed in chunks of ``chunksize`` by the workers and
        yielded as the chunks come back. A worker's exception is raised here; a worker that
        ends without answering raises WorkerError."""
        pending = iter(items)
        busy: dict[subprocess.Popen[bytes], list[Any]] = {}
        with selectors.DefaultSelector() as selector:
            def give(worker: subprocess.Popen[bytes]) -> None:
                chunk = list(islice(pending, chunksize))
                if chunk:
                    busy[worker] = chunk
                    self._post(worker, (func, chunk), chunk)
                    selector.register(worker.stdout, selectors.EVENT_READ, worker)

            for worker in self._workers:
                give(worker)
            while busy:
                for key, _ in selector.select():
                    worker = key.data
                    selector.unregister(worker.stdout)
                    try:
                        ok, answer = _receive(worker.stdout)
                    except EOFError:
                        raise WorkerError(f"a worker process ended without answering ({_how(worker.wait())})",
                                          busy[worker]) from None
                    if not ok:
                        raise answer
                    del busy[worker]
                    yield from answer
                    give(worker)

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

    def terminate(self) -> None:
        """Stop the workers now; work in flight is lost."""
        for worker in self._workers:
            worker.kill()
        self.close()
        self.join()


def _how(code: int) -> str:
    """A worker's exit status in words."""
    return f"killed by signal {-code}" if code < 0 else f"exit code {code}"

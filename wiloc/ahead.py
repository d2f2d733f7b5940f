"""Items of an iterator computed by a helper thread ahead of the caller that consumes them.

The work that fills a run's pipeline (the difference kernels, numpy's sorts, the methods'
compiled per-row passes) releases the GIL, so a helper computing the next items runs on another
core beside the caller's sequential steps. Nothing here loads numpy or numba.

The caller's steps bound a run: the helper is always at least one item ahead, so on Linux it
runs at a lower scheduling priority (``HELPER_NICE``), as do the threads it starts (the
kernels' OpenMP workers inherit it). Where the helpers and the kernels' threads outnumber the
cores, the caller then gets a core whenever it can run instead of a fair share of one
(docs/scaling.md has the measurements).
"""
from __future__ import annotations

import os
import queue
import sys
import threading
from collections.abc import Generator, Iterable
from typing import TypeVar

T = TypeVar("T")

#: How much lower a helper thread's priority is than the process's main thread's (Linux nice increments).
HELPER_NICE = 10


def _lower_priority(increment: int) -> None:
    """Give this thread the nice value of the process's main thread plus ``increment`` unless its
    nice value is that high already (Linux: priorities are per thread, and a helper started by a
    helper ends at the same level; elsewhere, and where the system refuses, nothing changes)."""
    if sys.platform != "linux" or increment <= 0:
        return
    try:
        target = min(os.getpriority(os.PRIO_PROCESS, os.getpid()) + increment, 19)
        tid = threading.get_native_id()
        if os.getpriority(os.PRIO_PROCESS, tid) < target:
            os.setpriority(os.PRIO_PROCESS, tid, target)
    except OSError:
        pass


def computed_ahead(items: Iterable[T], depth: int = 1) -> Generator[T, None, None]:
    """The items of ``items`` in order, computed by a helper thread up to ``depth`` items ahead
    of the caller (plus the one it is computing). An exception raised computing an item is
    raised here, in its place; when the caller stops early the helper stops after its current
    item and closes ``items``."""
    ahead: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def hand(item: tuple[bool, object]) -> bool:
        """Queue ``item`` unless the caller has stopped; whether it was queued."""
        while not stop.is_set():
            try:
                ahead.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def compute() -> None:
        _lower_priority(HELPER_NICE)
        try:
            for item in items:
                if not hand((True, item)):
                    return
            hand((False, None))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, raised there
            hand((False, exc))
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=compute, name="wiloc-ahead", daemon=True)
    worker.start()
    try:
        while True:
            more, item = ahead.get()
            if not more:
                if item is not None:
                    raise item  # type: ignore[misc]
                return
            yield item  # type: ignore[misc]
    finally:
        stop.set()
        worker.join()

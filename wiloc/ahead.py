"""Items of an iterator computed by a helper thread ahead of the caller that consumes them.

The work that fills a run's pipeline (the difference kernels, numpy's sorts, the methods'
compiled per-row passes) releases the GIL, so a helper computing the next items runs on another
core beside the caller's sequential steps. Nothing here loads numpy or numba.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def computed_ahead(items: Iterable[T], depth: int = 1) -> Iterator[T]:
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
        try:
            for item in items:
                if not hand((True, item)):
                    return
            hand((False, None))
        except BaseException as exc:  # handed to the caller, raised there
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

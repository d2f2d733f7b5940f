"""Stretches of work that Ctrl-C must not cut in two: the interrupt is held until the stretch ends."""
from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold SIGINT (Ctrl-C) while the block runs, then deliver it to the handler it would have
    reached (Python's raises KeyboardInterrupt): a block that updates several objects (a
    localizer's method, its decisions and its names) ends whole, and the interrupt arrives right
    after. Only the main thread can set a handler, and only it gets SIGINT: elsewhere (and
    with SIGINT ignored, or handled outside Python) the block runs as it is."""
    previous = signal.getsignal(signal.SIGINT) if threading.current_thread() is threading.main_thread() else None
    if previous is None or previous == signal.SIG_IGN:
        yield
        return
    came: list[int] = []

    def held(signum: int, frame: FrameType | None) -> None:
        came.append(signum)

    signal.signal(signal.SIGINT, held)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)  # runs a SIGINT still pending with `held` first
        if came:
            signal.raise_signal(signal.SIGINT)

"""Arrays whose memory serves again once nothing refers to them any more.

Fresh memory is paid in page faults: the operating system zeroes every new page on first touch.
A run's pipeline hands out large arrays at a steady pace (difference blocks of 256 or 1,024 rows
against the whole map, the rows read ahead: their contrast and sorted values), and on this
project's 2-core machine zeroing their pages took about 2 of a cold catgraph run's 27 CPU-s at
N = 35,000 (docs/scaling.md). Nothing here loads numba.
"""
from __future__ import annotations

import weakref
from collections import deque

import numpy as np
from numpy.typing import DTypeLike, NDArray


class RecycledArrays:
    """C-contiguous arrays of one dtype, each over memory that a released array had.

    An array is handed out over a memoryview of its memory, so numpy bases every view of it (a
    row, a slice) on that array; only when the last of them is gone does the memory return to the
    free list (from whichever thread lets go). A caller that keeps its arrays simply gets fresh
    memory."""

    def __init__(self, dtype: DTypeLike) -> None:
        self.dtype = np.dtype(dtype)
        self._free: deque[NDArray] = deque()

    def take(self, shape: tuple[int, ...]) -> NDArray:
        """An uninitialised array of ``shape``, of free memory when some is large enough."""
        size = int(np.prod(shape))
        memory = None
        while self._free and memory is None:
            candidate = self._free.popleft()
            memory = candidate if candidate.size >= size else None
        memory = np.empty(size, dtype=self.dtype) if memory is None else memory
        array = np.frombuffer(memoryview(memory), dtype=self.dtype, count=size)  # based on no array:
        weakref.finalize(array, self._free.append, memory)  # every view of it is based on it
        return array.reshape(shape)

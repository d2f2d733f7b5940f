"""CAT-Graph's sequence-score step, compiled: one pass over speeds x nodes per frame
(``wiloc.methods.catgraph`` imports it with its first frame, so the command line loads no numba)."""
from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def advance(score: NDArray[np.float64], at: NDArray[np.intp], a: NDArray[np.float64],
            contrast: NDArray[np.float64], rate: float) -> NDArray[np.float64]:
    """The leaky sequence score one frame on: ``score`` read where ``catgraph._shifted_reads``
    says, linearly interpolated (the score ending at node j continues the one that ended a step
    back), times 1 - rate, plus rate times this frame's ``contrast``. One pass: the numpy
    expression ``(1 - rate) * ((1 - a) * prev[at] + a * prev[at + 1]) + rate * contrast``, value
    for value."""
    prev = score.ravel()
    out = np.empty_like(prev)
    n = contrast.size
    for k in range(prev.size):
        out[k] = (1.0 - rate) * ((1.0 - a[k]) * prev[at[k]] + a[k] * prev[at[k] + 1]) + rate * contrast[k % n]
    return out.reshape(score.shape)

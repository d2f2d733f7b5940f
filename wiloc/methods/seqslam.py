"""SeqSLAM (Milford and Wyeth, ICRA 2012) as a causal method, with OpenSeqSLAM's published defaults.

Each query frame's difference row is locally contrast-enhanced along the map (each difference
minus the mean of the map frames within +-R/2, over their standard deviation), then every map
node j is scored by the lowest, over a range of velocities, sum of enhanced differences along the
straight trajectory of the last ``ds`` query frames that ends at j. The match is the node of lowest
score; its uniqueness (OpenSeqSLAM's ratio of that score to the lowest outside +-Rwindow/2 of it)
becomes the confidence 1 - ratio: a heuristic, like the threshold baseline's, not a probability.

Unlike OpenSeqSLAM, whose trajectories are centred on the frame they decide, a trajectory here
ends at the frame decided, so a decision never waits for later frames (streaming and batch decide
the same). docs/seqslam.md gives every choice and its source.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.decisions import Decision
from wiloc.errors import ParameterError, WilocError
from wiloc.methods.base import MapContext, Method
from wiloc.parameters import Parameters, param

MAX_VELOCITIES = 1000  # a v_min..v_max range finer than this is surely a typo (and slow)
FLAT = 1e-12  # a window whose std is within this share of its mean is flat: it enhances to 0


@dataclass(frozen=True)
class SeqSLAMParams(Parameters):
    """Parameters of SeqSLAM; the defaults are OpenSeqSLAM's (``defaultParameters.m``)."""

    owner = "seqslam"
    ds: int = param(10, "Sequence length: the query frames each trajectory spans, ending at the frame "
                        "decided.", low=1, high=10_000)
    v_min: float = param(0.8, "Slowest velocity searched, in map frames per query frame (below 0: the "
                              "route travelled backwards).", low=-1000.0, high=1000.0)
    v_max: float = param(1.2, "Fastest velocity searched, in map frames per query frame.",
                         low=-1000.0, high=1000.0)
    v_step: float = param(0.1, "Step between the velocities searched.", low=0.0, low_open=True)
    enhance_window: int = param(10, "Local contrast enhancement window R: a difference is compared with "
                                    "those to the map frames within +-R/2.", low=2)
    unique_window: int = param(10, "Uniqueness window Rwindow: the second-best score is the lowest "
                                   "outside +-Rwindow/2 map frames of the best.", low=0)

    def check(self) -> None:
        if self.v_min > self.v_max:
            raise ParameterError("v_max", f"must be >= v_min ({self.v_min:g}), got {self.v_max:g}")
        if self.velocities().size > MAX_VELOCITIES:
            raise ParameterError("v_step", f"gives more than {MAX_VELOCITIES} velocities from v_min to v_max, "
                                           f"got {self.v_step:g}")

    def velocities(self) -> NDArray[np.float64]:
        """v_min, v_min + v_step, ... up to v_max (included within rounding)."""
        steps = min((self.v_max - self.v_min) / self.v_step, MAX_VELOCITIES)  # v_step 1e-320: inf steps
        count = int(np.floor(steps + 1e-9)) + 1
        return np.round(self.v_min + self.v_step * np.arange(min(count, MAX_VELOCITIES + 1)), 9)


def enhance(rows: NDArray[np.floating], half_window: int) -> NDArray[np.float64]:
    """OpenSeqSLAM's local contrast enhancement of difference rows (one row per query frame):
    each value minus the mean of the values within +-``half_window`` map frames of it (fewer at
    the map's ends), over their sample standard deviation; 0 where those values are flat.

    Two exact passes (the sum, then the squared deviations from the mean), each ``2 h + 1``
    shifted slices of the rows: O(h x rows x nodes), no window array in memory.
    """
    x = np.asarray(rows, dtype=np.float64)
    n = x.shape[-1]
    half_window = min(half_window, n)  # the whole map: wider shifts overlap none of it (and would fill memory)
    shifts = [(d, max(0, -d), min(n, n - d)) for d in range(-half_window, half_window + 1)]
    total, count = np.zeros_like(x), np.zeros(n, dtype=np.float64)
    for d, lo, hi in shifts:
        if lo < hi:
            total[..., lo:hi] += x[..., lo + d:hi + d]
            count[lo:hi] += 1.0
    mean = total / count
    squares = np.zeros_like(x)
    for d, lo, hi in shifts:
        if lo < hi:
            squares[..., lo:hi] += (x[..., lo + d:hi + d] - mean[..., lo:hi]) ** 2
    sd = np.sqrt(squares / np.maximum(count - 1.0, 1.0))
    flat = ~(sd > FLAT * np.abs(mean))
    return np.where(flat, 0.0, (x - mean) / np.where(flat, 1.0, sd))


def lowest_enhanced(n_nodes: int, half_window: int) -> float:
    """The lowest value :func:`enhance` can give: -(n - 1) / sqrt(n) for a window of n values
    (one low value among n - 1 equal ones). Adding its negation makes every value >= 0, as
    OpenSeqSLAM's subtracting the whole matrix's minimum does (which a causal method cannot know)."""
    n = min(2 * half_window + 1, n_nodes)
    return -(n - 1) / np.sqrt(n)


def trajectory_offsets(velocities: NDArray[np.float64], ds: int) -> NDArray[np.int64]:
    """(trajectories x ds): how many map frames before its end each trajectory is ``lag`` query
    frames before the frame decided (the nearest frame to v x lag); velocities giving the same
    frames count once."""
    lags = np.arange(ds, dtype=np.float64)
    offsets = np.floor(velocities[:, None] * lags[None, :] + 0.5 + 1e-9).astype(np.int64)
    return np.unique(offsets, axis=0)


def _add_shifted(out: NDArray[np.float64], row: NDArray[np.float64], shift: int) -> None:
    """out[j] += row[j - shift], the index clamped to the map (a trajectory leaving the map
    stays at its first or last frame)."""
    n = row.size
    shift = min(max(shift, -n), n)
    if shift >= 0:
        out[shift:] += row[:n - shift]
        out[:shift] += row[0]
    else:
        out[:n + shift] += row[-shift:]
        out[n + shift:] += row[-1]


class SeqSLAM(Method):
    """Match sequences, not frames: the map node ending the best straight trajectory of the last
    ``ds`` query frames, over a range of velocities, on locally contrast-enhanced differences.

    Each decision is that node, its difference in the frame's own row, the confidence
    1 - best / second (second: the lowest score outside +-``unique_window``/2 nodes; a heuristic
    in [0, 1], not calibrated) and the ``score`` (the best trajectory's sum, enhanced values
    shifted to be >= 0). The first ``ds`` - 1 frames use the frames there are.
    """

    name = "seqslam"
    Params = SeqSLAMParams
    needs = frozenset({"map"})
    columns = ("score",)
    ranks = False  # the match is the best trajectory's end, not the row's best
    params: SeqSLAMParams

    def prepare(self, context: MapContext) -> None:
        if context.sequence or context.n_map < 1:
            raise WilocError("seqslam", "needs a map (a reference trajectory)", parameter="reference")
        p = self.params
        self._offsets = trajectory_offsets(p.velocities(), p.ds)
        self._shift = -lowest_enhanced(context.n_map, p.enhance_window // 2)
        self._recent = np.zeros((p.ds, context.n_map), dtype=np.float64)  # ring: frame k in slot k % ds

    def ahead(self, rows: NDArray[np.floating]) -> list[NDArray[np.float64]]:
        """Each row's enhanced differences, shifted to be >= 0: row by row, whose passes stay in
        the CPU's cache (3x faster than a block at once at 35,000 map frames)."""
        return [enhance(row, self.params.enhance_window // 2) + self._shift for row in rows]

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        n, k, ds = self._recent.shape[1], self.frames, self.params.ds
        if row.shape != (n,) or not np.all(np.isfinite(row)):
            raise WilocError("seqslam", f"query frame {k}: expected {n} finite values, one per map frame")
        self._recent[k % ds] = self.row_ahead(row)
        used = min(k + 1, ds)
        lowest = np.full(n, np.inf)
        score = np.empty(n)
        for offsets in self._offsets:
            score[:] = 0.0
            for lag in range(used):
                _add_shifted(score, self._recent[(k - lag) % ds], int(offsets[lag]))
            np.minimum(lowest, score, out=lowest)
        match = int(np.argmin(lowest))
        best = float(lowest[match])
        half = self.params.unique_window // 2
        outside = np.concatenate((lowest[:max(0, match - half)], lowest[match + half + 1:]))
        second = float(outside.min()) if outside.size else np.nan
        confidence = 1.0 - best / second if second > 0 else 0.0
        return Decision(match=match, difference=float(row[match]), confidence=confidence, stage="track",
                        extra={"score": best})

    def facts(self) -> dict[str, Any]:
        return {"velocities": self.params.velocities().tolist(), "trajectories": len(self._offsets)}

    def save_state(self) -> dict[str, Any]:
        return {"recent": self._recent.copy()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        assert self.context is not None  # restore() sets it first
        self.prepare(self.context)
        recent = np.asarray(state["recent"], dtype=np.float64)
        if recent.shape != self._recent.shape:
            raise WilocError("seqslam", f"the saved state holds {recent.shape} enhanced rows, "
                                        f"expected {self._recent.shape}: another map or ds")
        self._recent = recent.copy()

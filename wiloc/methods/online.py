"""The online, training-free probability model (paper III.D and Appendix, SPEC.md section 4).

Each query frame's best match z and difference m = min d_k feed two histograms
that the run fills itself, without labels: during initialisation the minima go to the
different-place histogram ``c``; afterwards each frame's minimum goes to the same-place histogram
``b`` and its smallest difference to a frame that is *not* the same place as z (``m_r``) goes to
``c``. The Appendix's recursive test, repaired and made iterative, decides which frames are the
same place as z. The confidence is calibrated by a CAT-Graph filter run alongside on the same
rows: along the map, or in sequence mode along the traversal itself. See docs/algorithm.md for
every choice and the measurements behind the defaults.

The Appendix's pseudo-code by name: ``mainFunction`` is :meth:`Online.decide` ((m, z) =
min(d_k)); ``initialize`` is the initialization stage (the first ``init`` frames, the Appendix's
startFrame; in map mode the map's own minima, :func:`map_minima`), each adding d_min of eq. 11 to
c; ``calcProb`` then ``updateProb`` are the update stage: the confidence first (here the filter's
posterior, not eq. 2's P(L | m): docs/algorithm.md), then m into b, m_r ("the second-smallest
difference value that does not come from the same location", III.D) into c, and match(k) := z.
``recursiveUpdate`` is :func:`near_miss`; the Appendix's ``match`` array is ``Online._match``.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from wiloc.candidates import RANKED, finite_minimum
from wiloc.decisions import Decision
from wiloc.errors import WilocError
from wiloc.methods.base import MapContext, Method, self_summary
from wiloc.methods.catgraph.filter import CatGraph
from wiloc.model import HistogramModel
from wiloc.parameters import Parameters, param


@dataclass(frozen=True)
class OnlineParams(Parameters):
    """Parameters of the online model (docs/algorithm.md gives the measurements behind each);
    ``seed=None`` draws a fresh seed, so that confidences differ from run to run."""

    owner = "online"
    init: int = param(100, "Sequence mode: initialisation frames, whose minima fill c (map mode "
                           "initialises from every map frame).", low=1, sequence_only=True)
    bins: int = param(100, "Bins of the learned histograms b and c (Figure 1, and the confidence appendix's "
                                "P(L | m); the decisions and the filter's confidence do not use them).", low=1,
                      high=100_000)
    same_place_window: int = param(2, "Frames within +-W of the best match are the same place when m_r "
                                            "is sought (the m_r column and c; not the decisions).", low=0)
    prior: float | None = param(None, "P(L) of the learned model's P(L | d) (Figure 1 and the confidence "
                                      "appendix; not used by the decisions), the prior that a frame revisits a "
                                      "place; default: the share of same-place samples.", low=0.0, high=1.0,
                                low_open=True, high_open=True)
    smoothing: float = param(0.1, "Pseudo-count added to every bin of the learned histograms (Figure 1 and "
                                   "the confidence appendix; not used by the decisions).", low=0.0, low_open=True)
    seed: int | None = param(0, "Random seed of the CAT-Graph filter whose posterior calibrates the "
                                "confidence: the same seed gives identical results.", low=0)
    confidence: Literal["filter", "appendix"] = param(
        "filter", "What the confidence is: filter, the CAT-Graph filter's probability that the best match is "
                  "the place (calibrated); appendix, the paper's P(L | m) from the learned histograms, with "
                  "P(new place) 1 - P(L | m) (to reproduce the paper; not calibrated: docs/calibration.md).")


def near_miss(row: NDArray[np.floating], z: int, match: NDArray[np.int64] | None,
              window: int) -> float:
    """m_r: the smallest difference in ``row`` to a frame that is not the same place as ``z``.

    The Appendix's recursive test (``recursiveUpdate``), repaired and iterative. The same-place
    set M starts as z and the frames within +-``window`` of z (all skipped). Candidates are visited
    once in increasing difference; a candidate z_r joins M when ``match[z_r]`` is in M or a member
    of M was matched to z_r (the Appendix tests min(M) alone; with the window min(M) is z - W, and
    z's own link to its earlier visit was lost). ``match`` holds -1 for frames never decided, which
    never passes the test; ``None`` in map mode, where candidates are reference frames that are
    never decided. NaN when no candidate is left.
    """
    low, high = max(0, z - window), min(row.size, z + window + 1)
    if match is None:  # map mode: M never grows, so m_r is the smallest finite difference outside z's window
        rest = (row[:low], row[high:])
        smallest = min(float(np.fmin.reduce(part, initial=np.inf)) for part in rest)  # NaN-blind, no copy
        if np.isfinite(smallest):
            return smallest
        finite = np.concatenate(rest)  # none finite, or a -inf to skip
        finite = finite[np.isfinite(finite)]
        return float(finite.min()) if finite.size else float("nan")
    # a batch run's row spans the whole traversal (inf past the candidates): frames within the
    # window that are not decided yet (the recent window narrower than it) have no match
    same = set(range(low, high))
    targets = {int(match[i]) if i < match.size else -1 for i in same}  # what the members of M were matched to
    for cand in _increasing(row):
        if cand in same:
            continue
        linked = int(match[cand])
        if (linked >= 0 and linked in same) or cand in targets:
            same.add(cand)
            targets.add(linked)
            continue
        return float(row[cand])
    return float("nan")


def _increasing(row: NDArray[np.floating], first: int = 32) -> Iterator[int]:
    """The finite candidates of ``row`` in increasing difference, ties in index order (a stable
    sort), found a few at a time: the near miss is nearly always among the first few, so the
    whole row is partitioned, not sorted (0.4 instead of 7 ms per frame at 35,000 candidates)."""
    index = np.flatnonzero(np.isfinite(row))
    values = row[index]
    k = first
    while index.size:
        take = values <= np.partition(values, k - 1)[k - 1] if index.size > k else np.ones(index.size, bool)
        chunk, chunk_values = index[take], values[take]
        yield from chunk[np.lexsort((chunk, chunk_values))].tolist()
        index, values = index[~take], values[~take]
        k *= 8


@dataclass(frozen=True)
class OnlineAhead:
    """What the online model reads off a row alone in map mode (:meth:`Online.ahead`)."""

    match: int  # the best match z (-1: none)
    difference: float  # its difference m
    near_miss: float  # m_r: the smallest difference outside z's window
    ranking: tuple[int, ...]  # the row's best candidates, best first
    same_bin: int  # the histogram bin of m
    near_bin: int  # ... and of m_r
    filter: Any  # what the map filter computes ahead (CatGraph.ahead)


def map_minima(context: MapContext) -> NDArray[np.float64]:
    """Each map frame's smallest difference to the map frames outside its +-R: the samples that
    initialise ``c`` in map mode (frames with no such difference give none)."""
    minima = self_summary(context).minima
    return minima[np.isfinite(minima)]


class Online(Method):
    """The online model: decide the best match z, then learn from the frame (SPEC.md section 4).

    The confidence is the probability that z is the place (within +-2 nodes), given every frame so
    far: the posterior of a CAT-Graph filter run alongside on the same rows, along the map or in
    sequence mode along the traversal itself (``wiloc.methods.catgraph``); P(new place) is the
    filter's. The decision stays the single-frame best match, and the histograms are learned in
    both modes (the paper's Figure 1). ``confidence="appendix"`` reports the paper's own P(L | m)
    from those histograms instead (SPEC.md section 4), uncalibrated, to reproduce the paper.
    """

    name = "online"
    Params = OnlineParams
    needs = frozenset({"map_self", "map_neighbours"})
    columns = ("m_r", "new_place")
    params: OnlineParams

    def query_problem(self, n_frames: int, sequence: bool, exclude_recent: int) -> str | None:
        init, R = self.params.init, exclude_recent
        if sequence and n_frames <= init + R:
            return f"has {n_frames} frames, too few for init={init} with exclude_recent={R}"
        return None

    def prepare(self, context: MapContext) -> None:
        self._model: HistogramModel | None = None
        self._seen: list[float] = []
        self._match = np.empty(0, dtype=np.int64)  # sequence mode: recorded matches, for near_miss
        if not context.sequence:
            self._seen = map_minima(context).tolist()
            if not self._seen:
                raise WilocError("online", "the map's differences to itself hold no finite value")
            self._model = self._initial_model()
        self._filter = CatGraph(seed=self.params.seed)
        self._filter.start(context)

    def _initial_model(self) -> HistogramModel:
        """The model at the end of initialisation: range fixed from the minima seen, which fill c."""
        p = self.params
        values = np.asarray(self._seen, dtype=np.float64)
        model = HistogramModel.from_values(values, p.bins, smoothing=p.smoothing, prior=p.prior)
        model.add_different(values)
        return model

    def ahead(self, rows: NDArray[np.floating]) -> list[OnlineAhead] | None:
        """Map mode: each row's best match, its difference, near miss and ranking (one compiled
        pass over the rows) and what the map filter computes ahead; nothing in sequence mode,
        where the near miss depends on the matches of earlier frames."""
        from wiloc.methods.row_kernels import best_of_rows  # numba loads with the first rows

        if self.context is None or self.context.sequence:
            return None
        n = rows.shape[0]
        ranking, counts = np.empty((n, RANKED), dtype=np.int64), np.empty(n, dtype=np.intp)
        match, minimum, near = np.empty(n, dtype=np.intp), np.empty(n), np.empty(n)
        best_of_rows(rows, self.params.same_place_window, ranking, counts, match, minimum, near)
        assert self._model is not None  # map mode: the bins are fixed from the start
        same, different = self._model.bin_of(minimum).tolist(), self._model.bin_of(near).tolist()
        filtered = self._filter.ahead(rows)
        return [OnlineAhead(int(match[r]), float(minimum[r]), float(near[r]), tuple(ranking[r, :counts[r]].tolist()),
                            same[r], different[r], filtered[r]) for r in range(n)]

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        sequence = self.context is not None and self.context.sequence
        pre = None if sequence else self.row_ahead(row)
        # in sequence mode the filter sees every frame (its map grows with the traversal)
        tracked = self._filter.step(row) if sequence else None
        z, m = finite_minimum(row) if pre is None else (pre.match, pre.difference)
        decision = Decision(match=-1, difference=np.nan, confidence=np.nan, stage="none", extra={"m_r": np.nan})
        if z >= 0 and self._model is None:
            self._seen.append(m)
            if len(self._seen) == self.params.init:
                self._model = self._initial_model()
            decision = Decision(match=-1, difference=np.nan, confidence=np.nan, stage="init",
                                extra={"m_r": np.nan})
        elif z >= 0:
            assert self._model is not None
            if tracked is None:
                if self.passed:  # query frames left out since the last step: the filter's step covers them
                    self._filter.skip(self.passed)
                new_place = self._filter.step(row, ahead=None if pre is None else pre.filter).new_place
            else:  # before the traversal's map has 2 frames nothing is a revisit
                new_place = tracked.new_place if tracked.decided else 1.0
            if self.params.confidence == "appendix":  # the histograms as they are: the frame is not yet in them
                p = float(self._model.posterior(m))
                new_place = 1.0 - p
            else:
                p = self._filter.probability_near(z)
            if pre is None:
                m_r = near_miss(row, z, self._match[:self.frames], self.params.same_place_window)
                self._model.add_same(m)
                if np.isfinite(m_r):
                    self._model.add_different(m_r)
            else:
                m_r = pre.near_miss
                self._model.count_bins(pre.same_bin, pre.near_bin if np.isfinite(m_r) else None)
            decision = Decision(match=z, difference=m, confidence=p, stage="update", new_place=new_place,
                                extra={"m_r": m_r}, ranking=() if pre is None else pre.ranking)
        if sequence:
            self._record(decision.match)
        return decision

    def _record(self, match: int) -> None:
        """Record this frame's match (the array's capacity doubles, so appends are O(1))."""
        n = self.frames
        if n == self._match.size:
            self._match = np.concatenate([self._match, np.full(max(16, n), -1, dtype=np.int64)])
        self._match[n] = match

    @property
    def model(self) -> HistogramModel | None:
        if self._model is None and getattr(self, "_seen", None):
            return self._initial_model()  # a run that never left initialisation: c as learned
        return getattr(self, "_model", None)

    def facts(self) -> dict[str, Any]:
        return {"sequence": bool(self.context and self.context.sequence), "init_frames": len(self._seen)}

    def save_state(self) -> dict[str, Any]:
        return {"seen": np.asarray(self._seen, dtype=np.float64), "match": self._match[:self.frames].copy(),
                "filter": self._filter.state(), "model": None if self._model is None else self._model.to_dict()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self._seen = np.asarray(state["seen"], dtype=np.float64).tolist()
        self._match = np.asarray(state["match"], dtype=np.int64).copy()
        self._model = None if state["model"] is None else HistogramModel.from_dict(state["model"])
        self._filter = CatGraph(seed=self.params.seed)
        self._filter.restore(self.context, state["filter"])  # type: ignore[arg-type]

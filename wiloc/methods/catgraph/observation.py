"""What makes the filter's confidences probabilities, learned online and without labels (SPEC 8).

Three pieces, used by the CAT-Graph filter (``wiloc.methods.catgraph.filter``); docs/calibration.md gives
the derivation and the measurements behind every default.

- ``RankLikelihood``: the observation model (in place of the paper's eq. 8 ratio P(d | x) / P(d)
  of histograms). A difference d in query frame k's row is scored by its mid-rank p-value
  within that row, u = (#{j: d_kj < d} + 1/2) / N, t = -ln u (tied values take their group's
  lowest rank; docs/catgraph-research.md, "Tied differences"). At the same
  place u follows Beta(a, 1), elsewhere Uniform(0, 1), so the likelihood ratio is
  lambda = a u^(a - 1): proper (its mean over a uniform u is 1; over a row's N ranks (r + 1/2) / N
  a little less: 0.91 at a = 0.32 and N = 200, 0.98 at N = 35,000), monotone in d, with
  no smoothing, floor or cap. FAB-MAP's evidence rows are ranked negated (-log-ratio as the
  difference): their scale, hundreds of nats, no longer reaches the posterior. ``a`` is learned by EM from the filter's own posterior (the run
  labels its own samples, as the paper's Appendix does), starting from ``a0`` with weight ``n0``.
  Each node's rank is read against its own chance resemblance (a node of a generic scene ranks
  low in many rows): t is divided by the mean t the node has had in the run's rows (never
  below 1), learned online as ``a`` is.
- ``novelty_weights``: map frames that nearly repeat their neighbours (a stopped vehicle) are not
  independent evidence; at node j the model uses a_j = 1 - omega_j (1 - a) (in sequence mode
  from bounds of the steps: ``wiloc.methods.catgraph.self_map``).
- ``Unexplained`` (in place of the paper's new location particle, eqs 9-10): a two-state chain
  for "the frame is not explained by the map" (a new place or a blind spot of the map), with
  hazards of leaving and re-entering the map and a small chance of
  jumping elsewhere on it; the share of unexplained stretches that are departures (not blind
  spots) is learned from the stretches the run has completed. P(new place) = q U.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from wiloc.recycled import RecycledArrays


def novelty_weights(neighbours: NDArray[np.float64], threshold: float,
                    median: float | None = None) -> NDArray[np.float64]:
    """omega_j = min(1, c_j / (threshold * median)), c_j node j's mean difference to its two
    neighbours on the map (``neighbours[j]`` = d(j, j + 1)) and ``median`` theirs (computed when
    not given); all ones when ``threshold`` is 0."""
    n = neighbours.size + 1
    if threshold <= 0 or n < 2:
        return np.ones(n)
    c = np.empty(n)
    c[0], c[-1] = neighbours[0], neighbours[-1]
    c[1:-1] = 0.5 * (neighbours[:-1] + neighbours[1:])
    median = float(np.median(neighbours)) if median is None else median
    if median <= 0:
        return np.ones(n)
    c /= threshold * median
    return np.minimum(np.maximum(c, 0.0, out=c), 1.0, out=c)  # np.clip's values, in a tenth of its time


def rank_table(n: int) -> NDArray[np.float64]:
    """-ln u of each left rank 0..n in rows of n values: u = (rank + 1/2) / n."""
    return -np.log((np.arange(n + 1) + 0.5) / n)


class RankLikelihood:
    """Beta(a, 1) against Uniform(0, 1) on a difference's rank within its own row, each node's
    rank read against how often that node resembles frames by chance; a by EM.

    The observation model of a filter over difference rows: :meth:`use_row` for each frame, then
    :meth:`at` the particles' positions and :meth:`mean` over the map, :meth:`learn` after the
    frame's posterior is known.

    Chance resemblance (hubs): a map frame of a generic scene (a stretch of forest, a blank wall)
    ranks low in many query rows whatever the place, so a low rank there is weaker evidence than
    the uniform null assumes. Node j's t = -ln u is divided by its *chance scale* m_j, the mean
    t it has had in the run's rows so far, with a prior of 1 worth ``hub_weight`` frames: under
    the null t / m_j is again Exp(1), so the ratio stays proper. Every row counts for every
    node, the few taken at its place too, so look-alike places keep equal evidence (rows taken
    away from a node only would teach the place the posterior doubts that it resembles by chance,
    and hand the track to its look-alike). m_j is never taken below 1: a node that rarely
    resembles anything is not trusted more than a uniform rank (its tail is the least known).
    """

    def __init__(self, a0: float, n0: float, a_min: float, hub_weight: float = 0.0) -> None:
        self.a_min = a_min
        self.hub_weight = hub_weight
        self.s0, self.s1 = n0, n0 / a0  # EM sufficient statistics: weight and weighted sum of t
        self.chance_sum, self.chance_count = np.zeros(0), np.zeros(0)  # per node: weighted sum of t, weight
        self._sorted = np.empty(0)  # the current row, sorted
        self._row = np.empty(0)
        self._table = np.empty(0)  # t of each left rank 0..N for rows of N values
        self._nodes_t = np.empty(0)  # t of every node in the current row (unscaled)
        self._scale = np.ones(0)  # each node's chance scale m_j for the current row
        self._t = np.empty(0)  # t / m at the particles of the current frame

    @property
    def a(self) -> float:
        """The current shape: S0 / S1, kept in [a_min, 1] (1: no evidence at all)."""
        return min(1.0, max(self.a_min, self.s0 / self.s1))

    def order(self, rows: NDArray[np.floating], memory: RecycledArrays | None = None) -> NDArray[np.floating]:
        """What :meth:`use_row` ranks against, for each of a block of rows: the row sorted (as
        float32 when its values are float32 values, as the difference kernels give them: that
        sort took 0.07 ms against float64's 0.18 ms and an argsort's 0.34 ms at 35,000 nodes).
        Sorted float32 rows go to ``memory`` when given (a run's recycled float32 arrays)."""
        narrow = rows.astype(np.float32, copy=False)
        if narrow is rows or np.array_equal(narrow, rows):
            ordered = np.empty(rows.shape, np.float32) if memory is None else memory.take(rows.shape)
            ordered[...] = narrow
            ordered.sort(axis=1)
            return ordered
        return np.sort(rows, axis=1)

    def use_row(self, row: NDArray[np.float64], ordered: NDArray[np.floating] | None = None) -> None:
        """Rank later differences against this query row (finite values), given its
        :meth:`order` when that was computed ahead; every node's rank and chance scale."""
        from wiloc.methods.catgraph.rank_kernels import chance_scale  # numba loads with the first frame

        self._row = row
        self._sorted = self.order(row[None, :])[0] if ordered is None else ordered
        n = row.size
        self._nodes_t = self.t(row)
        if self.chance_sum.size < n:  # sequence mode: the map grew
            grown = n - self.chance_sum.size
            self.chance_sum = np.concatenate((self.chance_sum, np.zeros(grown)))
            self.chance_count = np.concatenate((self.chance_count, np.zeros(grown)))
        if self._scale.size != n:
            self._scale = np.ones(n)
        if self.hub_weight > 0:
            chance_scale(self.chance_sum, self.chance_count, self.hub_weight, self._scale)

    def _ranks_of(self, n: int) -> NDArray[np.float64]:
        """The table of -ln u for rows of n values (kept for the next row of that length)."""
        if self._table.size != n + 1:
            self._table = rank_table(n)
        return self._table

    def at(self, j: NDArray[np.intp], frac: NDArray[np.float64], omega: NDArray[np.float64]) -> NDArray[np.float64]:
        """ln lambda at positions a ``frac`` of the way from node j to j + 1 (the difference and
        the chance scale interpolated there), each with its near-duplicate weight ``omega``."""
        from wiloc.methods.catgraph.rank_kernels import rank_log_ratio  # numba loads with the first frame

        self._t, out = np.empty(j.size), np.empty(j.size)
        rank_log_ratio(self._row, self._sorted, self._ranks_of(self._row.size), self._scale, j, frac, omega, self.a,
                       self._t, out)
        return out

    def mean(self, omega: NDArray[np.float64]) -> float:
        """ln of the mean lambda over every map node: the evidence for "somewhere on the map"."""
        from wiloc.methods.catgraph.rank_kernels import ratio_sum  # numba loads with the first frame

        return float(np.log(ratio_sum(self._nodes_t, self._scale, omega, self.a))) - np.log(self._row.size)

    def t(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        """-ln u of each difference: its rank p-value in the row (ties at their lowest rank)."""
        from wiloc.methods.catgraph.rank_kernels import table_at_ranks  # numba loads with the first frame

        t = np.empty(d.size)
        table_at_ranks(self._sorted, self._ranks_of(self._row.size), d, t)
        return t

    def log_ratio(self, t: NDArray[np.float64], omega: NDArray[np.float64]) -> NDArray[np.float64]:
        """ln lambda = ln a_j + (1 - a_j) t, a_j = 1 - omega (1 - a)."""
        a = 1.0 - omega * (1.0 - self.a)
        return np.log(a) + (1.0 - a) * t

    def learn(self, weight: NDArray[np.float64], in_map: float) -> None:
        """EM step: the frame's posterior weights of the particles (times their near-duplicate
        weight, and the probability that the map explains the frame) add to the statistics of
        a; every node's t to its chance statistics."""
        self.s0 += in_map * float(weight.sum())
        self.s1 += in_map * float(np.dot(weight, self._t))
        n = self._nodes_t.size
        self.chance_sum[:n] += self._nodes_t
        self.chance_count[:n] += 1.0

    def state(self) -> dict[str, Any]:
        return {"s0": self.s0, "s1": self.s1, "chance_sum": self.chance_sum.copy(),
                "chance_count": self.chance_count.copy()}

    def load(self, state: dict[str, Any]) -> None:
        self.s0, self.s1 = float(state["s0"]), float(state["s1"])
        self.chance_sum = np.asarray(state["chance_sum"], dtype=np.float64).copy()
        self.chance_count = np.asarray(state["chance_count"], dtype=np.float64).copy()


@dataclass(frozen=True)
class Transition:
    """Prior masses of the next frame's three hypotheses, from the previous U."""

    track: float  # the particles move on as the motion model says
    jump: float  # somewhere else on the map (carried by re-seeded particles)
    unexplained: float  # a new place or a blind spot

    def beyond(self, share: float) -> Transition:
        """The masses when a ``share`` of the track's particle weight was carried past the map's
        ends: the query has left the mapped route there, a new place, so that share of the
        track's mass goes to the unexplained hypothesis."""
        share = min(max(share, 0.0), 1.0)
        return Transition(track=self.track * (1.0 - share), jump=self.jump,
                          unexplained=self.unexplained + self.track * share)


class Anchor(NamedTuple):
    """The last frame the map explained well, to reckon an unexplained stretch from: where the
    track was, how far the query had travelled, and its pace and motion noise there."""

    frame: int
    odometer: float
    position: float
    pace: float
    sigma: float


class Unexplained:
    """The probability U that the map does not explain the current frame, and the learned share
    q of unexplained stretches that are departures from the map (P(new place) = q U).

    A stretch opens when U reaches ``open_at`` after an anchor frame (U below ``close_at``) and
    closes when U falls below ``close_at`` again; it was a blind spot when the track resumed
    within 2 + 3 sigma sqrt(frames since the anchor) nodes of the anchor dead-reckoned at the
    track's pace there, else a departure. q has a Beta prior (``q_prior``: departures, blind spots).
    """

    def __init__(self, u0: float, h_in: float, h_out: float, jump: float, q_prior: tuple[float, float],
                 open_at: float, close_at: float) -> None:
        self.u = u0
        self.h_in, self.h_out, self.jump = h_in, h_out, jump
        self.q_prior, self.open_at, self.close_at = q_prior, open_at, close_at
        self.departures = 0.0
        self.blind_spots = 0.0
        self.anchor: Anchor | None = None  # the last frame the map explained well
        self.in_stretch = False

    def transition(self, first: bool) -> Transition:
        """Prior masses for the next frame (the first frame has no jump: nothing to jump from)."""
        u, h_in, h_out, eps = self.u, self.h_in, self.h_out, self.jump
        if first:
            return Transition(track=1.0 - u, jump=0.0, unexplained=u)
        return Transition(track=(1.0 - u) * (1.0 - h_in) * (1.0 - eps),
                          jump=(1.0 - u) * (1.0 - h_in) * eps + u * h_out,
                          unexplained=(1.0 - u) * h_in + u * (1.0 - h_out))

    def update(self, log_map: float, unexplained: float) -> None:
        """Bayes: U = unexplained mass / (unexplained mass + the map's total mass exp(log_map))."""
        log_u = np.log(max(unexplained, 1e-300))
        self.u = float(np.exp(log_u - np.logaddexp(log_map, log_u)))

    @property
    def q(self) -> float:
        """P(an unexplained stretch is a departure from the map), as learned so far."""
        a_new, a_blind = self.q_prior
        return (a_new + self.departures) / (a_new + a_blind + self.departures + self.blind_spots)

    @property
    def new_place(self) -> float:
        return self.q * self.u

    def follow(self, frame: int, odometer: float, position: float, spacing: float, pace: float,
               sigma: float) -> None:
        """Track stretches: open, close (learning whether it was a departure), move the anchor.

        ``odometer`` is the distance travelled since the start, ``position`` the decided place's
        (both in the map's units); ``pace`` the decided track's pace (map distance per unit
        travelled, negative backwards) and ``sigma`` its motion noise per frame in node spacings.
        A blind spot is reckoned across at the pace the query kept where the map last explained
        it: reckoned at the map's pace, every blind spot of a query at another pace was counted
        a departure.
        """
        if not self.in_stretch and self.u >= self.open_at and self.anchor is not None:
            self.in_stretch = True
        elif self.in_stretch and self.u < self.close_at:
            self.in_stretch = False
            at = self.anchor
            assert at is not None  # a stretch opens only after an anchor
            reckoned = at.position + at.pace * (odometer - at.odometer)
            blind = bool(abs(position - reckoned) <= 2 * spacing + 3 * at.sigma * spacing * np.sqrt(frame - at.frame))
            self.blind_spots += blind
            self.departures += not blind
        if self.u < self.close_at and not self.in_stretch:
            self.anchor = Anchor(frame, odometer, position, pace, sigma)

    def state(self) -> dict[str, Any]:
        return {"u": self.u, "departures": self.departures, "blind_spots": self.blind_spots,
                "anchor": None if self.anchor is None else list(self.anchor), "in_stretch": self.in_stretch}

    def load(self, state: dict[str, Any]) -> None:
        self.u = float(state["u"])
        self.departures, self.blind_spots = float(state["departures"]), float(state["blind_spots"])
        anchor = state["anchor"]
        self.anchor = None if anchor is None else Anchor(int(anchor[0]), *(float(value) for value in anchor[1:]))
        self.in_stretch = bool(state["in_stretch"])

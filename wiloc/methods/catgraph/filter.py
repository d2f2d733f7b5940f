"""Whole-image CAT-Graph: a particle filter along the reference trajectory (paper III.C, eqs 7-10).

The reference traversal is a trajectory: node j sits at arc length s_j. M particles live at
continuous positions on it, each moving at its own pace (map nodes per query frame: one drawn
from a prior over paces at the start, the map's pace the likeliest, or the pace of the sequence
trajectory it was re-seeded on; drifting too when ``speed_noise`` > 0). Per query frame: move the particles, re-seed a few at the best nodes of a
causal sequence score (a leaky sum of contrast-normalised differences along straight trajectories
at several paces), weight each by the likelihood ratio of the difference interpolated at its
position (eq. 8), weigh the hypothesis that the map does not explain the frame (a new place or a
blind spot: eq. 10's role), normalise, read out the mode of the particle density and resample when
the effective sample size drops.

Without a map (sequence mode: loop closure within one traversal) the map is the traversal's own
frames older than ``exclude_recent`` + ``frontier``, one node more per frame, and P(new place) is
the probability that it does not explain the frame.

The observation model and the unexplained state are the ones of ``wiloc.methods.catgraph.observation``: a
difference is scored by its rank within its own row (Beta(a, 1) at the same place, uniform
elsewhere, a learned online by EM), so the posterior is a probability: the confidence is the
posterior mass within +-``mode_window`` nodes of the decided node, times 1 - P(new place).
FAB-MAP's evidence rows (``log_ratio``, high = alike) are ranked the same way, negated: only
their order counts, never their scale (FAB-MAP's log-ratios span hundreds of nats).
docs/catgraph.md gives the formulation in full and docs/calibration.md the measurements behind
every default. The paper's eq. 1 runs as this particle filter, eq. 7 as ``_moved`` then ``weigh``, eq. 8
as ``locate`` then ``RankLikelihood.at``; eqs 9-10's new location particle is ``Unexplained``.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.decisions import Decision
from wiloc.errors import WilocError
from wiloc.methods.base import MapContext, Method
from wiloc.methods.catgraph.observation import RankLikelihood, Unexplained, novelty_weights
from wiloc.methods.catgraph.paces import (TINY, log_normal, odometry_factors, reseed_counts, sequence_paces,
                                          start_paces)
from wiloc.methods.catgraph.params import CatGraphParams
from wiloc.methods.catgraph.self_map import SelfMap
from wiloc.methods.catgraph.trajectory import (even_shifted_reads, locate, lowest_nodes, node_positions,
                                               posterior_ranking, read_runs, shifted_reads, smallest, systematic,
                                               track_pace)
from wiloc.recycled import RecycledArrays

MODE_TIE = 1e-12  # window masses (shares of a unit total) this close to the largest count as tied


@dataclass(frozen=True)
class RowAhead:
    """What the filter computes from a row alone (:meth:`CatGraph.ahead`)."""

    contrast: NDArray[np.float64]  # the sequence score's contrast-normalised row, low = alike
    finite: bool  # whether every value of the row is finite
    ordered: NDArray[np.floating]  # what the rank model ranks against: the row sorted


class CatGraph(Method):
    """Track the query along the reference trajectory with the whole-image CAT-Graph filter.

    Started on a map: the differences of each map frame to the next (to damp near-duplicates)
    and optionally its node positions (``MapContext.arclength``, from odometry; else the node
    index). Each step takes the query frame's differences to every map node and optionally its
    travelled distance since the previous frame (odometry, same units as the map's); without it,
    the mean node spacing. Re-seeding uses a causal sequence score per node: for each speed ratio
    in ``sequence_speeds`` an exponentially weighted (rate ``sequence_rate``) sum of contrast-
    normalised differences (+-``contrast_window`` nodes) along the trajectory ending there; the
    lowest over the forward speeds counts, and apart from it the lowest over the backward ones
    (negative speeds: the route driven the other way) and over those faster than ``fast_pace``,
    where shares ``reseed_backward`` and ``reseed_fast`` of the re-seeded particles go (speeds
    slower than ``rank_pace_min`` rank no node); each moves at the speed whose trajectory scored
    best at its node (half of the forward ones at the map's pace). The particles start at paces
    drawn from a prior (``start_paces``: the other paces' share of the mass). Once frames come
    with odometry, which measures the query's pace, a pace is its direction alone (the signs of
    ``sequence_speeds``) for the sequence score, and for each particle its direction times a
    factor of its own near 1 (``odometry_scale``), which the two odometries' scales may differ by.
    Each decision is the node at the density mode (the largest weight mass within
    +-``mode_window`` nodes; among tied nodes the one holding most weight itself), its difference,
    the confidence (that mass times 1 - P(new place)) and P(new place). The same seed gives
    identical decisions, on any CPU. In sequence mode (no map) the map grows with the traversal
    (:meth:`_grow`, :class:`~wiloc.methods.catgraph.self_map.SelfMap`: placed by its own odometry
    when it has one, near-duplicates damped). A particle carried past either end of the map is
    re-seeded; on a map its weight goes to the unexplained hypothesis (it left the mapped route).
    """

    name = "catgraph"
    Params = CatGraphParams
    needs = frozenset({"map_neighbours", "odometry"})
    rows = frozenset({"differences", "log_ratio"})
    columns = ("new_place",)
    ranks = True  # by the posterior: the mode, then the nodes of most particle weight (posterior_ranking)
    params: CatGraphParams

    def query_problem(self, n_frames: int, sequence: bool, exclude_recent: int) -> str | None:
        shortest = exclude_recent + self.params.frontier + 3  # a map of 2 frames, then a frame to decide
        if sequence and n_frames < shortest:
            return (f"has {n_frames} frames, too few for sequence mode with frontier={self.params.frontier} and "
                    f"exclude_recent={exclude_recent} (at least {shortest})")
        return None

    def prepare(self, context: MapContext) -> None:
        self._growing = context.sequence  # sequence mode: the map is the run's own older frames
        self._filtered = 0  # frames the filter has stepped (in sequence mode, once it has 2 nodes)
        self._odometry = False  # whether any step came with odometry
        if context.sequence:
            if context.arclength is not None:
                raise WilocError("catgraph", "takes no map odometry in sequence mode (the map is the traversal, "
                                             "placed by its own odometry: the query's)", parameter="map_odometry")
            self._nodes, self._self_map = np.empty(0), SelfMap()
            return
        if context.neighbours is None:
            raise WilocError("catgraph", "needs a map (a reference trajectory)", parameter="reference")
        neighbours = np.asarray(context.neighbours(), dtype=np.float64)
        n_nodes = neighbours.size + 1
        if n_nodes < 2:
            raise WilocError("catgraph", f"the map needs at least 2 frames, got {n_nodes}")
        omega = novelty_weights(neighbours, self.params.near_duplicate)
        if context.arclength is None and context.frame_positions is not None:  # frames left out: count them
            self._begin(np.asarray(context.frame_positions, dtype=np.float64), omega, self.params.unexplained0, 1.0)
            return
        self._begin(node_positions(context.arclength, n_nodes), omega, self.params.unexplained0)

    def _begin(self, nodes: NDArray[np.float64], omega: NDArray[np.float64], unexplained0: float,
               spacing: float | None = None) -> None:
        """The filter before its first frame, on a map of these node positions and near-duplicate
        weights, with this prior probability that the map does not explain the first frame. A
        query frame's step without odometry is ``spacing``, by default the mean node spacing (a
        map whose frames left out are counted in its positions: 1, one frame of its full order)."""
        p = self.params
        n_nodes = nodes.size
        self._nodes = nodes
        self._spacing = float((self._nodes[-1] - self._nodes[0]) / (n_nodes - 1)) if spacing is None else spacing
        self._omega = omega
        self._likelihood = self._observation_model()
        self._unexplained = Unexplained(unexplained0, p.leave, p.rejoin, p.jump, p.departure_prior,
                                        p.stretch_open, p.stretch_close)
        self._rng = np.random.default_rng(p.seed)
        # evenly spaced from one random offset (stratified): every stretch of the map starts with
        # its share of particles, so look-alike places start with equal mass
        self._pos = self._nodes[0] + (np.arange(p.particles) + self._rng.uniform()) / p.particles * (
            self._nodes[-1] - self._nodes[0])
        self._speed, self._log_w = start_paces(p)

        self._set_paces()
        self._sequence = np.zeros((self._paces.size, n_nodes))
        self._spare: NDArray[np.float64] | None = None  # memory for the next sequence score
        self._own = np.zeros(n_nodes)  # the last frame's in-map posterior mass per node
        self._marks = np.zeros(n_nodes, dtype=np.int64)  # the read-out's scratch: the frame that last summed a node
        self._odometer = 0.0  # distance travelled since the first frame, in the map's units
        self._shifted: tuple[float, tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.intp]]] | None = None
        self._last: NDArray[np.floating] | None = None  # the last row, to know a repeated image
        self._standing: NDArray[np.bool_] | None = None  # during a repeat: the particles that stand still
        self._repeat_pace = np.ones(0)  # ... and the factor of the pace of those that move on
        self._recycle()

    def _grow(self, n_nodes: int) -> None:
        """Sequence mode: the map extended to its first ``n_nodes`` frames (the filter started on
        the first two). A new node's sequence score starts at 0, a contrast-normalised row's mean;
        the particles stay where they are. Nodes whose steps the rows bound near 0 are damped."""
        omega = self._self_map.bounds.weights(n_nodes, self.params.near_duplicate)  # old nodes' too: bounds grow
        if self._nodes.size == 0:
            self._begin(self._self_map.trail.nodes(n_nodes), omega, 1.0 - self.params.rejoin)
            return
        old, self._omega = self._nodes.size, omega
        if n_nodes == old:
            return
        self._nodes = self._self_map.trail.nodes(n_nodes)
        self._spacing = float((self._nodes[-1] - self._nodes[0]) / (n_nodes - 1))
        sequence = np.zeros((self._paces.size, n_nodes))
        sequence[:, :old] = self._sequence
        self._sequence, self._spare = sequence, None
        self._group_lowest = np.empty((4, n_nodes))
        self._own = np.concatenate((self._own, np.zeros(n_nodes - old)))
        self._marks = np.concatenate((self._marks, np.zeros(n_nodes - old, dtype=np.int64)))
        self._shifted = None

    def _set_paces(self) -> None:
        """The sequence score's paces and their groups (:func:`~wiloc.methods.catgraph.paces.sequence_paces`)."""
        self._paces, self._groups = sequence_paces(self.params, self._odometry)
        self._group_lowest = np.empty((4, self._nodes.size))  # the score's lowest per group and node

    def _recycle(self) -> None:
        """Memory for what :meth:`ahead` computes, used again once its rows are stepped."""
        self._ahead_memory = RecycledArrays(np.float64)  # the rows' contrast
        self._sorted_memory = RecycledArrays(np.float32)  # their sorted values

    def _observation_model(self) -> RankLikelihood:
        """Ranks within each row: of the differences (whole images), or of FAB-MAP's negated
        log-likelihood ratios (``bow``), whose scale is then of no account."""
        p = self.params
        return RankLikelihood(p.a0, p.n0, p.a_min, p.hub_weight)

    @property
    def _sign(self) -> float:
        """What turns a row into differences (low = alike): -1 for FAB-MAP's evidence rows."""
        return -1.0 if self.context is not None and self.context.rows == "log_ratio" else 1.0

    def _shift_lookup(self, u: float) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.intp]]:
        """:func:`shifted_reads` for step u and their :func:`read_runs`: the same for every
        frame of equal step (always, without odometry), so they are computed once per distinct step."""
        if self._shifted is None or self._shifted[0] != u:
            shifts = self._paces * u
            if self._growing and not self._self_map.trail.odometry:  # the nodes 0, 1, ..., n - 1, one more each frame
                self._shifted = (u, even_shifted_reads(self._nodes.size, shifts))
            else:
                at, a = shifted_reads(self._nodes, shifts)
                self._shifted = (u, (at, a, read_runs(at, a, self._nodes.size)))
        return self._shifted[1]

    def _advance(self, sequence: NDArray[np.float64], contrast: NDArray[np.float64], u: float,
                 first: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The sequence score after a frame of this contrast and step u (a new array: the leaky
        sum along each speed's trajectory, causal, O(speeds x nodes)), and its lowest per group of
        speeds (:meth:`_set_paces`) and node, which re-seeding ranks nodes by."""
        from wiloc.methods.catgraph import filter_kernels  # numba loads with the first frame, not the command line

        lowest = self._group_lowest
        if first:
            lowest[:] = contrast
            return np.broadcast_to(contrast, sequence.shape).copy(), lowest
        spare = self._spare  # the score before last: its memory takes the new one (fresh pages cost faults)
        after = spare if spare is not None and spare.shape == sequence.shape else np.empty_like(sequence)
        filter_kernels.advance(sequence, *self._shift_lookup(u), contrast, self.params.sequence_rate,
                               self._groups, after, lowest)
        self._spare = sequence
        return after, lowest

    def ahead(self, rows: NDArray[np.floating]) -> list[RowAhead | None]:
        """Each row's contrast (low = alike), whether it is finite, and what the observation
        model ranks against: computed for a block of rows in compiled passes (None for rows
        that are not one value per map node)."""
        if self._growing or rows.shape[1] != self._nodes.size:  # sequence mode: the map grows as rows are decided
            return [None] * rows.shape[0]
        return self._ahead_rows(rows)

    def _ahead_rows(self, rows: NDArray[np.floating]) -> list[RowAhead]:
        """:meth:`ahead` of rows of one value per map node."""
        from wiloc.methods.catgraph import filter_kernels  # numba loads with the first frame, not the command line

        sign = self._sign
        contrast, finite = self._ahead_memory.take(rows.shape), np.empty(rows.shape[0], dtype=np.bool_)
        filter_kernels.contrast_rows(rows, self.params.contrast_window, sign, contrast, finite)
        ordered = self._likelihood.order(rows if sign > 0 else -rows, self._sorted_memory)
        return [RowAhead(contrast[r], bool(finite[r]), ordered[r]) for r in range(rows.shape[0])]

    def decide(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        from wiloc.methods.catgraph import rank_kernels  # numba loads with the first frame, not the command line
        from wiloc.methods.catgraph import filter_kernels

        if self._growing:  # sequence mode: the map is the run's frames before the recent window and the frontier
            n_map = self.frames - self.context.exclude_recent - self.params.frontier
            self._self_map.add(self.frames, odometry, row[:max(0, self.frames - self.context.exclude_recent)], n_map,
                               bounds=self._sign > 0)  # FAB-MAP's evidence bounds no step
            if not self._self_map.trail.spans(n_map):
                return Decision(match=-1, difference=float("nan"), confidence=float("nan"), stage="none")
            self._grow(n_map)
            row = row[:n_map]
            pre = self._ahead_rows(row[None, :])[0]
        p, rng, nodes = self.params, self._rng, self._nodes
        n_nodes = nodes.size
        if not self._growing:
            pre = self.row_ahead(row) if row.shape == (n_nodes,) else None
        if pre is None or not pre.finite:
            raise WilocError("catgraph", f"query frame {self.frames}: expected {n_nodes} finite values, one per map frame")
        first = self._filtered == 0
        self._filtered += 1
        if self._last is not None and np.array_equal(row, self._last):  # None before the first frame
            return self._repeat(row, odometry)
        self._last, self._standing = row.copy(), None
        contrast = pre.contrast
        u = self._travelled(odometry)
        self._sequence, lowest = self._advance(self._sequence, contrast, u, first)
        if not first:
            self._odometer += u
        likelihood, unexplained = self._likelihood, self._unexplained
        likelihood.use_row(row if self._sign > 0 else -row, pre.ordered)  # ranked as differences
        log_mean_ratio = likelihood.mean(self._omega)
        prior = unexplained.transition(first)

        pos, speed = self._pos, self._speed
        if not first:  # motion model: s += v u_k + noise
            if p.speed_noise > 0:
                speed = np.clip(speed + rng.normal(0.0, p.speed_noise, p.particles), *p.speed_range)
            pos = self._moved(pos, speed, u)
        n_reseed = int(round(p.reseed * p.particles))
        weakness = self._log_w
        outside = (pos < nodes[0]) | (pos > nodes[-1])  # carried past either end of the map: re-seeded
        if outside.any():
            weakness = np.where(outside, -np.inf, self._log_w)
            n_reseed = max(n_reseed, int(outside.sum()))
            if not self._growing:  # past a map's ends lies unmapped ground: their mass goes to U
                prior = prior.beyond(float(np.exp(self._log_w[outside]).sum()))
        kept = np.ones(p.particles, dtype=bool)
        if n_reseed > 0:  # re-seed the weakest particles at the best sequence-score nodes
            weakest = smallest(weakness, n_reseed, rng)
            kept[weakest] = False
            self._reseed(weakest, lowest, pos, speed, first)

        j, a = locate(nodes, pos)  # eq. 8: the observation interpolated between the nodes around
        omega = np.empty(p.particles)
        rank_kernels.interpolate(self._omega, j, a, omega)
        log_w, w = np.empty(p.particles), np.empty(p.particles)  # the posterior, from the prior's weights
        log_map, squares = filter_kernels.weigh(  # log_map: the map's total mass against the unexplained hypothesis
            self._log_w, kept, n_reseed > 0 and bool(kept.any()), likelihood.at(j, a, omega),
            float(np.log(max(prior.track, TINY))),
            float(np.log(max(prior.jump, TINY)) + log_mean_ratio - np.log(max(n_reseed, 1))), log_w, w)
        unexplained.update(log_map, prior.unexplained)

        decision = self._read_out(row, j, a, w)
        pace = track_pace(j, a, w, speed, decision.match, p.mode_window)  # to reckon an unexplained stretch at
        unexplained.follow(self.frames, self._odometer, float(nodes[decision.match]), self._spacing, pace,
                           float(np.hypot(p.step_noise * pace, p.noise_floor)))
        likelihood.learn(w * omega, 1.0 - unexplained.u)

        if 1.0 / squares < p.resample_ess * p.particles:
            idx = systematic(w, rng)
            pos, speed = pos[idx], speed[idx]
            log_w = np.full(p.particles, -np.log(p.particles))
        self._pos, self._speed, self._log_w = pos, speed, log_w
        return decision

    def _moved(self, pos: NDArray[np.float64], speed: NDArray[np.float64], u: float) -> NDArray[np.float64]:
        """The motion model: s += v u + noise (sd ``step_noise`` of the step, floored); a particle
        carried past either end of the map is re-seeded by :meth:`decide`."""
        p = self.params
        sd = np.hypot(p.step_noise * u * np.abs(speed), p.noise_floor * self._spacing)
        return pos + speed * u + self._rng.normal(0.0, sd, p.particles)

    def _read_out(self, row: NDArray[np.floating], j: NDArray[np.intp], a: NDArray[np.float64],
                  w: NDArray[np.float64]) -> Decision:
        """The decision: the node at the mode of the particle density (weights ``w`` at positions
        ``j``, ``a``), the confidence its window's mass times 1 - P(new place)."""
        from wiloc.methods.catgraph import filter_kernels  # numba loads with the first frame, not the command line

        mode, mass = filter_kernels.posterior_mode(j, a, w, self.params.mode_window, MODE_TIE, self._own, self._marks,
                                                   self.frames + 1)
        p_new = self._new_place
        return Decision(match=mode, difference=float(self._sign * row[mode]), confidence=float(mass * (1.0 - p_new)),
                        stage="track", new_place=p_new, ranking=tuple(posterior_ranking(self._own, mode).tolist()))

    def _repeat(self, row: NDArray[np.floating], odometry: float | None) -> Decision:
        """A frame whose row repeats the last one exactly: an image repeated, which holds no
        evidence the last one did not. The query stood still there, or moved on while its camera
        repeated an image (a frozen video, frames duplicated to another rate): each particle, drawn
        once per repeat, stands still with probability ``repeat_standing`` or moves on at its pace
        times a factor drawn with it (log-normal, sd ``repeat_pace_spread``: while no image tells
        the pace, it is known only roughly, so the group moving on spreads as the one standing does
        not); with odometry, which says which, every particle moves by it. Weights, the sequence
        score, the rank model and the unexplained hypothesis stay as they were."""
        p = self.params
        if odometry is None and self._standing is None:
            self._standing = self._rng.random(p.particles) < p.repeat_standing
            self._repeat_pace = log_normal(p.repeat_pace_spread, self._rng, p.particles)
        u = self._travelled(odometry)
        self._odometer += u
        moved = self._moved(self._pos, self._speed if odometry is not None else self._speed * self._repeat_pace, u)
        self._pos = moved if odometry is not None else np.where(self._standing, self._pos, moved)
        return self._read_out(row, *locate(self._nodes, self._pos), np.exp(self._log_w))  # log_w is normalised

    def _reseed(self, weakest: NDArray[np.intp], lowest: NDArray[np.float64], pos: NDArray[np.float64],
                speed: NDArray[np.float64], first: bool) -> None:
        """Move the ``weakest`` particles to the ``reseed_top`` nodes of lowest sequence score: a
        share ``reseed_backward`` to the best backward trajectories' nodes and a share
        ``reseed_fast`` to the best trajectories faster than ``fast_pace``, each at the pace of its
        group that scored best there; the rest to the best forward ones, half of those at the
        map's pace and half at the forward pace that scored best there. On the first frame every
        pace scores alike: all go forward at the map's pace."""
        p, groups = self.params, self._groups
        start = 0
        for group, count in reseed_counts(p, groups, weakest.size, first, self._rng):
            chosen = weakest[start:start + count]
            start += count
            best = lowest_nodes(lowest[group], p.reseed_top)
            best = best[np.arange(chosen.size) % best.size]
            pos[chosen] = self._nodes[best]
            speed[chosen] = 1.0
            if first:
                continue
            way = (groups == 3) if group == 3 else (  # slow paces give a pace too
                (self._paces < 0 if group == 1 else self._paces > 0) & (groups != 3))
            alike = slice(None) if group else slice(1, None, 2)  # forward: every other one keeps the map's pace
            scores = self._sequence[:, best[alike]][way]  # the chosen nodes' columns only, not every node
            speed[chosen[alike]] = self._paces[way][np.argmin(scores, axis=0)]
        if self._odometry:  # a direction, times a factor of its own
            speed[weakest] *= odometry_factors(p.odometry_scale, p.odometry_scale_wide, self._rng, weakest.size)

    def probability_near(self, node: int) -> float:
        """After a step: the probability that the frame shows the place of ``node`` (within
        +-mode_window nodes), the map explaining it."""
        from wiloc.methods.catgraph import filter_kernels  # numba loads with the first frame, not the command line

        if self._nodes.size == 0:  # sequence mode before the filter starts
            return 0.0
        mass = filter_kernels.window_sum(self._own, self.params.mode_window, node)
        return float(mass * (1.0 - self._new_place))

    @property
    def _new_place(self) -> float:
        """P(new place): in sequence mode every frame the map does not explain (one traversal
        has no blind spots), on a map the learned share of departures among them."""
        return self._unexplained.u if self._growing else self._unexplained.new_place

    def check_odometry(self) -> None:
        """A query frame's odometry needs the map's positions in the same units (sequence mode: its own)."""
        if not self._growing and self.context.arclength is None:
            raise WilocError(None, "a query odometry needs the map's too (map_odometry), in the same units",
                             parameter="odometry")

    def odometry_next(self) -> bool | None:
        """In sequence mode, from the third frame: as the frames before (``self_map.Trail``); on a
        map with odometry, from the second frame (the first's, from no frame, is not read)."""
        if self._growing:
            return self._self_map.trail.odometry if self.frames > 1 else None
        return True if self.context.arclength is not None and self.frames > 0 else None

    def _travelled(self, odometry: float | None) -> float:
        """u_k: the query's odometry step (which covers the frames left out before it), else the
        mean node spacing times the query frames since the last step (:attr:`elapsed`; in
        sequence mode one, the traversal's nodes being its kept frames); paces become
        directions with odometry."""
        if not self._odometry and (odometry is not None or self.context.arclength is not None):  # a map's: at once
            self._odometry = True
            self._paces_to_directions()
        if odometry is not None:
            return odometry
        return self._spacing if self._growing else self._spacing * self.elapsed

    def _paces_to_directions(self) -> None:
        """At the first frame with odometry: every particle's pace becomes its direction times its
        factor (:func:`~wiloc.methods.catgraph.paces.odometry_factors`); the sequence score keeps
        paces 1 and -1 (a direction it did not have starts at 0, a contrast-normalised row's mean)."""
        before = self._paces
        self._set_paces()
        kept = [np.flatnonzero(before == pace) for pace in self._paces]
        self._sequence = np.stack([self._sequence[at[0]] if at.size else np.zeros(self._nodes.size) for at in kept])
        self._spare, self._shifted = None, None
        p = self.params
        self._speed = np.sign(self._speed) * odometry_factors(p.odometry_scale, p.odometry_scale_wide, self._rng,
                                                              self._speed.size)

    def facts(self) -> dict[str, Any]:
        return {"odometry": getattr(self, "_odometry", False),
                "learned_a": self._likelihood.a if hasattr(self, "_likelihood") else None,
                "departure_share": self._unexplained.q if hasattr(self, "_unexplained") else None}

    def save_state(self) -> dict[str, Any]:
        trail = self._self_map.state() if self._growing else {}
        if self._nodes.size == 0:  # sequence mode before the filter starts
            return {"nodes": self._nodes, "filtered": 0, **trail}
        return {**trail, "nodes": self._nodes, "filtered": self._filtered, "omega": self._omega, "pos": self._pos,
                "speed": self._speed, "log_w": self._log_w, "sequence": self._sequence.copy(), "own": self._own.copy(),
                "odometer": self._odometer, "spacing": self._spacing,
                "odometry": self._odometry, "likelihood": self._likelihood.state(),
                "unexplained": self._unexplained.state(), "rng": self._rng.bit_generator.state,
                "last": np.empty(0) if self._last is None else self._last.copy(),
                "standing": np.empty(0, dtype=bool) if self._standing is None else self._standing.copy(),
                "repeat_pace": np.empty(0) if self._standing is None else self._repeat_pace.copy()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        p = self.params
        self._growing = self.context is not None and self.context.sequence
        self._filtered = int(state["filtered"])
        self._nodes = np.asarray(state["nodes"], dtype=np.float64)
        self._odometry = False
        if self._growing:  # a state saved before sequence mode took odometry has none
            self._self_map = SelfMap(state, self.frames)
        if self._nodes.size == 0:
            return
        mean = float((self._nodes[-1] - self._nodes[0]) / (self._nodes.size - 1))
        self._spacing = float(state.get("spacing", mean))  # a state saved before it was kept: the mean
        self._omega = np.asarray(state["omega"], dtype=np.float64)
        self._pos = np.asarray(state["pos"], dtype=np.float64).copy()
        self._speed = np.asarray(state["speed"], dtype=np.float64).copy()
        self._log_w = np.asarray(state["log_w"], dtype=np.float64).copy()
        self._odometry = bool(state["odometry"])
        self._set_paces()
        self._sequence = np.asarray(state["sequence"], dtype=np.float64).copy()
        self._spare = None
        self._own = np.asarray(state["own"], dtype=np.float64).copy()
        self._marks = np.zeros(self._own.size, dtype=np.int64)
        self._odometer = float(state["odometer"])
        self._likelihood = self._observation_model()
        self._likelihood.load(state["likelihood"])
        self._unexplained = Unexplained(p.unexplained0, p.leave, p.rejoin, p.jump, p.departure_prior,
                                        p.stretch_open, p.stretch_close)  # u0 is overwritten: any will do
        self._unexplained.load(state["unexplained"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = state["rng"]
        self._shifted = None
        last, standing = np.asarray(state["last"]), np.asarray(state["standing"], dtype=bool)
        self._last = last.copy() if last.size else None
        self._standing = standing.copy() if standing.size else None
        pace = np.asarray(state.get("repeat_pace", np.empty(0)), dtype=np.float64)  # saved before it was kept: 1
        self._repeat_pace = pace.copy() if pace.size else np.ones(standing.size)
        self._recycle()

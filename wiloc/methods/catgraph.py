"""Whole-image CAT-Graph: a particle filter along the reference trajectory (paper III.C, eqs 7-10).

The reference traversal is a trajectory: node j sits at arc length s_j. M particles live at
continuous positions on it, optionally each with its own speed ratio (``speed_noise`` > 0).
Per query frame: move the particles, re-seed a few at the best nodes of a causal sequence score
(a leaky sum of contrast-normalised differences along straight trajectories), weight each by
P(d|L)/P(d) of the difference interpolated at its position (eq. 8), weigh a
new-place particle by the mean P(not L | d) over sampled nodes (eq. 10), normalise, read out the
mode of the particle density and resample when the effective sample size drops. P(d|L) comes from
the online, training-free ``b`` (each frame's smallest difference, added after the frame is used);
P(d|not L) from the bulk of the reference's differences to itself outside +-R, read block of rows
by block of rows. docs/catgraph.md gives the formulation in full and the measurements behind
every default.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d, uniform_filter1d
from scipy.special import expit

from wiloc.errors import ParameterError, WilocError
from wiloc.methods.base import Decision, MapContext, Method, RowBlocks, iter_blocks
from wiloc.model import HistogramModel
from wiloc.parameters import Parameters, param

MODE_TIE = 1e-12  # window masses (shares of a unit total) this close to the largest count as tied


def _bulk_blocks(ref_self: RowBlocks, exclude_recent: int) -> Iterator[NDArray[np.float64]]:
    """The finite differences of every reference pair further apart than ``exclude_recent``.

    One block of rows at a time, each ordered pair (i, j) once; never the whole matrix.
    """
    cols = np.arange(ref_self.shape[1])
    for start, block in iter_blocks(ref_self):
        far = np.abs(np.arange(start, start + block.shape[0])[:, None] - cols[None, :]) > exclude_recent
        values = block[far]
        yield values[np.isfinite(values)]


def bulk_model(ref_self: RowBlocks, exclude_recent: int, bins: int) -> HistogramModel:
    """The observation model before the query run: ``c`` holds the bulk of ordinary differences.

    ``ref_self``: the reference-by-reference differences as a row-block reader (``.shape`` and
    ``.rows(start, stop)``; ``wiloc.methods.base.ArrayRows`` wraps an array), read in blocks of
    rows, twice (range, then counts). Every pair of reference frames further apart than
    ``exclude_recent`` counts as a different place (no labels: along one traversal, frames apart
    are mostly different places). Bins span [min(0, lowest), highest] of those differences; ``b``
    starts empty.
    """
    shape = tuple(ref_self.shape)
    if len(shape) != 2 or shape[0] != shape[1]:
        raise WilocError("catgraph", f"the map's differences to itself must be a square matrix, got shape {shape}")
    low, high, count = np.inf, -np.inf, 0
    for values in _bulk_blocks(ref_self, exclude_recent):
        if values.size:
            low, high, count = min(low, float(values.min())), max(high, float(values.max())), count + values.size
    if count == 0:
        raise WilocError("catgraph", f"no finite map difference between frames more than {exclude_recent} "
                                     f"apart ({shape[0]} map frames)")
    model = HistogramModel.from_range(min(0.0, low), high, bins)
    for values in _bulk_blocks(ref_self, exclude_recent):
        model.c += np.bincount(model.bin_of(values), minlength=model.n_bins)
    return model


@dataclass(frozen=True)
class _Tables:
    """Per-bin observation terms: log P(d|L)/P(d) for particles, P(not L|d) for the new place."""

    log_ratio: NDArray[np.float64]
    p_not_same: NDArray[np.float64]


def _density(counts: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """Gaussian-smoothed histogram as a density, with a floor so no bin is empty."""
    smooth = gaussian_filter1d(counts, sigma, mode="nearest") if sigma > 0 else counts.copy()
    total = smooth.sum()
    if total <= 0:
        return np.full(counts.size, 1.0 / counts.size)
    dens = smooth / total
    return np.maximum(dens, 1e-9 / counts.size)


def observation_tables(model: HistogramModel, sigma: float, prior: float, outlier: float,
                       pseudo: float) -> _Tables:
    """Observation terms per bin from the current model.

    The likelihood ratio P(d|L)/P(d|not L) is made non-increasing in d (running maximum from the
    large end): a smaller difference is never less evidence of the same place than a larger one.
    This keeps the sparse low tail of either histogram from penalising very good matches.
    """
    p_diff = _density(model.c, sigma)
    n_b = model.b.sum()
    share = max(outlier, pseudo / (n_b + pseudo)) if n_b + pseudo > 0 else 1.0
    p_same = (1.0 - share) * _density(model.b, sigma) + share * p_diff
    ratio = np.maximum.accumulate((p_same / p_diff)[::-1])[::-1]
    same = ratio * prior
    p_d = same + (1.0 - prior)  # P(d) / P(d|not L), eq. 6
    return _Tables(log_ratio=np.log(ratio / p_d), p_not_same=(1.0 - prior) / p_d)


def _arclength(ref_arclength: NDArray[np.float64] | None, n_nodes: int) -> NDArray[np.float64]:
    """Node positions: the given arc lengths (non-decreasing), else the frame index."""
    if ref_arclength is None:
        return np.arange(n_nodes, dtype=np.float64)
    s = np.asarray(ref_arclength, dtype=np.float64)
    if s.shape != (n_nodes,):
        raise WilocError(None, f"gives {s.size} positions for {n_nodes} map frames", parameter="map_odometry")
    if not np.all(np.isfinite(s)) or np.any(np.diff(s) < 0):
        raise WilocError(None, "the map's distances along its route must be finite and non-decreasing",
                         parameter="map_odometry")
    if not s[-1] > s[0]:
        raise WilocError(None, "the map's route has zero length (the odometry never moves)",
                         parameter="map_odometry")
    return s


def _locate(nodes: NDArray[np.float64], pos: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """For each particle: the node j just before it and its fraction a of the way to node j + 1."""
    j = np.clip(np.searchsorted(nodes, pos, side="right") - 1, 0, nodes.size - 2)
    gap = nodes[j + 1] - nodes[j]
    a = np.divide(pos - nodes[j], gap, out=np.zeros_like(pos), where=gap > 0)
    return j, np.clip(a, 0.0, 1.0)


def contrast_normalise(row: NDArray[np.float64], half_window: int) -> NDArray[np.float64]:
    """Each difference minus the mean of its +-``half_window`` neighbouring nodes, over their std.

    Removes what a whole stretch of the map shares (a tunnel, snow, a dark scene all look alike
    to every query frame), so a node stands out only by being lower than its neighbours
    (SeqSLAM's local contrast enhancement, on one row: causal). A flat stretch (std within
    rounding of 0) gives 0.
    """
    size = 2 * half_window + 1
    mean = uniform_filter1d(row, size, mode="nearest")
    sd = np.sqrt(np.maximum(uniform_filter1d(row * row, size, mode="nearest") - mean * mean, 0.0))
    flat = sd <= 1e-6 * np.abs(mean)
    return np.divide(row - mean, sd, out=np.zeros_like(row), where=~flat & (sd > 0))


def _shifted_reads(nodes: NDArray[np.float64],
                   shifts: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Where each row v of a (speeds x nodes) score is read at s_j - shifts[v], clamped to the
    trajectory: flat indices of the node before and the fraction of the way to the next."""
    j, a = _locate(nodes, (nodes[None, :] - shifts[:, None]).ravel())
    return np.arange(shifts.size).repeat(nodes.size) * nodes.size + j, a


def _advance(score: NDArray[np.float64], at: NDArray[np.intp], a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``score`` read where :func:`_shifted_reads` says, linearly interpolated.

    The leaky sequence score ending at node j now continues the one that ended a step back.
    """
    prev = score.ravel()
    return ((1.0 - a) * prev[at] + a * prev[at + 1]).reshape(score.shape)


def _log_normalizer(log_w: NDArray[np.float64]) -> float:
    """log(sum(exp(log_w))), computed stably."""
    top = float(log_w.max())
    return top + float(np.log(np.exp(log_w - top).sum()))


def _systematic(weights: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.intp]:
    """Indices drawn by systematic resampling (one uniform offset, M evenly spaced pointers)."""
    m = weights.size
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    pointers = (rng.random() + np.arange(m)) / m
    return np.searchsorted(cum, pointers, side="left")


@dataclass(frozen=True)
class CatGraphParams(Parameters):
    """Parameters of the whole-image CAT-Graph filter (docs/catgraph.md: every default measured)."""

    owner = "catgraph"
    particles: int = param(2000, "Number of particles.", low=1, high=1_000_000)
    seed: int | None = param(0, "Random seed: the same seed gives identical decisions (none: a fresh one).",
                             low=0)
    bins: int = param(100, "Histogram bins of the observation model.", low=2, high=100_000)
    smoothing_bins: float = param(16.0, "Gaussian smoothing of both histograms, in bins.", low=0.0)
    prior: float = param(0.01, "P(L) of eq. 6 for a particle's place.", low=0.0, high=1.0, high_open=True)
    outlier: float = param(0.05, "Floor of the bulk's share in P(d|L): bounds the penalty of one odd frame.",
                           low=0.0, high=1.0)
    pseudo: float = param(10.0, "Pseudo-count of the bulk in P(d|L): uninformative until b has samples.",
                          low=0.0)
    step_noise: float = param(0.3, "Motion noise, a fraction of each step.", low=0.0)
    noise_floor: float = param(0.5, "Motion noise floor, a fraction of the mean node spacing.", low=0.0)
    speed_noise: float = param(0.0, "Per-particle speed noise per frame (0: no velocity state).", low=0.0)
    speed_range: tuple[float, float] = param((0.0, 3.0), "Range of the particles' speed ratios (low, high).",
                                             low=0.0)
    resample_ess: float = param(0.5, "Resample when the effective sample size falls below this share.",
                                low=0.0, high=1.0)
    reseed: float = param(0.01, "Share of particles re-seeded each frame at the best sequence score.",
                          low=0.0, high=1.0)
    reseed_top: int = param(1, "Nodes of best sequence score that re-seeded particles go to.", low=1)
    sequence_rate: float = param(0.1, "Rate of the leaky sequence score (about 1 / frames remembered).",
                                 low=0.0, high=1.0, low_open=True)
    sequence_speeds: tuple[float, ...] = param((0.5, 1.0, 1.5, 2.0), "Speed ratios of the sequence score.",
                                               low=0.0)
    contrast_window: int = param(10, "Half window (nodes) of the sequence score's contrast normalisation.",
                                 low=1)
    new_place_samples: int = param(100, "Map nodes sampled per frame for the new-place particle (eq. 10).",
                                   low=1, high=1_000_000)
    mode_window: int = param(2, "Half window (nodes) summed around the mode for the confidence.", low=0)

    def check(self) -> None:
        low, high = self.speed_range
        if low > high:
            raise ParameterError("speed_range", f"must be (low, high) with low <= high, got {self.speed_range!r}")


class CatGraph(Method):
    """Track the query along the reference trajectory with the whole-image CAT-Graph filter.

    Started on a map: its differences to itself (for P(d|not L)) and optionally its node
    positions (``MapContext.arclength``, from odometry; else the node index). Each step takes the
    query frame's differences to every map node and optionally its travelled distance since the
    previous frame (odometry, same units as the map's); without it, the mean node spacing. The
    noise and ``noise_floor`` are relative to the step and to the mean node spacing respectively.
    Re-seeding uses a causal sequence score per node: for each speed ratio in ``sequence_speeds``
    an exponentially weighted (rate ``sequence_rate``) sum of contrast-normalised differences
    (+-``contrast_window`` nodes) along the trajectory ending there; the lowest over speeds counts.
    Each decision is the node at the density mode (the largest weight mass within
    +-``mode_window`` nodes; among tied nodes the one holding most weight itself), its difference,
    that mass (after normalising with the new-place particle) as confidence, and the new-place
    probability. The same seed gives identical decisions.
    """

    name = "catgraph"
    Params = CatGraphParams
    needs = frozenset({"map", "map_self", "odometry"})
    columns = ("new_place",)
    params: CatGraphParams

    def prepare(self, context: MapContext) -> None:
        p = self.params
        if context.sequence or context.map_self is None:
            raise WilocError("catgraph", "needs a map (a reference trajectory)", parameter="map")
        ref_self = context.map_self()
        n_nodes = ref_self.shape[0]
        if n_nodes < 2:
            raise WilocError("catgraph", f"the map needs at least 2 frames, got {n_nodes}")
        self._model = bulk_model(ref_self, context.exclude_recent, p.bins)
        self._nodes = _arclength(context.arclength, n_nodes)
        self._spacing = float((self._nodes[-1] - self._nodes[0]) / (n_nodes - 1))
        self._rng = np.random.default_rng(p.seed)
        self._pos = self._rng.uniform(self._nodes[0], self._nodes[-1], p.particles)
        self._speed = (self._rng.uniform(p.speed_range[0], p.speed_range[1], p.particles) if p.speed_noise > 0
                       else np.ones(p.particles))
        self._log_w = np.full(p.particles, -np.log(p.particles))
        self._sequence = np.zeros((len(p.sequence_speeds), n_nodes))
        self._odometry = False  # whether any step came with odometry
        self._shifted: tuple[float, tuple[NDArray[np.intp], NDArray[np.float64]]] | None = None

    def _shift_lookup(self, u: float) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """:func:`_shifted_reads` for step u: the same for every frame of equal step (always,
        without odometry), so it is computed once per distinct step."""
        if self._shifted is None or self._shifted[0] != u:
            shifts = np.asarray(self.params.sequence_speeds, dtype=np.float64) * u
            self._shifted = (u, _shifted_reads(self._nodes, shifts))
        return self._shifted[1]

    def decide(self, row: NDArray[np.float64], odometry: float | None) -> Decision:
        p, model, rng, nodes = self.params, self._model, self._rng, self._nodes
        n_nodes = nodes.size
        if row.shape != (n_nodes,) or not np.all(np.isfinite(row)):
            raise WilocError("catgraph", f"query frame {self.frames}: expected {n_nodes} finite differences to the map")
        u = self._travelled(odometry)
        tables = observation_tables(model, p.smoothing_bins, p.prior, p.outlier, p.pseudo)
        contrast = contrast_normalise(row, p.contrast_window)
        if self.frames == 0:
            self._sequence[:] = contrast
        else:  # the leaky sum along each speed's trajectory: causal, O(speeds x nodes) per frame
            self._sequence = ((1.0 - p.sequence_rate) * _advance(self._sequence, *self._shift_lookup(u))
                              + p.sequence_rate * contrast)

        pos, speed, log_w = self._pos, self._speed, self._log_w
        if self.frames > 0:  # motion model: s += v u_k + noise
            if p.speed_noise > 0:
                speed = np.clip(speed + rng.normal(0.0, p.speed_noise, p.particles), *p.speed_range)
            sd = np.hypot(p.step_noise * u, p.noise_floor * self._spacing)
            pos = np.clip(pos + speed * u + rng.normal(0.0, sd, p.particles), nodes[0], nodes[-1])
        n_reseed = int(round(p.reseed * p.particles))
        if n_reseed > 0:  # re-seed the weakest particles at the best sequence-score nodes
            weakest = np.argpartition(log_w, n_reseed - 1)[:n_reseed]
            score = self._sequence.min(axis=0)
            best = np.argpartition(score, min(p.reseed_top, n_nodes) - 1)[:p.reseed_top]
            pos[weakest] = nodes[best[np.arange(n_reseed) % best.size]]
            speed[weakest] = speed[rng.integers(0, p.particles, n_reseed)]
            log_w[weakest] = -np.log(p.particles)
            log_w = log_w - _log_normalizer(log_w)

        j, a = _locate(nodes, pos)  # eq. 8: d linearly interpolated between the nodes around
        log_w = log_w + tables.log_ratio[model.bin_of((1.0 - a) * row[j] + a * row[j + 1])]
        log_total = _log_normalizer(log_w)  # log of sum_i w_i P(d_i|L)/P(d_i), the prior mass being 1
        sampled = rng.integers(0, n_nodes, p.new_place_samples)
        log_new = np.log(tables.p_not_same[model.bin_of(row[sampled])].mean())
        p_new = float(expit(log_new - log_total))  # eq. 10 weight normalised with the particles
        log_w = log_w - log_total
        w = np.exp(log_w)

        own = np.bincount(j + (a >= 0.5), weights=w, minlength=n_nodes)
        window = np.ones(2 * p.mode_window + 1)
        mass = np.convolve(own, window)[p.mode_window:p.mode_window + n_nodes]  # "same" is wrong for a short map
        tied = np.flatnonzero(mass >= mass.max() - MODE_TIE)
        mode = int(tied[np.argmax(own[tied])])

        if 1.0 / np.sum(w * w) < p.resample_ess * p.particles:
            idx = _systematic(w, rng)
            pos, speed = pos[idx], speed[idx]
            log_w = np.full(p.particles, -np.log(p.particles))
        self._pos, self._speed, self._log_w = pos, speed, log_w
        model.add_same(row.min())  # causal online b: the frame's smallest difference, after use
        return Decision(match=mode, difference=float(row[mode]), confidence=float(mass[mode] * (1.0 - p_new)),
                        stage="track", new_place=p_new)

    def _travelled(self, odometry: float | None) -> float:
        """u_k: the query's odometry step, else the mean node spacing."""
        if odometry is None:
            return self._spacing
        if self.context is None or self.context.arclength is None:
            raise WilocError(None, "a query odometry needs the map's too (map_odometry), in the same units",
                             parameter="odometry")
        if not (np.isfinite(odometry) and odometry >= 0):
            raise WilocError(None, f"query frame {self.frames}: the step must be finite and >= 0, got {odometry}",
                             parameter="odometry")
        self._odometry = True
        return float(odometry)

    @property
    def model(self) -> HistogramModel | None:
        return getattr(self, "_model", None)

    def facts(self) -> dict[str, Any]:
        return {"exclude_recent": self.context.exclude_recent if self.context else None,
                "odometry": self._odometry}

    def save_state(self) -> dict[str, Any]:
        return {"model": self._model.to_dict(), "nodes": self._nodes, "pos": self._pos, "speed": self._speed,
                "log_w": self._log_w, "sequence": self._sequence, "odometry": self._odometry,
                "rng": self._rng.bit_generator.state}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self._model = HistogramModel.from_dict(state["model"])
        self._nodes = np.asarray(state["nodes"], dtype=np.float64)
        self._spacing = float((self._nodes[-1] - self._nodes[0]) / (self._nodes.size - 1))
        self._pos = np.asarray(state["pos"], dtype=np.float64).copy()
        self._speed = np.asarray(state["speed"], dtype=np.float64).copy()
        self._log_w = np.asarray(state["log_w"], dtype=np.float64).copy()
        self._sequence = np.asarray(state["sequence"], dtype=np.float64).copy()
        self._odometry = bool(state["odometry"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = state["rng"]
        self._shifted = None

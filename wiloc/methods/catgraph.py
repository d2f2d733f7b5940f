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

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d, uniform_filter1d
from scipy.special import expit

from wiloc.errors import WilocError
from wiloc.methods.base import Decisions
from wiloc.methods.online import DEFAULT_BINS, DEFAULT_EXCLUDE_RECENT
from wiloc.model import HistogramModel

Progress = Callable[[int, int], None]

DEFAULT_PARTICLES = 2000
DEFAULT_SMOOTHING_BINS = 16.0
DEFAULT_PRIOR = 0.01
DEFAULT_OUTLIER = 0.05
DEFAULT_PSEUDO = 10.0
DEFAULT_STEP_NOISE = 0.3
DEFAULT_NOISE_FLOOR = 0.5
DEFAULT_SPEED_NOISE = 0.0
DEFAULT_SPEED_RANGE = (0.0, 3.0)
DEFAULT_RESAMPLE_ESS = 0.5
DEFAULT_RESEED = 0.01
DEFAULT_RESEED_TOP = 1
DEFAULT_SEQUENCE_RATE = 0.1
DEFAULT_SEQUENCE_SPEEDS = (0.5, 1.0, 1.5, 2.0)
DEFAULT_CONTRAST_WINDOW = 10
DEFAULT_NEW_PLACE_SAMPLES = 100
DEFAULT_MODE_WINDOW = 2
BULK_BLOCK_VALUES = 1 << 22  # reference differences read per block for the bulk histogram (32 MB as float64)
MODE_TIE = 1e-12  # window masses (shares of a unit total) this close to the largest count as tied


class RowBlocks(Protocol):
    """A matrix read block of rows by block of rows, e.g. ``wiloc.differences.DifferenceMatrix``."""

    @property
    def shape(self) -> tuple[int, int]: ...

    def rows(self, start: int, stop: int) -> NDArray[np.float32]: ...


def _bulk_blocks(ref_self: NDArray[np.floating] | RowBlocks,
                 exclude_recent: int) -> Iterator[NDArray[np.float64]]:
    """The finite differences of every reference pair further apart than ``exclude_recent``.

    One block of rows at a time, each ordered pair (i, j) once; never the whole matrix.
    """
    n_rows, n_cols = ref_self.shape
    step = max(1, BULK_BLOCK_VALUES // max(n_cols, 1))
    cols = np.arange(n_cols)
    for start in range(0, n_rows, step):
        stop = min(start + step, n_rows)
        block = ref_self.rows(start, stop) if hasattr(ref_self, "rows") else ref_self[start:stop]
        far = np.abs(np.arange(start, stop)[:, None] - cols[None, :]) > exclude_recent
        values = np.asarray(block, dtype=np.float64)[far]
        yield values[np.isfinite(values)]


def bulk_model(ref_self: NDArray[np.floating] | RowBlocks, exclude_recent: int,
               bins: int) -> HistogramModel:
    """The observation model before the query run: ``c`` holds the bulk of ordinary differences.

    ``ref_self``: the reference-by-reference differences, an array or a row-block reader (any
    object with ``.shape`` and ``.rows(start, stop)``), read in blocks of rows, twice (range,
    then counts). Every pair of reference frames further apart than ``exclude_recent`` counts as
    a different place (no labels: along one traversal, frames apart are mostly different places).
    Bins span [min(0, lowest), highest] of those differences; ``b`` starts empty.
    """
    if not hasattr(ref_self, "rows"):
        ref_self = np.asarray(ref_self)
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
        raise WilocError("--map-odometry", f"gives {s.size} positions for {n_nodes} map frames")
    if not np.all(np.isfinite(s)) or np.any(np.diff(s) < 0):
        raise WilocError("--map-odometry", "the map's distances along its route must be finite and non-decreasing")
    if not s[-1] > s[0]:
        raise WilocError("--map-odometry", "the map's route has zero length (the odometry never moves)")
    return s


def _steps(query_steps: NDArray[np.float64] | None, n_frames: int, spacing: float,
           have_arclength: bool) -> NDArray[np.float64]:
    """u_k per query frame: the odometry steps, else the mean node spacing."""
    if query_steps is None:
        return np.full(n_frames, spacing)
    if not have_arclength:
        raise WilocError("--odometry", "a query odometry CSV needs the map's too (--map-odometry), in the same units")
    u = np.asarray(query_steps, dtype=np.float64)
    if u.shape != (n_frames,):
        raise WilocError("--odometry", f"gives {u.size} steps for {n_frames} query frames")
    if not np.all(np.isfinite(u)) or np.any(u < 0):
        raise WilocError("--odometry", "the query's steps must be finite and >= 0")
    return u


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


def _advance(score: NDArray[np.float64], nodes: NDArray[np.float64],
             shifts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row v of ``score`` read at s_j - shifts[v] for every node j (clamped to the trajectory).

    The leaky sequence score ending at node j now continues the one that ended a step back.
    """
    j, a = _locate(nodes, (nodes[None, :] - shifts[:, None]).ravel())
    at = np.arange(shifts.size).repeat(nodes.size) * nodes.size + j
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


def localize_catgraph(
    query_rows: Iterable[NDArray[np.float64]],
    ref_self: NDArray[np.floating] | RowBlocks,
    n_frames: int,
    *,
    ref_arclength: NDArray[np.float64] | None = None,
    query_steps: NDArray[np.float64] | None = None,
    particles: int = DEFAULT_PARTICLES,
    seed: int | None = 0,
    exclude_recent: int = DEFAULT_EXCLUDE_RECENT,
    bins: int = DEFAULT_BINS,
    smoothing_bins: float = DEFAULT_SMOOTHING_BINS,
    prior: float = DEFAULT_PRIOR,
    outlier: float = DEFAULT_OUTLIER,
    pseudo: float = DEFAULT_PSEUDO,
    step_noise: float = DEFAULT_STEP_NOISE,
    noise_floor: float = DEFAULT_NOISE_FLOOR,
    speed_noise: float = DEFAULT_SPEED_NOISE,
    speed_range: tuple[float, float] = DEFAULT_SPEED_RANGE,
    resample_ess: float = DEFAULT_RESAMPLE_ESS,
    reseed: float = DEFAULT_RESEED,
    reseed_top: int = DEFAULT_RESEED_TOP,
    sequence_rate: float = DEFAULT_SEQUENCE_RATE,
    sequence_speeds: tuple[float, ...] = DEFAULT_SEQUENCE_SPEEDS,
    contrast_window: int = DEFAULT_CONTRAST_WINDOW,
    new_place_samples: int = DEFAULT_NEW_PLACE_SAMPLES,
    mode_window: int = DEFAULT_MODE_WINDOW,
    progress: Progress | None = None,
) -> Decisions:
    """Track the query along the reference trajectory with the whole-image CAT-Graph filter.

    ``query_rows`` yields ``n_frames`` rows of differences of query frame k to every reference
    node; ``ref_self`` is the reference-by-reference difference matrix (for P(d|not L)), an array
    or a row-block reader such as ``DifferenceMatrix``, read a block of rows at a time.
    Positions are in arc-length units (``ref_arclength``, else node index); ``query_steps`` are
    the query's travelled distances since its previous frame in the same units. The noise and
    ``noise_floor`` are relative to the step and to the mean node spacing respectively.
    Re-seeding uses a causal sequence score per node: for each speed ratio in ``sequence_speeds``
    an exponentially weighted (rate ``sequence_rate``) sum of contrast-normalised differences
    (+-``contrast_window`` nodes) along the trajectory ending there; the lowest over speeds counts.
    Returns per frame the node at the density mode (the largest weight mass within
    +-``mode_window`` nodes; among tied nodes the one holding most weight itself), its difference,
    that mass (after normalising with the new-place particle) as confidence, and
    ``columns["new_place"]``. The same seed gives identical Decisions.
    """
    checks = [(particles >= 1, "--particles must be >= 1"), (exclude_recent >= 0, "--exclude-recent must be >= 0"),
              (bins >= 2, "bins must be >= 2"), (smoothing_bins >= 0, "smoothing_bins must be >= 0"),
              (0.0 <= prior < 1.0, "prior must lie in [0, 1)"),
              (min(step_noise, noise_floor, speed_noise) >= 0,
               "--step-noise, --noise-floor and --speed-noise must be >= 0"),
              (0.0 <= speed_range[0] <= speed_range[1], "speed_range must be (low, high), 0 <= low <= high"),
              (0.0 <= resample_ess <= 1.0, "--resample-ess must lie in [0, 1]"),
              (0.0 <= reseed <= 1.0, "--reseed must lie in [0, 1]"), (reseed_top >= 1, "reseed_top must be >= 1"),
              (0.0 < sequence_rate <= 1.0, "sequence_rate must lie in (0, 1]"),
              (len(sequence_speeds) >= 1 and min(sequence_speeds, default=0.0) >= 0,
               "sequence_speeds must hold at least one speed ratio >= 0"),
              (contrast_window >= 1, "contrast_window must be >= 1"),
              (new_place_samples >= 1, "new_place_samples must be >= 1"), (mode_window >= 0, "mode_window must be >= 0")]
    for ok, problem in checks:
        if not ok:
            raise WilocError("catgraph", problem)

    n_nodes = ref_self.shape[0]
    if n_nodes < 2:
        raise WilocError("catgraph", f"the map needs at least 2 frames, got {n_nodes}")
    model = bulk_model(ref_self, exclude_recent, bins)
    nodes = _arclength(ref_arclength, n_nodes)
    spacing = (nodes[-1] - nodes[0]) / (n_nodes - 1)
    steps = _steps(query_steps, n_frames, spacing, ref_arclength is not None)
    rng = np.random.default_rng(seed)

    pos = rng.uniform(nodes[0], nodes[-1], particles)
    speed = rng.uniform(speed_range[0], speed_range[1], particles) if speed_noise > 0 else np.ones(particles)
    log_w = np.full(particles, -np.log(particles))
    n_reseed = int(round(reseed * particles))
    window = np.ones(2 * mode_window + 1)
    speeds_v = np.asarray(sequence_speeds, dtype=np.float64)
    sequence = np.zeros((speeds_v.size, n_nodes))

    match = np.full(n_frames, -1, dtype=np.int64)
    difference = np.full(n_frames, np.nan)
    confidence = np.full(n_frames, np.nan)
    new_place = np.full(n_frames, np.nan)

    k = -1
    for k, row in enumerate(query_rows):
        if k >= n_frames:
            raise WilocError("catgraph", f"more query rows than n_frames={n_frames}")
        row = np.asarray(row, dtype=np.float64)
        if row.shape != (n_nodes,) or not np.all(np.isfinite(row)):
            raise WilocError("catgraph", f"query frame {k}: expected {n_nodes} finite differences to the map")
        tables = observation_tables(model, smoothing_bins, prior, outlier, pseudo)
        contrast = contrast_normalise(row, contrast_window)
        if k == 0:
            sequence[:] = contrast
        else:  # the leaky sum along each speed's trajectory: causal, O(speeds x nodes) per frame
            sequence = ((1.0 - sequence_rate) * _advance(sequence, nodes, speeds_v * steps[k])
                        + sequence_rate * contrast)

        if k > 0:  # motion model: s += v u_k + noise
            if speed_noise > 0:
                speed = np.clip(speed + rng.normal(0.0, speed_noise, particles), *speed_range)
            sd = np.hypot(step_noise * steps[k], noise_floor * spacing)
            pos = np.clip(pos + speed * steps[k] + rng.normal(0.0, sd, particles), nodes[0], nodes[-1])
        if n_reseed > 0:  # re-seed the weakest particles at the best sequence-score nodes
            weakest = np.argpartition(log_w, n_reseed - 1)[:n_reseed]
            score = sequence.min(axis=0)
            best = np.argpartition(score, min(reseed_top, n_nodes) - 1)[:reseed_top]
            pos[weakest] = nodes[best[np.arange(n_reseed) % best.size]]
            speed[weakest] = speed[rng.integers(0, particles, n_reseed)]
            log_w[weakest] = -np.log(particles)
            log_w = log_w - _log_normalizer(log_w)

        j, a = _locate(nodes, pos)  # eq. 8: d linearly interpolated between the nodes around
        log_w = log_w + tables.log_ratio[model.bin_of((1.0 - a) * row[j] + a * row[j + 1])]
        log_total = _log_normalizer(log_w)  # log of sum_i w_i P(d_i|L)/P(d_i), the prior mass being 1
        sampled = rng.integers(0, n_nodes, new_place_samples)
        log_new = np.log(tables.p_not_same[model.bin_of(row[sampled])].mean())
        p_new = float(expit(log_new - log_total))  # eq. 10 weight normalised with the particles
        log_w = log_w - log_total
        w = np.exp(log_w)

        own = np.bincount(j + (a >= 0.5), weights=w, minlength=n_nodes)
        mass = np.convolve(own, window)[mode_window:mode_window + n_nodes]  # "same" is wrong for a short map
        tied = np.flatnonzero(mass >= mass.max() - MODE_TIE)
        mode = int(tied[np.argmax(own[tied])])
        match[k], difference[k] = mode, row[mode]
        confidence[k] = mass[mode] * (1.0 - p_new)
        new_place[k] = p_new

        if 1.0 / np.sum(w * w) < resample_ess * particles:
            idx = _systematic(w, rng)
            pos, speed = pos[idx], speed[idx]
            log_w = np.full(particles, -np.log(particles))
        model.add_same(row.min())  # causal online b: the frame's smallest difference, after use
        if progress is not None:
            progress(k + 1, n_frames)
    if k + 1 != n_frames:
        raise WilocError("catgraph", f"got {k + 1} query rows, expected n_frames={n_frames}")

    params = {"method": "catgraph", "particles": particles, "seed": seed, "exclude_recent": exclude_recent,
              "bins": bins, "smoothing_bins": smoothing_bins, "prior": prior, "step_noise": step_noise,
              "noise_floor": noise_floor, "speed_noise": speed_noise, "speed_range": list(speed_range),
              "resample_ess": resample_ess, "reseed": reseed, "reseed_top": reseed_top,
              "sequence_rate": sequence_rate, "sequence_speeds": list(sequence_speeds),
              "contrast_window": contrast_window,
              "new_place_samples": new_place_samples, "mode_window": mode_window,
              "odometry": query_steps is not None}
    return Decisions(match=match, difference=difference, confidence=confidence,
                     stage=np.full(n_frames, "track"), columns={"new_place": new_place},
                     model=model, params=params)

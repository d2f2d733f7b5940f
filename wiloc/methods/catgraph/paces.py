"""CAT-Graph's paces, on plain arrays: which paces the sequence score runs and the group of each
(which ranks nodes for re-seeding), how many re-seeded particles each group gets, and, with
odometry, each particle's factor between the query's odometry and the map's. The filter
(:mod:`wiloc.methods.catgraph.filter`) holds the state and calls these."""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from wiloc.methods.catgraph.params import CatGraphParams

START_DEALT = 0.5  # share of particles that start at the paces other than the map's (start_paces)
TINY = 1e-300  # the smallest prior mass a hypothesis keeps, so that its log is finite
WIDE_FACTORS = 0.1  # share of odometry factors drawn from the wide prior (odometry_factors)


def sequence_paces(params: CatGraphParams, odometry: bool) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """The sequence score's paces and the group of each: 0 forward, 1 backward and 3 faster than
    ``fast_pace`` (each ranking nodes for re-seeding apart), 2 slower than ``rank_pace_min``
    (giving only a pace). With odometry, the directions of ``sequence_speeds``, forward first: the
    odometry says how far the query went, and a pace other than 1 would say the map's odometry
    and the query's disagree by that factor (free paces let look-alike tracks at a third or three
    times the measured pace win)."""
    speeds = np.asarray(params.sequence_speeds, dtype=np.float64)
    if odometry:
        paces = np.unique(np.sign(speeds))[::-1].copy()
        return paces, (paces < 0).astype(np.intp)
    groups = np.select([np.abs(speeds) < params.rank_pace_min, speeds > params.fast_pace, speeds < 0], [2, 3, 1], 0)
    return speeds, groups.astype(np.intp)


def reseed_counts(params: CatGraphParams, groups: NDArray[np.intp], n: int, first: bool,
                  rng: np.random.Generator) -> list[tuple[int, int]]:
    """How many of ``n`` re-seeded particles go to each group of paces that ranks nodes
    (:func:`sequence_paces`): the backward and fast groups their shares (the fast group's count
    rounded up or down at random, drawn from ``rng``), the forward group the rest; a group
    without paces none (its share goes to the forward group, or when that has none either, to
    the first group that has paces). The first frame: all forward."""
    present = [g for g in (0, 1, 3) if np.any(groups == g)]
    if first and 0 in present:
        return [(0, n)]
    shares = {1: params.reseed_backward, 3: params.reseed_fast}
    counts = {g: int(np.floor(shares[g] * n + (rng.random() if g == 3 else 0.5))) for g in present if g in shares}
    rest = n - sum(counts.values())
    main = 0 if 0 in present else present[0]
    counts[main] = counts.get(main, 0) + rest
    return [(g, counts[g]) for g in present if counts.get(g, 0) > 0]


def odometry_factors(sd: float, wide: float, rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """With odometry, n particles' factors between the query's odometry and the map's, drawn from
    ``rng``: log-normal around 1 (sd ``sd`` of the log, ``odometry_scale``), and a share
    ``WIDE_FACTORS`` of them with the wider sd ``wide`` (``odometry_scale_wide``: two odometries
    of other kinds, wheels against a GPS map, may disagree by a third); ones when both are 0.
    Copies inherit their parent's, so the factor that keeps a track on its place survives
    (docs/catgraph.md, "With odometry": a query whose odometry is 10 % longer than the map's is
    followed with it, lost without)."""
    narrow = log_normal(sd, rng, n)
    if wide <= 0:
        return narrow
    wider = log_normal(wide, rng, n)
    return np.where(rng.random(n) < WIDE_FACTORS, wider, narrow)


def log_normal(sd: float, rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """n factors around 1, log-normal with sd ``sd`` of the log, drawn from ``rng``; ones (no draw)
    when ``sd`` is 0."""
    return np.exp(sd * rng.standard_normal(n)) if sd > 0 else np.ones(n)


def start_paces(params: CatGraphParams) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each particle's pace and log weight before any frame. The query's pace is not known at the
    start: half of the particles (``START_DEALT``) cycle through the paces of ``sequence_speeds``
    other than the map's, the rest move at the map's pace, and the weights give the other paces
    together the prior probability ``start_paces``: a query at another pace is followed from its
    start (re-seeded particles take tens of frames to outweigh a cloud that lags), and weak
    evidence at the start does not hand the track to a lagging pace. The paces are dealt in a
    fixed pattern along the evenly spaced particles: every stretch of the map starts with the same
    mix, as it starts with the same mass."""
    m = params.particles
    speed, log_w = np.ones(m), np.full(m, -np.log(m))
    others = np.asarray([v for v in params.sequence_speeds if v != 1.0], dtype=np.float64)
    i = np.arange(m)
    dealt = np.floor((i + 1) * START_DEALT) > np.floor(i * START_DEALT)
    n_dealt = int(dealt.sum())
    if others.size == 0 or n_dealt in (0, m):
        return speed, log_w
    speed[dealt] = others[np.arange(n_dealt) % others.size]
    log_w[dealt] = np.log(max(params.start_paces / n_dealt, TINY))
    log_w[~dealt] = np.log((1.0 - params.start_paces) / (m - n_dealt))
    return speed, log_w

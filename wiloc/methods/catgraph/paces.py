"""CAT-Graph's paces, on plain arrays: which paces the sequence score runs and the group of each
(which ranks nodes for re-seeding), how many re-seeded particles each group gets, and, with
odometry, each particle's factor between the query's odometry and the map's. The filter
(:mod:`wiloc.methods.catgraph.filter`) holds the state and calls these."""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from wiloc.methods.catgraph.params import CatGraphParams


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


def odometry_factors(sd: float, rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """With odometry, n particles' factors between the query's odometry and the map's: log-normal
    around 1 (sd ``sd`` of the log, ``odometry_scale``), drawn from ``rng``; ones when ``sd`` is 0.
    Copies inherit their parent's, so the factor that keeps a track on its place survives
    (docs/catgraph.md, "With odometry": a query whose odometry is 10 % longer than the map's is
    followed with it, lost without)."""
    return np.exp(sd * rng.standard_normal(n)) if sd > 0 else np.ones(n)

"""Localization when the query does not retrace the map at the map's pace: R@1, AP and ECE per variant.

    python benchmarks/bench_pace.py                                   # every traversal, variant, method
    python benchmarks/bench_pace.py --traversals day_left/sad --variants same,pace-2 --methods catgraph
    python benchmarks/bench_pace.py --param catgraph.speed_noise=0.05 --json pace.json
    python benchmarks/bench_pace.py --traversals winter/sad --frames 600   # the first 600 Nordland frames
    python benchmarks/bench_pace.py --methods catgraph --seeds 0-4         # means over five seeds
    python benchmarks/bench_pace.py --methods catgraph --traversals held-out --seeds 0-2   # maps and queries swapped
    python benchmarks/bench_pace.py --methods catgraph --odometry 0.1      # with odometry, 10 % noise a step

Each traversal pairs a map folder with a query folder of the same route whose frame i is the
map's frame i (aligned ground truth: Gardens Point walking, map ``day_right``; Nordland, map
``summer``; ``--traversals held-out`` runs five more with maps and queries swapped, day_right and
night_right against a ``day_left`` map with ``sad`` and ``gist`` and Nordland ``summer`` against a
``winter`` map, for checking on runs no default was chosen on). Both folders are described once
through wiloc's cache; every variant is then a re-sampling of frame indices, never a copy of an
image:

    same        the query retraces the map at its pace (query frame i, map every frame)
    pace-1/3    map thinned to every 3rd frame, query every frame: the query at a third of the map's pace
    pace-1/2    map thinned to every 2nd frame, query every frame
    pace-2      query every 2nd frame (twice the map's pace)
    pace-3      query every 3rd frame
    reversed    the route walked backwards
    stop        standing still: frame 60 held for 20 frames, and every 200 frames after it a stop of 10-20
    u-turn      frames 0-119, then back from 119 to 40 (scaled to the route's length: 0.6 n and 0.2 n)
    jump        frames 0-79, 150-199, then 80-149 (scaled likewise: 0.4 n and 0.75 n)
    drift       map thinned to every 2nd frame; the query's step drifts smoothly between 1 and 4
                frames (0.5x to 2x the map's pace), one slow-fast-slow cycle every 200 frames

Two more, run only when named (``--variants start-off,leave``), where part of the query has no
place on the map, so that a frame matched there is wrong and P(new place) should be high:

    start-off   the map begins a quarter of the way along the route (frame 50 of 200), the query
                at the route's start: its first frames lie before the map
    leave       the map without the route's frames 30-50 % (60-99 of 200): the query leaves the
                map and comes back to it

The ground truth of a query frame is the map node holding its original frame (for a thinned map,
the nearest node), +-2 map nodes. The method runs on the difference rows of the re-sampled query
to the re-sampled map, started on the re-sampled map (its size, its neighbours' differences, its
differences to itself) exactly as ``wiloc localize`` starts it on a folder holding those frames,
with the default recent window and no odometry (``--odometry SD``: see below). The measures are wiloc's own (``wiloc.evaluation.metrics``,
``wiloc.evaluation.reliability``): R@1 (the decided match is right, over every query frame), AP (the PR
curve's average precision), ECE of the confidence, the precision among frames with confidence
>= 0.9 and their count, and the mean P(new place) of methods that give it.

From an experiment script (with ``benchmarks/`` on ``sys.path``, e.g. ``sys.path.insert(0, "benchmarks")``)::

    from bench_pace import load_traversal, variants, run_variant
    trav = load_traversal("day_left/sad")            # data_root=None, frames=None, cache=None
    for v in variants(trav.length):                  # Variant(name, map_frames, query_frames, truth)
        row = run_variant(trav, v, "catgraph", {"speed_noise": 0.05})
        print(v.name, row["r1"], row["ap"], row["ece"], row["precision@0.9"], row["accepted@0.9"],
              row["new_place"])

``run_variant(traversal, variant, method="catgraph", params=None, progress=None, odometry=None) -> dict``
returns the measures of one run as plain floats and ints (keys: traversal, variant, method, params,
odometry, odometry_factor, frames, map_nodes, decided, r1, ap, ece, precision@0.9, accepted@0.9,
new_place, new_place_ece, seconds; ``odometry``: the noise of the odometry the method was given,
None without; ``new_place_ece``: the ECE of P(new place) as the probability that the frame has no place
on the map); ``decide(traversal, variant, method, params, odometry=None)`` the run's ``Decisions``, ``score(decisions, variant)``
its measures and ``truth(variant, tolerance=2)`` its ground truth as a ``wiloc.evaluation.groundtruth.Truth``. ``variants(n)`` builds the variants of a route
of ``n`` frames (``names`` picks some); ``TRAVERSALS`` and ``HELD_OUT`` list the traversals by name.

``--odometry SD`` gives the methods that take odometry (catgraph) the query's travelled distance
per frame and the map's node positions, in route frames (a thinned map's nodes keep their frames'
indices; a stop travels 0, the route walked backwards a positive distance: odometry measures how
far, not which way), each step times 1 + SD x N(0, 1), clipped at 0 (``odometry_steps``: 0 is
exact odometry, 0.1 a wheel odometry's 10 % error a step), and ``--odometry-factor F`` times
that (the query's odometry F times the map's: 1.1 for one that reads 10 % long); the other
methods run without.

Seed 0 is one draw of a random filter: ``--seeds`` runs each method that takes a seed once per
seed, writes every run to ``--json`` (its seed in ``params``) and prints per traversal the means
over the seeds, with R@1's lowest and highest in brackets (``over_seeds(rows)`` makes those rows).

Last, a table of the counts the pace's acceptance reads, per method (``acceptance(rows)``): the
variants whose R@1 keeps 0.9 of the same pace's (0.95 on day_left's queries), the runs of ECE at
most 0.05, those whose precision among frames at confidence 0.9 or more is at least 0.9 (or that
accept none), the mean R@1, beside seqslam the runs where R@1 is above seqslam's, and the variants
that fall short of their ratio.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from scipy import sparse

from wiloc.cache.store import Cache
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT
from wiloc.decisions import Decisions
from wiloc.description.differences import ComputedDifferences, candidate_blocks, summarize as summarize_map
from wiloc.description.distances import DifferencesTo, consecutive
from wiloc.description.traversals import Describer
from wiloc.errors import WilocError
from wiloc.evaluation.groundtruth import Truth
from wiloc.evaluation.metrics import correct_matches, decided_confidence, summarize
from wiloc.evaluation.reliability import summarize_calibration, summarize_new_place
from wiloc.methods.base import MapContext
from wiloc.methods.registry import METHODS, make_method

from bench_common import (ODOMETRY_SEED, add_odometry, at_least, check_json_target, data_errors, default_data_root,
                          fmt, known_methods, noisy_steps, odometry_for, odometry_problem, parse_params,
                          parser as benchmark_parser, plain_console, wide_console, write_json)

TOLERANCE = 2  # map nodes either side of the true node that count as the same place
CUT = 0.9  # the confidence above which precision is reported
#: The pace's acceptance bar (:func:`acceptance`): a variant's R@1 at least this share of the same
#: pace's (day_left's queries: the second), ECE at most, precision among frames at CUT at least.
RATIO, RATIO_DAY_LEFT, ECE_BAR, PRECISION_BAR = 0.9, 0.95, 0.05, 0.9

#: name -> (dataset folder, map folder, query folder, descriptor)
TRAVERSALS: dict[str, tuple[str, str, str, str]] = {
    "day_left/sad": ("gardens-point-walking", "day_right", "day_left", "sad"),
    "day_left/gist": ("gardens-point-walking", "day_right", "day_left", "gist"),
    "night_right/sad": ("gardens-point-walking", "day_right", "night_right", "sad"),
    "night_right/gist": ("gardens-point-walking", "day_right", "night_right", "gist"),
    "winter/sad": ("nordland-summer-winter-64x32", "summer", "winter", "sad"),
}
#: run when named (``--traversals held-out``): the maps and queries swapped, for checking on runs no
#: default was chosen on what the five above suggest
HELD_OUT: dict[str, tuple[str, str, str, str]] = {
    **{f"{query}-on-day_left/{descriptor}": ("gardens-point-walking", "day_left", query, descriptor)
       for query in ("day_right", "night_right") for descriptor in ("sad", "gist")},
    "summer-on-winter/sad": ("nordland-summer-winter-64x32", "winter", "summer", "sad")}
KNOWN = {**TRAVERSALS, **HELD_OUT}

VARIANTS = ("same", "pace-1/3", "pace-1/2", "pace-2", "pace-3", "reversed", "stop", "u-turn", "jump", "drift")
OFF_MAP_VARIANTS = ("start-off", "leave")  # run when named: part of the query has no place on the map
NO_NODE = -1  # the true node of a query frame whose place is not on the map
SHORTEST = 10  # route frames the variants need at least


# ------------------------------------------------------------------------------------------ variants

@dataclass(frozen=True)
class Variant:
    """One re-sampling of a route of ``n`` frames (frame i of the query folder is frame i of the
    map folder): the route frames the map keeps, in order; the route frame of each query frame
    (repeats allowed); and each query frame's true map node (a position in ``map_frames``)."""

    name: str
    map_frames: NDArray[np.int64]
    query_frames: NDArray[np.int64]
    truth: NDArray[np.int64]


def _variant(name: str, query: Sequence[int] | NDArray[np.integer], n: int, map_step: int = 1) -> Variant:
    """A variant of query route frames against the map thinned to every ``map_step``-th frame;
    the true node is the nearest kept frame (ties to the earlier one)."""
    map_frames = np.arange(0, n, map_step, dtype=np.int64)
    q = np.asarray(query, dtype=np.int64)
    if q.size and (q.min() < 0 or q.max() >= n):
        raise ValueError(f"{name}: query frames outside 0..{n - 1}")
    nearest = np.minimum((2 * q + map_step - 1) // (2 * map_step), map_frames.size - 1)
    return Variant(name, map_frames, q, nearest.astype(np.int64))


def _off_map(name: str, kept: NDArray[np.int64], n: int) -> Variant:
    """The query retracing the whole route against a map of the route frames ``kept`` only: a
    query frame's true node is its place's when the map keeps it, else the nearest kept frame
    within the tolerance, else none (:data:`NO_NODE`)."""
    q = np.arange(n, dtype=np.int64)
    after = np.clip(np.searchsorted(kept, q), 0, kept.size - 1)
    before = np.clip(after - 1, 0, kept.size - 1)
    nearest = np.where(np.abs(kept[before] - q) < np.abs(kept[after] - q), before, after)
    truth = np.where(np.abs(kept[nearest] - q) <= TOLERANCE, nearest, NO_NODE)
    return Variant(name, kept, q, truth.astype(np.int64))


def _stops(n: int) -> NDArray[np.int64]:
    """The route with stops: frame 60 held for 20 frames, then every 200 frames one of 10-20."""
    frames: list[int] = []
    stops = {at: 20 - (7 * k) % 11 for k, at in enumerate(range(60, n, 200))}  # 20, 13, 17, 10, ...
    for i in range(n):
        frames.extend([i] * stops.get(i, 1))
    return np.array(frames, dtype=np.int64)


def _drift(n: int, period: float = 200.0) -> NDArray[np.int64]:
    """Route frames of a query whose step drifts smoothly between 1 and 4 frames: 2.5 - 1.5 cos of
    the distance travelled, one slow-fast-slow cycle every ``period`` frames."""
    frames, x = [], 0.0
    while round(x) < n:
        frames.append(int(round(x)))
        x += 2.5 - 1.5 * math.cos(2 * math.pi * x / period)
    return np.array(frames, dtype=np.int64)


def variants(n: int, names: Sequence[str] | None = None) -> list[Variant]:
    """The variants of a route of ``n`` frames (all of :data:`VARIANTS`, or those ``names``), in order."""
    if n < SHORTEST:
        raise ValueError(f"a route of {n} frames is too short for the variants")
    everything = np.arange(n)
    turn, back_to = round(0.6 * n) - 1, round(0.2 * n)  # 119 and 40 of 200
    cut, resume = round(0.4 * n), round(0.75 * n)  # 80 and 150 of 200
    build: dict[str, Callable[[], Variant]] = {
        "same": lambda: _variant("same", everything, n),
        "pace-1/3": lambda: _variant("pace-1/3", everything, n, map_step=3),
        "pace-1/2": lambda: _variant("pace-1/2", everything, n, map_step=2),
        "pace-2": lambda: _variant("pace-2", everything[::2], n),
        "pace-3": lambda: _variant("pace-3", everything[::3], n),
        "reversed": lambda: _variant("reversed", everything[::-1], n),
        "stop": lambda: _variant("stop", _stops(n), n),
        "u-turn": lambda: _variant("u-turn", np.r_[0:turn + 1, turn:back_to - 1:-1], n),
        "jump": lambda: _variant("jump", np.r_[0:cut, resume:n, cut:resume], n),
        "drift": lambda: _variant("drift", _drift(n), n, map_step=2),
        "start-off": lambda: _off_map("start-off", everything[round(0.25 * n):], n),
        "leave": lambda: _off_map("leave", np.r_[0:round(0.3 * n), round(0.5 * n):n].astype(np.int64), n),
    }
    chosen = list(VARIANTS) if names is None else list(names)
    unknown = [name for name in chosen if name not in build]
    if unknown:
        raise ValueError(f"unknown variant(s) {', '.join(unknown)} (choose from "
                         f"{', '.join(VARIANTS + OFF_MAP_VARIANTS)})")
    return [build[name]() for name in chosen]


def truth(variant: Variant, tolerance: int = TOLERANCE) -> Truth:
    """The variant's ground truth as wiloc scores it: query frame k matches map nodes within
    +-``tolerance`` of its true node (the matrix form of ``wiloc.evaluation.groundtruth``), on
    the same stretch of the map (not across a gap the map leaves out); a frame whose true node is
    :data:`NO_NODE` matches none."""
    n_query, n_map = variant.truth.size, variant.map_frames.size
    offsets = np.arange(-tolerance, tolerance + 1)
    rows = np.repeat(np.arange(n_query), offsets.size)
    true_node = np.repeat(variant.truth, offsets.size)
    cols = true_node + np.tile(offsets, n_query)
    keep = (true_node != NO_NODE) & (cols >= 0) & (cols < n_map)
    step = int(np.diff(variant.map_frames).min()) if n_map > 1 else 1
    frames = variant.map_frames
    keep[keep] = np.abs(frames[cols[keep]] - frames[true_node[keep]]) <= tolerance * step
    matrix = sparse.coo_array((np.ones(int(keep.sum()), dtype=np.bool_), (rows[keep], cols[keep])),
                              shape=(n_query, n_map)).tocsr()
    # distinct names on each axis, so that a variant is never taken for a run against itself
    return Truth(matrix, [f"q{k}:{f}" for k, f in enumerate(variant.query_frames)],
                 [f"m{f}" for f in variant.map_frames])


# ---------------------------------------------------------------------------------------- traversals

@dataclass
class Traversal:
    """A map folder and a query folder of one route, described, in route order (row i of both is
    the same place)."""

    name: str
    map_folder: Path
    query_folder: Path
    descriptor: str
    map_data: NDArray
    query_data: NDArray
    metric: str
    scale: float
    natural_max: float | None

    @property
    def length(self) -> int:
        return int(self.map_data.shape[0])


def load_traversal(name: str, data_root: Path | None = None, frames: int | None = None,
                   cache: Cache | None = None, progress: Callable[[str, int, int], None] | None = None) -> Traversal:
    """Describe (or read from the cache) the map and query folders of traversal ``name``
    (:data:`TRAVERSALS` or :data:`HELD_OUT`), aligned by file name; ``frames`` keeps the first so
    many route frames."""
    if name not in KNOWN:
        raise ValueError(f"unknown traversal {name!r} (choose from {', '.join(KNOWN)})")
    dataset, map_name, query_name, descriptor = KNOWN[name]
    root = Path(data_root or default_data_root()) / dataset
    describer = Describer(descriptor, {}, cache or Cache(), progress=progress)
    m, q = describer.entry(root / map_name), describer.entry(root / query_name)
    at = {frame: i for i, frame in enumerate(q.names)}
    common = [(i, at[frame]) for i, frame in enumerate(m.names) if frame in at]
    if len(common) < len(m.names):
        print(f"note: {name}: {len(m.names) - len(common)} map frames have no query frame of the same name "
              "and are left out", file=sys.stderr)
    map_rows, query_rows = (np.array(side, dtype=np.int64) for side in zip(*common))
    if frames is not None:
        map_rows, query_rows = map_rows[:frames], query_rows[:frames]
    return Traversal(name=name, map_folder=root / map_name, query_folder=root / query_name, descriptor=descriptor,
                     map_data=m.data[map_rows], query_data=q.data[query_rows], metric=m.metric, scale=m.scale,
                     natural_max=m.natural_max)


# ------------------------------------------------------------------------------------------------ runs

def odometry_steps(variant: Variant, noise: float, factor: float = 1.0,
                   seed: int = ODOMETRY_SEED) -> NDArray[np.float64]:
    """The query's travelled distance per frame, in route frames (0 for its first frame and a
    repeated one) times ``factor`` (a scale the query's odometry and the map's disagree by), each
    step times 1 + ``noise`` x N(0, 1), clipped at 0, drawn with ``seed``."""
    return noisy_steps(factor * np.r_[0.0, np.abs(np.diff(variant.query_frames))], noise, seed)


def decide(traversal: Traversal, variant: Variant, method: str = "catgraph",
           params: Mapping[str, Any] | None = None, exclude_recent: int = DEFAULT_EXCLUDE_RECENT,
           progress: Callable[[int, int], None] | None = None, odometry: float | None = None,
           odometry_factor: float = 1.0) -> Decisions:
    """The method's decisions on the variant: started on the re-sampled map and stepped over the
    re-sampled query's difference rows, as ``wiloc.api.localize`` runs a query folder against a
    map folder holding those frames; with ``odometry`` (a noise; ``odometry_factor``:
    :func:`odometry_steps`) and a method that takes it, as it runs with the query's and the map's
    odometry CSVs."""
    algo, given = make_method(method, params), odometry_for(method, odometry)
    algo.check_inputs(sequence=False, training=False, odometry=given is not None, map_odometry=given is not None)
    map_data = np.ascontiguousarray(traversal.map_data[variant.map_frames])
    query_data = np.ascontiguousarray(traversal.query_data[variant.query_frames])
    to_map = DifferencesTo(map_data, traversal.metric, traversal.scale)
    problem = algo.query_problem(query_data.shape[0], False, exclude_recent)
    if problem is not None:
        raise ValueError(f"{method} on {traversal.name} {variant.name}: {problem}")
    context = MapContext(
        sequence=False, exclude_recent=exclude_recent, n_map=map_data.shape[0], rows="differences",
        natural_max=traversal.natural_max, map_summary=lambda: summarize_map(ComputedDifferences(map_data, to_map), exclude_recent),
        neighbours=lambda: consecutive(map_data, traversal.metric, traversal.scale),
        arclength=None if given is None else variant.map_frames.astype(np.float64))
    algo.start(context)
    rows = candidate_blocks(ComputedDifferences(query_data, to_map), False, exclude_recent)
    steps = None if given is None else odometry_steps(variant, given, odometry_factor)
    return algo.run(rows, query_data.shape[0], odometry=steps, progress=progress)


def score(decisions: Decisions, variant: Variant) -> dict[str, float | int]:
    """wiloc's measures of a run's decisions against the variant's ground truth (as
    ``wiloc.api.evaluate`` computes them)."""
    known = truth(variant)
    summary = summarize(decisions.match, decisions.confidence, known, decisions.ranking)
    correct = correct_matches(decisions.match, known)
    confidence = decided_confidence(decisions.match, decisions.confidence)
    calibration = summarize_calibration(confidence, correct, summary.with_true_match, (CUT,)).row()
    new_place = decisions.columns.get("new_place")
    p_new = None if new_place is None else summarize_new_place(new_place, known.has_match(), (CUT,))
    return {"frames": summary.frames, "map_nodes": int(variant.map_frames.size), "decided": summary.decided,
            "r1": summary.recall_at_1, "ap": summary.auc, "ece": calibration["ece"],
            f"precision@{CUT:g}": calibration[f"precision@{CUT:g}"],
            f"accepted@{CUT:g}": calibration[f"accepted@{CUT:g}"],
            "new_place": float("nan") if p_new is None else p_new.mean_confidence,
            "new_place_ece": float("nan") if p_new is None else p_new.ece}


def run_variant(traversal: Traversal, variant: Variant, method: str = "catgraph",
                params: Mapping[str, Any] | None = None,
                progress: Callable[[int, int], None] | None = None, odometry: float | None = None,
                odometry_factor: float = 1.0) -> dict[str, Any]:
    """One run's measures (see the module's docstring for the keys; ``odometry``: the noise of
    the odometry given to a method that takes it, None when it was given none)."""
    started = time.perf_counter()
    decisions = decide(traversal, variant, method, params, progress=progress, odometry=odometry,
                       odometry_factor=odometry_factor)
    given = odometry_for(method, odometry)
    return {"traversal": traversal.name, "variant": variant.name, "method": method, "params": dict(params or {}),
            "odometry": given, "odometry_factor": odometry_factor if given is not None else None,
            **score(decisions, variant), "seconds": time.perf_counter() - started}


def over_seeds(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (traversal, variant, method) of runs that differ only in their seed: each
    measure's mean over the seeds (precision among the runs that accepted any frame), R@1's
    lowest and highest (``r1_low``, ``r1_high``) and the seeds (``seeds``), in the order first seen."""
    groups: dict[tuple[str, str, str], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["traversal"], row["variant"], row["method"]), []).append(row)
    merged = []
    for runs in groups.values():
        row = dict(runs[0])
        for key in ("r1", "ap", "ece", f"precision@{CUT:g}", f"accepted@{CUT:g}", "new_place", "new_place_ece",
                    "seconds"):
            values = np.array([np.nan if r[key] is None else r[key] for r in runs], dtype=np.float64)
            row[key] = float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")
        row[f"accepted@{CUT:g}"] = round(row[f"accepted@{CUT:g}"])
        row["r1_low"], row["r1_high"] = min(r["r1"] for r in runs), max(r["r1"] for r in runs)
        row["seeds"] = [r["params"].get("seed") for r in runs]
        merged.append(row)
    return merged


def seed_list(text: str) -> list[int]:
    """``--seeds``: comma-separated seeds or ranges, "0-4" or "0,3,7-9"."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        low, dash, high = part.partition("-")
        if not (low.isdigit() and (not dash or high.isdigit())):
            raise ValueError(f"--seeds {text!r}: give seeds or ranges of them, e.g. 0-4 or 0,3,7-9")
        seeds += list(range(int(low), int(high or low) + 1))
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds {text!r}: give at least one seed, each once")
    return seeds


def acceptance(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per method, over its runs (one per traversal and variant, or their means over seeds): the
    variants whose R@1 keeps RATIO of the same pace's (RATIO_DAY_LEFT for day_left's queries) of
    those with a same-pace run, the runs of ECE at most ECE_BAR, those whose precision among frames
    at confidence CUT or more is at least PRECISION_BAR (or that accept none), the mean R@1, and
    beside seqslam the runs where R@1 is above seqslam's: the counts the pace's acceptance reads."""
    same = {(r["method"], r["traversal"]): r["r1"] for r in rows if r["variant"] == "same"}
    seqslam = {(r["traversal"], r["variant"]): r["r1"] for r in rows if r["method"] == "seqslam"}
    summary = []
    for method in dict.fromkeys(r["method"] for r in rows):
        runs = [r for r in rows if r["method"] == method]
        paced = [r for r in runs if r["variant"] in VARIANTS[1:] and (method, r["traversal"]) in same]
        held = [r for r in paced if r["r1"] >= (RATIO_DAY_LEFT if r["traversal"].startswith("day_left/") else RATIO)
                * same[(method, r["traversal"])] - 1e-12]
        precise = [r for r in runs if r[f"accepted@{CUT:g}"] == 0 or (r[f"precision@{CUT:g}"] or 0.0) >= PRECISION_BAR]
        versus = [r for r in runs if (r["traversal"], r["variant"]) in seqslam] if method != "seqslam" else []
        summary.append({"method": method, "runs": len(runs), "ratio_held": len(held), "ratio_runs": len(paced),
                        "ece_held": sum(r["ece"] <= ECE_BAR for r in runs), "precision_held": len(precise),
                        "mean_r1": float(np.mean([r["r1"] for r in runs])),
                        "above_seqslam": sum(r["r1"] > seqslam[(r["traversal"], r["variant"])] for r in versus),
                        "versus_seqslam": len(versus),
                        "ratio_failed": [f"{r['traversal']} {r['variant']} {r['r1']:.3f}" for r in paced if r not in held]})
    return summary


def render_acceptance(summary: list[dict[str, Any]]) -> Table:
    """:func:`acceptance` as a table: a row per method, and the variants that fall short of their ratio."""
    table = Table(title=f"acceptance: R@1 >= {RATIO:g} x the same pace's ({RATIO_DAY_LEFT:g} on day_left), "
                        f"ECE <= {ECE_BAR:g}, precision >= {PRECISION_BAR:g} at confidence >= {CUT:g}",
                  title_justify="left")
    for column in ("method", "ratio held", f"ECE <= {ECE_BAR:g}", f"P@{CUT:g} >= {PRECISION_BAR:g}", "mean R@1",
                   "above seqslam", "short of the ratio"):
        table.add_column(column, justify="left" if column in ("method", "short of the ratio") else "right")
    for s in summary:
        table.add_row(s["method"], f"{s['ratio_held']} / {s['ratio_runs']}", f"{s['ece_held']} / {s['runs']}",
                      f"{s['precision_held']} / {s['runs']}", fmt(s["mean_r1"], 4),
                      f"{s['above_seqslam']} / {s['versus_seqslam']}" if s["versus_seqslam"] else "-",
                      "; ".join(s["ratio_failed"]) or "-")
    return table


# ------------------------------------------------------------------------------------------ command


def render(name: str, rows: list[dict[str, Any]], methods: Sequence[str]) -> Table:
    """One traversal's table: a row per variant; per method R@1, R@1 / same pace, AP, ECE,
    precision at confidence >= 0.9 (frames) and mean P(new place)."""
    table = Table(title=f"{name}: map {rows[0]['map']}, ground truth +-{TOLERANCE} map nodes", title_justify="left")
    table.add_column("variant")
    table.add_column("frames / nodes", justify="right")
    for method in methods:
        for column in ("R@1", "/ same", "AP", "ECE", f"P@{CUT:g} (n)", "P(new)"):
            table.add_column(f"{method}\n{column}" if column == "R@1" else column, justify="right")
    by = {(r["variant"], r["method"]): r for r in rows}
    for variant in dict.fromkeys(r["variant"] for r in rows):
        first = next(r for r in rows if r["variant"] == variant)
        cells = [variant, f"{first['frames']} / {first['map_nodes']}"]
        for method in methods:
            r = by.get((variant, method))
            if r is None:
                cells += ["-"] * 6
                continue
            same = by.get(("same", method))
            relative = r["r1"] / same["r1"] if same and same["r1"] > 0 else float("nan")
            spread = f" ({fmt(r['r1_low'])}-{fmt(r['r1_high'])})" if len(r.get("seeds", ())) > 1 else ""
            cells += [fmt(r["r1"]) + spread, fmt(relative, 2), fmt(r["ap"]), fmt(r["ece"]),
                      f"{fmt(r[f'precision@{CUT:g}'])} ({r[f'accepted@{CUT:g}']})", fmt(r["new_place"])]
        table.add_row(*cells)
    return table


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    parser = benchmark_parser(__doc__, "catgraph,seqslam", "catgraph.particles=4000")
    parser.add_argument("--traversals", default=",".join(TRAVERSALS), help="comma-separated (default: "
                        + ", ".join(TRAVERSALS) + "; 'held-out': " + ", ".join(HELD_OUT) + ")")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated (default: all of "
                        + ", ".join(VARIANTS) + "; also " + ", ".join(OFF_MAP_VARIANTS) + ")")
    parser.add_argument("--seed", type=int, default=None, help="seed of methods that take one (default: 0)")
    parser.add_argument("--seeds", default=None, help="run methods that take a seed once per seed and print "
                        "the means, e.g. 0-4 or 0,3,7-9 (instead of --seed)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"keep only the first N route frames (at least {SHORTEST})")
    add_odometry(parser, "the query's steps and the map's positions")
    parser.add_argument("--odometry-factor", type=float, default=1.0, metavar="F",
                        help="with --odometry: the query's odometry F times the map's (a scale the two disagree "
                             "by; default: 1)")
    args = parser.parse_args(argv)
    if odometry_problem(args.odometry):
        parser.error(odometry_problem(args.odometry))
    if not (math.isfinite(args.odometry_factor) and args.odometry_factor > 0):
        parser.error(f"--odometry-factor {args.odometry_factor:g}: give a factor above 0")
    if args.odometry is None and args.odometry_factor != 1.0:
        parser.error("--odometry-factor applies to runs with --odometry only")
    if args.frames is not None:
        at_least(parser, "--frames", args.frames, SHORTEST)
    check_json_target(parser, args.json)
    console, err = wide_console(), plain_console(stderr=True)  # wide enough for every method's columns

    methods = known_methods(parser, "--methods", args.methods, METHODS)
    traversal_names = [name for t in args.traversals.split(",") if t.strip()
                       for name in (HELD_OUT if t.strip() == "held-out" else [t.strip()])]
    variant_names = [v.strip() for v in args.variants.split(",") if v.strip()]
    for t in traversal_names:
        if t not in KNOWN:
            parser.error(f"unknown traversal {t!r} (choose from {', '.join(KNOWN)}, or held-out)")
    bad = [v for v in variant_names if v not in VARIANTS + OFF_MAP_VARIANTS]
    if bad:
        parser.error(f"unknown variant(s) {', '.join(bad)} (choose from {', '.join(VARIANTS + OFF_MAP_VARIANTS)})")
    if args.seed is not None and args.seeds is not None:
        parser.error("give --seed or --seeds, not both")
    try:
        seeds = seed_list(args.seeds) if args.seeds is not None else [args.seed or 0]
    except ValueError as exc:
        parser.error(str(exc))
    params = parse_params(args.param, methods)
    runs_of: dict[str, list[dict[str, Any]]] = {}  # each method's runs: one per seed, or one without a seed
    for method in methods:
        fields = METHODS[method].Params.__dataclass_fields__
        for key, value in params[method].items():  # one number given for a list of them: a list of one
            if key in fields and isinstance(fields[key].default, tuple) and isinstance(value, (int, float)):
                params[method][key] = (float(value),)
        if "seed" in fields and "seed" in params[method]:
            parser.error(f"--param {method}.seed: give seeds with --seed or --seeds")
        try:
            make_method(method, params[method])  # a bad name or value stops here, before any run
        except (WilocError, TypeError, ValueError) as exc:
            parser.error(f"--param {method}: {exc}")
        runs_of[method] = [{**params[method], "seed": seed} for seed in seeds] if "seed" in fields else [params[method]]

    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with data_errors(parser), Progress(*columns, console=err, transient=True) as bar:
        runs = bar.add_task("runs", total=len(traversal_names) * len(variant_names) * sum(map(len, runs_of.values())))
        for name in traversal_names:
            describing: dict[str, Any] = {}

            def described(label: str, done: int, total: int) -> None:
                if label not in describing:
                    describing[label] = bar.add_task(label, total=total)
                bar.update(describing[label], completed=done, total=total)

            traversal = load_traversal(name, args.data, args.frames, progress=described)
            for task in describing.values():
                bar.remove_task(task)
            table_rows = []
            for variant in variants(traversal.length, variant_names):
                for method, chosen in ((m, p) for m in methods for p in runs_of[m]):
                    task = bar.add_task(f"{name} {variant.name} {method}", total=variant.query_frames.size)
                    row = run_variant(traversal, variant, method, chosen,
                                      progress=lambda done, total, task=task: bar.update(task, completed=done),
                                      odometry=args.odometry, odometry_factor=args.odometry_factor)
                    bar.remove_task(task)
                    row["map"] = traversal.map_folder.name
                    table_rows.append(row)
                    bar.advance(runs)
            rows += table_rows
            if table_rows:
                console.print(render(name, over_seeds(table_rows) if len(seeds) > 1 else table_rows, methods))
    changed = {m: p for m, p in params.items() if p}
    said = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {args.seeds} (means; R@1's range in brackets)"
    given = sorted({r["method"] for r in rows if r["odometry"] is not None})
    odometry = (f"odometry to {', '.join(given)} (noise sd {args.odometry:g} a step, seed {ODOMETRY_SEED}; "
                f"{args.odometry_factor:g} times the map's)" if given else "no odometry")
    if rows:
        console.print(render_acceptance(acceptance(over_seeds(rows) if len(seeds) > 1 else rows)))
    console.print(f"{len(rows)} runs in {time.perf_counter() - started:.0f} s; {said}, {odometry}"
                  + (f"; parameters {changed}" if changed else "; default parameters"))
    write_json(args.json, rows, console)
    return rows


if __name__ == "__main__":
    main()

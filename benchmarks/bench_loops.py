"""Loop closure within one traversal (sequence mode): how well the confidence is calibrated.

    python benchmarks/bench_loops.py                                  # every loop: online, threshold, catgraph
    python benchmarks/bench_loops.py --loops dr+dl,out-back-on --descriptors sad,gist
    python benchmarks/bench_loops.py --param online.init=50 --json loops.json
    python benchmarks/bench_loops.py --methods catgraph --loops paced --odometry 0   # revisits at another pace

Each *loop* is one traversal in sequence mode (``wiloc localize QUERY`` without ``--map``: every
frame is compared with the frames before it, the latest ``exclude_recent`` left out), put
together from described folders by re-sampling frame indices, never by copying an image. Frame i
of every folder of a dataset is place i (Gardens Point walking: day_right, day_left,
night_right, 200 frames; Nordland: summer, winter):

    dr+dl        GP day_right 0-199, then day_left 0-199: a first pass of new places, then a revisit
    dr+nr        GP day_right 0-199, then night_right 0-199
    s+w          Nordland summer 0-999, then winter 0-999
    out-back-on  GP day_right 0-119 (out), day_left 40-119 (round a loop over part of it again),
                 then day_right 120-199 (on to new ground)
    u-turn-on    GP day_right 80-199 (out), day_left 199 down to 120 (back over part of it, walked
                 the other way), then day_right 79 down to 0 (on, past the start, to new ground);
                 re-sampled backwards, its frames still face the first pass's way

``--loops paced`` runs four whose revisit does not keep the first pass's pace: dr+dl-2x and
dr+dl-3x (day_left's every second and third frame), dr+dl-half (day_right's every second frame
first: the revisit at half its pace) and dr+dl-back (day_left walked from its end to its start).

``--odometry SD`` gives the methods that take odometry (catgraph) the traversal's own odometry:
each frame's distance from the frame before in places (one place where one part of a loop ends
and the next begins), each step times 1 + SD x N(0, 1), clipped at 0 (0: exact).

``--loops held-out`` runs six more, put together the same way from the other traversals, for
checking on loops not looked at what the five suggested: dl+dr, nr+dl (GP day_left then
day_right, night_right then day_left), w+s (Nordland winter 0-999 then summer 0-999), s+w-later
(summer then winter, frames 1000-1999), out-back-on-dl (day_left out and on, day_right round the
loop) and u-turn-on-nr (night_right out and on, day_right back).

Ground truth: frame k's true matches are the candidate frames (before k - exclude_recent) whose
place is within +-2 of its own; a frame with none is a *first visit*, and any match accepted
there is wrong. The measures are wiloc's own (``wiloc.evaluation.metrics``, ``wiloc.evaluation.reliability``): recall at
100 % precision, AP, R@1 over revisits, ECE over all decided frames, precision (and frames) at
confidence >= 0.9 and >= 0.99, and the mean P(new place) over first visits and over revisits
after their first 5 frames (a revisit is a run of consecutive frames with a true match).

From an experiment script (with ``benchmarks/`` on ``sys.path``)::

    from bench_loops import LOOPS, load_loop, run_loop
    loop = load_loop("dr+dl", "sad")
    print(run_loop(loop, "online", {"init": 50}))
"""
from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.table import Table
from scipy import sparse

from wiloc.cache.store import Cache
from wiloc.candidates import DEFAULT_EXCLUDE_RECENT
from wiloc.decisions import Decisions
from wiloc.description.differences import ComputedDifferences, candidate_blocks
from wiloc.description.differences import summarize as summarize_self
from wiloc.description.distances import DifferencesTo
from wiloc.description.traversals import Describer, descriptor_spec
from wiloc.errors import WilocError
from wiloc.evaluation.groundtruth import Truth
from wiloc.evaluation.metrics import correct_matches, decided_confidence, summarize
from wiloc.evaluation.reliability import summarize_calibration
from wiloc.methods.base import MapContext
from wiloc.methods.registry import METHODS, make_method

from bench_common import (add_odometry, check_json_target, data_errors, default_data_root, fmt, known_methods,
                          noisy_steps, odometry_for, odometry_problem, parse_params, parser as benchmark_parser,
                          wide_console, write_json)

TOLERANCE = 2  # places either side that count as the same place
CUTS = (0.9, 0.99)
SETTLE = 5  # revisit frames left out at the start of each revisit when averaging P(new place)
GP, NORDLAND = "gardens-point-walking", "nordland-summer-winter-64x32"

#: name -> (dataset, [(folder, first frame, last frame[, every n-th frame])]): backwards when last < first
LOOPS: dict[str, tuple[str, list[tuple[str, int, int]]]] = {
    "dr+dl": (GP, [("day_right", 0, 199), ("day_left", 0, 199)]),
    "dr+nr": (GP, [("day_right", 0, 199), ("night_right", 0, 199)]),
    "s+w": (NORDLAND, [("summer", 0, 999), ("winter", 0, 999)]),
    "out-back-on": (GP, [("day_right", 0, 119), ("day_left", 40, 119), ("day_right", 120, 199)]),
    "u-turn-on": (GP, [("day_right", 80, 199), ("day_left", 199, 120), ("day_right", 79, 0)]),
    # held out: put together the same way from other traversals, for checking what the loops above suggested
    "dl+dr": (GP, [("day_left", 0, 199), ("day_right", 0, 199)]),
    "nr+dl": (GP, [("night_right", 0, 199), ("day_left", 0, 199)]),
    "w+s": (NORDLAND, [("winter", 0, 999), ("summer", 0, 999)]),
    "s+w-later": (NORDLAND, [("summer", 1000, 1999), ("winter", 1000, 1999)]),
    "out-back-on-dl": (GP, [("day_left", 0, 119), ("day_right", 40, 119), ("day_left", 120, 199)]),
    "u-turn-on-nr": (GP, [("night_right", 80, 199), ("day_right", 199, 120), ("night_right", 79, 0)]),
    # paced: the revisit at another pace than the first pass, or walked the other way
    "dr+dl-2x": (GP, [("day_right", 0, 199), ("day_left", 0, 199, 2)]),
    "dr+dl-3x": (GP, [("day_right", 0, 199), ("day_left", 0, 199, 3)]),
    "dr+dl-half": (GP, [("day_right", 0, 199, 2), ("day_left", 0, 199)]),
    "dr+dl-back": (GP, [("day_right", 0, 199), ("day_left", 199, 0)]),
}
HELD_OUT = ("dl+dr", "nr+dl", "w+s", "s+w-later", "out-back-on-dl", "u-turn-on-nr")
PACED = ("dr+dl-2x", "dr+dl-3x", "dr+dl-half", "dr+dl-back")
GROUPS = {"held-out": HELD_OUT, "paced": PACED}
DEFAULT_LOOPS = tuple(name for name in LOOPS if name not in HELD_OUT + PACED)


@dataclass
class Loop:
    """One sequence-mode traversal: its descriptors in order, each frame's place and its distance
    from the frame before, in places (one where a part of the loop begins; 0 for the first)."""

    name: str
    descriptor: str
    data: NDArray
    places: NDArray[np.int64]
    steps: NDArray[np.float64]
    labels: list[str]
    metric: str
    scale: float
    natural_max: float | None


def load_loop(name: str, descriptor: str = "sad", data_root: Path | None = None,
              cache: Cache | None = None) -> Loop:
    """Describe (or read from the cache) the folders of loop ``name`` and re-sample their frames."""
    if name not in LOOPS:
        raise ValueError(f"unknown loop {name!r} (choose from {', '.join(LOOPS)})")
    dataset, segments = LOOPS[name]
    root = Path(data_root or default_data_root()) / dataset
    describer = Describer(descriptor, {}, cache or Cache())
    parts, places, steps, labels = [], [], [], []
    entry = None
    for folder, first, last, *every in segments:
        entry = describer.entry(root / folder)
        way = (every[0] if every else 1) * (1 if last >= first else -1)
        frames = np.arange(first, last + np.sign(way), way)
        if frames.max() >= len(entry.names):
            raise ValueError(f"{name}: {folder} has {len(entry.names)} frames, the loop needs frame {frames.max()}")
        parts.append(entry.data[frames])
        places.append(frames)
        steps.append(np.r_[float(bool(steps)), np.abs(np.diff(frames))])
        labels += [f"{folder}/{entry.names[f]}" for f in frames]
    assert entry is not None
    return Loop(name, descriptor, np.ascontiguousarray(np.concatenate(parts)), np.concatenate(places).astype(np.int64),
                np.concatenate(steps).astype(np.float64), labels, entry.metric, entry.scale, entry.natural_max)


def truth(loop: Loop, exclude_recent: int = DEFAULT_EXCLUDE_RECENT, tolerance: int = TOLERANCE) -> Truth:
    """Frame k matches the candidate frames j < k - exclude_recent within +-``tolerance`` places."""
    k, j = np.meshgrid(np.arange(loop.places.size), np.arange(loop.places.size), indexing="ij")
    same = (np.abs(loop.places[k] - loop.places[j]) <= tolerance) & (j < k - exclude_recent)
    names = [f"{i}:{label}" for i, label in enumerate(loop.labels)]
    return Truth(sparse.csr_array(same), names, names)


def decide(loop: Loop, method: str, params: Mapping[str, Any] | None = None,
           exclude_recent: int = DEFAULT_EXCLUDE_RECENT, odometry: float | None = None) -> Decisions:
    """The method's decisions in sequence mode, started and fed as ``wiloc.api.localize`` does
    for a folder holding the loop's frames without ``--map``; with ``odometry`` (a noise) and a
    method that takes it, as it runs with the loop's odometry CSV (``Loop.steps``, noisy)."""
    algo, given = make_method(method, params), odometry_for(method, odometry)
    algo.check_inputs(sequence=True, training=False, odometry=given is not None)
    problem = algo.query_problem(loop.places.size, True, exclude_recent)
    if problem is not None:
        raise ValueError(f"{method} on {loop.name}: {problem}")
    to_self = DifferencesTo(loop.data, loop.metric, loop.scale)
    algo.start(MapContext(sequence=True, exclude_recent=exclude_recent, natural_max=loop.natural_max,
                          map_summary=lambda: summarize_self(ComputedDifferences(loop.data, to_self), exclude_recent)))
    rows = candidate_blocks(ComputedDifferences(loop.data, to_self), True, exclude_recent)
    return algo.run(rows, loop.places.size, odometry=None if given is None else noisy_steps(loop.steps, given))


def settled_revisits(has_match: NDArray[np.bool_], settle: int = SETTLE) -> NDArray[np.bool_]:
    """Revisit frames (with a true match) after the first ``settle`` frames of their run."""
    out = np.zeros_like(has_match)
    run = 0
    for k, revisit in enumerate(has_match):
        run = run + 1 if revisit else 0
        out[k] = run > settle
    return out


def score(decisions: Decisions, loop: Loop, exclude_recent: int = DEFAULT_EXCLUDE_RECENT) -> dict[str, Any]:
    """wiloc's measures of the decisions against the loop's ground truth."""
    known = truth(loop, exclude_recent)
    summary = summarize(decisions.match, decisions.confidence, known)
    correct = correct_matches(decisions.match, known)
    confidence = decided_confidence(decisions.match, decisions.confidence)
    calibration = summarize_calibration(confidence, correct, summary.with_true_match, CUTS).row()
    has_match = known.has_match()
    new_place = np.asarray(decisions.columns.get("new_place", np.full(has_match.size, np.nan)), dtype=np.float64)
    first, revisit = ~has_match & ~np.isnan(new_place), settled_revisits(has_match) & ~np.isnan(new_place)
    return {"frames": summary.frames, "decided": summary.decided, "revisits": summary.with_true_match,
            "r100": summary.recall_at_100, "ap": summary.auc, "r1": summary.recall_at_1, "ece": calibration["ece"],
            **{f"{key}@{cut:g}": calibration[f"{key}@{cut:g}"] for cut in CUTS for key in ("precision", "accepted")},
            "new_first": float(new_place[first].mean()) if first.any() else float("nan"),
            "new_revisit": float(new_place[revisit].mean()) if revisit.any() else float("nan")}


def run_loop(loop: Loop, method: str, params: Mapping[str, Any] | None = None,
             odometry: float | None = None) -> dict[str, Any]:
    """One run's measures, with the loop, method, the odometry's noise (None: none given) and
    seconds taken."""
    started = time.perf_counter()
    decisions = decide(loop, method, params, odometry=odometry)
    return {"loop": loop.name, "descriptor": loop.descriptor, "method": method, "params": dict(params or {}),
            "odometry": odometry_for(method, odometry),
            **score(decisions, loop), "seconds": time.perf_counter() - started}


def render(rows: list[dict[str, Any]], odometry: float | None = None) -> Table:
    """A row per loop, descriptor and method (``odometry``: the noise of the odometry given to
    the methods that take it)."""
    given = "" if odometry is None else f", odometry (noise sd {odometry:g} a step) to methods that take it"
    table = Table(title=f"sequence mode, ground truth +-{TOLERANCE} places, exclude_recent "
                        f"{DEFAULT_EXCLUDE_RECENT}{given}", title_justify="left")
    for column in ("loop", "descr.", "method", "frames / revisits", "R@100P", "AP", "R@1 rev.", "ECE",
                   *(f"P@{cut:g} (n)" for cut in CUTS), "P(new) first", "P(new) revisit"):
        table.add_column(column, justify="left" if column in ("loop", "descr.", "method") else "right")
    for r in rows:
        table.add_row(r["loop"], r["descriptor"], r["method"], f"{r['frames']} / {r['revisits']}", fmt(r["r100"]),
                      fmt(r["ap"]), fmt(r["r1"]), fmt(r["ece"]),
                      *(f"{fmt(r[f'precision@{cut:g}'])} ({r[f'accepted@{cut:g}']})" for cut in CUTS),
                      fmt(r["new_first"]), fmt(r["new_revisit"]))
    return table


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    parser = benchmark_parser(__doc__, "online,threshold,catgraph", "online.init=50")
    parser.add_argument("--loops", default=",".join(DEFAULT_LOOPS),
                        help="comma-separated (default: %(default)s; " + "; ".join(
                            f"'{group}': {', '.join(names)}" for group, names in GROUPS.items()) + ")")
    parser.add_argument("--descriptors", default="sad", help="comma-separated (default: %(default)s)")
    add_odometry(parser, "the traversal's own steps")
    args = parser.parse_args(argv)
    if odometry_problem(args.odometry):
        parser.error(odometry_problem(args.odometry))
    check_json_target(parser, args.json)
    console = wide_console(200)
    loops = [loop for name in args.loops.split(",") if name.strip()
             for loop in GROUPS.get(name.strip(), [name.strip()])]
    methods = known_methods(parser, "--methods", args.methods, METHODS)
    for name in loops:
        if name not in LOOPS:
            parser.error(f"unknown loop {name!r} (choose from {', '.join(LOOPS)})")
    params = parse_params(args.param, methods)
    descriptors = [d.strip() for d in args.descriptors.split(",") if d.strip()]
    try:  # a bad name or value stops here, before any loop is described
        for method in methods:
            make_method(method, params[method])
    except WilocError as exc:
        parser.error(f"--param {method}.{exc}")
    try:
        for descriptor in descriptors:
            descriptor_spec(descriptor, {})
    except WilocError as exc:
        parser.error(f"--descriptors: {exc.problem}")
    rows = []
    with data_errors(parser):  # the data: a folder missing or unreadable
        for descriptor in descriptors:
            for name in loops:
                loop = load_loop(name, descriptor, args.data)
                rows += [run_loop(loop, method, params[method], args.odometry) for method in methods]
    console.print(render(rows, args.odometry))
    write_json(args.json, rows, console)
    return rows


if __name__ == "__main__":
    main()

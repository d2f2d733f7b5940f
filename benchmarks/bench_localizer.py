"""Per-frame latency of ``Localizer.observe`` against generated maps, with the batch cost beside it.

    python benchmarks/bench_localizer.py                          # maps of 1,000, 10,000 and 35,000 frames
    python benchmarks/bench_localizer.py --sizes 1000 --frames 50 # quicker
    python benchmarks/bench_localizer.py --sizes 35000 --methods catgraph --sequence

For every map size and method, in one run: the median wall and CPU milliseconds per frame of
``observe`` given a descriptor (descriptor excluded: the difference row and the method's step) and
given a decoded 640x360 gray image, a new one each frame (descriptor included), and the batch
cost per frame of the same query (its difference rows computed as one block, then the method run
over them). Starting the method (learning from the map's differences to itself) is timed once
and reported apart. Frames are random ``sad`` descriptors (1152 uint8 values); the query follows
the map at its own speed with noise, so the methods track as on real data.

``--sequence`` adds, for the methods that run without a map, ``observe`` in sequence mode (loop
closure within one traversal): a localizer without a map is given the map's frames as the first
part of its traversal, then the query, which revisits them; the query's frames are timed as in
map mode (descriptor excluded), when the traversal's earlier frames number as many as the map's.
Growing the traversal to the map's size takes a while (every frame is compared with all before
it: about two minutes for 35,000 frames).
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from rich.table import Table

from wiloc.description.differences import ComputedDifferences, summarize
from wiloc.description.distances import DifferencesTo, consecutive
from wiloc.description.traversals import entry_from_array
from wiloc.descriptors.registry import get_descriptor
from wiloc.localization.localizer import Localizer
from wiloc.methods.base import MapContext, TrainingRows
from wiloc.methods.registry import METHODS, make_method

from bench_common import at_least, known_methods, wide_console, whole_numbers

SPEC = get_descriptor("sad")


def route(n_map: int, n_query: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(map descriptors, query descriptors, the query's true map node per frame). Neighbouring map
    frames look alike (an AR(1) walk), as along a real route."""
    z = rng.standard_normal((n_map, SPEC.length))
    for i in range(1, n_map):
        z[i] = 0.95 * z[i - 1] + 0.31 * z[i]
    places = np.clip(np.rint(128 + 32 * z), 0, 255)
    truth = np.minimum(np.rint(np.linspace(0.1, 0.9, n_query) * n_map), n_map - 1).astype(int)
    query = np.clip(places[truth] + rng.normal(0, 20, (n_query, SPEC.length)), 0, 255)
    return places.astype(np.uint8), query.astype(np.uint8), truth


def timed(run: Callable[[], Any]) -> tuple[float, float, Any]:
    """(wall seconds, process CPU seconds, result) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = run()
    return time.perf_counter() - wall, time.process_time() - cpu, out


def training(n_map: int, map_data: np.ndarray, rng: np.random.Generator) -> TrainingRows:
    """A labelled training pair for ``trained``: 100 noisy frames against the map; every other
    frame is labelled 5 nodes off, so that training sees wrong best matches too (timing only)."""
    _, query, truth = route(n_map, 100, rng)
    query = np.clip(map_data[truth].astype(float) + rng.normal(0, 20, query.shape), 0, 255).astype(np.uint8)
    rows = DifferencesTo(map_data, SPEC.metric, SPEC.scale)(query).astype(np.float64)
    labelled = np.minimum(truth + 5 * (np.arange(truth.size) % 2), n_map - 1)
    labels = labelled[:, None] == np.arange(n_map)[None, :]
    return TrainingRows(list(rows), labels)


def measure(method: str, n_map: int, frames: int, rng: np.random.Generator,
            sequence: bool = False) -> dict[str, float]:
    """Startup, observe (descriptor excluded / included), batch and, with ``sequence``, sequence-mode
    observe per-frame times, in ms."""
    map_data, query, _ = route(n_map, frames, rng)
    names = [f"m{i:06d}" for i in range(n_map)]
    params = {"seed": 0} if method == "catgraph" else {}
    pair = training(n_map, map_data, rng) if method == "trained" else None
    entry = entry_from_array(map_data, names, SPEC)

    start_wall, _, loc = timed(lambda: Localizer(entry, method=method, training=pair, **params))
    excluded = [timed(lambda q=q: loc.observe(q))[:2] for q in query]
    # a new image each frame: catgraph takes a repeated one as no evidence and skips its step
    images = [cv2.resize(np.clip(rng.normal(128, 40, (36, 64)), 0, 255).astype(np.uint8), (640, 360))
              for _ in range(frames)]
    included = [timed(lambda image=image: loc.observe(image))[:2] for image in images]

    to_map = DifferencesTo(map_data, SPEC.metric, SPEC.scale)
    self_rows = ComputedDifferences(map_data, to_map)
    batch_method = make_method(method, params)
    steps = consecutive(map_data, SPEC.metric, SPEC.scale)
    context = MapContext(sequence=False, exclude_recent=10, n_map=n_map, natural_max=SPEC.natural_max,
                         map_summary=lambda: summarize(self_rows, 10), neighbours=lambda: steps,
                         training=(lambda: pair) if pair is not None else None)
    batch_method.start(context)
    wall, cpu, _ = timed(lambda: batch_method.run(iter(to_map(query).astype(np.float64)), frames))
    ms = 1000.0
    revisits = [timed(lambda q=q, seq=seq: seq.observe(q))[:2] for seq in [sequence_grown(method, params, map_data)]
                for q in query] if sequence else [(np.nan, np.nan)]
    return {"sequence_wall": ms * statistics.median(w for w, _ in revisits),
            "sequence_cpu": ms * statistics.median(c for _, c in revisits),
            "startup_s": start_wall,
            "excluded_wall": ms * statistics.median(w for w, _ in excluded),
            "excluded_cpu": ms * statistics.median(c for _, c in excluded),
            "included_wall": ms * statistics.median(w for w, _ in included),
            "included_cpu": ms * statistics.median(c for _, c in included),
            "batch_wall": ms * wall / frames, "batch_cpu": ms * cpu / frames}


def sequence_grown(method: str, params: dict[str, Any], first_pass: np.ndarray) -> Localizer:
    """A localizer in sequence mode that has observed ``first_pass`` (every frame new)."""
    loc = Localizer(None, descriptor=SPEC.name, method=method, **params)
    for frame in first_pass:
        loc.observe(frame)
    return loc


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1000,10000,35000", help="map sizes, comma-separated")
    parser.add_argument("--frames", type=int, default=200, help="query frames timed per method and size")
    parser.add_argument("--methods", default=",".join(m for m, cls in METHODS.items() if "differences" in cls.rows),
                        help="methods, comma-separated (those reading difference rows)")
    parser.add_argument("--sequence", action="store_true",
                        help="also time observe in sequence mode, after a first pass as long as the map (slow)")
    args = parser.parse_args(argv)
    sizes = whole_numbers(parser, "--sizes", args.sizes)
    at_least(parser, "--frames", args.frames)
    methods = known_methods(parser, "--methods", args.methods, METHODS)
    rng = np.random.default_rng(0)
    table = Table(title="Localizer.observe: median ms per frame (wall / CPU); batch: ms per frame of one run")
    columns = ["map frames", "method", "startup s", "descriptor excluded", "descriptor included", "batch",
               "observe / batch"] + (["sequence mode", "sequence / map"] if args.sequence else [])
    for column in columns:
        table.add_column(column, justify="right")
    for n_map in sizes:
        for method in methods:
            sequence = args.sequence and not {"map", "training"} & METHODS[method].needs
            r = measure(method, n_map, args.frames, rng, sequence)
            cells = [f"{n_map:,}", method, f"{r['startup_s']:.1f}",
                     f"{r['excluded_wall']:.2f} / {r['excluded_cpu']:.2f}",
                     f"{r['included_wall']:.2f} / {r['included_cpu']:.2f}",
                     f"{r['batch_wall']:.2f} / {r['batch_cpu']:.2f}",
                     f"{r['excluded_cpu'] / r['batch_cpu']:.2f}x" if r["batch_cpu"] > 0 else "-"]
            if args.sequence:
                cells += [f"{r['sequence_wall']:.2f} / {r['sequence_cpu']:.2f}",
                          f"{r['sequence_cpu'] / r['excluded_cpu']:.2f}x"] if sequence else ["-", "-"]
            table.add_row(*cells)
    wide_console().print(table)


if __name__ == "__main__":
    main()

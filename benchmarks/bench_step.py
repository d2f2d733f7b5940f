"""CPU milliseconds per query frame of a method against generated maps: what a batch run pays
per frame besides the difference kernel, split as a batch run splits it between two threads.

    python benchmarks/bench_step.py                                  # N = 10,000 and 35,000
    python benchmarks/bench_step.py --sizes 35000 --profile catgraph # and where the step's time goes

A generated ``sad`` route (``bench_localizer.route``); the query follows the map node by node
from its 10 % mark with noise, so the filters track as on real data. The rows are computed
beforehand as float32, as the difference blocks arrive. As ``Method.run`` does, what the method
computes from the rows alone (``Method.ahead``) is computed for 64 rows at a time (a batch run
does it in a helper thread: the ``ahead`` column, per frame) and each row is then stepped with
its item (the ``step`` column: the run's own thread). Figures are medians over the timed frames
(after ``--warmup`` frames: the first frame compiles numba kernels) of this thread's CPU time.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time

import numpy as np

from bench_common import at_least, known_methods, whole_numbers
from bench_localizer import SPEC, route
from wiloc.description.differences import ComputedDifferences, summarize
from wiloc.description.distances import DifferencesTo, consecutive
from wiloc.methods.base import AHEAD_ROWS, MapContext
from wiloc.methods.registry import METHODS, make_method


def rows_and_context(n_map: int, frames: int, rng: np.random.Generator) -> tuple[np.ndarray, MapContext]:
    """The query's float32 difference rows and the map context of a generated route."""
    map_data, _, _ = route(n_map, 1, rng)
    nodes = np.arange(frames) + n_map // 10
    query = np.clip(map_data[nodes].astype(np.float64) + rng.normal(0, 20, (frames, SPEC.length)), 0, 255)
    to_map = DifferencesTo(map_data, SPEC.metric, SPEC.scale)
    rows = to_map(query.astype(np.uint8))
    steps = consecutive(map_data, SPEC.metric, SPEC.scale)
    summary = summarize(ComputedDifferences(map_data, to_map), 10)
    context = MapContext(sequence=False, exclude_recent=10, n_map=n_map, natural_max=SPEC.natural_max,
                         map_summary=lambda: summary, neighbours=lambda: steps)
    return rows, context


def step_ms(method: str, rows: np.ndarray, context: MapContext, warmup: int,
            profile: bool) -> tuple[list[float], list[float]]:
    """CPU ms of each frame's ahead and step after the first ``warmup`` frames (the steps
    profiled to stdout when asked)."""
    m = make_method(method, {})
    m.start(context)
    ahead_times, step_times = [], []
    profiler = cProfile.Profile() if profile else None
    for first in range(0, len(rows), AHEAD_ROWS):
        chunk = rows[first:first + AHEAD_ROWS]
        cpu = time.thread_time()
        computed = m.ahead(chunk)
        ahead_times += [1000.0 * (time.thread_time() - cpu) / len(chunk)] * len(chunk)
        for k, row in enumerate(chunk, first):
            if k == warmup and profiler is not None:
                profiler.enable()
            cpu = time.thread_time()
            m.step(row, ahead=None if computed is None else computed[k - first])
            step_times.append(1000.0 * (time.thread_time() - cpu))
    if profiler is not None:
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(18)
    return ahead_times[warmup:], step_times[warmup:]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="10000,35000", help="map sizes, comma-separated")
    parser.add_argument("--methods", default="catgraph,online")
    parser.add_argument("--frames", type=int, default=300, help="query frames per size")
    parser.add_argument("--warmup", type=int, default=20, help="frames not timed")
    parser.add_argument("--profile", default="", help="methods to profile (cProfile, comma-separated, of --methods)")
    args = parser.parse_args()
    at_least(parser, "--warmup", args.warmup, 0)
    if args.frames < args.warmup + 2:  # the 10 % and 90 % marks take two timed frames
        parser.error(f"--frames must be at least --warmup + 2 = {args.warmup + 2} "
                     f"(the first {args.warmup} are not timed), got {args.frames}")
    sizes = whole_numbers(parser, "--sizes", args.sizes)
    methods = known_methods(parser, "--methods", args.methods, METHODS)
    profiled = known_methods(parser, "--profile", args.profile, methods)
    most = min(sizes) - min(sizes) // 10  # the query follows the map from its 10 % mark to its end
    if args.frames > most:
        parser.error(f"--frames must be at most {most} for a map of {min(sizes)} frames (the query starts "
                     f"at its 10 % mark), got {args.frames}")
    print(f"{'N':>7} {'method':<10} {'ahead ms':>9} {'step ms':>9} {'p10 ms':>7} {'p90 ms':>7}")
    for n_map in sizes:
        rows, context = rows_and_context(n_map, args.frames, np.random.default_rng(n_map))
        for method in methods:
            ahead, t = step_ms(method, rows, context, args.warmup, method in profiled)
            q = statistics.quantiles(t, n=10)
            print(f"{n_map:>7,} {method:<10} {statistics.median(ahead):>9.3f} {statistics.median(t):>9.3f} "
                  f"{q[0]:>7.3f} {q[-1]:>7.3f}", flush=True)


if __name__ == "__main__":
    main()

"""End-to-end `wiloc.api.localize` at scale against the SAD kernel time of the same blocks, and
`describe` with 1 and 2 workers.

    python benchmarks/bench_scale.py                              # N = 1,000 .. 35,000 (long)
    python benchmarks/bench_scale.py --sizes 1000,5000 --repeat 3 # quicker
    python benchmarks/bench_scale.py --sizes 0 --describe         # the describe table only

One query of N frames against one map of N frames, map mode, generated ``sad`` descriptors (an
AR(1) walk, the query following the map with noise; see bench_localizer.py). Each traversal is a
folder of N empty ``.jpg`` files whose descriptors are put into a fresh cache beforehand, so
``localize`` runs exactly as on real folders and finds every frame described. Every run is a
child process (its peak RSS is its own): *cold* starts from a cache holding only the
descriptors, *warm* repeats it on the cache the cold run left. ``trained`` learns from a labelled
pair of min(1,000, N / 2) frames against the same map.

The kernel column is the SAD kernel alone (``pairwise_blocks``, 1024-row blocks) over the blocks
the method needs, in this run: query x map for every method, plus map x map for ``online``, plus
training query x map for ``trained``, measured again right before each cold run, so that load on
the (shared) machine hits both alike; ratio = the median over ``--repeat`` runs of cold (or warm)
wall / that run's kernel wall, and cpu ratio the same of CPU seconds (what the run costs against
the kernel, less moved by the load than wall time: other jobs take cores, not CPU seconds).
Times are medians over the runs; CPU seconds are the child's process time (all its threads).

The describe table times ``api.describe`` on the 600 Gardens Point images (fresh cache each
run) with ``jobs`` 1 and 2 (and with ``--scheduler``, on that Dask cluster with 2 workers),
against plain JPEG decoding, in the same run. Each describe runs in a fresh process and pays the
start of its workers, as one ``wiloc describe`` call does.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench_common import at_least, data_errors, folder_problem, known_methods, last_error_line, whole_numbers
from bench_describe import data_root, gardens_point_folders, gardens_point_frames, plain_decode_rate
from bench_localizer import SPEC, route
from wiloc.cache.entries import FrameRecord, StoredEntry
from wiloc.cache.store import Cache
from wiloc.description.describing import folder_header
from wiloc.description.traversals import descriptor_spec
from wiloc.errors import WilocError

METHODS = ("online", "threshold", "trained", "catgraph")
KERNEL_BLOCKS = {"online": ("query", "map"), "threshold": ("query",), "trained": ("query", "train"),
                 "catgraph": ("query",)}


def seed_folder(folder: Path, data: np.ndarray, names: list[str], cache: Cache) -> None:
    """A folder of empty image files whose `sad` descriptors the cache already holds, under the
    key `describe` looks the folder up by."""
    folder.mkdir(parents=True)
    records = {}
    for name, row in zip(names, data):
        path = folder / name
        path.touch()
        stat = path.stat()
        records[name] = FrameRecord(name, stat.st_size, stat.st_mtime_ns, "", row, "", 64, 32)
    cache.write_entry(StoredEntry(folder_header(folder, SPEC), records), complete=True)


def make_case(root: Path, n: int) -> dict[str, Any]:
    """Map, query and training folders of a generated route, described into ``root/cache``."""
    rng = np.random.default_rng(n)
    cache = Cache(root / "cache")
    map_data, query, _ = route(n, n, rng)
    names = [f"f{i:06d}.jpg" for i in range(n)]
    seed_folder(root / "map", map_data, names, cache)
    seed_folder(root / "query", query, names, cache)
    # training: frames at known map nodes, named as those nodes (ground truth aligned by name);
    # every fourth is unrelated noise, so that training sees wrong best matches too
    nodes = np.unique(np.rint(np.linspace(0, n - 1, min(1000, n // 2))).astype(int))
    noisy = np.clip(map_data[nodes].astype(float) + rng.normal(0, 20, (nodes.size, SPEC.length)), 0, 255)
    noisy[::4] = np.clip(128 + 32 * rng.standard_normal(noisy[::4].shape), 0, 255)  # some wrong best matches
    seed_folder(root / "train", noisy.astype(np.uint8), [names[i] for i in nodes], cache)
    return {"query": query, "map": map_data, "train": noisy.astype(np.uint8)}


def peak_rss_mb() -> float:
    """This process's peak resident memory (VmHWM: unlike ru_maxrss, not inherited across exec
    from the forked parent)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child_localize(args: argparse.Namespace) -> dict[str, float]:
    """One localize run in this (child) process: wall, CPU, peak RSS."""
    from wiloc import api
    from wiloc.evaluation.truth_source import TruthSource

    root = Path(args.root)
    training = None
    if args.method == "trained":
        training = api.Training(root / "train", root / "map", TruthSource("aligned", tolerance=2))
    extra = {"scheduler": args.scheduler} if args.scheduler else {}
    wall, cpu = time.perf_counter(), time.process_time()
    run = api.localize(root / "query", reference=root / "map", method=args.method, training=training,
                       cache=Cache(root / "cache"), jobs=1, **extra)
    return {"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu,
            "rss_mb": peak_rss_mb(),
            "decided": int(run.decisions.decided.sum())}


def child_kernel(args: argparse.Namespace) -> dict[str, float]:
    """The SAD kernel alone over query x map, map x map and training x map: wall and CPU each."""
    from wiloc.cache.store import Cache
    from wiloc.description.distances import pairwise, pairwise_blocks

    cache = Cache(Path(args.root) / "cache")
    entries = {e.folder: cache.read_entry(e.key) for e in cache.list_entries()}
    data = {Path(folder).name: entry.data for folder, entry in entries.items()}
    pairwise(data["map"][:9], data["map"][:9], SPEC.metric, SPEC.scale)  # compile outside the timing
    out: dict[str, float] = {}
    for side in ("query", "map", "train"):
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in pairwise_blocks(data[side], data["map"], SPEC.metric, SPEC.scale):
            pass
        out[f"{side}_wall"], out[f"{side}_cpu"] = time.perf_counter() - wall, time.process_time() - cpu
    return out


def run_child(*argv: str) -> dict[str, float]:
    """Run this script as a child with ``argv`` and return the JSON it prints last. A child that
    fails ends the benchmark with its last error line (what went wrong, the end of its traceback),
    which a CalledProcessError would leave unsaid."""
    done = subprocess.run([sys.executable, __file__, *argv], capture_output=True, text=True, check=False)
    if done.returncode:
        sys.exit(f"error: {' '.join(argv)}: {last_error_line(done.stderr, done.returncode)}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def median_of(runs: list[dict[str, float]]) -> dict[str, float]:
    return {key: statistics.median(r[key] for r in runs) for key in runs[0]}


def folder_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def scale_rows(n: int, methods: list[str], repeat: int, scheduler: str | None, work: Path) -> list[str]:
    """The table rows of one size N."""
    root = work / f"n{n}"
    shutil.rmtree(root, ignore_errors=True)
    make_case(root, n)
    cache = root / "cache"
    rows = []
    for method in methods:
        argv = ["--child", "localize", "--root", str(root), "--method", method]
        argv += ["--scheduler", scheduler] if scheduler else []
        kernel, cold, warm, size = [], [], [], []
        for _ in range(repeat):  # each run right after its own kernel run: load on the machine hits both alike
            measured = run_child("--child", "kernel", "--root", str(root))
            kernel.append({key: sum(measured[f"{side}_{key}"] for side in KERNEL_BLOCKS[method])
                           for key in ("wall", "cpu")})
            for derived in cache.iterdir():
                if derived.name != "descriptors":
                    shutil.rmtree(derived)
            cold.append(run_child(*argv))
            size.append({"mb": sum(folder_mb(d) for d in cache.iterdir() if d.name != "descriptors")})
            warm.append(run_child(*argv))
        k, c, w = median_of(kernel), median_of(cold), median_of(warm)
        ratios = {f"{run}_{key}": statistics.median(r[key] / kk[key] for r, kk in zip(runs, kernel))
                  for run, runs in (("cold", cold), ("warm", warm)) for key in ("wall", "cpu")}
        rows.append(f"{n:>7,} {method:<10} {k['wall']:>8.2f} {k['cpu']:>8.2f} {c['wall']:>8.2f} {c['cpu']:>8.2f} "
                    f"{ratios['cold_wall']:>6.2f}x {ratios['cold_cpu']:>8.2f}x {w['wall']:>8.2f} {w['cpu']:>8.2f} "
                    f"{ratios['warm_wall']:>6.2f}x {ratios['warm_cpu']:>8.2f}x "
                    f"{max(c['rss_mb'], w['rss_mb']):>8.0f} {median_of(size)['mb']:>9.1f}")
    shutil.rmtree(root, ignore_errors=True)
    return rows


def child_describe(args: argparse.Namespace) -> dict[str, float]:
    """One describe of the Gardens Point folders in this (child) process, as one `wiloc
    describe` call: workers (or the Dask client) start inside the timing."""
    from wiloc import api

    folders = gardens_point_folders(Path(args.root))
    with tempfile.TemporaryDirectory() as temp:
        start = time.perf_counter()
        reports = api.describe(folders, args.method, cache=Cache(Path(temp)), jobs=args.jobs, scheduler=args.scheduler)
        return {"rate": sum(report.computed for report in reports) / (time.perf_counter() - start)}


def describe_rows(data: Path, frames: list[Path], repeat: int, descriptors: list[str],
                  scheduler: str | None) -> Iterator[str]:
    """The describe table's lines as they are measured (its header first): images/s of each
    descriptor with 1 and 2 processes (and on the Dask ``scheduler`` with 2 workers, when given),
    against plain decoding of ``frames`` (``data``'s), medians; each run a fresh process. The
    first column is as wide as its longest label, so that every figure stands under its header."""
    decoding = "cv2.imread full size"
    width = max(len(label) for label in ("descriptor", decoding, *descriptors))
    yield f"{'descriptor':<{width}} {'jobs':>7} {'images/s':>9} {'/decode':>7} {'vs 1':>8}"
    decode = statistics.median(plain_decode_rate(frames) for _ in range(repeat))
    yield f"{decoding:<{width}} {'':>7} {decode:>9.1f} {1.0:>7.2f} {'':>8}"
    ways = {"1": ["--jobs", "1"], "2": ["--jobs", "2"],
            **({"dask": ["--jobs", "2", "--scheduler", scheduler]} if scheduler else {})}
    for name in descriptors:
        rates: dict[str, list[float]] = {way: [] for way in ways}
        for _ in range(repeat):  # alternate, so that load on the machine hits each alike
            for way, argv in ways.items():
                rates[way].append(run_child("--child", "describe", "--root", str(data), "--method", name, *argv)["rate"])
        one = statistics.median(rates["1"])
        for way in ways:
            r = statistics.median(rates[way])
            vs = f"{r / one:>7.2f}x" if way != "1" else f"{'':>8}"
            yield f"{name:<{width}} {way:>7} {r:>9.1f} {r / decode:>7.2f} {vs}"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1000,5000,20000,35000", help="N, comma-separated (0: none)")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure; medians are reported")
    parser.add_argument("--scheduler", help="localize (and describe) on this Dask scheduler, or 'local'")
    parser.add_argument("--describe", action="store_true", help="also the describe table")
    parser.add_argument("--descriptors", default="sad,gist,brisk-gist")
    parser.add_argument("--data", help="folder holding gardens-point-walking/ (default: $WILOC_DATA)")
    parser.add_argument("--work", help="scratch folder (default: a temporary one)")
    parser.add_argument("--child", choices=("localize", "kernel", "describe"), help=argparse.SUPPRESS)
    parser.add_argument("--jobs", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--root", help=argparse.SUPPRESS)
    parser.add_argument("--method", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        children: dict[str, Callable[[argparse.Namespace], dict[str, float]]] = {
            "localize": child_localize, "kernel": child_kernel, "describe": child_describe}
        print(json.dumps(children[args.child](args)))
        return
    at_least(parser, "--repeat", args.repeat)
    sizes = [n for n in whole_numbers(parser, "--sizes", args.sizes, 0) if n > 0]
    methods = known_methods(parser, "--methods", args.methods, METHODS)
    descriptors = args.descriptors.split(",")
    try:
        for name in descriptors:
            descriptor_spec(name)
    except WilocError as exc:
        parser.error(f"--descriptors: {exc.problem}")
    if args.work and folder_problem(Path(args.work)):
        parser.error(f"--work {args.work}: {folder_problem(Path(args.work))}")
    frames: list[Path] = []
    if args.describe:
        with data_errors(parser):  # the data: a folder missing or holding no frames stops here, before any run
            frames = gardens_point_frames(data_root(args.data))
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}, medians of {args.repeat}")
    if sizes:
        header = (f"{'N':>7} {'method':<10} {'kernel s':>8} {'kern cpu':>8} {'cold s':>8} {'cold cpu':>8} "
                  f"{'ratio':>7} {'cpu ratio':>9} {'warm s':>8} {'warm cpu':>8} {'ratio':>7} {'cpu ratio':>9} "
                  f"{'RSS MB':>8} {'cache MB':>9}")
        print(header)
        print("-" * len(header))
        with tempfile.TemporaryDirectory(dir=args.work) as temp:
            for n in sizes:
                for row in scale_rows(n, methods, args.repeat, args.scheduler, Path(temp)):
                    print(row, flush=True)
        print("kernel: SAD kernel wall and CPU s over the blocks the method needs, measured before each cold run;"
              " ratio (cpu ratio): median of each run's wall (CPU) / its kernel's wall (CPU); cache MB: what"
              " localize left in the cache besides the descriptors.")
    if args.describe:
        print()
        for row in describe_rows(data_root(args.data), frames, args.repeat, descriptors, args.scheduler):
            print(row, flush=True)


if __name__ == "__main__":
    main()

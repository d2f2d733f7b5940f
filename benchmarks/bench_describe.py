"""Describe throughput and CPU: images/s of each descriptor on the 600 Gardens Point images with
`--jobs` 1 and 2, against plainly decoding the same JPEGs at full size with cv2.imread, and the
CPU milliseconds per image of the calling process and of its workers.

    python benchmarks/bench_describe.py [DATA_ROOT] [--repeat 3]
        (DATA_ROOT default: $WILOC_DATA, else ../shared/data)

Each describe runs in a fresh process, with a fresh temporary cache, over the three folders in
one `describe_folders` call (as one `wiloc describe` call: one stream of frames, workers start once). CPU is the
process's and its waited-for children's user + system time (getrusage): on a machine that other
jobs share, wall-time ratios move with the load, while CPU per image shows what `--jobs 2`
costs: on 2 idle cores its speed-up is at most 2 x CPU(jobs 1) / CPU(jobs 2). Figures are
medians over `--repeat` runs, alternating the ways, so that load hits each alike.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folders
from wiloc.descriptors.registry import get_descriptor
from wiloc.sources.frames import list_traversal

from bench_common import at_least, data_errors

TRAVERSALS = ("day_left", "day_right", "night_right")
DESCRIPTORS = ("sad", "gist", "brisk-gist")
JOBS = (1, 2)


def data_root(argument: str | None) -> Path:
    """The data folder: the argument, else $WILOC_DATA, else shared/data beside the repository."""
    if argument:
        return Path(argument)
    env = os.environ.get("WILOC_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared/data"


def gardens_point_folders(data: Path) -> list[Path]:
    """The Gardens Point traversals timed, under the data folder ``data``."""
    return [data / "gardens-point-walking" / t for t in TRAVERSALS]


def gardens_point_frames(data: Path) -> list[Path]:
    """The image files of the Gardens Point traversals under ``data``; a WilocError naming a
    folder that is missing or holds no frames."""
    return [path for folder in gardens_point_folders(data) for path in list_traversal(folder).frames]


def plain_decode_rate(paths: list[Path]) -> float:
    """Images/s of cv2.imread at full size, in colour as a plain user would, single process."""
    start = time.perf_counter()
    for path in paths:
        if cv2.imread(str(path)) is None:
            raise RuntimeError(f"{path}: cannot decode")
    return len(paths) / (time.perf_counter() - start)


def _cpu_seconds(who: int) -> float:
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


def describe_run(name: str, folders: list[Path], jobs: int) -> dict[str, float]:
    """One describe of the folders in this process, fresh cache: images/s and CPU ms per image
    of this process and of its workers (children, counted once they are waited for)."""
    spec = get_descriptor(name)
    with tempfile.TemporaryDirectory() as temp:
        cache = Cache(Path(temp))
        wall = time.perf_counter()
        parent, children = _cpu_seconds(resource.RUSAGE_SELF), _cpu_seconds(resource.RUSAGE_CHILDREN)
        computed = sum(report.computed for report in describe_folders(folders, spec, cache, jobs))
        parent = _cpu_seconds(resource.RUSAGE_SELF) - parent
        children = _cpu_seconds(resource.RUSAGE_CHILDREN) - children
        wall = time.perf_counter() - wall
    return {"rate": computed / wall, "parent_ms": 1000 * parent / computed,
            "workers_ms": 1000 * children / computed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_root", nargs="?", help="folder holding gardens-point-walking/")
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure; medians are reported")
    parser.add_argument("--child", nargs=2, metavar=("DESCRIPTOR", "JOBS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    at_least(parser, "--repeat", args.repeat)
    data = data_root(args.data_root)
    folders = gardens_point_folders(data)
    if args.child:
        print(json.dumps(describe_run(args.child[0], folders, int(args.child[1]))))
        return
    with data_errors(parser):  # the data: a folder missing or holding no frames stops here, before any run
        paths = gardens_point_frames(data)
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}, medians of {args.repeat}")
    decode = statistics.median(plain_decode_rate(paths) for _ in range(args.repeat))
    print(f"{'what':<22}{'jobs':>5}{'images/s':>10}{'/decode':>8}{'vs 1':>7}"
          f"{'CPU ms/image: caller':>22}{'workers':>9}{'total':>7}")
    print(f"{'cv2.imread full size':<22}{'':>5}{decode:>10.1f}{1.0:>8.2f}")
    for name in DESCRIPTORS:
        runs: dict[int, list[dict[str, float]]] = {jobs: [] for jobs in JOBS}
        for _ in range(args.repeat):
            for jobs in JOBS:
                argv = [sys.executable, __file__, str(folders[0].parents[1]), "--child", name, str(jobs)]
                done = subprocess.run(argv, check=True, capture_output=True, text=True)
                runs[jobs].append(json.loads(done.stdout.strip().splitlines()[-1]))
        one = statistics.median(r["rate"] for r in runs[1])
        for jobs in JOBS:
            median = {key: statistics.median(r[key] for r in runs[jobs]) for key in runs[jobs][0]}
            total = statistics.median(r["parent_ms"] + r["workers_ms"] for r in runs[jobs])
            print(f"{name:<22}{jobs:>5}{median['rate']:>10.1f}{median['rate'] / decode:>8.2f}"
                  f"{median['rate'] / one:>6.2f}x{median['parent_ms']:>22.2f}{median['workers_ms']:>9.2f}{total:>7.2f}",
                  flush=True)


if __name__ == "__main__":
    main()

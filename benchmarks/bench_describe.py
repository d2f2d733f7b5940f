"""Describe throughput: images/s of each descriptor on the 600 Gardens Point images, through
`describe_folder` with a fresh temporary cache and the default --jobs, against plainly decoding
the same JPEGs at full size with cv2.imread.

    python benchmarks/bench_describe.py [DATA_ROOT]   (default: $WILOC_DATA, else ../shared/data)
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2

from wiloc.cache import Cache
from wiloc.describing import describe_folder
from wiloc.descriptors.registry import get_descriptor
from wiloc.frames import list_traversal
from wiloc.workers import keeping_pools

TRAVERSALS = ("day_left", "day_right", "night_right")
DESCRIPTORS = ("sad", "gist", "brisk-gist")


def data_root(argument: str | None) -> Path:
    """The data folder: the argument, else $WILOC_DATA, else shared/data beside the repository."""
    if argument:
        return Path(argument)
    env = os.environ.get("WILOC_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared/data"


def plain_decode_rate(folders: list[Path]) -> float:
    """Images/s of cv2.imread at full size, in colour as a plain user would, single process."""
    paths = [p for folder in folders for p in list_traversal(folder).frames]
    start = time.perf_counter()
    for path in paths:
        if cv2.imread(str(path)) is None:
            raise RuntimeError(f"{path}: cannot decode")
    return len(paths) / (time.perf_counter() - start)


def describe_rate(name: str, folders: list[Path]) -> tuple[int, float]:
    """(images described, images/s) of one descriptor over the folders, fresh cache, default jobs."""
    spec = get_descriptor(name)
    with tempfile.TemporaryDirectory() as temp:
        cache = Cache(Path(temp))
        start = time.perf_counter()
        with keeping_pools():  # one set of workers for all folders, as one `wiloc describe` call
            computed = sum(describe_folder(folder, spec, cache).computed for folder in folders)
        return computed, computed / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_root", nargs="?", help="folder holding gardens-point-walking/")
    args = parser.parse_args()
    folders = [data_root(args.data_root) / "gardens-point-walking" / t for t in TRAVERSALS]
    decode = plain_decode_rate(folders)
    print(f"{'what':<22}{'images':>8}{'images/s':>11}{'ratio':>8}")
    print(f"{'cv2.imread full size':<22}{sum(len(list_traversal(f).frames) for f in folders):>8}"
          f"{decode:>11.1f}{1.0:>8.2f}")
    for name in DESCRIPTORS:
        count, rate = describe_rate(name, folders)
        print(f"{name:<22}{count:>8}{rate:>11.1f}{rate / decode:>8.2f}")


if __name__ == "__main__":
    main()

"""Time the full N x N difference matrix per kernel against a straightforward numpy version.

    python benchmarks/bench_kernels.py            # N = 20,000 (a few minutes on 2 cores)
    python benchmarks/bench_kernels.py --n 4000   # quicker

Our kernel runs blockwise through ``pairwise_blocks`` (one preallocated float32 block, the matrix
is never stored). The numpy baseline is timed on the first ``--baseline-rows`` query rows only and
extrapolated linearly to N rows (said so in the table). Data are random frames shaped like the
real descriptors: ``sad`` 1152 uint8 values quantised as 128 + 32 z, ``hamming`` 1600 bytes
(25 BRISK descriptors of 64 bytes), ``sqeuclidean`` 512 non-negative float32 values (GIST-like).
"""
from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Sequence

import numba
import numpy as np

from wiloc.description.distances import pairwise, pairwise_blocks, simd_path

from bench_common import at_least


def make_frames(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Random frames of one descriptor kind."""
    if kind == "sad":
        return np.clip(np.rint(128 + 32 * rng.standard_normal((n, 1152))), 0, 255).astype(np.uint8)
    if kind == "hamming":
        return rng.integers(0, 256, size=(n, 1600), dtype=np.uint8)
    return rng.random((n, 512), dtype=np.float32)


def numpy_rows(kind: str, queries: np.ndarray, frames: np.ndarray) -> None:
    """The straightforward numpy difference of some query rows to every frame, row by row or by block."""
    if kind == "sad":
        wide = frames.astype(np.int16)
        for q in queries.astype(np.int16):
            np.abs(wide - q).sum(axis=1)
    elif kind == "hamming":
        words = frames.view(np.uint64)
        for q in queries.view(np.uint64):
            np.bitwise_count(words ^ q).sum(axis=1)
    else:
        norms = np.einsum("ij,ij->i", frames, frames)
        for start in range(0, len(queries), 1024):
            q = queries[start : start + 1024]
            np.maximum(np.einsum("ij,ij->i", q, q)[:, None] + norms[None, :] - 2 * q @ frames.T, 0)


def timed(run: Callable[[], None]) -> tuple[float, float]:
    """(wall seconds, process CPU seconds) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    run()
    return time.perf_counter() - wall, time.process_time() - cpu


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=20_000, help="frames (the matrix is N x N)")
    parser.add_argument("--block-rows", type=int, default=1024, help="query rows per block of our kernel")
    parser.add_argument(
        "--baseline-rows", type=int, default=100, help="query rows timed for the numpy baseline (x10 for sqeuclidean)"
    )
    kinds = ["sad", "hamming", "sqeuclidean"]
    parser.add_argument("--kinds", nargs="+", default=kinds, choices=kinds)
    args = parser.parse_args(argv)
    for option, value in (("--n", args.n), ("--block-rows", args.block_rows), ("--baseline-rows", args.baseline_rows)):
        at_least(parser, option, value)

    rng = np.random.default_rng(0)
    metric_of = {"sad": "l1", "hamming": "hamming", "sqeuclidean": "sqeuclidean"}
    print(
        f"N = {args.n}, SIMD path {simd_path()}, {numba.get_num_threads()} numba threads, "
        f"block {args.block_rows} rows, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    header = (
        f"{'kernel':<12} {'values':>7} {'dtype':>8} {'ours s':>8} {'ours cpu s':>11} "
        f"{'numpy s':>9} {'numpy rows':>11} {'numpy/ours':>11}"
    )
    print(header)
    print("-" * len(header))
    for kind in args.kinds:
        frames = make_frames(kind, args.n, rng)
        metric = metric_of[kind]
        pairwise(frames[:9], frames[:9], metric)  # compile (or load the numba cache) outside the timing

        def ours() -> None:
            for _ in pairwise_blocks(frames, frames, metric, block_rows=args.block_rows):  # noqa: B023 - timed at once
                pass

        wall, cpu = timed(ours)
        rows = min(args.n, args.baseline_rows * (10 if kind == "sqeuclidean" else 1))
        base, _ = timed(lambda: numpy_rows(kind, frames[:rows], frames))  # noqa: B023 - timed at once
        base *= args.n / rows
        print(
            f"{kind:<12} {frames.shape[1]:>7} {frames.dtype!s:>8} {wall:>8.2f} {cpu:>11.2f} "
            f"{base:>9.1f} {rows:>11} {base / wall:>11.1f}"
        )
    print("numpy s: timed on 'numpy rows' query rows and extrapolated linearly to N rows.")


if __name__ == "__main__":
    main()

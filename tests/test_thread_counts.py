"""A run decides the same whatever number of threads computes it.

numba's parallel kernels (``sad``), OpenCV and the describe workers split their work by thread
count; every value must still be summed in one order, so that a machine with more cores decides
exactly as one with fewer. Each case describes and localizes the demo route twice in
subprocesses, with one thread everywhere and with two, each on its own cache, and compares the
results rows. (Not yet so: ``sqeuclidean`` and ``cosine`` differences, ``gist``'s, come from
OpenBLAS, whose float sums change with its thread count.)
"""
from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pandas as pd
import pytest

from wiloc import demo

CLI = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


@pytest.fixture(scope="module")
def route(tmp_path_factory: pytest.TempPathFactory) -> demo.DemoRoute:
    return demo.make_demo_route(tmp_path_factory.mktemp("route"))


def _localize(route: demo.DemoRoute, descriptor: str, method: str, threads: int, tmp_path: Path) -> pd.DataFrame:
    out = tmp_path / f"{threads}.csv"
    env = {**os.environ, **dict.fromkeys(THREAD_VARIABLES, str(threads)), "WILOC_CACHE": str(tmp_path / f"cache{threads}")}
    args = ["localize", str(route.queries[0]), "--map", str(route.reference), "--descriptor", descriptor,
            "--method", method, "--jobs", str(threads), "--out", str(out)]
    proc = subprocess.run([sys.executable, "-c", CLI, *args], env=env, capture_output=True, text=True, timeout=600,
                          check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return pd.read_csv(out, comment="#", dtype=str, keep_default_na=False)


@pytest.mark.slow
@pytest.mark.parametrize(("descriptor", "method"), [("sad", "catgraph"), ("sad", "online")])
def test_one_thread_and_two_decide_alike(route: demo.DemoRoute, descriptor: str, method: str, tmp_path: Path) -> None:
    with ThreadPoolExecutor(2) as pool:
        one, two = pool.map(lambda n: _localize(route, descriptor, method, n, tmp_path), (1, 2))
    assert len(one) == len(list(route.queries[0].iterdir()))
    pd.testing.assert_frame_equal(one, two)

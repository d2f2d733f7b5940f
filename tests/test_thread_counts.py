"""A run decides the same whatever number of threads and whichever SIMD loops compute it.

numba's parallel kernels, OpenCV and the describe workers split their work by thread count, and
numpy picks its loops by the CPU's instruction sets; every value must still come out the same, so
that a machine with more cores or other instruction sets decides exactly as this one. Each test
describes and localizes the demo route (``sad``) twice in subprocesses, each on its own cache, and
compares the results rows. (``sqeuclidean`` and ``cosine`` differences, ``gist``'s, are summed in
float64 and rounded below a float64 bound, so OpenBLAS's thread count leaves them alike too:
docs/kernels.md.)
"""
from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from wiloc import demo

CLI = "import sys; from wiloc.cli import app; sys.exit(app(prog_name='wiloc'))"
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
#: numpy's AVX-512 dispatch targets this CPU runs, by the names NPY_DISABLE_CPU_FEATURES takes
#: (numpy's private core module: ``numpy._core`` from numpy 2, ``numpy.core`` before).
_multiarray_umath = (np._core if hasattr(np, "_core") else np.core)._multiarray_umath
_NUMPY_AVX512 = [f for f in _multiarray_umath.__cpu_dispatch__
                 if (f.startswith("AVX512") or f == "X86_V4") and _multiarray_umath.__cpu_features__.get(f)]


def _localize(demo_route: demo.DemoRoute, method: str, jobs: int, run_env: dict[str, str], out: Path) -> pd.DataFrame:
    """``wiloc localize`` of the demo route's first query (``sad``) in a subprocess with ``run_env``
    added to the environment, on its own cache beside ``out``."""
    env = {**os.environ, **run_env, "WILOC_CACHE": str(out.with_suffix(".cache"))}
    args = ["localize", str(demo_route.queries[0]), "--map", str(demo_route.reference), "--method", method,
            "--jobs", str(jobs), "--out", str(out)]
    proc = subprocess.run([sys.executable, "-c", CLI, *args], env=env, capture_output=True, text=True, timeout=600,
                          check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = pd.read_csv(out, comment="#", dtype=str, keep_default_na=False)
    assert len(rows) == len(list(demo_route.queries[0].iterdir()))
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("method", ["catgraph", "online"])
def test_one_thread_and_two_decide_alike(demo_route: demo.DemoRoute, method: str, tmp_path: Path) -> None:
    with ThreadPoolExecutor(2) as pool:
        one, two = pool.map(lambda n: _localize(demo_route, method, n, dict.fromkeys(THREAD_VARIABLES, str(n)),
                                                tmp_path / f"{n}.csv"), (1, 2))
    pd.testing.assert_frame_equal(one, two)


@pytest.mark.slow
@pytest.mark.skipif(not _NUMPY_AVX512, reason="numpy has no AVX-512 loops to turn off on this CPU")
@pytest.mark.parametrize("method", ["catgraph", "online"])
def test_numpy_s_avx512_loops_on_and_off_decide_alike(demo_route: demo.DemoRoute, method: str, tmp_path: Path) -> None:
    clean = {"NPY_DISABLE_CPU_FEATURES": ""}
    off = {"NPY_DISABLE_CPU_FEATURES": " ".join(_NUMPY_AVX512)}
    with ThreadPoolExecutor(2) as pool:
        on_, off_ = pool.map(lambda e: _localize(demo_route, method, 1, e[1], tmp_path / f"{e[0]}.csv"),
                             (("on", clean), ("off", off)))
    pd.testing.assert_frame_equal(on_, off_)

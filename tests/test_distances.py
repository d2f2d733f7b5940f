"""Difference kernels against plain numpy: exact integers for l1/hamming, stated tolerances otherwise."""
from __future__ import annotations

import itertools
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numba import njit

from wiloc.description.distances import METRICS, _panel, consecutive, pairwise, pairwise_blocks, simd_path
from wiloc.descriptors import registry

SAD_SCALE = 1.0 / (32 * 1152)  # 1152 values quantised as 128 + 32 z
# (query rows, reference rows, values): odd lengths, single rows, empty sides, more rows than a
# parallel panel (64), counts that are not multiples of the 4 x 4 tile.
SHAPES = [(1, 1, 1), (0, 5, 10), (5, 0, 10), (4, 3, 0), (7, 13, 1152), (70, 33, 67), (5, 130, 3), (131, 6, 200)]


def _l1_exact(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a[:, None, :].astype(np.int64) - b[None, :, :].astype(np.int64)).sum(axis=-1)


def _hamming_exact(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=-1).sum(axis=-1, dtype=np.int64)


def _sq_exact(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    diff = a[:, None, :].astype(np.float64) - b[None, :, :].astype(np.float64)
    return (diff**2).sum(axis=-1)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


@pytest.mark.parametrize("shape", SHAPES)
def test_l1_uint8_is_exact(shape: tuple[int, int, int], rng: np.random.Generator) -> None:
    n, m, d = shape
    a = rng.integers(0, 256, (n, d), dtype=np.uint8)
    b = rng.integers(0, 256, (m, d), dtype=np.uint8)
    exact = _l1_exact(a, b)
    got = pairwise(a, b, "l1")
    assert got.dtype == np.float32 and got.shape == (n, m)
    np.testing.assert_array_equal(got, exact.astype(np.float32))
    np.testing.assert_array_equal(pairwise(a, b, "l1", SAD_SCALE), (exact * SAD_SCALE).astype(np.float32))


@pytest.mark.parametrize("shape", SHAPES)
def test_hamming_is_exact(shape: tuple[int, int, int], rng: np.random.Generator) -> None:
    n, m, d = shape
    a = rng.integers(0, 256, (n, d), dtype=np.uint8)
    b = rng.integers(0, 256, (m, d), dtype=np.uint8)
    np.testing.assert_array_equal(pairwise(a, b, "hamming"), _hamming_exact(a, b).astype(np.float32))


def test_hamming_on_brisk_frames_counts_differing_bits(rng: np.random.Generator) -> None:
    """brisk-gist frames: 25 BRISK descriptors of 64 bytes each, flattened to 1600 bytes."""
    frames = rng.integers(0, 256, (9, 25, 64), dtype=np.uint8)
    flat = frames.reshape(9, 1600)
    got = pairwise(flat, flat, "hamming")
    for i in range(9):
        for j in range(9):
            assert got[i, j] == np.unpackbits(np.bitwise_xor(frames[i], frames[j])).sum()
    assert np.all(np.diag(got) == 0)


@pytest.mark.parametrize("shape", SHAPES)
def test_l1_float32_within_float32_rounding(shape: tuple[int, int, int], rng: np.random.Generator) -> None:
    """Sums of non-negative float32 terms in vector lanes: relative error below 2e-5."""
    n, m, d = shape
    a = rng.standard_normal((n, d)).astype(np.float32)
    b = rng.standard_normal((m, d)).astype(np.float32)
    exact = np.abs(a[:, None, :].astype(np.float64) - b[None, :, :]).sum(axis=-1)
    np.testing.assert_allclose(pairwise(a, b, "l1"), exact, rtol=2e-5, atol=0)


def test_l1_mixed_dtypes_uses_float_values(rng: np.random.Generator) -> None:
    a = rng.integers(0, 256, (6, 40), dtype=np.uint8)
    b = rng.random((5, 40), dtype=np.float32) * 255
    exact = np.abs(a[:, None, :].astype(np.float64) - b[None, :, :]).sum(axis=-1)
    np.testing.assert_allclose(pairwise(a, b, "l1"), exact, rtol=2e-5)


@pytest.mark.parametrize("shape", SHAPES)
def test_sqeuclidean_within_stated_tolerance(shape: tuple[int, int, int], rng: np.random.Generator) -> None:
    """Matrix-product form in float32: |error| <= 1e-5 * (|a - mu|^2 + |b - mu|^2), mu = mean of b."""
    n, m, d = shape
    a = rng.random((n, d), dtype=np.float32)
    b = rng.random((m, d), dtype=np.float32)
    got = pairwise(a, b, "sqeuclidean")
    mu = b.astype(np.float64).mean(axis=0) if m else 0.0
    na = ((a - mu) ** 2).sum(axis=1)
    nb = ((b - mu) ** 2).sum(axis=1)
    assert np.all(got >= 0)
    assert np.all(np.abs(got - _sq_exact(a, b)) <= 1e-5 * (na[:, None] + nb[None, :]) + 1e-12)


def test_sqeuclidean_survives_a_large_common_offset(rng: np.random.Generator) -> None:
    """Rows near 1000 differing by ~1: without centring, float32 cancellation loses everything."""
    b = (1000 + rng.standard_normal((20, 512))).astype(np.float32)
    a = (1000 + rng.standard_normal((15, 512))).astype(np.float32)
    np.testing.assert_allclose(pairwise(a, b, "sqeuclidean"), _sq_exact(a, b), rtol=1e-4)


def test_cosine_matches_definition_and_zero_rows(rng: np.random.Generator) -> None:
    a = rng.standard_normal((7, 33)).astype(np.float32)
    b = rng.standard_normal((9, 33)).astype(np.float32)
    b[4] = 0
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    norms = np.linalg.norm(a64, axis=1)[:, None] * np.linalg.norm(b64, axis=1)[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        exact = 1 - (a64 @ b64.T) / norms
    exact[:, 4] = 1.0  # a zero row is similar to nothing
    got = pairwise(a, b, "cosine", scale=2.0)
    np.testing.assert_allclose(got, 2.0 * exact, atol=1e-6)
    assert np.all((got >= 0) & (got <= 4.0))


@pytest.mark.parametrize("metric", METRICS)
@pytest.mark.parametrize("block_rows", [1, 4, 64, 1000])
def test_blocks_cover_the_matrix(metric: str, block_rows: int, rng: np.random.Generator) -> None:
    a = rng.integers(0, 256, (37, 48), dtype=np.uint8)
    b = rng.integers(0, 256, (11, 48), dtype=np.uint8)
    whole = pairwise(a, b, metric, scale=0.5)
    stops = []
    for start, stop, block in pairwise_blocks(a, b, metric, scale=0.5, block_rows=block_rows):
        assert block.shape == (stop - start, 11) and block.dtype == np.float32
        np.testing.assert_array_equal(block, whole[start:stop])  # float metrics: summed in float64
        stops.append((start, stop))
    assert stops[0][0] == 0 and stops[-1][1] == 37
    assert all(prev[1] == nxt[0] for prev, nxt in itertools.pairwise(stops))
    assert max(stop - start for start, stop in stops) <= block_rows


@pytest.mark.parametrize("metric", ["sqeuclidean", "cosine"])
def test_a_float_row_alone_is_the_row_of_any_block(metric: str, rng: np.random.Generator) -> None:
    """BLAS orders a product's sums by the rows it is given at once (and by its threads and the
    CPU's kernels); summed in float32 a frame's row alone (a Localizer's) differed from the same row
    in a batch's block in its last digits. Summed in float64 and rounded once, it is the same."""
    b = (rng.random((700, 512), dtype=np.float32) * 0.3).astype(np.float32)
    a = b[:300] + rng.normal(0, 0.01, (300, 512)).astype(np.float32)
    whole = pairwise(a, b, metric)
    assert all(np.array_equal(pairwise(a[i:i + 1], b, metric)[0], whole[i]) for i in range(0, 300, 7))
    for block_rows in (3, 100, 257):
        assert all(np.array_equal(block, whole[start:stop])
                   for start, stop, block in pairwise_blocks(a, b, metric, block_rows=block_rows))


@pytest.mark.parametrize("metric", ["sqeuclidean", "cosine"])
def test_a_row_equal_to_a_reference_row_is_0_alone_and_in_any_block(metric: str, rng: np.random.Generator) -> None:
    """Near 0 float32 keeps every digit of the float64 sum's rounding: a query repeating a map
    row (a copied folder, a frame recorded twice) got 4e-13 or 0 by its block and BLAS's threads,
    a stream and a batch apart. A difference below the rounding's bound is 0."""
    b = np.abs(rng.standard_normal((300, 514))).astype(np.float32)
    a = np.concatenate([b[:150], b[100:250]])
    whole = pairwise(a, b, metric)
    assert not whole[np.arange(150), np.arange(150)].any() and not whole[np.arange(150, 300), np.arange(100, 250)].any()
    assert all(np.array_equal(pairwise(a[i:i + 1], b, metric)[0], whole[i]) for i in range(300))
    assert (np.sort(whole, axis=1)[:, 1] > 0).all()  # every other row stays apart


def test_out_is_filled_and_checked(rng: np.random.Generator) -> None:
    a = rng.integers(0, 256, (5, 64), dtype=np.uint8)
    out = np.full((5, 5), -1, np.float32)
    assert pairwise(a, a, "l1", out=out) is out
    np.testing.assert_array_equal(out, _l1_exact(a, a).astype(np.float32))
    with pytest.raises(ValueError, match="out must be"):
        pairwise(a, a, "l1", out=np.empty((5, 4), np.float32))
    with pytest.raises(ValueError, match="out must be"):
        pairwise(a, a, "l1", out=np.empty((5, 5), np.float64))


def test_bad_inputs_raise() -> None:
    a = np.zeros((3, 8), np.uint8)
    with pytest.raises(ValueError, match="unknown metric"):
        pairwise(a, a, "euclid")
    with pytest.raises(ValueError, match="differ in length"):
        pairwise(a, np.zeros((3, 9), np.uint8), "l1")
    with pytest.raises(ValueError, match="hamming needs uint8"):
        pairwise(a.astype(np.float32), a.astype(np.float32), "hamming")
    with pytest.raises(ValueError, match="2-D"):
        pairwise(a[0], a, "l1")
    with pytest.raises(ValueError, match="block_rows"):
        next(pairwise_blocks(a, a, "l1", block_rows=0))


@pytest.mark.skipif(simd_path() == "generic", reason="not an x86 CPU")
def test_sad_kernel_uses_psadbw() -> None:
    fresh = njit(_panel.py_func)  # numba cannot inspect code loaded from its cache
    a = np.zeros((2, 64), np.uint8)
    fresh(a, a, np.empty((2, 2), np.float32), 0, 2, 1.0)
    asm = "".join(fresh.inspect_asm().values())
    register = {"avx512": "zmm", "avx2": "ymm", "sse2": "xmm"}[simd_path()]
    assert any("psadbw" in line and register in line for line in asm.splitlines())


_PORTABILITY_SCRIPT = """
import numpy as np
from wiloc.description.distances import pairwise, simd_path
rng = np.random.default_rng(3)
a = rng.integers(0, 256, (9, 200), dtype=np.uint8)
b = rng.integers(0, 256, (6, 200), dtype=np.uint8)
l1 = np.abs(a[:, None].astype(np.int64) - b[None].astype(np.int64)).sum(-1)
ham = np.unpackbits(a[:, None] ^ b[None], axis=-1).sum(-1)
assert np.array_equal(pairwise(a, b, "l1"), l1), "l1"
assert np.array_equal(pairwise(a, b, "hamming"), ham), "hamming"
fa, fb = a.astype(np.float32), b.astype(np.float32)
assert np.allclose(pairwise(fa, fb, "l1"), l1, rtol=1e-5), "l1 float32"
print(simd_path())
"""


def test_kernels_compile_for_other_cpus() -> None:
    """Numba compiles for the CPU it is told: an AVX2-only CPU and a CPU with no x86 features.

    Numba's cache keys code by CPU name and features, so these builds sit beside the host's in the
    usual cache and later runs load them instead of compiling again.
    """
    haswell = "+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+avx,+avx2,+fma,+bmi,+bmi2,+f16c,+lzcnt,+movbe"
    targets = {
        "avx2": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": haswell},
        "generic": {"NUMBA_CPU_NAME": "generic"},
    }

    def run(path: str) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, **targets[path], "NUMBA_NUM_THREADS": "1"}
        command = [sys.executable, "-c", _PORTABILITY_SCRIPT]
        return subprocess.run(command, env=env, capture_output=True, text=True, timeout=300, check=False)

    with ThreadPoolExecutor(2) as pool:
        results = dict(zip(targets, pool.map(run, targets)))
    for path, result in results.items():
        assert result.returncode == 0, result.stderr[-2000:]
        assert result.stdout.strip() == path


def test_metrics_is_the_registry_list() -> None:
    assert METRICS is registry.METRICS


@pytest.mark.parametrize("metric", sorted(METRICS))
def test_consecutive_gives_the_kernel_s_difference_of_each_row_to_the_next(metric: str) -> None:
    rng = np.random.default_rng(7)
    rows = rng.integers(0, 256, (40, 96), dtype=np.uint8)
    if metric in ("sqeuclidean", "cosine"):
        rows = rows.astype(np.float32)
    steps = consecutive(rows, metric, 0.25, block_rows=16)
    full = pairwise(rows, rows, metric, 0.25)
    want = full[np.arange(39), np.arange(1, 40)]
    if metric in ("l1", "hamming"):  # integer sums: exact
        np.testing.assert_array_equal(steps, want)
    else:
        np.testing.assert_allclose(steps, want, rtol=1e-5, atol=1e-6)


def test_idle_kernel_threads_sleep_unless_the_user_chose_otherwise() -> None:
    probe = "import os, wiloc.description.distances; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    default = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    chosen = subprocess.run([sys.executable, "-c", probe], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                            capture_output=True, text=True, check=True)
    assert (default.stdout.strip(), chosen.stdout.strip()) == ("PASSIVE", "ACTIVE")

"""Where numba's compiled kernels go (wiloc/jitcache.py) and how ``WILOC_SIMD`` narrows the kernels'
instruction set (wiloc.description.distances.simd_path), each in a fresh process: both are read at start."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import write_images

from wiloc.description.distances import SIMD_PATHS, _cpu_features

SIMD_AND_CACHE = ("NUMBA_CACHE_DIR", "WILOC_SIMD", "WILOC_CACHE")


def _python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if k not in SIMD_AND_CACHE}
    return subprocess.run([sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True,
                          timeout=120, check=False)


def _numba_cache(**env: str) -> str:
    return _python("import os, wiloc; print(os.environ['NUMBA_CACHE_DIR'])", **env).stdout.strip()


def test_numba_caches_under_wiloc_s_cache_folder_unless_told_otherwise(tmp_path: Path) -> None:
    assert _numba_cache(WILOC_CACHE=str(tmp_path)) == str(tmp_path / "numba")
    assert _numba_cache(WILOC_CACHE=str(tmp_path), WILOC_SIMD="sse2") == str(tmp_path / "numba-sse2")
    assert _numba_cache(WILOC_CACHE=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / "mine")) == str(tmp_path / "mine")
    # a folder of the user's held every path's kernels alike: a narrower path loaded the widest's
    assert _numba_cache(NUMBA_CACHE_DIR=str(tmp_path / "mine"), WILOC_SIMD="sse2") == str(tmp_path / "mine" / "numba-sse2")
    inherited = str(tmp_path / "mine" / "numba-sse2")  # as a worker process started by such a run sees it
    assert _numba_cache(NUMBA_CACHE_DIR=inherited, WILOC_SIMD="sse2") == inherited


def test_a_cache_folder_that_cannot_be_written_sends_the_kernels_to_the_temporary_folder(tmp_path: Path) -> None:
    """numba refuses to define a cached kernel it cannot store, or stores it beside the package's
    source, where nothing of wiloc's may go: a cache folder that cannot be made or written (shared
    read-only; here under a file) sends the kernels to the user's folder in the temporary folder."""
    import getpass
    import tempfile

    (tmp_path / "file").write_text("not a folder")
    blocked = str(tmp_path / "file" / "cache")
    assert _numba_cache(WILOC_CACHE=blocked) == str(Path(tempfile.gettempdir()) / f"wiloc-numba-{getpass.getuser()}")
    assert _numba_cache(WILOC_CACHE=blocked, WILOC_SIMD="sse2").endswith(f"wiloc-numba-sse2-{getpass.getuser()}")
    assert _numba_cache(WILOC_CACHE=str(tmp_path / "new" / "deep")) == str(tmp_path / "new" / "deep" / "numba")
    assert not (tmp_path / "new").exists()  # nothing made to find out


def test_wiloc_simd_narrows_the_path_but_never_widens_it() -> None:
    widest = next(name for name, feature in SIMD_PATHS.items() if not feature or feature in _cpu_features())
    order = list(SIMD_PATHS)
    for forced in order:
        got = _python("from wiloc.description.distances import simd_path; print(simd_path())", WILOC_SIMD=forced)
        assert got.stdout.strip() == order[max(order.index(forced), order.index(widest))], got.stderr[-1000:]


@pytest.mark.parametrize("value", ["avx3", "AVX2"])
def test_an_unknown_instruction_set_is_one_line_naming_the_variable(value: str, tmp_path: Path) -> None:
    got = _python(f"import sys; from wiloc.cli import app; sys.argv[1:] = ['describe', {str(tmp_path)!r}]; "
                  "sys.exit(app(prog_name='wiloc'))", WILOC_SIMD=value, WILOC_CACHE=str(tmp_path))
    assert got.returncode != 0
    assert got.stderr.strip() == f"error: WILOC_SIMD: unknown instruction set {value!r}; expected one of " \
                                 f"{', '.join(SIMD_PATHS)}"


def test_every_instruction_set_gives_the_same_differences_to_the_last_bit(tmp_path: Path) -> None:
    """SPEC section 11: the float32 ``l1`` kernel's sums do not depend on the vector width (each of
    16 lanes sums the same values on every path), nor do the integer kernels'; a block, single
    rows and a route's steps, with rows that are not a whole number of chunks."""
    code = ("import hashlib, numpy as np\n"
            "from wiloc.description.distances import DifferencesTo, consecutive\n"
            "rng = np.random.default_rng(0)\n"
            "parts = []\n"
            "rows = {'float32': lambda shape: rng.standard_normal(shape).astype(np.float32),\n"
            "        'uint8': lambda shape: rng.integers(0, 256, shape, dtype=np.uint8)}\n"
            "for dtype, metric in (('float32', 'l1'), ('uint8', 'l1'), ('uint8', 'hamming')):\n"
            "    for d in (7, 514):\n"
            "        a, b = rows[dtype]((23, d)), rows[dtype]((37, d))\n"
            "        to_b = DifferencesTo(b, metric, 0.5)\n"
            "        parts += [to_b(a), to_b(a[3:4]), consecutive(a, metric, 0.5)]\n"
            "print(hashlib.sha256(b''.join(np.ascontiguousarray(p).tobytes() for p in parts)).hexdigest())\n")
    digests = {}
    for path in SIMD_PATHS:
        got = _python(code, WILOC_SIMD=path, WILOC_CACHE=str(tmp_path))
        assert got.returncode == 0, got.stderr[-1000:]
        digests[path] = got.stdout.strip()
    assert len(set(digests.values())) == 1, digests


def _localize(root: Path, patch: str = "") -> subprocess.CompletedProcess[str]:
    """``wiloc localize`` of a small query against a small map (it compiles or loads the difference
    kernel) with ``root`` as the cache, after ``patch`` (Python run first)."""
    for seed, name in enumerate(("map", "query")):
        if not (root / name).exists():
            write_images(root / name, 8, seed=seed)
    args = ["localize", str(root / "query"), "--map", str(root / "map"), "--method", "threshold",
            "--out", str(root / "run.csv")]
    return _python(f"import sys\n{patch}\nfrom wiloc.cli import app\nsys.argv[1:] = {args!r}\n"
                   "sys.exit(app(prog_name='wiloc'))", WILOC_CACHE=str(root))


def _numba_cache_line(root: Path) -> str:
    return f"error: {root / 'numba'}: cannot"


def test_a_damaged_numba_cache_file_is_one_line_naming_the_folder(tmp_path: Path) -> None:
    """numba (0.68) raises an unpickling error for a truncated kernel file or index, every run
    until the folder is removed: one line naming the folder and that removing it is safe."""
    assert _localize(tmp_path).returncode == 0
    [kernel] = (tmp_path / "numba").rglob("*.nbc")
    [index] = (tmp_path / "numba").rglob("*.nbi")
    for damage in (lambda: os.truncate(kernel, kernel.stat().st_size // 2), lambda: os.truncate(index, 0)):
        damage()
        got = _localize(tmp_path)
        assert got.returncode == 1, got.stderr[-2000:]
        [line] = got.stderr.splitlines()
        assert line.startswith(_numba_cache_line(tmp_path)) and "read numba's compiled kernels" in line, line
        assert line.endswith("removing the folder is safe (the kernels compile again)"), line


def test_a_full_disk_while_numba_saves_a_kernel_is_one_line_naming_the_folder(tmp_path: Path) -> None:
    full_disk = ("import builtins, errno, numba.core.caching as caching\n"
                 "def full(file, mode='r', *args, **kwargs):\n"
                 "    if 'w' in mode:\n"
                 "        raise OSError(errno.ENOSPC, 'No space left on device')\n"
                 "    return builtins.open(file, mode, *args, **kwargs)\n"
                 "caching.open = full")  # numba's own files only: the module's name for the builtin
    got = _localize(tmp_path, full_disk)
    assert got.returncode == 1, got.stderr[-2000:]
    [line] = got.stderr.splitlines()
    assert line.startswith(_numba_cache_line(tmp_path)) and "write numba's compiled kernels" in line, line
    assert "No space left on device" in line, line

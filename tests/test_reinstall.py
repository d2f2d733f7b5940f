"""Installing, running and re-installing in one virtual environment keeps ``wiloc`` working.

The README's two Quick start commands install the package (``pip install .``), run the demo, then
install it again editable into the same ``.venv``. numba used to write its compiled kernels into
``site-packages/wiloc/**/__pycache__``; pip does not know those files, the editable re-install left
the folder behind, and it shadowed the real package as an empty namespace package. Here the same
sequence runs offline in a new virtual environment that sees this one's packages through a
``.pth`` file, on a copy of the project's sources.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import wiloc

REPO = Path(__file__).resolve().parents[1]
# A numba-cached kernel, compiled (and cached) by the installed package.
KERNEL = """
import numpy as np
from wiloc.description.distances import pairwise
assert pairwise(np.zeros((1, 8), np.uint8), np.ones((1, 8), np.uint8), "l1")[0, 0] == 8
"""


def _run(*args: str | Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([str(a) for a in args], env=env, capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, f"{args}: {proc.stdout[-1000:]}{proc.stderr[-2000:]}"
    return proc


def test_reinstalling_editable_after_a_numba_cached_run_keeps_wiloc_working(tmp_path: Path) -> None:
    src = tmp_path / "src"
    shutil.copytree(REPO / "wiloc", src / "wiloc", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    site = Path(_run(python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])",
                     env=dict(os.environ)).stdout.strip())
    outer = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "outer.pth").write_text("\n".join(sorted(outer)) + "\n", encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # wiloc's default, not this run's
    env.update(WILOC_CACHE=str(tmp_path / "cache"), PIP_NO_INDEX="1", PIP_DISABLE_PIP_VERSION_CHECK="1")
    install = [python, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation"]
    _run(*install, src, env=env)
    _run(python, "-c", KERNEL, env=env)
    assert not [p for p in (site / "wiloc").rglob("*") if p.suffix in (".nbi", ".nbc")]
    assert list((tmp_path / "cache").glob("numba*/**/*.nbi"))  # numba-<value> under WILOC_SIMD
    _run(*install, "-e", src, env=env)
    assert not (site / "wiloc").exists()  # nothing left behind to shadow the editable package
    version = _run(venv / "bin" / "wiloc", "--version", env=env)
    assert version.stdout.strip() == f"wiloc {wiloc.__version__}"

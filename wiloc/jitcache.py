"""Where numba keeps wiloc's compiled kernels: under wiloc's cache folder, never in the package.

The kernels are compiled with ``cache=True``. By default numba writes them into ``__pycache__``
beside the module's source, i.e. into the installed package; pip does not know those files, so
uninstalling or re-installing (``pip install -e .`` over ``pip install .``) leaves a
``site-packages/wiloc`` folder behind that then shadows the real package as an empty namespace
package. Importing wiloc therefore points ``NUMBA_CACHE_DIR`` at ``<cache root>/numba`` (the cache
root is ``$WILOC_CACHE``, else the per-user cache folder) unless the variable is already set.
numba reads the variable when it compiles or loads a kernel, and wiloc imports numba only later,
with the first kernel it needs. The variable is set in ``os.environ``, so subprocesses (Dask
workers, ``--jobs``) share the same compiled kernels.

numba keys its cache by CPU name and features, but not by the instruction set ``$WILOC_SIMD``
makes wiloc's kernels use (wiloc.description.distances.simd_path): kernels compiled under it go into
``<cache root>/numba-<value>`` instead, so that no run loads another path's code.

numba (0.68) cannot recover from a damaged file of its cache (a truncated kernel or index: an
unpickling error every run until the folder is removed; numba/numba#10434) nor go on when saving a
kernel fails (a full disk), and offers no supported way to: :func:`numba_cache_failure` turns such
an error into one line naming the folder, which is always safe to remove.
"""
from __future__ import annotations

import getpass
import os
import tempfile
from pathlib import Path
from types import TracebackType

import platformdirs

from wiloc.errors import WilocError

#: The environment variable numba reads for its cache folder.
NUMBA_CACHE_VARIABLE = "NUMBA_CACHE_DIR"
#: Environment variable naming a narrower instruction set for wiloc's kernels than the CPU's
#: widest (wiloc.description.distances.simd_path, docs/kernels.md).
SIMD_VARIABLE = "WILOC_SIMD"
#: The module of numba that reads and writes its cache files.
NUMBA_CACHING = "numba.core.caching"


def cache_root() -> Path:
    """wiloc's cache folder: ``$WILOC_CACHE`` (made absolute: numba resolves its folder when it
    compiles, perhaps after a change of directory), else the per-user cache folder."""
    env = os.environ.get("WILOC_CACHE")
    return Path(env).absolute() if env else Path(platformdirs.user_cache_dir("wiloc"))


def place_numba_cache() -> Path:
    """Point numba's cache at ``<cache root>/numba`` (``numba-<$WILOC_SIMD>`` when that is set)
    unless ``NUMBA_CACHE_DIR`` is set; return the folder. Where that folder cannot be written (a
    cache folder shared read-only), the kernels go to ``wiloc-numba-<user>`` (the same suffix) in
    the temporary folder: numba refuses to define a cached kernel it could not store, so every
    command ended in its traceback there. A ``NUMBA_CACHE_DIR`` of the user's gets the
    ``numba-<$WILOC_SIMD>`` subfolder (once: a subprocess inherits the folder made so): one
    folder for every path loaded one path's kernels into another."""
    forced = os.environ.get(SIMD_VARIABLE, "")
    name = f"numba-{forced}" if forced else "numba"
    given = os.environ.get(NUMBA_CACHE_VARIABLE)
    if given is not None:
        if forced and Path(given).name != name:
            os.environ[NUMBA_CACHE_VARIABLE] = str(Path(given) / name)
        return Path(os.environ[NUMBA_CACHE_VARIABLE])
    folder = cache_root() / name
    if not _writable(folder):
        folder = Path(tempfile.gettempdir()) / f"wiloc-{name}-{getpass.getuser()}"
    os.environ[NUMBA_CACHE_VARIABLE] = str(folder)
    return folder


def _writable(folder: Path) -> bool:
    """Whether ``folder`` can be written, or made where its nearest existing parent can be: checked
    without creating anything (a cache folder is made on first use)."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    return existing.is_dir() and os.access(existing, os.W_OK | os.X_OK)


def numba_cache_failure(exc: BaseException) -> WilocError | None:
    """The one-line error for ``exc`` when numba's caching module raised it, or it was raised while
    handling one such (a damaged cache file, a full disk); None otherwise. It names the folder
    (``NUMBA_CACHE_DIR``), whether reading or writing failed and why."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        steps = _caching_steps(exc.__traceback__)
        if steps:
            problem = exc.strerror if isinstance(exc, OSError) and exc.strerror else f"{type(exc).__name__}: {exc}"
            action = "write" if "save_overload" in steps else "read"
            folder = os.environ.get(NUMBA_CACHE_VARIABLE, "numba's cache folder")
            return WilocError(folder, f"cannot {action} numba's compiled kernels ({problem}); removing the folder "
                                      "is safe (the kernels compile again)")
        exc = exc.__cause__ or exc.__context__
    return None


def _caching_steps(tb: TracebackType | None) -> set[str]:
    """The names of the functions of numba's caching module a traceback passes through."""
    steps = set()
    while tb is not None:
        if tb.tb_frame.f_globals.get("__name__") == NUMBA_CACHING:
            steps.add(tb.tb_frame.f_code.co_name)
        tb = tb.tb_next
    return steps

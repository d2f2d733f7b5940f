"""numpy files read without running anything they name. numpy saves an object array (a list of
index arrays per query, frame names kept as Python strings) as a pickle, and
``np.load(allow_pickle=True)`` would run whatever code such a file names. Here the pickle is
read by an unpickler that builds numpy arrays, numbers, text and lists only, so a hostile file
is an error rather than a program; plain arrays are read as numpy reads them, without pickles."""
from __future__ import annotations

import pickle
import zipfile
from pathlib import Path
from typing import IO, Any

import numpy as np

#: What a pickled numpy object array may name: the array's and its elements' constructors (as
#: numpy 1.x and 2.x spell their modules), nothing else.
_NUMPY_GLOBALS: dict[str, Any] = {"_reconstruct": np.empty(0).__reduce__()[0], "ndarray": np.ndarray,
                                  "dtype": np.dtype, "scalar": np.int64(0).__reduce__()[0]}
_NUMPY_MODULES = frozenset({"numpy", "numpy.core.multiarray", "numpy._core.multiarray"})


class _ArraysOnly(pickle.Unpickler):
    """An unpickler that builds numpy arrays, numbers, text and lists only; any other global a
    pickle names is an UnpicklingError, never imported or called."""

    def find_class(self, module: str, name: str) -> Any:
        if module in _NUMPY_MODULES and name in _NUMPY_GLOBALS:
            return _NUMPY_GLOBALS[name]
        raise pickle.UnpicklingError(f"it names {module}.{name}, which is no part of a numpy array")


def npy_header(file: IO[bytes]) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype in a ``.npy`` stream's header, the stream left after it; ValueError
    when it has none."""
    version = np.lib.format.read_magic(file)
    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read_header(file)
    return shape, dtype


def read_npy(file: IO[bytes]) -> Any:
    """The array of a ``.npy`` stream (a file opened in binary, a zip member; both seek): a plain array as
    numpy reads it, an object array unpickled by :class:`_ArraysOnly` (whatever its pickle
    holds, which may be no array). ValueError, EOFError or pickle.UnpicklingError when it is no
    such stream or names anything else."""
    start = file.tell()
    _, dtype = npy_header(file)
    if dtype.hasobject:
        return _ArraysOnly(file).load()
    file.seek(start)
    return np.lib.format.read_array(file, allow_pickle=False)


def read_npz(path: Path) -> dict[str, Any]:
    """Every array of a ``.npz`` archive (``np.savez``), by name, each read as :func:`read_npy`
    reads it, object arrays included. zipfile.BadZipFile when it is no zip archive."""
    arrays = {}
    with zipfile.ZipFile(path) as archive:
        for member in archive.namelist():
            if member.endswith(".npy"):
                with archive.open(member) as file:
                    arrays[member[:-len(".npy")]] = read_npy(file)
    return arrays

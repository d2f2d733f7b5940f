"""Reading a descriptor matrix the user brings: N frames x D values, with frame names and a metric.

Formats (chosen by suffix):

- ``.npy``: the N x D matrix; names from ``names_path`` (one per line, or the first column of a
  ``.csv``; a first cell ``name``/``frame``/``file`` is a header) or generated ``frame000000``...
- ``.csv``: one row per frame, first column the frame name, the rest numbers; an optional header
  row (recognised when none of its value cells is a number).
- ``.h5`` / ``.hdf5``: dataset ``descriptors`` (N x D) and, optionally, dataset ``names``
  (N strings); ``names_path`` overrides it.

Hamming matrices must be uint8 (8 packed bits per byte; CSV cells integers 0..255); other
metrics give float32 (float64 input stays float64). Every problem raises ``WilocError`` naming
the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.registry import METRICS
from wiloc.errors import WilocError, load_problem

_NAME_HEADERS = frozenset({"name", "names", "frame", "frames", "file", "filename"})
_HAMMING_HINT = "hamming descriptors must be uint8 (8 packed bits per byte)"


def _generated_names(count: int) -> list[str]:
    width = max(6, len(str(count - 1)))
    return [f"frame{i:0{width}d}" for i in range(count)]


def read_names(path: Path) -> list[str]:
    """Frame names from a text file (one per line) or the first column of a ``.csv`` file.

    Blank lines are skipped; a first entry ``name``, ``frame`` or ``file`` is taken as a header.
    """
    import pandas as pd  # pandas and h5py load in 0.2-0.5 s: only when a matrix is imported

    try:
        if path.suffix.lower() == ".csv":
            table = pd.read_csv(path, header=None, dtype=str, keep_default_na=False, usecols=[0])
            lines = table.iloc[:, 0].tolist()
        else:
            lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError, ValueError, pd.errors.ParserError) as exc:
        raise WilocError(path, f"cannot read frame names ({exc})") from exc
    names = [line.strip() for line in lines if line.strip()]
    if names and names[0].lower() in _NAME_HEADERS:
        names = names[1:]
    if not names:
        raise WilocError(path, "no frame names")
    return names


def _read_npy(path: Path) -> NDArray:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise WilocError(path, f"not a readable .npy array ({load_problem(exc)})") from exc


def _read_h5(path: Path) -> tuple[NDArray, list[str] | None]:
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            if "descriptors" not in handle or not isinstance(handle["descriptors"], h5py.Dataset):
                raise WilocError(path, "no dataset 'descriptors' (N x D)")
            matrix = handle["descriptors"][()]
            names = None
            if "names" in handle:
                names = [_text(path, i, n) for i, n in enumerate(np.ravel(handle["names"][()]))]
    except OSError as exc:
        raise WilocError(path, f"not a readable HDF5 file ({exc})") from exc
    return matrix, names


def _text(path: Path, i: int, name: object) -> str:
    """One frame name of an HDF5 ``names`` dataset as text; WilocError when its bytes are no UTF-8."""
    if not isinstance(name, bytes):
        return str(name)
    try:
        return name.decode("utf-8")
    except UnicodeDecodeError:
        raise WilocError(path, f"dataset 'names', entry {i + 1}: {name[:40]!r} is not UTF-8 text") from None


def _read_csv(path: Path) -> tuple[NDArray, list[str]]:
    import pandas as pd

    try:
        table = pd.read_csv(path, header=None, dtype=str, keep_default_na=False)
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise WilocError(path, f"not a readable CSV table ({exc})") from exc
    if table.shape[1] < 2:
        raise WilocError(path, "need a name column and at least one value column")
    cells = table.iloc[:, 1:].apply(lambda col: pd.to_numeric(col.str.strip(), errors="coerce"))
    if len(table) and cells.iloc[0].isna().all():
        table, cells = table.iloc[1:], cells.iloc[1:]
    if cells.empty:
        raise WilocError(path, "no data rows")
    bad = np.argwhere(cells.isna().to_numpy())
    if bad.size:
        row, col = bad[0]
        value = table.iloc[row, col + 1]
        raise WilocError(
            path, f"row {table.index[row] + 1}, column {col + 2}: {value!r} is not a number"
        )
    names = [name.strip() for name in table.iloc[:, 0].tolist()]
    return cells.to_numpy(dtype=np.float64), names


def _checked_matrix(path: Path, matrix: NDArray, metric: str, from_text: bool) -> NDArray:
    if matrix.ndim != 2 or matrix.shape[0] < 1 or matrix.shape[1] < 1:
        raise WilocError(path, f"need an N x D matrix (N, D >= 1); got shape {matrix.shape}")
    if metric == "hamming":
        if from_text:
            if np.any((matrix < 0) | (matrix > 255) | (matrix != np.round(matrix))):
                raise WilocError(path, f"{_HAMMING_HINT}; found values outside integers 0..255")
            return matrix.astype(np.uint8)
        if matrix.dtype != np.uint8:
            raise WilocError(path, f"{_HAMMING_HINT}; got {matrix.dtype}")
        return matrix
    if not (np.issubdtype(matrix.dtype, np.number) or matrix.dtype == np.bool_):
        raise WilocError(path, f"descriptors must be numeric; got {matrix.dtype}")
    if np.issubdtype(matrix.dtype, np.complexfloating):
        raise WilocError(path, "descriptors must be real numbers, not complex")
    out = matrix.astype(np.float64 if matrix.dtype == np.float64 and not from_text else np.float32)
    if not np.all(np.isfinite(out)):
        row = int(np.argwhere(~np.isfinite(out))[0, 0])
        raise WilocError(path, f"NaN or infinite value in row {row + 1}")
    if metric == "cosine":
        zero = np.flatnonzero(~np.any(out != 0, axis=1))
        if zero.size:
            raise WilocError(path, f"row {zero[0] + 1} is all zeros (cosine difference undefined)")
    return out


def read_external(
    path: Path, names_path: Path | None = None, metric: str = "l1"
) -> tuple[list[str], NDArray]:
    """Read a user's descriptor matrix and its frame names; check them against the metric."""
    path = Path(path)
    if metric not in METRICS:
        raise WilocError(path, f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
    if not path.is_file():
        raise WilocError(path, "file does not exist")
    suffix = path.suffix.lower()
    names: list[str] | None = None
    if suffix == ".npy":
        matrix = _read_npy(path)
    elif suffix in (".h5", ".hdf5"):
        matrix, names = _read_h5(path)
    elif suffix == ".csv":
        if names_path is not None:
            raise WilocError(names_path, "a .csv matrix names its frames in its first column")
        matrix, names = _read_csv(path)
    else:
        raise WilocError(path, "unknown matrix format (use .npy, .csv or .h5)")
    matrix = _checked_matrix(path, np.asarray(matrix), metric, from_text=suffix == ".csv")
    if names_path is not None:
        names = read_names(Path(names_path))
    if names is None:
        names = _generated_names(matrix.shape[0])
    where = path if names_path is None else Path(names_path)
    if len(names) != matrix.shape[0]:
        raise WilocError(where, f"{len(names)} frame names for {matrix.shape[0]} descriptor rows")
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise WilocError(where, f"duplicate frame name {name!r}")
        seen.add(name)
    return names, matrix

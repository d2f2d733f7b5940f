"""Reading a descriptor matrix the user brings: N frames x D values, with frame names and a metric;
and writing one in wiloc's own HDF5 layout, which records names and metric once.

Formats (chosen by suffix; a folder is one ``.npy`` vector per image):

- ``.npy``: the N x D matrix; names from ``names_path`` (one per line, the first column of a
  ``.csv``, or a ``.npy`` of text; a first cell ``name``/``frame``/``file`` is a header) or
  generated ``frame000000``...
- ``.npz``: numpy's archive holding one N x D array of numbers, and optionally one array of N
  names (text, UTF-8 bytes or Python strings, read without running anything), else as ``.npy``.
- ``.csv``: one row per frame, first column the frame name, the rest numbers; an optional header
  row (recognised when none of its value cells is a number, or its first cell is empty or a
  word such as ``name``: pandas heads the value columns 0, 1, 2, ...); pandas' unheaded index
  column before a column headed ``name`` is passed over. A first column that is evidently
  values, not names (``np.savetxt`` of the descriptors alone), is refused.
- ``.h5`` / ``.hdf5``: dataset ``descriptors`` (N x D) and, optionally, dataset ``names``
  (N strings) and attribute ``metric`` (what :func:`write_matrix` writes); ``names_path``
  overrides the names. Or hloc's ``global-feats-*.h5``: one group per image name (names with
  ``/`` are nested groups), each holding a dataset ``global_descriptor``.
- a folder: one ``.npy`` vector per image, in any subfolder; the frame name is the file's path
  inside the folder without ``.npy`` (``db/img001.jpg.npy`` is ``db/img001.jpg``).

hloc files and folders are in natural order of names, as image folders are; the other formats
keep their row order.

Hamming matrices must be uint8 (8 packed bits per byte; CSV cells integers 0..255); other
metrics give float32 (float64 input stays float64). Every problem raises ``WilocError`` naming
the file.
"""
from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.atomic import written_whole
from wiloc.descriptors.base import METRICS
from wiloc.errors import WilocError, load_problem
from wiloc.given import check_frame_names, uneven_line  # check_frame_names: also of a map's names held in memory
from wiloc.object_arrays import read_npy, read_npz
from wiloc.sources.natural_order import natural_sorted

METRIC_ATTRIBUTE = "metric"
"""The attribute of a wiloc descriptor file that records its metric."""
#: Which reading of the formats above made an imported entry, part of its cache key: raised when
#: a format's reading changes (the rows, names or order a file gives), so that no entry an
#: earlier reader made is reused. 2: a pandas CSV's header is no frame; names that are decimal
#: timestamps sort in time order. 3: a CSV whose first column is evidently values is refused.
#: 4: names numbered with dots (``scene1.1`` .. ``scene1.10``) keep each dotted run's value.
#: 5: a whole number among decimals (``1614000000``, its fraction's zeros dropped) is one of fraction 0.
READER_VERSION = 5
HLOC_DATASET = "global_descriptor"
_NAME_HEADERS = frozenset({"name", "names", "frame", "frames", "file", "filename", "image", "path"})
_HAMMING_HINT = "hamming descriptors must be uint8 (8 packed bits per byte)"


def _generated_names(count: int) -> list[str]:
    width = max(6, len(str(count - 1)))
    return [f"frame{i:0{width}d}" for i in range(count)]


def check_names_file(path: Path) -> None:
    """WilocError naming ``path`` unless it is a file, saying so when it is a folder (a folder
    given to --names was said not to exist)."""
    if path.is_dir():
        raise WilocError(path, "a folder, not a file of frame names (one name a line)")
    if not path.is_file():
        raise WilocError(path, "file does not exist")


def read_names(path: Path) -> list[str]:
    """Frame names from a text file (one per line), the first column of a ``.csv`` file, or a
    ``.npy`` array of text (``np.save`` of the names, read as :func:`_read_npz` reads them).

    Blank lines are skipped; a first entry ``name``, ``frame`` or ``file`` is taken as a header.
    """
    import pandas as pd  # pandas and h5py load in 0.2-0.5 s: only when a matrix is imported

    check_names_file(path)
    if path.suffix.lower() == ".npy":
        return _npy_names(path)
    try:
        if path.suffix.lower() == ".csv":
            table = pd.read_csv(path, header=None, dtype=str, keep_default_na=False, usecols=[0], encoding="utf-8-sig")
            lines = table.iloc[:, 0].tolist()
        else:
            lines = path.read_text(encoding="utf-8-sig").splitlines()  # a byte-order mark is no part of a name
    except (OSError, UnicodeDecodeError, ValueError, pd.errors.ParserError) as exc:
        raise WilocError(path, f"cannot read frame names ({exc})") from exc
    names = [line.strip() for line in lines if line.strip()]
    if names and names[0].lower() in _NAME_HEADERS:
        names = names[1:]
    if not names:
        raise WilocError(path, "no frame names")
    return names


def _blank_line(path: Path) -> int | None:
    """The first empty line of a text file of names that stands among names (not after the
    last), which :func:`read_names` skips: a name left out that leaves a row unnamed."""
    if path.suffix.lower() == ".npy":
        return None
    lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    filled = [n for n, line in enumerate(lines, 1) if line.strip()]
    return next((n for n, line in enumerate(lines, 1) if not line.strip() and filled and n < filled[-1]), None)


def _npy_names(path: Path) -> list[str]:
    """The frame names of a ``.npy`` file: one 1-D array of text (str, UTF-8 bytes or Python
    strings, read without running anything)."""
    try:
        with path.open("rb") as file:
            array = read_npy(file)
    except (OSError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        raise WilocError(path, f"cannot read frame names ({load_problem(exc)})") from exc
    names = _texts(path, "names", array)
    if names is None:
        shape = " x ".join(map(str, getattr(array, "shape", ()))) or "0-d"
        raise WilocError(path, f"holds a {shape} array of {getattr(array, 'dtype', type(array).__name__)}, "
                               "not frame names (a 1-D array of text)")
    return [name.strip() for name in names]


def _read_npy(path: Path) -> NDArray:
    try:
        if path.stat().st_size == 0:  # numpy's own error for it differs by version (EOFError, or a pickle's)
            raise EOFError
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise WilocError(path, f"not a readable .npy array ({load_problem(exc)})") from exc


def _read_npz(path: Path) -> tuple[NDArray, list[str] | None]:
    """numpy's archive (``np.savez``): its one 2-D array of numbers, and as frame names its one
    1-D array of text (str, UTF-8 bytes, or Python strings, which numpy pickles: read without
    running anything, :mod:`wiloc.object_arrays`), or of several the one as long as the matrix."""
    import zipfile

    if not zipfile.is_zipfile(path):
        return _read_npy(path), None  # an .npy array named .npz
    try:
        arrays = read_npz(path)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, pickle.UnpicklingError) as exc:
        raise WilocError(path, f"not a readable .npz archive ({load_problem(exc)})") from exc
    matrices = [name for name, array in arrays.items()
                if isinstance(array, np.ndarray) and array.ndim == 2 and array.dtype.kind in "biuf"]
    if len(matrices) != 1:
        raise WilocError(path, f"holds {len(matrices)} 2-D arrays of numbers ({', '.join(matrices) or 'none'}); "
                               "give an archive of one, the N x D descriptors")
    matrix = arrays[matrices[0]]
    texts = {name: names for name, array in arrays.items() if (names := _texts(path, name, array)) is not None}
    if len(texts) > 1:
        texts = {name: names for name, names in texts.items() if len(names) == matrix.shape[0]}
    return matrix, next(iter(texts.values())) if len(texts) == 1 else None


def _texts(path: Path, name: str, array: Any) -> list[str] | None:
    """A 1-D array of text as frame names (bytes decoded as UTF-8), None for any other array."""
    if not isinstance(array, np.ndarray) or array.ndim != 1 or array.dtype.kind not in "USO":
        return None
    if array.dtype.kind == "O" and not all(isinstance(item, (str, bytes)) for item in array):
        return None
    return [_text(path, i, item, name) for i, item in enumerate(array)]


def _read_h5(path: Path) -> tuple[NDArray, list[str] | None]:
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            if "descriptors" not in handle:
                names, rows = _hloc_rows(path, handle)
                return _stacked(rows, path, [f"'{name}/{HLOC_DATASET}'" for name in names]), names
            if not isinstance(handle["descriptors"], h5py.Dataset):
                raise WilocError(path, "no dataset 'descriptors' (N x D)")
            matrix = handle["descriptors"][()]
            names = None
            if "names" in handle:
                names = [_text(path, i, n) for i, n in enumerate(np.ravel(handle["names"][()]))]
    except OSError as exc:
        raise WilocError(path, f"not a readable HDF5 file ({exc})") from exc
    return matrix, names


def _hloc_rows(path: Path, handle: Any) -> tuple[list[str], list[NDArray]]:
    """hloc's layout: the group path of every ``global_descriptor`` dataset is an image name."""
    import h5py

    found: dict[str, NDArray] = {}
    others: list[str] = []

    def visit(name: str, item: Any) -> None:
        if isinstance(item, h5py.Dataset) and name.rsplit("/", 1)[-1] == HLOC_DATASET:
            found[item.parent.name.strip("/")] = item[()]
        elif isinstance(item, h5py.Dataset):
            others.append(f"{name} ({' x '.join(map(str, item.shape)) or 'scalar'})")

    handle.visititems(visit)
    if not found:
        held = f"; it holds {', '.join(others[:5])}{', ...' if len(others) > 5 else ''}" if others else ""
        raise WilocError(path, f"neither a dataset 'descriptors' (N x D) nor hloc's groups holding "
                               f"'{HLOC_DATASET}' (global-feats-*.h5){held}")
    names = natural_sorted(found)
    return names, [found[name] for name in names]


def _stacked(rows: list[NDArray], source: Path, labels: list[str]) -> NDArray:
    """One vector per frame stacked into N x D; a row that is no vector, or of another length than
    the first, is an error naming ``source`` and the row's label (its dataset or file)."""
    vectors = [np.asarray(row) for row in rows]
    for label, vector in zip(labels, vectors):
        if sum(n > 1 for n in vector.shape) > 1:
            raise WilocError(source, f"{label} holds a {' x '.join(map(str, vector.shape))} array, "
                                     "not one descriptor vector")
    vectors = [vector.reshape(-1) for vector in vectors]
    length = vectors[0].size
    bad = next((i for i, vector in enumerate(vectors) if vector.size != length), None)
    if bad is not None:
        raise WilocError(source, f"{labels[bad]} holds {vectors[bad].size} values, but {labels[0]} holds "
                                 f"{length}: every frame needs a descriptor of the same length")
    return np.stack(vectors)


def _read_npy_folder(folder: Path) -> tuple[NDArray, list[str]]:
    """One ``.npy`` vector per image, named by its path inside ``folder`` without ``.npy``."""
    files = {path.relative_to(folder).as_posix()[:-len(".npy")]: path
             for path in folder.rglob("*.npy") if path.is_file()}
    if not files:
        raise WilocError(folder, "no .npy files (one descriptor vector per image)")
    names = natural_sorted(files)
    rows = [_read_npy(files[name]) for name in names]
    return _stacked(rows, folder, [f"{name}.npy" for name in names]), names


def recorded_metric(path: Path) -> str | None:
    """The metric a wiloc descriptor file records (:func:`write_matrix`), None for any other
    file; a recorded metric wiloc does not know is an error naming the file."""
    path = Path(path)
    if path.suffix.lower() not in (".h5", ".hdf5") or not path.is_file():
        return None
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            metric = handle.attrs.get(METRIC_ATTRIBUTE)
    except OSError as exc:
        raise WilocError(path, f"not a readable HDF5 file ({exc})") from exc
    if metric is None:
        return None
    metric = metric.decode("utf-8", "replace") if isinstance(metric, bytes) else str(metric)
    if metric not in METRICS:
        raise WilocError(path, f"records the metric {metric!r}, which is none of {', '.join(METRICS)}")
    return metric


def write_matrix(path: Path, names: list[str], matrix: NDArray, metric: str) -> Path:
    """Write descriptors in wiloc's layout (datasets ``descriptors`` and ``names``, attribute
    ``metric``), whole or not at all, so that later commands read names and metric from it."""
    import io

    import h5py

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as handle:
        handle.create_dataset("descriptors", data=matrix)
        handle.create_dataset("names", data=names, dtype=h5py.string_dtype())
        handle.attrs[METRIC_ATTRIBUTE] = metric
    with written_whole(Path(path), "the descriptor file", binary=True) as file:
        file.write(buffer.getbuffer())
    return Path(path)


def _text(path: Path, i: int, name: object, dataset: str = "names") -> str:
    """One frame name of a ``names`` dataset (HDF5, or an array of a .npz) as text; WilocError
    when its bytes are no UTF-8."""
    if not isinstance(name, bytes):
        return str(name)
    try:
        return name.decode("utf-8")
    except UnicodeDecodeError:
        raise WilocError(path, f"dataset '{dataset}', entry {i + 1}: {name[:40]!r} is not UTF-8 text") from None


def _is_name_header(cell: str) -> bool:
    """Whether a CSV's first cell heads its name column: empty (pandas' ``to_csv`` of an unnamed
    index) or a word such as ``name``. Such a header's value cells may be numbers (pandas' column
    labels 0, 1, 2, ...), so they alone do not tell it from a frame's row."""
    return cell.strip().lower() in _NAME_HEADERS | {""}


def _read_csv(path: Path) -> tuple[NDArray, list[str]]:
    import pandas as pd

    try:
        table = pd.read_csv(path, header=None, dtype=str, keep_default_na=False, encoding="utf-8-sig")
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        uneven = isinstance(exc, pd.errors.ParserError) and uneven_line(path)
        if uneven:
            raise WilocError(path, f"{uneven}: a header line? a .csv matrix holds a frame's name and its values on "
                                   "each line (name,d0,d1,...), a header, if any, naming as many columns") from None
        raise WilocError(path, f"not a readable CSV table ({exc})") from exc
    if table.shape[1] < 2:
        first = str(table.iloc[0, 0]) if table.size else ""
        hint = "; columns must be separated by commas" if ";" in first or "\t" in first else ""
        raise WilocError(path, f"need a name column and at least one value column{hint}")
    if table.shape[1] > 2 and len(table) and not table.iloc[0, 0].strip() and \
            table.iloc[0, 1].strip().lower() in _NAME_HEADERS:
        table = table.iloc[:, 1:]  # pandas' unnamed index before a name column (to_csv without index=False)
    cells = table.iloc[:, 1:].apply(lambda col: pd.to_numeric(col.str.strip(), errors="coerce"))
    if len(table) and (cells.iloc[0].isna().all() or _is_name_header(table.iloc[0, 0])):
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
    values = cells.to_numpy(dtype=np.float64)
    if _values_as_names(names, values):
        raise WilocError(path, f"its first column holds numbers such as {names[0]!r}, as large as the other "
                               "columns' values, not frame names: a .csv matrix needs the frame names in its first "
                               "column (name,d0,d1,...); descriptors alone go in a .npy, their names in a text "
                               "file of one a line")
    return values, names


def _values_as_names(names: list[str], values: NDArray[np.float64]) -> bool:
    """Whether a CSV's first column is evidently one more column of values rather than frame
    names: every cell a number, some with a fraction (names such as ``12`` or ``000012`` are
    frame numbers), none more than ten times the largest value cell in size (a timestamp such
    as ``1614000000.15`` is)."""
    import pandas as pd

    numbers = pd.to_numeric(pd.Series(names), errors="coerce").to_numpy(np.float64)
    return bool(np.isfinite(numbers).all() and np.any(numbers != np.round(numbers))
                and np.abs(numbers).max() <= 10 * np.abs(values).max())


def _largest_value(metric: str, length: int) -> float:
    """The largest magnitude a value of rows of ``length`` values may have so that no ``metric``
    difference (computed in float32) overflows: an l1 difference sums up to 2 x that per value,
    a squared euclidean one (2 x that) squared; cosine rows are made float32 before they are
    scaled to unit length."""
    most = float(np.finfo(np.float32).max)
    if metric == "l1":
        return most / (2 * length)
    if metric == "sqeuclidean":
        return math.sqrt(most / length) / 2
    return most


def check_value_range(rows: NDArray, metric: str, where: str | Path) -> None:
    """Refuse, as a WilocError naming ``where``, descriptor ``rows`` (the last axis a row's values)
    whose values would overflow their ``metric`` differences, computed in float32
    (:func:`_largest_value`): they would be infinite, read as no candidate, every frame undecided."""
    if rows.size == 0:
        return
    largest, limit = max(abs(float(rows.max())), abs(float(rows.min()))), _largest_value(metric, rows.shape[-1])
    if largest > limit:
        raise WilocError(where, f"values up to {largest:.3g}: {metric} differences of rows of {rows.shape[-1]} values "
                                f"would pass float32's range, in which they are computed; scale the descriptors "
                                f"to within +-{limit:.3g}")


def _checked_matrix(path: Path, matrix: NDArray, metric: str, from_text: bool) -> NDArray:
    if matrix.ndim > 2 and matrix.shape[0] >= 1 and sum(n != 1 for n in matrix.shape[1:]) <= 1:
        matrix = matrix.reshape(matrix.shape[0], -1)  # N x D x 1 x 1 (a network's pooled output), N x 1 x D
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
    check_value_range(out, metric, path)
    if metric == "cosine":
        zero = np.flatnonzero(~np.any(out != 0, axis=1))
        if zero.size:
            raise WilocError(path, f"row {zero[0] + 1} is all zeros (cosine difference undefined)")
    return out


def refuse_results_file(path: Path, problem: str) -> None:
    """A WilocError naming ``path`` when it is a wiloc results file given where descriptors go
    (as a traversal, or to import): ``problem`` says what was wanted instead."""
    from wiloc.evaluation.results_header import starts_as_results  # a later module: read only here

    if starts_as_results(path):
        raise WilocError(path, f"a wiloc results file {problem}; evaluate and compare read results files")


def read_external(
    path: Path, names_path: Path | None = None, metric: str = "l1", prefix: str = ""
) -> tuple[list[str], NDArray]:
    """Read a user's descriptor matrix (or folder of per-image ``.npy`` vectors) and its frame
    names; check them against the metric. ``prefix``: keep only the frames whose names begin with
    it, and drop it from their names (hloc keeps a dataset's queries and database in one file)."""
    path = Path(path)
    if metric not in METRICS:
        raise WilocError(path, f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
    if not path.is_file() and not path.is_dir():
        raise WilocError(path, "file does not exist")
    refuse_results_file(path, "holds no descriptors to import: give a descriptor matrix file (.npy, .npz, .csv, .h5)")
    suffix = path.suffix.lower()
    names: list[str] | None = None
    if path.is_dir():
        if names_path is not None:
            raise WilocError(names_path, "a folder of .npy files names its frames by its file names")
        matrix, names = _read_npy_folder(path)
    elif suffix == ".npy":
        matrix = _read_npy(path)
    elif suffix == ".npz":
        matrix, names = _read_npz(path)
    elif suffix in (".h5", ".hdf5"):
        matrix, names = _read_h5(path)
    elif suffix == ".csv":
        if names_path is not None:
            raise WilocError(names_path, "a .csv matrix names its frames in its first column")
        matrix, names = _read_csv(path)
    else:
        raise WilocError(path, "unknown matrix format (use .npy, .npz, .csv or .h5)")
    matrix = _checked_matrix(path, np.asarray(matrix), metric, from_text=suffix == ".csv")
    if names_path is not None:
        names = read_names(Path(names_path))
    if names is None:
        names = _generated_names(matrix.shape[0])
    where = path if names_path is None else Path(names_path)
    if len(names) != matrix.shape[0]:
        turned = (f" (the matrix is {matrix.shape[0]} x {matrix.shape[1]}: one column per frame? save its "
                  "transpose, one row per frame)" if len(names) == matrix.shape[1] else
                  f" (is the first, {names[0]!r}, a header? only {', '.join(sorted(_NAME_HEADERS))} are known as one)"
                  if len(names) == matrix.shape[0] + 1 and names_path is not None else "")
        blank = names_path is not None and len(names) < matrix.shape[0] and _blank_line(Path(names_path))
        turned = f" (line {blank} is empty: each descriptor row's name goes on a line of its own)" if blank else turned
        raise WilocError(where, f"{len(names)} frame names for {matrix.shape[0]} descriptor rows{turned}")
    if prefix:
        keep = [i for i, name in enumerate(names) if name.startswith(prefix)]
        if not keep:
            raise WilocError(where, f"no frame name begins with {prefix!r} (the first is {names[0]!r})")
        names, matrix = [names[i][len(prefix):] for i in keep], matrix[keep]
    check_frame_names(names, where)
    return names, matrix

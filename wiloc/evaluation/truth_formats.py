"""Ground truth as VPR datasets ship it, read into the same :class:`~wiloc.evaluation.groundtruth.Truth` as
the pairs and positions forms: a queries x references mask (the matrix form: FAB-MAP's masks,
VPR_Tutorial's ``GT.npz``), VPR-Bench's ``ground_truth_new.npy``, the ``@UTM_east@UTM_north@``
file names of the datasets that VPR-methods-evaluation and VPR-datasets-downloader produce, and
the GPS position in each photo's EXIF. See docs/evaluation.md."""
from __future__ import annotations

import pickle
from collections.abc import Sequence
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import scipy.io
from numpy.typing import NDArray
from scipy import sparse

from wiloc.errors import WilocError, load_problem
from wiloc.evaluation.groundtruth import Positions, Truth, TruthMismatch, name_index, truth_from_pairs, truth_within
from wiloc.evaluation.truth_warnings import query_frames_without
from wiloc.given import check_file, check_metres, uneven_line
from wiloc.object_arrays import npy_header, read_npy

DEFAULT_RADIUS_M = 25.0
"""Same place within 25 m: the threshold of VPR-methods-evaluation and of the benchmarks it follows
(Pitts30k, Tokyo 24/7, MSLS, SF-XL), used by ``utm-names`` and ``exif`` unless a radius is given."""

# ---------------------------------------------------------------------------------------- matrix

def _named_array(path: Path, arrays: dict[str, NDArray], variable: str | None) -> NDArray:
    """The 2-D numeric array named ``variable`` among a .mat's or .npz's ``arrays``, or the only
    one when ``variable`` is None."""
    arrays = {k: v for k, v in arrays.items() if not k.startswith("__") and getattr(v, "ndim", 0) == 2
              and (np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_)}
    if variable is not None:
        if variable not in arrays:
            raise WilocError(path, f"no 2-D variable {variable!r}; choose one of {', '.join(sorted(arrays)) or 'none'}")
        return arrays[variable]
    if len(arrays) != 1:
        raise WilocError(path, f"holds {len(arrays)} 2-D arrays, name one of: {', '.join(sorted(arrays)) or 'none'}")
    return next(iter(arrays.values()))


def _mat_arrays(path: Path) -> dict[str, NDArray]:
    """A .mat file's variables: scipy reads MATLAB up to v7; a v7.3 file is HDF5, read with h5py,
    its arrays (stored in MATLAB's column order) transposed back to MATLAB's shape."""
    try:
        return scipy.io.loadmat(path)
    except NotImplementedError:  # v7.3
        import h5py

        with h5py.File(path, "r") as handle:
            return {name: item[()].T for name, item in handle.items() if isinstance(item, h5py.Dataset)}


def _read_matrix(path: Path, variable: str | None) -> NDArray[np.float64] | sparse.sparray:
    """The 2-D array stored in a .npy, .csv, .npz or .mat file."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            return np.load(path, allow_pickle=False)
        if suffix == ".csv":
            return np.loadtxt(path, delimiter=",", dtype=np.float64, ndmin=2, encoding="utf-8-sig")
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                return _named_array(path, {name: archive[name] for name in archive.files}, variable)
        if suffix == ".mat":
            return _named_array(path, _mat_arrays(path), variable)
    except (ValueError, OSError, NotImplementedError, EOFError, IndexError, scipy.io.matlab.MatReadError) as exc:
        hint = ("; an array of reference indices per query is the positives form, VPR-Bench's "
                "ground_truth_new.npy the vprbench form" if str(exc).startswith("Object arrays") else "")
        uneven = uneven_line(path) if suffix == ".csv" and isinstance(exc, ValueError) else None
        problem = uneven or load_problem(exc)
        raise WilocError(path, f"cannot read matrix ({problem}){hint}") from exc
    raise WilocError(path, f"unsupported matrix file type {suffix or '(none)'}; use .npy, .csv, .npz or .mat")


def matrix_truth(path: Path, query_names: Sequence[str], ref_names: Sequence[str],
                 variable: str | None = None) -> Truth:
    """Matrix form: queries x references, 1 = same place, 0 = not (e.g. the FAB-MAP masks); any
    other value is refused (a matrix of differences would make nearly every pair the same place).

    The matrix carries no names: row i is the i-th query frame and column j the j-th reference
    frame in the traversals' natural order, so its shape must match both exactly.
    ``variable`` picks one array in a .mat or .npz file holding several.
    """
    path = Path(path)
    check_file(path)
    data = _read_matrix(path, variable)
    if data.dtype.kind not in "biuf":
        raise WilocError(path, f"matrix holds {data.dtype} values; give numbers (1 = same place, 0 = not) or booleans")
    expected = (len(query_names), len(ref_names))
    if data.ndim != 2 or data.shape != expected:
        raise TruthMismatch(path, f"matrix is {' x '.join(map(str, data.shape))}, expected "
                               f"{expected[0]} x {expected[1]} (query x reference frames){_shape_hint(data, expected)}")
    matrix = sparse.csr_array(data)
    values = matrix.data.astype(np.float64, copy=False)
    if not np.isfinite(values).all():
        raise WilocError(path, "matrix holds NaN or infinite values")
    if not np.isin(values, (0.0, 1.0)).all():  # a matrix of distances would make nearly every pair true
        k = int(np.flatnonzero(~np.isin(values, (0.0, 1.0)))[0])
        row = int(np.searchsorted(matrix.indptr, k, side="right") - 1)
        raise WilocError(path, f"matrix holds {values[k]:g} at row {row + 1}, column {matrix.indices[k] + 1}: "
                               "ground truth is a same-place mask of 0 and 1, not differences or distances")
    return Truth(matrix, list(query_names), list(ref_names), [])


def _shape_hint(data: NDArray | sparse.sparray, expected: tuple[int, int]) -> str:
    """What a matrix of the wrong shape may be: reference x query frames; with a row per query
    frame, rows of reference indices (whole numbers, some above 1: the positives form) or a mask
    whose columns are not the map's frames."""
    if data.shape == expected[::-1]:
        return ": it is reference x query frames (as VPR_Tutorial's GThard); save its transpose, M.T"
    if data.ndim != 2 or data.shape[0] != expected[0]:
        return ""
    values = data.data if sparse.issparse(data) else data
    if np.isfinite(values).all() and (values == np.floor(values)).all() and (values > 1).any():
        return "; rows of reference indices are the positives form (positives:FILE)"
    return f"; it has {data.shape[1]} columns but the map has {expected[1]} frames (a column each)"


# ------------------------------------------------------------------------------------- VPR-Bench

_VPRBENCH = "VPR-Bench's rows of [query index, [reference indices]]"
_POSITIVES = "one array of reference indices per query frame"


def _read_npy(path: Path) -> NDArray:
    """The array of a ``.npy`` file, object arrays read by :func:`~wiloc.object_arrays.read_npy`
    (nothing a file names is run); a pickle that holds no array, such as a dict, is an error."""
    check_file(path)
    try:
        with path.open("rb") as file:
            array = read_npy(file)
    except (ValueError, OSError, EOFError, pickle.UnpicklingError) as exc:
        raise WilocError(path, f"not a readable .npy file of reference indices ({exc})") from exc
    if not isinstance(array, np.ndarray):
        raise WilocError(path, f"holds a pickled {type(array).__name__}, not an array of reference indices")
    return array


def npy_form(path: Path) -> str:
    """The ground-truth form of a ``.npy`` file given without its kind, from its header alone: an
    object array of two columns is VPR-Bench's rows, of one axis a list of positives per query,
    anything else a matrix (whose reader says what is wrong)."""
    try:
        with Path(path).open("rb") as file:
            shape, dtype = npy_header(file)
    except (ValueError, OSError, EOFError):
        return "matrix"
    if not dtype.hasobject:
        return "matrix"
    return "vprbench" if len(shape) == 2 and shape[1] == 2 else "positives" if len(shape) == 1 else "matrix"


def _whole_number(value: Any) -> int | None:
    """An integer index (Python or numpy, or a 0-d integer array), else None."""
    if isinstance(value, np.ndarray):
        return int(value) if value.ndim == 0 and value.dtype.kind in "iu" else None
    return int(value) if isinstance(value, (int, np.integer)) and not isinstance(value, bool) else None


def _references(value: Any) -> NDArray[np.int64] | None:
    """A row's reference indices (a list or array of integers, or one integer), else None."""
    if (single := _whole_number(value)) is not None:
        return np.array([single], dtype=np.int64)
    if not isinstance(value, (list, tuple, np.ndarray)):
        return None
    if isinstance(value, np.ndarray) and value.dtype.kind in "iu" and value.ndim == 1:
        return value.astype(np.int64)
    items = [_whole_number(v) for v in value]
    return None if any(i is None for i in items) else np.array(items, dtype=np.int64)


def _check_references(path: Path, place: str, refs: NDArray[np.int64], n_ref: int) -> NDArray[np.int64]:
    """``refs``, the reference indices of one row or entry of ``path`` (``place``: ``row 3``), or a
    WilocError naming the first that is no frame of the reference traversal's ``n_ref``, and saying
    that they count from 0 (where ``place`` counts from 1, as every row and line a message names)."""
    if refs.size and not (0 <= refs.min() and refs.max() < n_ref):
        bad = int(refs[(refs < 0) | (refs >= n_ref)][0])
        raise TruthMismatch(path, f"{place}: reference index {bad} is no frame of the reference traversal, whose "
                                  f"{n_ref} frames are numbered 0 to {n_ref - 1}")
    return refs


def read_vprbench(path: Path) -> list[tuple[int, NDArray[np.int64]]]:
    """The (query index, reference indices) rows of a VPR-Bench ``ground_truth_new.npy``."""
    path = Path(path)
    array = _read_npy(path)
    if not array.dtype.hasobject:
        raise WilocError(path, f"holds a plain {' x '.join(map(str, array.shape))} array of {array.dtype}, not "
                               f"{_VPRBENCH} (a queries x references matrix is the matrix form)")
    if array.ndim not in (1, 2) or (array.ndim == 2 and array.shape[1] != 2):
        shape = " x ".join(map(str, array.shape)) or "0-d"
        raise WilocError(path, f"holds a {shape} object array, not {_VPRBENCH}")
    rows = []
    for i, row in enumerate(array):
        pair = isinstance(row, (list, tuple, np.ndarray)) and len(row) == 2
        query = _whole_number(row[0]) if pair else None
        refs = _references(row[1]) if query is not None else None
        if query is None or refs is None:
            raise WilocError(path, f"row {i + 1} is not [query index, [reference indices]] ({_VPRBENCH})")
        rows.append((query, refs))
    if not rows:
        raise WilocError(path, "holds no rows")
    return rows


def vprbench_truth(path: Path, query_names: Sequence[str], ref_names: Sequence[str]) -> Truth:
    """VPR-Bench form: row [q, [r1, r2, ...]] says query frame q is the same place as reference
    frames r1, r2, ...; indices count frames in each traversal's natural order, as VPR-Bench's
    numbered images (0.jpg, 1.jpg, ...) do."""
    path = Path(path)
    rows = read_vprbench(path)
    n_query, n_ref = len(query_names), len(ref_names)
    for i, (query, refs) in enumerate(rows):
        if not 0 <= query < n_query:
            raise TruthMismatch(path, f"row {i + 1}: query index {query}, but the query traversal has {n_query} frames")
        _check_references(path, f"row {i + 1}", refs, n_ref)
    queries = np.repeat(np.array([q for q, _ in rows], dtype=np.int64), [refs.size for _, refs in rows])
    refs = np.concatenate([refs for _, refs in rows])
    without = np.ones(n_query, dtype=np.bool_)
    without[[q for q, _ in rows]] = False
    warnings = query_frames_without(path, without, "query frames have no row (never a true match)")
    return truth_from_pairs(queries, refs, query_names, ref_names, warnings)


def _looks_like_mask(array: NDArray, n_ref: int) -> bool:
    """Whether a 2-D array given as positives is plainly a queries x references same-place mask
    (the matrix form), whose rows would be read as reference indices 0 and 1: booleans, or only
    0s and 1s in rows as wide as the reference traversal, some row repeating an index, which
    positives (distinct frames) never do. A queries x k array of distinct indices is read."""
    if array.ndim != 2 or array.dtype.kind not in "biuf":
        return False
    if array.dtype.kind == "b":
        return True
    if array.shape[1] != n_ref or not array.size or not ((array == 0) | (array == 1)).all():
        return False
    # a row of 0s and 1s more than two wide repeats one; up to two wide, [0, 1] does not
    return n_ref > 2 or bool((np.diff(np.sort(array, axis=1), axis=1) == 0).any())


def positives_truth(path: Path, query_names: Sequence[str], ref_names: Sequence[str]) -> Truth:
    """Positives form: the i-th entry lists the reference indices that are the same place as the
    i-th query frame (an object array of index arrays, as pytorch-NetVLAD's and
    VPR-methods-evaluation's ``positives_per_query`` are, or a queries x k integer array); the
    indices count frames in each traversal's natural order, so the file must have one entry per
    query frame. A same-place mask (the matrix form) is refused, not read as indices 0 and 1."""
    path = Path(path)
    array = _read_npy(path)
    n_query, n_ref = len(query_names), len(ref_names)
    if _looks_like_mask(array, n_ref):
        raise WilocError(path, f"holds a {' x '.join(map(str, array.shape))} array of {array.dtype}, every value 0 "
                               "or 1: it looks like a same-place mask (queries x references), not "
                               f"{_POSITIVES}; give it as matrix:FILE")
    if not ((array.dtype.hasobject and array.ndim == 1) or (array.dtype.kind in "iu" and array.ndim == 2)):
        raise WilocError(path, f"holds a {' x '.join(map(str, array.shape)) or '0-d'} array of {array.dtype}, not "
                               f"{_POSITIVES} (a queries x references mask of 0 and 1 is the matrix form)")
    if len(array) != n_query:
        raise TruthMismatch(path, f"lists positives of {len(array)} query frames, but the query traversal has {n_query}: "
                               "entry i is the i-th query frame in natural order")
    positives = []
    for i, entry in enumerate(array):
        refs, place = _references(entry), f"entry {i + 1} of {n_query} (query frame {query_names[i]})"
        if refs is None:
            raise WilocError(path, f"{place} is not a list of reference indices ({_POSITIVES})")
        positives.append(_check_references(path, place, refs, n_ref))
    queries = np.repeat(np.arange(n_query, dtype=np.int64), [refs.size for refs in positives])
    refs = np.concatenate(positives) if positives else np.zeros(0, dtype=np.int64)
    return truth_from_pairs(queries, refs, query_names, ref_names, [])


# ------------------------------------------------------------------------------------ @UTM names

def utm_positions(folder: Path, names: Sequence[str]) -> tuple[Positions, dict[str, Path]]:
    """Positions in metres from file names ``@UTM_east@UTM_north@UTM_zone_number@UTM_zone_letter@
    latitude@longitude@...@.jpg`` (as VPR-methods-evaluation reads them: the two numbers after the
    first ``@``), and the first file of each UTM zone number the names give. A name without the
    two numbers is an error naming it."""
    coords = np.empty((len(names), 2), dtype=np.float64)
    zones: dict[str, Path] = {}
    for i, name in enumerate(names):
        fields = PurePosixPath(name).name.split("@")
        try:
            coords[i] = float(fields[1]), float(fields[2])
            usable = bool(np.isfinite(coords[i]).all())
        except (IndexError, ValueError):
            usable = False
        if not usable:
            raise WilocError(Path(folder) / name, "not a name of the form @UTM_east@UTM_north@...@.jpg "
                                                  "(the datasets of VPR-methods-evaluation), so it gives no position")
        check_metres(coords[i], Path(folder) / name)
        if len(fields) > 3 and fields[3]:
            zones.setdefault(fields[3], Path(folder) / name)
    return Positions(f"{folder} (@UTM names)", name_index(names), coords, geographic=False), zones


def utm_names_truth(query_folder: Path, ref_folder: Path | None, radius: float, query_names: Sequence[str],
                    ref_names: Sequence[str]) -> Truth:
    """``utm-names`` form: frames whose @UTM names lie within ``radius`` metres are the same place
    (``ref_folder`` None: sequence mode). Names of several UTM zones are an error: their
    coordinates are not on one plane."""
    query, zones = utm_positions(query_folder, query_names)
    ref, ref_zones = (query, {}) if ref_folder is None else utm_positions(ref_folder, ref_names)
    zones = {**ref_zones, **zones}
    if len(zones) > 1:
        (a, first), (b, second) = list(zones.items())[:2]
        raise WilocError(second, f"in UTM zone {b}, but {first} is in zone {a}: their coordinates are not on one plane")
    return truth_within(query, ref, radius, query_names, ref_names)


# ------------------------------------------------------------------------------------- EXIF GPS

_GPS_IFD = 0x8825  # EXIF tags: the GPS block; in it 1/2 latitude ref/value, 3/4 longitude ref/value


def _degrees(value: Any, ref: Any, negative: str) -> float:
    """EXIF degrees, minutes, seconds (rationals) and a hemisphere letter as signed degrees."""
    parts = [float(v) for v in (value if isinstance(value, (tuple, list)) else (value,))]
    degrees = sum(part / 60.0 ** k for k, part in enumerate(parts[:3]))
    letter = ref.decode("ascii", "replace") if isinstance(ref, bytes) else str(ref or "")
    return -degrees if letter.strip("\0 ").upper() == negative else degrees


def gps_position(path: Path) -> tuple[float, float] | None:
    """An image's (latitude, longitude) in degrees from its EXIF, None when it has none. Pillow
    reads the EXIF block without decoding the pixels."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            gps = image.getexif().get_ifd(_GPS_IFD)
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as exc:
        raise WilocError(path, f"cannot read its EXIF ({exc})") from exc
    if 2 not in gps or 4 not in gps:
        return None
    try:
        lat, lon = _degrees(gps[2], gps.get(1), "S"), _degrees(gps[4], gps.get(3), "W")
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return (lat, lon) if np.isfinite([lat, lon]).all() and abs(lat) <= 90 and abs(lon) <= 180 else None


def exif_positions(folder: Path, names: Sequence[str]) -> Positions:
    """The GPS positions (lat, lon) of a folder's images; any image without one is an error naming
    the first, with the count."""
    folder = Path(folder)
    if not folder.is_dir():
        raise WilocError(folder, "exif ground truth reads the images of an image folder, and this is not one"
                                 if folder.exists() else "folder does not exist")
    found = [gps_position(folder / name) for name in names]
    missing = [name for name, at in zip(names, found) if at is None]
    if missing:
        raise WilocError(folder / missing[0], f"no GPS position in its EXIF ({len(missing)} of {len(names)} "
                                              f"images in {folder} have none)")
    return Positions(f"{folder} (EXIF GPS)", name_index(names), np.array(found, dtype=np.float64).reshape(-1, 2),
                     geographic=True)


def exif_truth(query_folder: Path, ref_folder: Path | None, radius: float, query_names: Sequence[str],
               ref_names: Sequence[str]) -> Truth:
    """``exif`` form: frames whose EXIF GPS positions lie within ``radius`` metres (great-circle)
    are the same place (``ref_folder`` None: sequence mode)."""
    query = exif_positions(query_folder, query_names)
    ref = query if ref_folder is None else exif_positions(ref_folder, ref_names)
    return truth_within(query, ref, radius, query_names, ref_names)

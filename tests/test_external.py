"""Reading user-supplied descriptor matrices (wiloc/descriptors/external.py)."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from wiloc import demo
from wiloc.descriptors.external import read_external
from wiloc.errors import WilocError

NAMES = ["a.png", "b.png", "c.png"]


def _matrix(dtype: type = np.float32) -> np.ndarray:
    return np.arange(12, dtype=np.float64).reshape(3, 4).astype(dtype) + 1


def _csv(path: Path, rows: list[list[object]]) -> Path:
    path.write_text("\n".join(",".join(map(str, row)) for row in rows) + "\n", encoding="utf-8")
    return path


def test_npy_with_generated_names(tmp_path: Path) -> None:
    np.save(tmp_path / "m.npy", _matrix())
    names, matrix = read_external(tmp_path / "m.npy", None, "l1")
    assert names == ["frame000000", "frame000001", "frame000002"]
    assert matrix.dtype == np.float32 and np.array_equal(matrix, _matrix())


@pytest.mark.parametrize("sidecar", ["names.txt", "names.csv"])
def test_npy_with_sidecar_names(tmp_path: Path, sidecar: str) -> None:
    np.save(tmp_path / "m.npy", _matrix(np.float64))
    text = "name\n" + "\n".join(NAMES) if sidecar.endswith(".csv") else "\n".join(NAMES) + "\n\n"
    (tmp_path / sidecar).write_text(text, encoding="utf-8")
    names, matrix = read_external(tmp_path / "m.npy", tmp_path / sidecar, "sqeuclidean")
    assert names == NAMES
    assert matrix.dtype == np.float64 and np.array_equal(matrix, _matrix(np.float64))


@pytest.mark.parametrize("header", [True, False])
def test_csv_round_trip(tmp_path: Path, header: bool) -> None:
    rows = [[n, *row] for n, row in zip(NAMES, _matrix().tolist())]
    path = _csv(tmp_path / "m.csv", ([["name", "d0", "d1", "d2", "d3"]] if header else []) + rows)
    names, matrix = read_external(path, None, "cosine")
    assert names == NAMES and np.array_equal(matrix, _matrix())


@pytest.mark.parametrize("index_label", ["name", None])
def test_csv_written_by_pandas_keeps_its_header_out(tmp_path: Path, index_label: str | None) -> None:
    # DataFrame.to_csv heads the value columns 0, 1, 2, ... (numbers) and an unnamed index with an
    # empty cell: the header is no frame, whose row would have held the column labels
    import pandas as pd

    pd.DataFrame(_matrix(np.float64), index=NAMES).to_csv(tmp_path / "m.csv", index_label=index_label)
    names, matrix = read_external(tmp_path / "m.csv", None, "l1")
    assert names == NAMES and np.array_equal(matrix, _matrix())


def test_a_csv_of_pandas_index_then_names_passes_the_index_over(tmp_path: Path) -> None:
    # df.to_csv(path) of a table with a name column writes its index first: it was
    # "row 2, column 2: 'a.png' is not a number"
    import pandas as pd

    table = pd.DataFrame(_matrix(np.float64))
    table.insert(0, "name", NAMES)
    table.to_csv(tmp_path / "m.csv")
    names, matrix = read_external(tmp_path / "m.csv", None, "l1")
    assert names == NAMES and np.array_equal(matrix, _matrix())


def test_a_csv_of_values_alone_is_not_read_with_its_first_column_as_names(tmp_path: Path) -> None:
    # np.savetxt(m.csv, features, delimiter=",") writes no names: its first column of values was
    # taken as frame names ('1.257e-01', ...) and the descriptors lost a dimension, silently
    values = np.random.default_rng(0).normal(size=(5, 4))
    np.savetxt(tmp_path / "bare.csv", values, delimiter=",")
    with pytest.raises(WilocError, match=r"bare\.csv: its first column holds numbers such as '.*', as large as "
                                         r"the other columns' values, not frame names"):
        read_external(tmp_path / "bare.csv", None, "l1")
    # names that are numbers outside the values' range (timestamps) or whole (frame numbers) stay names
    for first in (1614000000.0 + np.arange(5) * 0.25, np.arange(5.0)):
        np.savetxt(tmp_path / "named.csv", np.column_stack([first, values]), delimiter=",", fmt="%.15g")
        names, matrix = read_external(tmp_path / "named.csv", None, "l1")
        assert [float(name) for name in names] == first.tolist() and matrix.shape == (5, 4)


@pytest.mark.parametrize("separator", [";", "\t"])
def test_a_csv_of_another_separator_is_told_to_use_commas(tmp_path: Path, separator: str) -> None:
    path = tmp_path / "m.csv"
    path.write_text("\n".join(separator.join(map(str, [name, *row])) for name, row in zip(NAMES, _matrix().tolist())))
    with pytest.raises(WilocError, match="need a name column and at least one value column; columns must be "
                                         "separated by commas"):
        read_external(path, None, "l1")


@pytest.mark.parametrize("shape", [(3, 4, 1, 1), (3, 1, 4)])
def test_a_pooled_network_output_is_one_vector_per_frame(tmp_path: Path, shape: tuple[int, ...]) -> None:
    # a CNN's globally pooled features, saved as they come (N x D x 1 x 1), were 'need an N x D matrix'
    np.save(tmp_path / "m.npy", _matrix().reshape(shape))
    assert np.array_equal(read_external(tmp_path / "m.npy", None, "l1")[1], _matrix())
    np.save(tmp_path / "m.npy", np.ones((3, 2, 2)))
    with pytest.raises(WilocError, match=r"need an N x D matrix \(N, D >= 1\); got shape \(3, 2, 2\)"):
        read_external(tmp_path / "m.npy", None, "l1")


def test_names_saved_with_np_save_are_read(tmp_path: Path) -> None:
    # np.save(names.npy, names) was 'cannot read frame names ('utf-8' codec can't decode byte 0x93 ...)'
    np.save(tmp_path / "m.npy", _matrix())
    for dtype in ("U", "O"):
        np.save(tmp_path / "names.npy", np.array(NAMES, dtype=dtype))
        assert read_external(tmp_path / "m.npy", tmp_path / "names.npy", "l1")[0] == NAMES
    np.save(tmp_path / "names.npy", np.arange(3))
    with pytest.raises(WilocError, match=r"names\.npy: holds a 3 array of int64, not frame names \(a 1-D array of text\)"):
        read_external(tmp_path / "m.npy", tmp_path / "names.npy", "l1")


def test_an_h5_of_other_dataset_names_lists_them(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "m.h5", "w") as handle:
        handle["features"] = _matrix()
        handle["meta/image_names"] = np.array([b"a", b"b", b"c"])
    with pytest.raises(WilocError, match=r"neither a dataset 'descriptors' \(N x D\) nor hloc's groups holding "
                                         r"'global_descriptor' \(global-feats-\*\.h5\); it holds features \(3 x 4\), "
                                         r"meta/image_names \(3\)$"):
        read_external(tmp_path / "m.h5", None, "l1")


def test_a_names_file_with_a_header_of_its_own_is_told(tmp_path: Path) -> None:
    np.save(tmp_path / "m.npy", np.ones((3, 6)))
    (tmp_path / "names.txt").write_text("\n".join(["image_path", *NAMES]))
    with pytest.raises(WilocError, match=r"names\.txt: 4 frame names for 3 descriptor rows \(is the first, "
                                         r"'image_path', a header\? only file, filename, frame, .* are known as one\)"):
        read_external(tmp_path / "m.npy", tmp_path / "names.txt", "l1")


def test_a_matrix_of_one_column_per_frame_is_told_with_its_transpose(tmp_path: Path) -> None:
    # tools that store one descriptor per column (MATLAB's habit) give a D x N matrix
    np.save(tmp_path / "m.npy", _matrix().T)
    (tmp_path / "names.txt").write_text("\n".join(NAMES))
    with pytest.raises(WilocError, match=r"3 frame names for 4 descriptor rows \(the matrix is 4 x 3: one column "
                                         r"per frame\? save its transpose"):
        read_external(tmp_path / "m.npy", tmp_path / "names.txt", "l1")
    np.save(tmp_path / "m.npy", _matrix())
    assert read_external(tmp_path / "m.npy", tmp_path / "names.txt", "l1")[0] == NAMES


def test_npz_archive_with_or_without_names(tmp_path: Path) -> None:
    # np.savez of the descriptors and, as another tool may add, their names
    np.savez(tmp_path / "named.npz", descriptors=_matrix(), names=np.array(NAMES))
    names, matrix = read_external(tmp_path / "named.npz", None, "l1")
    assert names == NAMES and np.array_equal(matrix, _matrix())
    np.savez(tmp_path / "bare.npz", _matrix())
    (tmp_path / "names.txt").write_text("\n".join(NAMES[::-1]))
    assert read_external(tmp_path / "bare.npz", tmp_path / "names.txt", "l1")[0] == NAMES[::-1]
    assert read_external(tmp_path / "bare.npz", None, "l1")[0] == ["frame000000", "frame000001", "frame000002"]
    np.savez(tmp_path / "two.npz", a=_matrix(), b=_matrix())
    with pytest.raises(WilocError, match=r"holds 2 2-D arrays of numbers \(a, b\)"):
        read_external(tmp_path / "two.npz", None, "l1")


@pytest.mark.parametrize("dtype", ["U", "S", "O"])
def test_npz_names_as_text_bytes_or_python_strings(tmp_path: Path, dtype: str) -> None:
    # names saved as bytes (as h5py gives them) were passed over and frames named frame000000...;
    # names as Python strings (a pandas column's .values) made the whole archive unreadable
    np.savez(tmp_path / "m.npz", descriptors=_matrix(), names=np.array(NAMES, dtype=dtype))
    names, matrix = read_external(tmp_path / "m.npz", None, "l1")
    assert names == NAMES and np.array_equal(matrix, _matrix())


def test_npz_of_descriptors_one_column_per_frame_is_told(tmp_path: Path) -> None:
    # a D x N archive with its N names imported as D frames named frame000000...
    np.savez(tmp_path / "t.npz", descriptors=_matrix().T, names=np.array(NAMES))
    with pytest.raises(WilocError, match=r"t\.npz: 3 frame names for 4 descriptor rows \(the matrix is 4 x 3: one "
                                         r"column per frame\? save its transpose"):
        read_external(tmp_path / "t.npz", None, "l1")


def test_npz_naming_foreign_code_is_refused_unrun(tmp_path: Path) -> None:
    names = np.array([Path("a"), Path("b"), Path("c")], dtype=object)
    np.savez(tmp_path / "m.npz", descriptors=_matrix(), names=names)
    with pytest.raises(WilocError, match=r"m\.npz: not a readable \.npz archive \(it names pathlib\.\w+, which is no "
                                         r"part of a numpy array\)"):
        read_external(tmp_path / "m.npz", None, "l1")


def test_a_row_without_a_name_is_refused(tmp_path: Path) -> None:
    # a blank name cell was a frame named '' that no ground truth or results file can name
    path = _csv(tmp_path / "m.csv", [["name", "d0", "d1"], ["a.png", 1, 2], ["", 3, 4], ["c.png", 5, 6]])
    with pytest.raises(WilocError, match="row 2: frame name ''; each row needs a non-empty text name"):
        read_external(path, None, "l1")
    with h5py.File(tmp_path / "m.h5", "w") as handle:
        handle["descriptors"] = _matrix()
        handle["names"] = np.array([b"a.png", b"b.png", b""])
    with pytest.raises(WilocError, match="row 3: frame name ''; each row needs a non-empty text name"):
        read_external(tmp_path / "m.h5", None, "l1")


def test_csv_hamming_becomes_uint8(tmp_path: Path) -> None:
    path = _csv(tmp_path / "h.csv", [["x", 0, 255], ["y", 17, 3]])
    names, matrix = read_external(path, None, "hamming")
    assert names == ["x", "y"] and matrix.dtype == np.uint8
    assert matrix.tolist() == [[0, 255], [17, 3]]


def test_rows_keep_the_file_order(tmp_path: Path) -> None:
    order = ["zeta", "alpha", "mid10", "mid2", "beta"]  # time order, not name order
    values = np.arange(10, dtype=np.float32).reshape(5, 2) + 1
    path = _csv(tmp_path / "seq.csv", [[n, *row] for n, row in zip(order, values.tolist())])
    names, matrix = read_external(path, None, "l1")
    assert names == order and np.array_equal(matrix, values)


@pytest.mark.parametrize("as_bytes", [True, False])
def test_h5_round_trip(tmp_path: Path, as_bytes: bool) -> None:
    path = tmp_path / "m.h5"
    packed = np.random.default_rng(0).integers(0, 256, (3, 8), dtype=np.uint8)
    with h5py.File(path, "w") as handle:
        handle["descriptors"] = packed
        handle["names"] = [n.encode() for n in NAMES] if as_bytes else np.array(NAMES, dtype=object)
    names, matrix = read_external(path, None, "hamming")
    assert names == NAMES and matrix.dtype == np.uint8 and np.array_equal(matrix, packed)


def _bad_npy_1d(tmp: Path) -> tuple[Path, Path | None, str]:
    np.save(tmp / "m.npy", np.ones(5, np.float32))
    return tmp / "m.npy", None, "l1"


def _bad_npy_nan(tmp: Path) -> tuple[Path, Path | None, str]:
    m = _matrix()
    m[1, 2] = np.nan
    np.save(tmp / "m.npy", m)
    return tmp / "m.npy", None, "l1"


def _bad_npy_inf(tmp: Path) -> tuple[Path, Path | None, str]:
    m = _matrix()
    m[0, 0] = np.inf
    np.save(tmp / "m.npy", m)
    return tmp / "m.npy", None, "sqeuclidean"


def _bad_duplicates(tmp: Path) -> tuple[Path, Path | None, str]:
    np.save(tmp / "m.npy", _matrix())
    (tmp / "n.txt").write_text("a\nb\na\n")
    return tmp / "m.npy", tmp / "n.txt", "l1"


def _bad_count(tmp: Path) -> tuple[Path, Path | None, str]:
    np.save(tmp / "m.npy", _matrix())
    (tmp / "n.txt").write_text("a\nb\n")
    return tmp / "m.npy", tmp / "n.txt", "l1"


def _bad_metric(tmp: Path) -> tuple[Path, Path | None, str]:
    np.save(tmp / "m.npy", _matrix())
    return tmp / "m.npy", None, "manhattan"


def _bad_cell(tmp: Path) -> tuple[Path, Path | None, str]:
    return _csv(tmp / "m.csv", [["a", 1, 2], ["b", 3, "x7"]]), None, "l1"


def _bad_hamming_float(tmp: Path) -> tuple[Path, Path | None, str]:
    np.save(tmp / "m.npy", _matrix())
    return tmp / "m.npy", None, "hamming"


def _bad_hamming_csv(tmp: Path) -> tuple[Path, Path | None, str]:
    return _csv(tmp / "m.csv", [["a", 1, 256], ["b", 3, 4]]), None, "hamming"


def _bad_h5_missing(tmp: Path) -> tuple[Path, Path | None, str]:
    with h5py.File(tmp / "m.h5", "w") as handle:
        handle["other"] = _matrix()
    return tmp / "m.h5", None, "l1"


def _bad_h5_names(tmp: Path) -> tuple[Path, Path | None, str]:
    with h5py.File(tmp / "m.h5", "w") as handle:
        handle["descriptors"] = _matrix()
        handle["names"] = [b"a", b"b"]
    return tmp / "m.h5", None, "l1"


def _bad_cosine_zero(tmp: Path) -> tuple[Path, Path | None, str]:
    m = _matrix()
    m[2] = 0
    np.save(tmp / "m.npy", m)
    return tmp / "m.npy", None, "cosine"


def _bad_suffix(tmp: Path) -> tuple[Path, Path | None, str]:
    (tmp / "m.mat").write_bytes(b"x")
    return tmp / "m.mat", None, "l1"


def _bad_missing(tmp: Path) -> tuple[Path, Path | None, str]:
    return tmp / "nothing.npy", None, "l1"


def _bad_not_npy(tmp: Path) -> tuple[Path, Path | None, str]:
    (tmp / "m.npy").write_bytes(b"garbage")
    return tmp / "m.npy", None, "l1"


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (_bad_npy_1d, "N x D"),
        (_bad_npy_nan, "NaN"),
        (_bad_npy_inf, "infinite"),
        (_bad_duplicates, "rows 1 and 3: duplicate frame name 'a'; each row names a frame of its own"),
        (_bad_count, "2 frame names for 3"),
        (_bad_metric, "unknown metric"),
        (_bad_cell, "'x7' is not a number"),
        (_bad_hamming_float, "uint8"),
        (_bad_hamming_csv, "uint8"),
        (_bad_h5_missing, "descriptors"),
        (_bad_h5_names, "2 frame names for 3"),
        (_bad_cosine_zero, "all zeros"),
        (_bad_suffix, "unknown matrix format"),
        (_bad_missing, "does not exist"),
        (_bad_not_npy, "npy"),
    ],
)
def test_bad_input_raises_wiloc_error_naming_the_file(tmp_path: Path, make, match: str) -> None:
    path, names_path, metric = make(tmp_path)
    with pytest.raises(WilocError, match=match) as err:
        read_external(path, names_path, metric)
    assert err.value.where in (str(path), str(names_path))


def test_a_metric_for_image_folders_is_refused_not_recorded(demo_route: demo.DemoRoute, tmp_path: Path,
                                                            cache_dir: Path) -> None:
    """The library refuses a metric where no traversal is a descriptor matrix file, as the command
    line does: images are compared by their descriptor's difference, and a localizer had recorded
    the metric in its state while comparing by l1."""
    from wiloc import api
    from wiloc.errors import ParameterError
    from wiloc.localization.localizer import Localizer

    for run in (lambda: Localizer(demo_route.reference, metric="cosine"),
                lambda: api.localize(demo_route.queries[0], reference=demo_route.reference, metric="cosine")):
        with pytest.raises(ParameterError, match=r"applies to descriptor matrix files \(.npy, .npz, .csv, .h5\) only") as err:
            run()
        assert err.value.parameter == "metric"
    matrix = tmp_path / "map.npy"
    np.save(matrix, np.random.default_rng(0).random((5, 8), dtype=np.float32))
    assert Localizer(matrix, method="threshold", metric="cosine").metric == "cosine"


def test_a_descriptor_for_matrix_files_is_refused_not_recorded(tmp_path: Path, cache_dir: Path) -> None:
    """The library refuses a descriptor (or its parameters) where every traversal is a descriptor
    matrix file, as the command line does: the rows are compared as imported, and a localizer had
    shown descriptor='gist' while its results said external:l1."""
    from wiloc import api
    from wiloc.errors import ParameterError
    from wiloc.localization.localizer import Localizer

    rng = np.random.default_rng(0)
    rows = rng.random((30, 16)).astype(np.float32)
    np.save(tmp_path / "map.npy", rows)
    np.save(tmp_path / "query.npy", rows + rng.normal(0, 0.01, rows.shape).astype(np.float32))
    for run, parameter in ((lambda: api.localize(tmp_path / "query.npy", reference=tmp_path / "map.npy", metric="l1",
                                                 method="threshold", descriptor="gist"), "descriptor"),
                           (lambda: Localizer(tmp_path / "map.npy", metric="l1", method="threshold",
                                              descriptor_params={"patch": 4}), "descriptor_params")):
        with pytest.raises(ParameterError, match="is a descriptor matrix file, compared by its metric") as err:
            run()
        assert err.value.parameter == parameter
    run = api.localize(tmp_path / "query.npy", reference=tmp_path / "map.npy", metric="l1", method="threshold")
    assert run.results.header.descriptor == "external:l1"


def test_a_csv_whose_header_holds_fewer_columns_says_which_line_has_how_many(tmp_path: Path) -> None:
    """Numbers and names of the file's own lines, not pandas' tokenizer's words."""
    path = _csv(tmp_path / "m.csv", [["name", "descriptor"], ["a.png", 1, 2, 3], ["b.png", 4, 5, 6]])
    with pytest.raises(WilocError, match=r"m\.csv: line 2 has 4 values where line 1 has 2: a header line\? a \.csv "
                                         r"matrix holds a frame's name and its values on each line \(name,d0,d1,\.\.\.\)"):
        read_external(path, None, "l1")


def test_a_blank_line_among_the_names_is_pointed_at(tmp_path: Path) -> None:
    np.save(tmp_path / "m.npy", _matrix())
    (tmp_path / "names.txt").write_text("a.png\n\nc.png\n\n")
    with pytest.raises(WilocError, match=r"names\.txt: 2 frame names for 3 descriptor rows \(line 2 is empty: each "
                                         r"descriptor row's name goes on a line of its own\)$"):
        read_external(tmp_path / "m.npy", tmp_path / "names.txt", "l1")

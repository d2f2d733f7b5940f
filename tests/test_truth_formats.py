"""Ground truth as VPR datasets ship it (wiloc/evaluation/truth_formats.py): VPR-Bench's ground_truth_new.npy,
@UTM_east@UTM_north@ file names and EXIF GPS each give the same evaluation as the pairs CSV that
lists the same true matches; bad files of each kind are one line and exit code 1."""
from __future__ import annotations

import json
import pathlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from PIL.TiffImagePlugin import IFDRational
from helpers import ends_in_one_error, places
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.errors import WilocError
from wiloc.evaluation.groundtruth import EARTH_RADIUS_M
from wiloc.evaluation.results import read_results
from wiloc.evaluation.truth_formats import read_vprbench
from wiloc.evaluation.truth_source import file_form, load_truth

runner = CliRunner()
N = 24
SPACING = 12.0  # metres between places: within 25 m lie the places +-2 along the route


def _rational_seconds(degrees: float) -> tuple[IFDRational, IFDRational, IFDRational]:
    """Degrees as EXIF writes them: whole degrees, whole minutes, seconds to 1e-4."""
    whole = int(degrees)
    minutes = int((degrees - whole) * 60)
    seconds = round(((degrees - whole) * 60 - minutes) * 60 * 10_000)
    return IFDRational(whole, 1), IFDRational(minutes, 1), IFDRational(seconds, 10_000)


def _as_degrees(parts: tuple[IFDRational, ...]) -> float:
    return sum(float(p) / 60.0 ** k for k, p in enumerate(parts))


def _write_images(folder: Path, scenes: list[np.ndarray], gain: float, seed: int) -> pd.DataFrame:
    """JPEGs in VPR-methods-evaluation's layout: @UTM_east@UTM_north@zone@letter@lat@lon@...@.jpg,
    with the GPS position in their EXIF (jittered by a few metres per traversal); returns each
    image's name, UTM and lat/lon as written."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    rows = []
    for i, scene in enumerate(scenes):
        east, north = np.round([500_000.0 + SPACING * i + rng.normal(0, 3), 4_100_000.0 + rng.normal(0, 3)], 2)
        lat_parts = _rational_seconds(51.5 + (SPACING * i + rng.normal(0, 3)) / 111_195.0)
        lon_parts = _rational_seconds(0.1 + rng.normal(0, 3) / 69_000.0)
        lat, lon = _as_degrees(lat_parts), -_as_degrees(lon_parts)
        name = f"@{east:.2f}@{north:.2f}@30@U@{lat:.6f}@{lon:.6f}@pano{i}@@@@@@@.jpg"
        image = np.clip(scene * gain + rng.normal(0, 6, scene.shape), 0, 255).astype(np.uint8)
        exif = Image.Exif()
        exif[0x8825] = {1: "N", 2: lat_parts, 3: "W", 4: lon_parts}
        Image.fromarray(image).save(folder / name, exif=exif, quality=95)
        rows.append({"name": name, "east": east, "north": north, "lat": lat, "lon": lon})
    return pd.DataFrame(rows)


def _great_circle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Haversine distances in metres between (lat, lon) degree rows of a and b."""
    lat1, lon1 = np.radians(a[:, :1]), np.radians(a[:, 1:])
    lat2, lon2 = np.radians(b[:, 0]), np.radians(b[:, 1])
    h = np.sin((lat2 - lat1) / 2) ** 2 + np.cos(lat1) * np.cos(lat2) * np.sin((lon2 - lon1) / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(h))


def _make_route(tmp_path: Path) -> dict:
    """database/ and queries/ over the same places, a threshold run of one against the other (on
    the cache in tmp_path), and the pairs CSVs that list the same place by UTM and by lat/lon within
    25 m (brute force)."""
    scenes = places(N)
    ref = _write_images(tmp_path / "database", scenes, 1.0, 1)
    query = _write_images(tmp_path / "queries", scenes, 0.7, 2)
    run = tmp_path / "run.csv"
    result = runner.invoke(app, ["localize", str(tmp_path / "queries"), "--map", str(tmp_path / "database"),
                                 "--method", "threshold", "--out", str(run), "--jobs", "1",
                                 "--cache", str(tmp_path / "cache")])
    assert result.exit_code == 0, result.output
    metres = {"utm": np.hypot(query["east"].to_numpy()[:, None] - ref["east"].to_numpy(),
                              query["north"].to_numpy()[:, None] - ref["north"].to_numpy()),
              "gps": _great_circle(query[["lat", "lon"]].to_numpy(), ref[["lat", "lon"]].to_numpy())}
    pairs = {}
    for kind, distances in metres.items():
        q, r = np.nonzero(distances <= 25.0)
        assert 0 < q.size < N * N / 4  # a band around the route, not everything
        pairs[kind] = tmp_path / f"pairs-{kind}.csv"
        pd.DataFrame({"query": query["name"].to_numpy()[q], "reference": ref["name"].to_numpy()[r]}).to_csv(
            pairs[kind], index=False)
    return {"root": tmp_path, "run": run, "pairs": pairs, "query": query, "ref": ref}


@pytest.fixture(scope="module")
def vpr_route(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The route of `_make_route`, made once for the tests that only read it (they write their own
    files into their own tmp_path)."""
    return _make_route(tmp_path_factory.mktemp("vpr-route"))


@pytest.fixture
def own_vpr_route(tmp_path: Path, cache_dir: Path) -> dict:
    """The route of `_make_route` for a test that changes its images."""
    return _make_route(tmp_path)


def _write_vprbench(path: Path, pairs_csv: Path, run: Path) -> Path:
    """VPR-Bench's ground_truth_new.npy for the pairs: [query index, [reference indices]] per
    query frame, indices in the traversals' natural order (the run's frame order)."""
    results = read_results(run)
    queries, refs = results.frames["frame"].tolist(), list(results.reference_frames)
    pairs = pd.read_csv(pairs_csv)
    rows = np.empty((len(queries), 2), dtype=object)
    for i, name in enumerate(queries):
        rows[i] = [i, [refs.index(r) for r in pairs.loc[pairs["query"] == name, "reference"]]]
    np.save(path, rows)
    return path


def _write_positives(path: Path, pairs_csv: Path, run: Path) -> Path:
    """The pairs as positives per query, as pytorch-NetVLAD and VPR-methods-evaluation keep them:
    an object array whose i-th entry holds the reference indices of the i-th query frame (empty
    for a query frame without one)."""
    results = read_results(run)
    queries, refs = results.frames["frame"].tolist(), list(results.reference_frames)
    pairs = pd.read_csv(pairs_csv)
    positives = np.empty(len(queries), dtype=object)
    for i, name in enumerate(queries):
        positives[i] = np.array([refs.index(r) for r in pairs.loc[pairs["query"] == name, "reference"]], dtype=np.int64)
    assert len({p.size for p in positives}) > 1  # ragged: numpy keeps it an object array
    np.save(path, positives)
    return path


def _evaluation(run: Path, gt: list[str]) -> dict:
    result = runner.invoke(app, ["evaluate", str(run), *gt, "--json"])
    assert result.exit_code == 0, result.output
    (record,) = json.loads(result.stdout)["runs"]
    return {k: v for k, v in record.items() if k not in ("ground_truth", "warnings")}


#: each form's command-line arguments, the pairs CSV it equals, and the same as a TruthSource
FORMS = {"utm-names": (["--gt", "utm-names", "--radius", "25"], "utm", ("utm-names", None)),
         "utm-names, default radius": (["--gt", "utm-names"], "utm", ("utm-names", None)),
         "exif": (["--gt", "exif", "--radius", "25"], "gps", ("exif", None)),
         "vprbench": (["--gt", "vprbench:{gt_file}"], "utm", ("vprbench", "{gt_file}")),
         "vprbench, the file alone": (["--gt", "{gt_file}"], "utm", ("vprbench", "{gt_file}")),
         "positives": (["--gt", "positives:{gt_file}"], "utm", ("positives", "{gt_file}")),
         "positives, the file alone": (["--gt", "{gt_file}"], "gps", ("positives", "{gt_file}"))}


@pytest.mark.parametrize("form", FORMS)
def test_each_form_evaluates_as_the_equivalent_pairs_csv(form: str, vpr_route: dict, tmp_path: Path) -> None:
    args, pairs_kind, (kind, path) = FORMS[form]
    pairs, run = vpr_route["pairs"][pairs_kind], vpr_route["run"]
    write = _write_positives if kind == "positives" else _write_vprbench
    gt_file = write(tmp_path / ("positives.npy" if kind == "positives" else "ground_truth_new.npy"), pairs, run)
    expected = _evaluation(run, ["--gt", f"pairs:{pairs}"])
    assert expected["with_true_match"] > 0
    assert _evaluation(run, [arg.format(gt_file=gt_file) for arg in args]) == expected
    source = api.TruthSource(kind=kind, path=path and path.format(gt_file=gt_file), radius=25.0)
    truth, reference = api.evaluate(run, source).truth, api.evaluate(run, api.TruthSource("pairs", str(pairs))).truth
    assert (truth.matrix != reference.matrix).nnz == 0 and truth.matrix.nnz == reference.matrix.nnz


def test_utm_names_in_sequence_mode_match_a_positions_csv(vpr_route: dict, tmp_path: Path, cache_dir: Path) -> None:
    run = tmp_path / "seq.csv"
    assert runner.invoke(app, ["localize", str(vpr_route["root"] / "queries"), "--method", "threshold",
                               "--out", str(run), "--jobs", "1", "-R", "1"]).exit_code == 0
    positions = tmp_path / "positions.csv"
    vpr_route["query"].rename(columns={"east": "x", "north": "y"})[["name", "x", "y"]].to_csv(positions, index=False)
    expected = _evaluation(run, ["--gt", f"positions:{positions}", "--radius", "25"])
    assert _evaluation(run, ["--gt", "utm-names", "--radius", "25"]) == expected


def test_a_smaller_radius_marks_fewer_places(vpr_route: dict) -> None:
    names = vpr_route["query"]["name"].tolist(), vpr_route["ref"]["name"].tolist()
    folders = {"query_folder": vpr_route["root"] / "queries", "ref_folder": vpr_route["root"] / "database"}
    wide = load_truth("utm-names", None, query_names=names[0], ref_names=names[1], **folders)
    narrow = load_truth("utm-names", None, query_names=names[0], ref_names=names[1], radius=5.0, **folders)
    assert 0 < narrow.matrix.nnz < wide.matrix.nnz


def test_vprbench_rows_may_hold_lists_arrays_or_one_index(tmp_path: Path) -> None:
    rows = np.empty((3, 2), dtype=object)
    rows[0], rows[1], rows[2] = [0, [1, 2]], [np.int64(1), np.array([3], dtype=np.int64)], [2, 0]
    np.save(tmp_path / "gt.npy", rows)
    got = [(q, r.tolist()) for q, r in read_vprbench(tmp_path / "gt.npy")]
    assert got == [(0, [1, 2]), (1, [3]), (2, [0])]


class Smuggled:
    """An object a pickle may name but that is no part of a numpy array."""


def _bad_vprbench(tmp: Path, kind: str) -> Path:
    path = tmp / f"{kind}.npy"
    rows = np.empty((2, 2), dtype=object)
    if kind == "numeric":
        np.save(path, np.eye(3))
        return path
    if kind in ("flat", "pickled dict"):
        np.save(path, np.array([1, 2, 3], dtype=object) if kind == "flat" else {"query": [0], "refs": [[1]]})
        return path
    rows[0], rows[1] = ([0, [1]], [1, {"a": 2}]) if kind == "dict" else \
        ([0, [1]], [1, pathlib.PurePosixPath("x")]) if kind == "foreign object" else ([0, [1]], [1, [9999]])
    np.save(path, rows)
    return path


@pytest.mark.parametrize("kind, message", [
    ("numeric", "holds a plain 3 x 3 array of float64, not VPR-Bench's rows"),
    ("dict", "row 2 is not [query index, [reference indices]]"),
    ("foreign object", "it names pathlib"),
    ("out of range", ("row 2: reference index 9999 is no frame of the reference traversal, whose 24 frames are "
                      "numbered 0 to 23")),
    ("flat", "row 1 is not [query index, [reference indices]]"),
    ("pickled dict", "holds a 0-d object array, not VPR-Bench's rows"),
])
def test_bad_vprbench_files_are_one_line(kind: str, message: str, vpr_route: dict, tmp_path: Path) -> None:
    path = _bad_vprbench(tmp_path, kind)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(vpr_route["run"]), "--gt", f"vprbench:{path}"]), 1,
                      str(path), message)


def test_a_foreign_pickle_is_never_run(tmp_path: Path) -> None:
    rows = np.empty((1, 2), dtype=object)
    rows[0] = [0, Smuggled()]
    np.save(tmp_path / "gt.npy", rows)
    with pytest.raises(WilocError, match="it names test_truth_formats.Smuggled"):
        read_vprbench(tmp_path / "gt.npy")


def _bad_positives(tmp: Path, kind: str, n_query: int) -> Path:
    path = tmp / f"{kind}.npy"
    positives = np.empty(n_query - (kind == "one short"), dtype=object)
    positives[:] = [np.array([i % 3], dtype=np.int64) for i in range(positives.size)]
    if kind == "out of range":
        positives[4] = np.array([2, 9999])
    elif kind == "not indices":
        positives[1] = np.array([0.5, 1.5])
    masks = {"mask": np.eye(n_query), "mask of uint8": _near_mask(n_query).astype(np.uint8),
             "mask of bool": _near_mask(n_query)}
    np.save(path, masks[kind] if kind in masks else positives)
    return path


def _near_mask(n: int) -> np.ndarray:
    """An n x n same-place mask: each frame and its neighbours (the matrix form)."""
    return np.abs(np.subtract.outer(np.arange(n), np.arange(n))) <= 1


@pytest.mark.parametrize("kind, message", [
    ("one short", "lists positives of 23 query frames, but the query traversal has 24: entry i is the i-th query frame"),
    ("out of range", ("@.jpg): reference index 9999 is no frame of the reference traversal, whose 24 frames are "
                      "numbered 0 to 23")),
    ("not indices", "@.jpg) is not a list of reference indices"),
    ("mask", "holds a 24 x 24 array of float64, every value 0 or 1: it looks like a same-place mask (queries x "
             "references), not one array of reference indices per query frame; give it as matrix:FILE"),
    ("mask of uint8", "holds a 24 x 24 array of uint8, every value 0 or 1: it looks like a same-place mask"),
    ("mask of bool", "holds a 24 x 24 array of bool, every value 0 or 1: it looks like a same-place mask"),
])
def test_bad_positives_files_are_one_line(kind: str, message: str, vpr_route: dict, tmp_path: Path) -> None:
    queries = read_results(vpr_route["run"]).frames["frame"]
    path = _bad_positives(tmp_path, kind, len(queries))
    entry = {"out of range": 4, "not indices": 1}.get(kind)
    where = () if entry is None else (f": entry {entry + 1} of 24 (query frame {queries.iloc[entry]})",)
    ends_in_one_error(runner.invoke(app, ["evaluate", str(vpr_route["run"]), "--gt", f"positives:{path}"]), 1,
                      str(path), *where, message)


def test_an_out_of_range_positive_names_its_query_frame_and_how_indices_count(tmp_path: Path) -> None:
    """Entry numbers count from 1 (as rows and lines do) and reference indices from 0 (as the file's
    do): 'entry 6: reference index 99' mixed the two without saying so; the message says which
    query frame the entry is and which indices the reference frames have."""
    positives = np.empty(3, dtype=object)
    positives[:] = [np.array([0]), np.array([1]), np.array([2, 3])]
    np.save(tmp_path / "positives.npy", positives)
    with pytest.raises(WilocError) as raised:
        load_truth("positives", tmp_path / "positives.npy", query_names=["a", "b", "c"], ref_names=["x", "y", "z"])
    assert raised.value.problem == ("entry 3 of 3 (query frame c): reference index 3 is no frame of the reference "
                                    "traversal, whose 3 frames are numbered 0 to 2")


def test_positives_of_equal_counts_saved_as_one_integer_array_are_read(tmp_path: Path) -> None:
    """np.save of positives that all hold k indices stores a queries x k integer array, no object
    array: the positives form reads it as such, where a bare .npy of it is a matrix."""
    np.save(tmp_path / "top2.npy", np.array([[0, 1], [1, 2], [2, 0]]))
    truth = load_truth("positives", tmp_path / "top2.npy", query_names=["a", "b", "c"], ref_names=["x", "y", "z"])
    assert truth.matrix.toarray().tolist() == [[True, True, False], [False, True, True], [True, False, True]]
    with pytest.raises(WilocError, match=r"matrix is 3 x 2, expected 3 x 3 \(query x reference frames\); rows of "
                                         r"reference indices are the positives form \(positives:FILE\)"):
        load_truth(file_form(tmp_path / "top2.npy"), tmp_path / "top2.npy", query_names=["a", "b", "c"],
                   ref_names=["x", "y", "z"])


@pytest.mark.parametrize("dtype", [np.uint8, np.int64, np.bool_])
def test_a_same_place_mask_given_as_positives_is_refused(dtype: type, tmp_path: Path) -> None:
    """A 0/1 mask given as positives was read row by row as reference indices 0 and 1, and scored
    silently wrong (R@1 near 0); it is refused, pointing to the matrix form, which reads it."""
    names = [f"f{i}" for i in range(5)]
    np.save(tmp_path / "mask.npy", _near_mask(5).astype(dtype))
    with pytest.raises(WilocError) as raised:
        load_truth("positives", tmp_path / "mask.npy", query_names=names, ref_names=names)
    assert raised.value.where == str(tmp_path / "mask.npy")
    assert "it looks like a same-place mask" in raised.value.problem
    assert raised.value.problem.endswith("give it as matrix:FILE")
    truth = load_truth("matrix", tmp_path / "mask.npy", query_names=names, ref_names=names)
    assert np.array_equal(truth.matrix.toarray(), _near_mask(5))


@pytest.mark.parametrize(("positives", "expected"), [
    ([[0, 1], [1, 0], [0, 1]], [[1, 1], [1, 1], [1, 1]]),  # as wide as the map, each row distinct frames
    ([[0], [1], [0]], [[1, 0], [0, 1], [1, 0]]),  # one positive each, of 0 and 1 only
])
def test_positives_of_only_0_and_1_that_are_no_mask_are_read(positives: list, expected: list, tmp_path: Path) -> None:
    """Positives listing distinct frames 0 and 1 are positives, whatever they look like."""
    np.save(tmp_path / "p.npy", np.array(positives, dtype=np.int64))
    truth = load_truth("positives", tmp_path / "p.npy", query_names=["a", "b", "c"], ref_names=["x", "y"])
    assert truth.matrix.toarray().astype(int).tolist() == expected


@pytest.mark.parametrize(("saved", "hint"), [
    ("mask.npy", "; it has 2 columns but the map has 3 frames (a column each)"),
    ("mask.csv", "; it has 2 columns but the map has 3 frames (a column each)"),
    ("indices.csv", "; rows of reference indices are the positives form (positives:FILE)")])
def test_a_matrix_of_the_wrong_width_is_called_indices_only_when_it_holds_some(saved: str, hint: str,
                                                                               tmp_path: Path) -> None:
    """A 0/1 mask one map frame short got the positives form's hint, as an integer array did: the
    hint follows the values (whole numbers, some above 1), whatever the dtype (a .csv is floats)."""
    values = np.array([[0, 2], [1, 2], [2, 0]]) if saved.startswith("indices") else np.array([[0, 1], [1, 0], [1, 1]])
    path = tmp_path / saved
    if saved.endswith(".npy"):
        np.save(path, values)
    else:
        np.savetxt(path, values, delimiter=",", fmt="%d")
    with pytest.raises(WilocError) as raised:
        load_truth("matrix", path, query_names=["a", "b", "c"], ref_names=["x", "y", "z"])
    assert raised.value.problem == f"matrix is 3 x 2, expected 3 x 3 (query x reference frames){hint}"


def test_a_name_without_utm_fields_is_one_line(own_vpr_route: dict) -> None:
    ref = own_vpr_route["root"] / "database"
    first = ref / own_vpr_route["ref"]["name"][3]
    first.rename(ref / "img3.jpg")
    run = own_vpr_route["root"] / "renamed.csv"
    assert runner.invoke(app, ["localize", str(own_vpr_route["root"] / "queries"), "--map", str(ref), "--method",
                               "threshold", "--out", str(run), "--jobs", "1"]).exit_code == 0
    ends_in_one_error(runner.invoke(app, ["evaluate", str(run), "--gt", "utm-names"]), 1,
                      f"{ref.resolve() / 'img3.jpg'}: not a name of the form @UTM_east@UTM_north@")


def test_a_name_too_far_out_is_one_line(own_vpr_route: dict) -> None:
    """An @UTM name whose easting overflows a squared distance: one line naming it, not scipy's traceback."""
    ref = own_vpr_route["root"] / "database"
    far = ref / "@1e200@4000000@33@T@.jpg"
    (ref / own_vpr_route["ref"]["name"][3]).rename(far)
    run = own_vpr_route["root"] / "far.csv"
    assert runner.invoke(app, ["localize", str(own_vpr_route["root"] / "queries"), "--map", str(ref), "--method",
                               "threshold", "--out", str(run), "--jobs", "1"]).exit_code == 0
    ends_in_one_error(runner.invoke(app, ["evaluate", str(run), "--gt", "utm-names"]), 1,
                      f"{far.resolve()}: a coordinate of 1e+200 metres is too far out to measure distances")


def test_names_of_two_utm_zones_are_one_line(own_vpr_route: dict) -> None:
    ref = own_vpr_route["root"] / "database"
    name = own_vpr_route["ref"]["name"][5]
    (ref / name).rename(ref / name.replace("@30@U@", "@31@U@"))
    run = own_vpr_route["root"] / "zones.csv"
    assert runner.invoke(app, ["localize", str(own_vpr_route["root"] / "queries"), "--map", str(ref), "--method",
                               "threshold", "--out", str(run), "--jobs", "1"]).exit_code == 0
    ends_in_one_error(runner.invoke(app, ["evaluate", str(run), "--gt", "utm-names"]), 1, "UTM zone")


def test_an_image_without_gps_exif_is_one_line(own_vpr_route: dict) -> None:
    query = own_vpr_route["root"] / "queries"
    name = own_vpr_route["query"]["name"][7]
    Image.open(query / name).save(query / name)  # written again without its EXIF
    ends_in_one_error(runner.invoke(app, ["evaluate", str(own_vpr_route["run"]), "--gt", "exif"]), 1,
                      f"{query.resolve() / name}: no GPS position in its EXIF (1 of {N} images")


def test_forms_without_a_file_refuse_one(vpr_route: dict) -> None:
    ends_in_one_error(runner.invoke(app, ["evaluate", str(vpr_route["run"]), "--gt", "exif:gps.csv"]), 2,
                      "--gt: 'exif' reads the traversals themselves and takes no file")

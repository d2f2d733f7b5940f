"""Ground-truth readers: the four forms, name matching, warnings and errors."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
from scipy import sparse
from scipy.spatial.distance import cdist

from wiloc.errors import WilocError
from wiloc.evaluation.aligned import _nearest_index, aligned_truth
from wiloc.evaluation.groundtruth import (EARTH_RADIUS_M, Truth, frame_indices, pairs_truth, positions_truth,
                                          restrict_sequence)
from wiloc.evaluation.truth_formats import matrix_truth
from wiloc.evaluation.truth_source import load_truth

REFS = [f"img{i}.jpg" for i in range(8)]


def dense(truth: Truth) -> np.ndarray:
    return truth.matrix.toarray()


def write_csv(path: Path, rows: dict[str, list]) -> Path:
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


# --- Truth -----------------------------------------------------------------------------------

def test_is_true_is_vectorised_and_minus_one_is_false() -> None:
    truth = aligned_truth(REFS[:3], REFS, tolerance=0)
    got = truth.is_true([0, 1, 2, 2, 0], [0, 0, 2, -1, 7])
    assert got.tolist() == [True, False, True, False, False]
    assert truth.has_match().tolist() == [True, True, True]


# --- aligned ---------------------------------------------------------------------------------

@pytest.mark.parametrize("tolerance", [0, 1, 2])
def test_aligned_by_name_follows_names_not_positions(tolerance: int) -> None:
    queries = ["img5.jpg", "img0.jpg", "img7.jpg", "other.jpg"]
    truth = aligned_truth(queries, REFS, tolerance)
    expected = np.zeros((4, 8), dtype=bool)
    for row, name in enumerate(queries[:3]):
        centre = REFS.index(name)
        for col in range(8):
            expected[row, col] = abs(col - centre) <= tolerance
    np.testing.assert_array_equal(dense(truth), expected)
    assert truth.warnings == ["aligned ground truth (by name): 1 of 4 query frames have no "
                              "reference frame to align with"]


def test_aligned_by_index_pairs_positions() -> None:
    queries = [f"q{i}" for i in range(10)]
    truth = aligned_truth(queries, REFS, tolerance=1, by="index")
    assert truth.is_true([0, 0, 3, 7, 8], [0, 1, 5, 6, 7]).tolist() == [True, True, False, True, False]
    assert truth.has_match().sum() == 8
    assert "2 of 10" in truth.warnings[0]


def test_aligned_by_index_reads_a_sampled_videos_frames_by_their_index_in_the_video() -> None:
    """A video sampled every 5th frame (``000000``, ``000005``, ...) against a folder of every
    frame, either way round: frame 000005 is the folder's sixth frame, not its second; against a
    sampled map a frame between two kept ones goes to the nearer (the lower on a tie), and one past
    the last kept frame by more than half the step to none."""
    video = [f"{i:06d}" for i in range(0, 20, 5)]
    folder = [f"Image{i:03d}.jpg" for i in range(20)]
    truth = aligned_truth(video, folder, tolerance=0, by="index")
    assert [np.flatnonzero(row).tolist() for row in dense(truth)] == [[0], [5], [10], [15]]
    assert truth.warnings == []
    truth = aligned_truth(folder, video, tolerance=0, by="index")
    assert [np.flatnonzero(row).tolist() for row in dense(truth)] == (
        [[0]] * 3 + [[1]] * 5 + [[2]] * 5 + [[3]] * 5 + [[]] * 2)
    assert "2 of 20" in truth.warnings[0]


def test_aligned_without_any_common_name_is_fatal() -> None:
    with pytest.raises(WilocError, match="none of the 2 query frames"):
        aligned_truth(["a", "b"], REFS, tolerance=2)


def test_aligned_rejects_negative_tolerance() -> None:
    with pytest.raises(WilocError, match="tolerance"):
        aligned_truth(REFS, REFS, tolerance=-1)


GAP_MAP = [f"Image{i:03d}.jpg" for i in [*range(60), *range(100, 200)]]  # day_right without frames 60-99


def _true_refs(truth: Truth, query: str) -> list[str]:
    return [truth.ref_names[c] for c in np.flatnonzero(dense(truth)[truth.query_names.index(query)])]


def test_aligned_counts_its_tolerance_in_route_frames_across_a_map_that_leaves_frames_out() -> None:
    """A map without frames 60-99: +-2 counted in the map's list reached across the gap (query
    Image058 true against map Image100, 42 frames on) and Image060 had no true match, though map
    Image058 and Image059 lie within 2 frames of it. The frames' numbers count the route."""
    queries = [f"Image{i:03d}.jpg" for i in range(200)]
    truth = aligned_truth(queries, GAP_MAP, tolerance=2)
    assert _true_refs(truth, "Image058.jpg") == ["Image056.jpg", "Image057.jpg", "Image058.jpg", "Image059.jpg"]
    assert _true_refs(truth, "Image060.jpg") == ["Image058.jpg", "Image059.jpg"]
    assert _true_refs(truth, "Image061.jpg") == ["Image059.jpg"]
    assert _true_refs(truth, "Image080.jpg") == []
    assert _true_refs(truth, "Image099.jpg") == ["Image100.jpg", "Image101.jpg"]
    assert _true_refs(truth, "Image101.jpg") == ["Image100.jpg", "Image101.jpg", "Image102.jpg", "Image103.jpg"]
    assert int(truth.has_match().sum()) == 200 - 36
    assert truth.warnings == [("aligned ground truth (by name): 36 of 200 query frames have no "
                               "reference frame to align with")]


def test_aligned_by_index_counts_a_sampled_videos_gap_by_its_frame_indices() -> None:
    """aligned:index the same: a video sampled every 5th frame without frames 300-495, against the
    video's every frame; a query frame in the gap goes to no map frame more than T kept frames off."""
    video = [f"{i:06d}" for i in [*range(0, 300, 5), *range(500, 1000, 5)]]
    queries = [f"{i:06d}" for i in range(1000)]
    truth = aligned_truth(queries, video, tolerance=2, by="index")
    assert _true_refs(truth, "000297") == ["000285", "000290", "000295"]  # nearest 295, +-2 kept frames
    assert _true_refs(truth, "000304") == ["000295"]  # in the gap: within 10 frames of its own index
    assert _true_refs(truth, "000400") == []
    assert _true_refs(truth, "000502") == ["000500", "000505", "000510"]


def test_aligned_counts_the_route_by_names_across_single_frames_the_map_leaves_out() -> None:
    """A map without frame 15 (steps of 1 and 2) was counted in its own order, so query Image015
    had no true match, though map Image013-Image017 lie within 2 frames of it (fewer missing
    frames lost more truth than 3, which the names count). A few such frames that the query
    holds are frames left out: the names count the route, every 20th frame missing too (of 200,
    190 had a true match)."""
    queries = [f"Image{i:03d}.jpg" for i in range(60)]
    truth = aligned_truth(queries, [q for q in queries if q != "Image015.jpg"], tolerance=2)
    assert _true_refs(truth, "Image015.jpg") == ["Image013.jpg", "Image014.jpg", "Image016.jpg", "Image017.jpg"]
    assert _true_refs(truth, "Image014.jpg") == ["Image012.jpg", "Image013.jpg", "Image014.jpg", "Image016.jpg"]
    assert truth.has_match().all() and truth.warnings == []
    queries = [f"Image{i:03d}.jpg" for i in range(200)]
    truth = aligned_truth(queries, [q for i, q in enumerate(queries) if i % 20 != 10], tolerance=2)
    assert _true_refs(truth, "Image030.jpg") == ["Image028.jpg", "Image029.jpg", "Image031.jpg", "Image032.jpg"]
    assert truth.has_match().all() and truth.warnings == []


def test_aligned_on_a_video_kept_at_25_of_its_30_frames_counts_the_maps_frames() -> None:
    """A map video sampled at 25 of 30 frames a second (one step in five is two frames) against
    the full-rate query: sampled, not frames deleted; +-T counts the map's frames (the route
    numbered by index gave query 000040 four map frames, not five)."""
    kept = sorted({k * 30 // 25 for k in range(92)})
    truth = aligned_truth([f"{i:06d}" for i in range(110)], [f"{i:06d}" for i in kept], tolerance=2, by="index")
    assert _true_refs(truth, "000040") == ["000038", "000039", "000040", "000042", "000043"]


def test_aligned_on_traversals_sampled_alike_counts_the_maps_frames() -> None:
    """Both traversals without frame 15 (sampled alike): the query holds no frame the map lacks,
    so +-T still counts map frames, as before (query Image014 true against Image017)."""
    names = [f"Image{i:03d}.jpg" for i in range(60) if i != 15]
    truth = aligned_truth(names, names, tolerance=2)
    assert _true_refs(truth, "Image014.jpg") == [f"Image0{i}.jpg" for i in (12, 13, 14, 16, 17)]
    assert truth.has_match().all() and truth.warnings == []


FULL_MAP = [f"Image{i:03d}.jpg" for i in range(60)]
LEFT_OUT = ((20, "Image020.jpg"),)
"""A map of frames Image000-059 whose Image020 was left out (unreadable): its place in the map's full order."""


def _within(query: int, tolerance: int) -> list[str]:
    """The map frames within +-``tolerance`` of frame ``query`` by their names, but the one left out."""
    return [f"Image{j:03d}.jpg" for j in range(query - tolerance, query + tolerance + 1)
            if 0 <= j < 60 and j != 20]


@pytest.mark.parametrize("by", ["name", "index"])
def test_aligned_counts_its_tolerance_in_the_maps_full_order_past_a_frame_left_out(by: str) -> None:
    """A map frame left out (unreadable) shifted the band by +-T kept positions: query Image018
    was true against Image021, 3 frames on, and Image020 had no true match. Counted in the map's
    full order (the left-out frame dropped from the band), every frame's truth is its neighbours
    within +-T by name, Image020's too; by index (names counted by position) the same."""
    kept = [name for name in FULL_MAP if name != "Image020.jpg"]
    truth = aligned_truth(FULL_MAP, kept, tolerance=2, by=by, left_out=LEFT_OUT)
    assert _true_refs(truth, "Image018.jpg") == _within(18, 2) == [f"Image0{i}.jpg" for i in (16, 17, 18, 19)]
    assert _true_refs(truth, "Image020.jpg") == [f"Image0{i}.jpg" for i in (18, 19, 21, 22)]
    assert all(_true_refs(truth, f"Image{i:03d}.jpg") == _within(i, 2) for i in range(60))
    assert truth.ref_names == kept and truth.warnings == []
    assert aligned_truth(FULL_MAP, kept, tolerance=0, by=by, left_out=LEFT_OUT).has_match().sum() == 59


def test_a_pairs_tolerance_counts_in_the_maps_full_order_past_a_frame_left_out(tmp_path: Path) -> None:
    """A pairs file's tolerance column is counted in the map's full order alike."""
    kept = [name for name in FULL_MAP if name != "Image020.jpg"]
    csv = write_csv(tmp_path / "pairs.csv", {"query": ["q18", "q20"], "reference": ["Image018.jpg", "Image020.jpg"],
                                             "tolerance": [2, 2]})
    truth = pairs_truth(csv, ["q18", "q20"], kept, left_out=LEFT_OUT)
    assert _true_refs(truth, "q18") == _within(18, 2) and _true_refs(truth, "q20") == _within(20, 2)
    assert truth.warnings == []


def test_a_left_out_frame_that_does_not_fit_the_map_is_refused() -> None:
    """Left-out frames placed beyond the map's full order, or named as kept frames, are no map's."""
    kept = [name for name in FULL_MAP if name != "Image020.jpg"]
    for left_out in (((60, "Image020.jpg"),), ((20, "Image021.jpg"),)):
        with pytest.raises(WilocError, match="reference_left_out"):
            aligned_truth(FULL_MAP, kept, tolerance=2, left_out=left_out)


@pytest.mark.parametrize("tolerance", [0, 1, 2, 3])
@pytest.mark.parametrize(("queries", "refs", "by"), [
    ([f"Image{i:03d}.jpg" for i in range(-2, 25)], [f"Image{i:03d}.jpg" for i in range(20)], "name"),
    ([f"images-{i:05d}.png" for i in range(0, 300, 5)], [f"images-{i:05d}.png" for i in range(10, 210, 10)], "name"),
    ([f"{i:06d}" for i in range(130)], [f"{i:06d}" for i in range(0, 100, 5)], "name"),
    ([f"{i:06d}" for i in range(130)], [f"{i:06d}" for i in range(0, 100, 5)], "index"),
    ([f"{i:06d}" for i in range(3, 40)], [f"Image{i:03d}.jpg" for i in range(30)], "index"),
    ([f"{i:06d}" for i in range(70)], [f"{k * 3 // 2:06d}" for k in range(40)], "index"),  # 30 fps kept at 20
    ([f"{i:06d}" for i in range(70)], [f"{k * 3 // 2:06d}" for k in range(40)], "name"),
    ([f"q{i}.jpg" for i in range(12)], REFS, "index"),
    (["img5.jpg", "img0.jpg", "img9.jpg", "other.jpg", "img7.jpg"], REFS, "name"),
])
def test_aligned_on_a_map_that_leaves_no_frame_out_bands_by_position(queries: list[str], refs: list[str],
                                                                     by: str, tolerance: int) -> None:
    """On a contiguous map (every frame, or every n-th: Gardens Point, Nordland's every 10th, a
    sampled video, also one kept at 20 of its 30 frames a second: steps of 1 and 2) the truth is
    the band by position, as before."""
    if by == "name":
        centres = np.array([refs.index(q) if q in refs else -1 for q in queries])
    else:
        centres = _nearest_index(frame_indices(queries), frame_indices(refs))
    expected = np.array([[c >= 0 and abs(col - c) <= tolerance for col in range(len(refs))] for c in centres])
    np.testing.assert_array_equal(dense(aligned_truth(queries, refs, tolerance, by=by)), expected)


# --- positions -------------------------------------------------------------------------------

def test_positions_metres_radius(tmp_path: Path) -> None:
    q = write_csv(tmp_path / "q.csv", {"name": ["a", "b"], "x": [0.0, 10.0], "y": [0.0, 0.0]})
    r = write_csv(tmp_path / "r.csv", {"name": ["r0", "r1", "r2"], "x": [0.0, 3.0, 13.9],
                                       "y": [4.0, 0.0, 0.0]})
    truth = positions_truth(q, r, 4.0, ["a", "b"], ["r0", "r1", "r2"])
    # a-r0 4.0 m (inside, radius inclusive), a-r1 3 m, b-r1 7 m, b-r2 3.9 m.
    np.testing.assert_array_equal(dense(truth), [[True, True, False], [False, False, True]])
    assert truth.warnings == []


def test_positions_metres_agree_with_brute_force(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    qxy, rxy = rng.uniform(0, 50, (30, 2)), rng.uniform(0, 50, (40, 2))
    qn, rn = [f"q{i}" for i in range(30)], [f"r{i}" for i in range(40)]
    q = write_csv(tmp_path / "q.csv", {"name": qn, "x": qxy[:, 0], "y": qxy[:, 1]})
    r = write_csv(tmp_path / "r.csv", {"name": rn, "x": rxy[:, 0], "y": rxy[:, 1]})
    truth = positions_truth(q, r, 7.5, qn, rn)
    np.testing.assert_array_equal(dense(truth), cdist(qxy, rxy) <= 7.5)


def haversine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    la, lb = np.radians(a[:, None, :]), np.radians(b[None, :, :])
    dlat, dlon = lb[..., 0] - la[..., 0], lb[..., 1] - la[..., 1]
    h = np.sin(dlat / 2) ** 2 + np.cos(la[..., 0]) * np.cos(lb[..., 0]) * np.sin(dlon / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(h))


def test_positions_latlon_uses_metres_on_the_sphere(tmp_path: Path) -> None:
    # 0.0001 degree of latitude is about 11.1 m.
    q = write_csv(tmp_path / "q.csv", {"name": ["a"], "lat": [-27.4770], "lon": [153.0280]})
    r = write_csv(tmp_path / "r.csv", {"name": ["b", "c"], "lat": [-27.4771, -27.4790],
                                       "lon": [153.0280, 153.0280]})
    assert dense(positions_truth(q, r, 15.0, ["a"], ["b", "c"])).tolist() == [[True, False]]
    assert dense(positions_truth(q, r, 10.0, ["a"], ["b", "c"])).tolist() == [[False, False]]
    assert dense(positions_truth(q, r, 250.0, ["a"], ["b", "c"])).tolist() == [[True, True]]


def test_positions_latlon_agree_with_haversine(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(51.750, 51.760, 50), rng.uniform(-1.26, -1.25, 50)])
    names = [f"f{i:03d}" for i in range(50)]
    csv = write_csv(tmp_path / "gps.csv", {"name": names, "lat": pts[:, 0], "lon": pts[:, 1]})
    truth = positions_truth(csv, csv, 120.0, names, names)  # sequence mode: one file
    expected = haversine(pts, pts) <= 120.0
    differ = dense(truth) != expected
    # Chord vs haversine only differ within rounding of the boundary.
    assert np.all(np.abs(haversine(pts, pts)[differ] - 120.0) < 1e-6)
    assert dense(truth).diagonal().all()


def test_positions_that_make_every_pair_the_same_place_are_warned(tmp_path: Path) -> None:
    # GPS degrees written as x,y are read as metres: a whole route spans a fraction of a "metre",
    # every frame is near every other, and every match would count as right without a word
    rng = np.random.default_rng(1)
    lat, lon = -27.4775 + np.cumsum(rng.uniform(1e-5, 2e-5, 8)), 153.028 + np.zeros(8)
    degrees = write_csv(tmp_path / "deg.csv", {"name": REFS, "x": lon, "y": lat})
    truth = positions_truth(degrees, degrees, 25.0, REFS, REFS)
    assert dense(truth).all() and any("look like degrees" in w and "lat,lon" in w for w in truth.warnings)
    as_latlon = write_csv(tmp_path / "gps.csv", {"name": REFS, "lat": lat, "lon": lon})
    assert not any("every match counts" in w for w in positions_truth(as_latlon, as_latlon, 5.0, REFS, REFS).warnings)
    metres = write_csv(tmp_path / "m.csv", {"name": REFS, "x": np.arange(8) * 10.0, "y": np.zeros(8)})
    wide = positions_truth(metres, metres, 100.0, REFS, REFS).warnings
    assert any("every match counts" in w and "degrees" not in w for w in wide)
    assert not any("every match counts" in w for w in positions_truth(metres, metres, 15.0, REFS, REFS).warnings)


@pytest.mark.parametrize("name, lat, lon", [("name", "latitude", "longitude"), ("name", "Latitude", "Longitude"),
                                            ("name", "lat", "lng"), ("filename", "lat", "lon"), ("Image", "lat", "lon")])
def test_positions_take_the_other_names_of_lat_lon(tmp_path: Path, name: str, lat: str, lon: str) -> None:
    # GPS logs and exports spell the columns out (latitude,longitude) or shorten longitude to lng;
    # a name column headed filename or image was 'missing column(s) name'
    from wiloc.evaluation.truth_source import file_form

    rng = np.random.default_rng(2)
    coords = {"name": REFS, "lat": 50 + rng.uniform(0, 1e-3, 8), "lon": 8 + rng.uniform(0, 1e-3, 8)}
    plain = write_csv(tmp_path / "plain.csv", coords)
    other = write_csv(tmp_path / "other.csv", {name: REFS, lat: coords["lat"], lon: coords["lon"]})
    assert file_form(other) == "positions"
    np.testing.assert_array_equal(dense(positions_truth(other, other, 20.0, REFS, REFS)),
                                  dense(positions_truth(plain, plain, 20.0, REFS, REFS)))


def test_positions_partial_names_are_warned_with_counts(tmp_path: Path) -> None:
    csv = write_csv(tmp_path / "p.csv", {"name": ["a", "b", "zzz"], "x": [0, 1, 2], "y": [0, 0, 0]})
    truth = positions_truth(csv, csv, 1.5, ["a", "b", "c"], ["a", "b", "c"])
    assert any("1 of 3 query frames have no ground-truth row" in w for w in truth.warnings)
    assert any("1 of 3 ground-truth rows name no query frame" in w for w in truth.warnings)
    assert truth.has_match().tolist() == [True, True, False]


@pytest.mark.parametrize("rows, problem", [
    ({"name": ["a", "b"], "x": [0.0, 1.0]}, "name,x,y"),
    ({"id": ["a", "b"], "x": [0.0, 1.0], "y": [0.0, 1.0]}, "missing column"),
    ({"name": ["a", "b"], "x": [0.0, np.nan], "y": [0.0, 1.0]}, "missing or non-numeric"),
    ({"name": ["a", "a"], "x": [0.0, 1.0], "y": [0.0, 1.0]}, "duplicate"),
    ({"name": ["x1", "x2"], "x": [0.0, 1.0], "y": [0.0, 1.0]}, "no name matches"),
    ({"name": ["a", "b"], "x": [0.0, 1e300], "y": [0.0, 1.0]}, "a coordinate of 1e[+]300 metres is too far out"),
])
def test_positions_bad_input_names_the_file(tmp_path: Path, rows: dict, problem: str) -> None:
    csv = write_csv(tmp_path / "bad.csv", rows)
    with pytest.raises(WilocError, match=problem) as err:
        positions_truth(csv, csv, 5.0, ["a", "b"], ["a", "b"])
    assert err.value.where == str(csv)


@pytest.mark.parametrize("rename, why", [
    (lambda name: f"q/{name}", "hold a folder: frames are matched by file name alone"),
    (lambda name: f"/data/run1/{name}", "hold a folder"),
    (lambda name: name.removesuffix(".jpg"), "differ from the frames' in their suffix"),
    (lambda name: name.replace(".jpg", ".png"), "differ from the frames' in their suffix"),
    (str.upper, "differ from the frames' in case"),
    (lambda name: name[3], "are numbers: frames are matched by file name, such as 'img0.jpg', not by index"),
])
def test_names_that_match_no_frame_say_how_they_differ(tmp_path: Path, rename, why: str) -> None:
    # a ground truth written with paths, without suffixes or in other case matches no frame: the
    # error shows one of its names beside the frame it would have named
    frames = [f"img{i}.jpg" for i in range(3)]
    names = [rename(frame) for frame in frames]
    positions = write_csv(tmp_path / "p.csv", {"name": names, "x": [0.0, 1.0, 2.0], "y": [0.0, 0.0, 0.0]})
    pairs = write_csv(tmp_path / "pairs.csv", {"query": names, "reference": frames})
    for read in (lambda: positions_truth(positions, positions, 1.0, frames, frames),
                 lambda: pairs_truth(pairs, frames, frames)):
        with pytest.raises(WilocError, match="names such as") as err:
            read()
        assert why in str(err.value) and repr(names[0]) in str(err.value) and repr(frames[0]) in str(err.value)


@pytest.mark.parametrize("text, problem", [
    ("a.jpg,0.0,0.0\nb.jpg,1.0,0.0\n",
     "missing column(s) name: its first line is 'a.jpg,0.0,0.0'; the first line must be a header naming the "
     "columns, such as 'name,x,y'"),
    ("name;x;y\na.jpg;0;0\n", "missing column(s) name: its first line is 'name;x;y'; columns must be separated by "
                               "commas"),
    ("id,x,y\na.jpg,0,0\n", "missing column(s) name: its first line is 'id,x,y'"),
])
def test_a_csv_without_the_columns_shows_its_first_line_and_why(tmp_path: Path, text: str, problem: str) -> None:
    """No header (a first line of data, which pandas would show lower-cased and de-duplicated as
    'found a.jpg, 0.0, 0.0.1'), a European spreadsheet's semicolons, or another column name."""
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    with pytest.raises(WilocError) as err:
        positions_truth(csv, csv, 5.0, ["a.jpg", "b.jpg"], ["a.jpg", "b.jpg"])
    assert err.value.problem == problem


def test_positions_mixed_coordinate_kinds_are_rejected(tmp_path: Path) -> None:
    q = write_csv(tmp_path / "q.csv", {"name": ["a"], "x": [0.0], "y": [0.0]})
    r = write_csv(tmp_path / "r.csv", {"name": ["b"], "lat": [0.0], "lon": [0.0]})
    with pytest.raises(WilocError, match="lat/lon"):
        positions_truth(q, r, 5.0, ["a"], ["b"])


# --- pairs -----------------------------------------------------------------------------------

def test_pairs_lists_true_matches(tmp_path: Path) -> None:
    csv = write_csv(tmp_path / "pairs.csv", {"query": ["q0", "q0", "q2"],
                                             "reference": ["img1.jpg", "img6.jpg", "img3.jpg"]})
    truth = pairs_truth(csv, ["q0", "q1", "q2"], REFS)
    expected = np.zeros((3, 8), dtype=bool)
    expected[0, [1, 6]] = expected[2, 3] = True
    np.testing.assert_array_equal(dense(truth), expected)
    assert truth.warnings == []


def test_pairs_tolerance_column_widens_per_row(tmp_path: Path) -> None:
    csv = write_csv(tmp_path / "pairs.csv", {"query": ["q0", "q1"], "reference": ["img0.jpg", "img4.jpg"],
                                             "tolerance": [2, 1]})
    truth = pairs_truth(csv, ["q0", "q1"], REFS)
    assert np.flatnonzero(dense(truth)[0]).tolist() == [0, 1, 2]
    assert np.flatnonzero(dense(truth)[1]).tolist() == [3, 4, 5]


def test_pairs_unknown_names_are_warned_and_duplicates_fatal(tmp_path: Path) -> None:
    csv = write_csv(tmp_path / "p.csv", {"query": ["q0", "nope"], "reference": ["img0.jpg", "img1.jpg"]})
    truth = pairs_truth(csv, ["q0"], REFS)
    assert truth.warnings == [f"{csv}: 1 of 2 rows name no query frame (skipped)"]
    dup = write_csv(tmp_path / "d.csv", {"query": ["q0", "q0"], "reference": ["img0.jpg", "img0.jpg"]})
    with pytest.raises(WilocError, match="duplicate"):
        pairs_truth(dup, ["q0"], REFS)
    missing = write_csv(tmp_path / "m.csv", {"query": ["q0"], "ref": ["img0.jpg"]})
    with pytest.raises(WilocError, match="reference"):
        pairs_truth(missing, ["q0"], REFS)
    with pytest.raises(WilocError, match="none of the 2 rows"):
        pairs_truth(csv, ["x"], REFS)


# --- matrix ----------------------------------------------------------------------------------

@pytest.fixture
def mask() -> np.ndarray:
    rng = np.random.default_rng(11)
    return (rng.random((5, 8)) < 0.3).astype(np.uint8)


@pytest.mark.parametrize("suffix", [".npy", ".csv", ".npz", ".mat"])
def test_matrix_forms_read_nonzero_as_same_place(tmp_path: Path, mask: np.ndarray, suffix: str) -> None:
    path = tmp_path / f"mask{suffix}"
    if suffix == ".npy":
        np.save(path, mask)
    elif suffix == ".csv":
        np.savetxt(path, mask, delimiter=",", fmt="%d")
    elif suffix == ".npz":
        np.savez(path, GThard=mask.astype(bool))
    else:
        scipy.io.savemat(path, {"truth": mask})
    truth = matrix_truth(path, [f"q{i}" for i in range(5)], REFS)
    np.testing.assert_array_equal(dense(truth), mask != 0)


def _save_mat_v73(path: Path, variables: dict[str, np.ndarray]) -> Path:
    """A MATLAB v7.3 file as MATLAB writes one: HDF5 behind a 512-byte header that names the
    format, each array stored in MATLAB's column order (as h5py shows it, transposed)."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as handle:
        for name, array in variables.items():
            stored = handle.create_dataset(name, data=np.asarray(array).T.astype(np.uint8))
            stored.attrs["MATLAB_class"] = np.bytes_("logical")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(116) + bytes(8) + b"\x00\x02IM"
    with path.open("r+b") as file:
        file.write(header)
    return path


def test_a_mat_file_of_matlab_v73_is_read(tmp_path: Path, mask: np.ndarray) -> None:
    """MATLAB saves with -v7.3 (and must, past 2 GB) as HDF5, which scipy refuses: the matrix
    form was 'cannot read matrix (Please use HDF reader for matlab v7.3 files, e.g. h5py)'."""
    names = [f"q{i}" for i in range(5)]
    path = _save_mat_v73(tmp_path / "gt.mat", {"GThard": mask != 0, "GTsoft": np.ones_like(mask)})
    np.testing.assert_array_equal(dense(matrix_truth(path, names, REFS, variable="GThard")), mask != 0)
    with pytest.raises(WilocError, match="holds 2 2-D arrays, name one of: GThard, GTsoft"):
        matrix_truth(path, names, REFS)


def test_matrix_shape_and_mat_choice_errors(tmp_path: Path, mask: np.ndarray) -> None:
    np.save(tmp_path / "m.npy", mask)
    with pytest.raises(WilocError, match="matrix is 5 x 8, expected 8 x 8"):
        matrix_truth(tmp_path / "m.npy", REFS, REFS)
    scipy.io.savemat(tmp_path / "two.mat", {"gt": mask, "other": mask.T})
    names = [f"q{i}" for i in range(5)]
    with pytest.raises(WilocError, match="holds 2 2-D arrays, name one of: gt, other"):
        matrix_truth(tmp_path / "two.mat", names, REFS)
    picked = matrix_truth(tmp_path / "two.mat", names, REFS, variable="gt")
    np.testing.assert_array_equal(dense(picked), mask != 0)
    with pytest.raises(WilocError, match="file does not exist"):
        matrix_truth(tmp_path / "absent.npy", names, REFS)


def test_matrix_of_reference_x_query_frames_is_told_and_npz_arrays_are_picked(tmp_path: Path,
                                                                             mask: np.ndarray) -> None:
    # VPR_Tutorial's GT.npz holds GThard and GTsoft as reference x query frames
    names = [f"q{i}" for i in range(5)]
    np.savez(tmp_path / "GT.npz", GThard=mask.T.astype(bool), GTsoft=mask.T.astype(bool))
    with pytest.raises(WilocError, match="holds 2 2-D arrays, name one of: GThard, GTsoft"):
        matrix_truth(tmp_path / "GT.npz", names, REFS)
    with pytest.raises(WilocError, match=r"matrix is 8 x 5, expected 5 x 8 \(query x reference frames\): it is "
                                         r"reference x query frames .*transpose"):
        matrix_truth(tmp_path / "GT.npz", names, REFS, variable="GThard")
    np.savez(tmp_path / "GT_t.npz", GThard=np.load(tmp_path / "GT.npz")["GThard"].T)
    np.testing.assert_array_equal(dense(matrix_truth(tmp_path / "GT_t.npz", names, REFS)), mask != 0)


# --- sequence restriction and dispatch -------------------------------------------------------

def test_restrict_sequence_keeps_earlier_frames_outside_the_window() -> None:
    full = Truth(np.ones((6, 6), dtype=bool), REFS[:6], REFS[:6])
    kept = dense(restrict_sequence(full, exclude_recent=2))
    rows, cols = np.indices((6, 6))
    np.testing.assert_array_equal(kept, cols < rows - 2)
    assert restrict_sequence(full, 2).has_match().tolist() == [False] * 3 + [True] * 3
    with pytest.raises(WilocError, match="same frames"):
        restrict_sequence(aligned_truth(REFS[:3], REFS, 0), 2)


def test_load_truth_dispatches_each_kind(tmp_path: Path, mask: np.ndarray) -> None:
    names = [f"q{i}" for i in range(5)]
    np.save(tmp_path / "m.npy", mask)
    pairs = write_csv(tmp_path / "p.csv", {"query": ["q1"], "reference": ["img2.jpg"]})
    pos = write_csv(tmp_path / "pos.csv", {"name": REFS, "x": np.arange(8.0), "y": np.zeros(8)})
    assert dense(load_truth("matrix", tmp_path / "m.npy", query_names=names, ref_names=REFS)).sum() == mask.sum()
    assert load_truth("pairs", pairs, query_names=names, ref_names=REFS).is_true(1, 2)
    assert dense(load_truth("aligned", None, query_names=REFS, ref_names=REFS, tolerance=1)).sum() == 8 + 2 * 7
    seq = load_truth("positions", pos, query_names=REFS, ref_names=REFS, radius=1.0)
    assert dense(seq).sum() == 8 + 2 * 7
    with pytest.raises(WilocError, match="unknown ground-truth kind"):
        load_truth("gps", pos, query_names=REFS, ref_names=REFS)
    with pytest.raises(WilocError, match="radius"):
        load_truth("positions", pos, query_names=REFS, ref_names=REFS)


# --- a file given without its form -------------------------------------------------------------

@pytest.mark.parametrize(("name", "text", "form"), [
    ("gt.csv", "query,reference\na.jpg,b.jpg\n", "pairs"),
    ("gt.csv", "Name, X, Y\na.jpg,0,0\n", "positions"),
    ("gt.csv", "name,lat,lon\na.jpg,0,0\n", "positions"),
    ("gt.csv", "name,Latitude,Longitude\na.jpg,0,0\n", "positions"),
    ("gt.csv", "filename,x,y\na.jpg,0,0\n", "positions"),  # the positions reader says 'name' is missing
    ("gt.csv", "1,0,0\n0,1,0\n", "matrix"),
    ("gt.csv", "1,0,x\n", "pairs"),  # not all numbers: the pairs reader says what is missing
    ("gt.csv", "", "pairs"),
    ("gt.npy", "", "matrix"),
    ("gt.mat", "", "matrix"),
    ("GT.npz", "", "matrix"),
    ("ground_truth_new.npy", "", "vprbench"),
])
def test_a_file_given_without_its_form_is_read_as_the_form_it_holds(tmp_path: Path, name: str, text: str,
                                                                     form: str) -> None:
    from wiloc.evaluation.truth_source import file_form

    path = tmp_path / name
    path.write_text(text)
    assert file_form(path) == form
    assert file_form(tmp_path / "absent.csv") == "pairs"  # ('{query}' in its name) the pairs reader names it


def test_one_helper_tells_a_number_in_a_csv_cell() -> None:
    """Odometry's header test and the ground-truth form guess share one helper: no module of the
    package holds a copy of ``try: float(text) ... return True``. It lives in a small module of
    its own, so that odometry reads no ground-truth module to find it."""
    import ast

    import wiloc
    from wiloc.given import is_number

    root = Path(wiloc.__file__).parent
    twins = sorted(f"{path.relative_to(root)}:{node.name}" for path in root.rglob("*.py")
                   for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.FunctionDef)
                   and any(isinstance(inner, ast.Try) and "float(" in ast.unparse(inner.body[0]) and
                           any(isinstance(s, ast.Return) and ast.unparse(s) == "return False"
                               for handler in inner.handlers for s in handler.body) for inner in node.body))
    assert twins == ["given.py:is_number"]
    odometry = ast.parse((root / "localization" / "odometry.py").read_text())
    assert not [node.module for node in ast.walk(odometry) if isinstance(node, ast.ImportFrom)
                and (node.module or "").startswith("wiloc.evaluation")]
    assert is_number(" 2.5e3") and is_number("-1") and not is_number("x") and not is_number("")



@pytest.mark.parametrize("suffix", [".mat", ".npz"])
def test_the_command_line_picks_one_array_of_a_file_holding_several(tmp_path: Path, suffix: str) -> None:
    """``--gt matrix:FILE:NAME`` names the array to read, in a .npz (VPR_Tutorial's GT.npz holds
    GThard and GTsoft) as in a .mat; without it the reader names the choices."""
    import json

    from typer.testing import CliRunner

    from wiloc.cli import app

    names = [f"{i}.jpg" for i in range(3)]
    header = {"wiloc-results": "1", "method": "online", "descriptor": "sad", "mode": "map", "query": "/q",
              "map": "/r", "exclude_recent": "0", "frames": "3", "reference_frames": json.dumps(names)}
    results = tmp_path / "q-online.csv"
    results.write_text("".join(f"# {key}: {value}\n" for key, value in header.items())
                       + "frame,match,difference,confidence,stage\n"
                       + "".join(f"{name},{name},0.5,0.9,update\n" for name in names))
    hard, soft = np.eye(3, dtype=bool), np.zeros((3, 3), dtype=bool)  # every match right by one, wrong by the other
    path = tmp_path / f"GT{suffix}"
    if suffix == ".npz":
        np.savez(path, GThard=hard, GTsoft=soft)
    else:
        scipy.io.savemat(path, {"GThard": hard, "GTsoft": soft})
    runner = CliRunner()
    for name, correct in [("GThard", 1), ("GTsoft", 0)]:
        result = runner.invoke(app, ["evaluate", str(results), "--gt", f"matrix:{path}:{name}", "--json"])
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["runs"][0]["share_correct"] == correct
    result = runner.invoke(app, ["evaluate", str(results), "--gt", f"matrix:{path}"])
    assert result.exit_code == 1 and "GThard" in result.output and "GTsoft" in result.output, result.output


def test_is_true_is_the_matrix_s_entry_for_every_pair() -> None:
    """is_true looks pairs up in the true pairs' sorted keys: the same answers as the dense
    matrix, a reference of -1 or past the map False, on a truth with rows of no pair too."""
    rng = np.random.default_rng(3)
    for n_q, n_r, density in ((7, 11, 0.3), (40, 25, 0.05), (5, 5, 0.0), (1, 1, 1.0)):
        dense = rng.random((n_q, n_r)) < density
        truth = Truth(sparse.csr_array(dense), [f"q{i}" for i in range(n_q)], [f"r{i}" for i in range(n_r)])
        q = rng.integers(0, n_q, 300)
        r = rng.integers(-1, n_r + 2, 300)
        inside = (r >= 0) & (r < n_r)
        expected = np.zeros(300, dtype=bool)
        expected[inside] = dense[q[inside], r[inside]]
        np.testing.assert_array_equal(truth.is_true(q, r), expected)
        np.testing.assert_array_equal(truth.is_true(np.arange(n_q)[:, None], np.arange(n_r)[None, :]), dense)


def test_a_radius_that_makes_too_many_true_pairs_is_refused_before_they_are_made(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The positions forms had no bound on their true pairs: a radius covering a long route asked
    for a pair per query and map frame. They are counted first and refused as a tolerance is."""
    import wiloc.evaluation.groundtruth as groundtruth

    names = [f"f{i}.png" for i in range(30)]
    path = tmp_path / "pos.csv"
    path.write_text("name,x,y\n" + "".join(f"{name},{i},0\n" for i, name in enumerate(names)))
    monkeypatch.setattr(groundtruth, "MAX_TRUE_PAIRS", 100)
    assert positions_truth(path, path, 1.0, names, names).matrix.nnz == 88  # 30 + 2 x 29
    with pytest.raises(WilocError, match="this radius makes 900 true pairs") as info:
        positions_truth(path, path, 100.0, names, names)
    assert info.value.parameter == "radius"



# --- aligned by index: a map frame added since the run ---------------------------------------

def test_aligned_by_index_tells_a_map_frame_added_since_the_run_from_one_left_out(tmp_path: Path) -> None:
    """A readable map frame the run never listed was added since: positions are counted by the run's
    own frames, so nothing is shifted and nothing is said (it was warned of as "left out of the run
    (unreadable?)"). One the run left out, unreadable, still shifts every later frame: warned of."""
    from helpers import write_images

    names = write_images(tmp_path / "map", 6)
    queries = [f"frame{i}.png" for i in range(6)]
    added = tmp_path / "map" / "img2b.jpg"  # between img2 and img3 in the folder's order
    added.write_bytes((tmp_path / "map" / "img2.jpg").read_bytes())
    truth = load_truth("aligned", None, query_names=queries, ref_names=names, by="index",
                       query_folder=tmp_path / "q", ref_folder=tmp_path / "map")
    assert truth.warnings == []
    gone = tmp_path / "map" / "img3.png"
    gone.write_bytes(gone.read_bytes()[:40])  # cut short: unreadable, as when the run left it out
    truth = load_truth("aligned", None, query_names=queries, ref_names=names[:3] + names[4:], by="index",
                       query_folder=tmp_path / "q", ref_folder=tmp_path / "map")
    shifted = [line for line in truth.warnings if "shifted" in line]
    assert len(shifted) == 1 and shifted[0].startswith(f"{gone}: left out of the run (unreadable?)"), truth.warnings
    assert "more frames" not in shifted[0]  # the frame added since is not counted among those left out


def test_evaluate_and_report_say_nothing_of_a_map_frame_added_since_the_run(tmp_path: Path, cache_dir: Path) -> None:
    """`evaluate --gt aligned:index` of a run whose map gained a frame since warned that the new
    frame was left out of the run (unreadable?), shifting every later frame; the run's own list of
    map frames is what is scored, so nothing is shifted. The report still says why it draws no
    matrix (the map's frames are not the run's)."""
    from helpers import write_images
    from typer.testing import CliRunner

    from wiloc.cli import app

    runner = CliRunner()
    write_images(tmp_path / "q", 8)
    mapped = tmp_path / "map"
    mapped.mkdir()
    for i, name in enumerate(write_images(tmp_path / "images", 8, seed=1)):
        (tmp_path / "images" / name).rename(mapped / f"{1614000000 + i}.5{Path(name).suffix}")
    out = tmp_path / "run.csv"
    ran = runner.invoke(app, ["localize", str(tmp_path / "q"), "--map", str(mapped), "--method", "threshold",
                              "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    (mapped / "1614000000.7.jpg").write_bytes((mapped / "1614000000.5.jpg").read_bytes())
    scored = runner.invoke(app, ["evaluate", str(out), "--gt", "aligned:index"])
    assert scored.exit_code == 0, scored.output
    assert "1614000000.7.jpg" not in scored.stderr and "shifted" not in scored.stderr, scored.stderr
    page = tmp_path / "report.html"
    reported = runner.invoke(app, ["report", str(out), "--gt", "aligned:index", "--out", str(page)])
    assert reported.exit_code == 0, reported.output
    assert "shifted" not in reported.stderr and reported.stderr.count("1614000000.7.jpg new") == 2, reported.stderr


def test_a_query_frame_left_out_is_warned_of_once_by_evaluate_and_report(tmp_path: Path, cache_dir: Path) -> None:
    """A query image the run left out (cut short) shifts every later query frame's position under
    aligned:index: evaluate and report each say so, once."""
    from helpers import write_images
    from typer.testing import CliRunner

    from wiloc.cli import app

    runner = CliRunner()
    write_images(tmp_path / "q", 8)
    write_images(tmp_path / "map", 8, seed=1)
    cut = tmp_path / "q" / "img3.png"
    cut.write_bytes(cut.read_bytes()[:40])
    out = tmp_path / "run.csv"
    ran = runner.invoke(app, ["localize", str(tmp_path / "q"), "--map", str(tmp_path / "map"), "--method",
                              "threshold", "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    for command in (["evaluate"], ["report", "--out", str(tmp_path / "report.html")]):
        said = runner.invoke(app, [*command, str(out), "--gt", "aligned:index"])
        assert said.exit_code == 0, said.output
        assert said.stderr.count(f"{cut}: left out of the run (unreadable?), so the position of every later query "
                                 "frame") == 1, said.stderr

"""The streaming Localizer: frame by frame it decides exactly what batch ``localize`` decides, in map
and sequence mode, and a saved run continues identically in another process."""
from __future__ import annotations

import json
import pickle
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from helpers import places, write_traversal

import wiloc
from wiloc import api, demo
from wiloc.cache.store import Cache
from wiloc.errors import CacheBusyError, FrameError, ParameterError, UsageError, WilocError
from wiloc.localization.localizer import Localizer
from wiloc.methods.registry import METHODS

FIELDS = ("match_name", "difference", "confidence", "stage")


def _batch_rows(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#", dtype=str, keep_default_na=False)


def _stream(loc: Localizer, frames: list[Path]) -> pd.DataFrame:
    """The decisions of a Localizer as results rows are written (same number formatting)."""
    rows = []
    for frame in frames:
        d = loc.observe(frame)
        rows.append({"frame": d.frame, "match": d.match_name, "difference": f"{d.difference:.9g}",
                     "confidence": f"{d.confidence:.9g}", "stage": d.stage})
    return pd.DataFrame(rows).replace("nan", "")


def _assert_same(batch: pd.DataFrame, streamed: pd.DataFrame) -> None:
    for column in ("frame", "match", "difference", "confidence", "stage"):
        assert batch[column].tolist() == streamed[column].tolist(), column


def _training(demo_route: demo.DemoRoute) -> api.Training:
    return api.Training(demo_route.queries[1], demo_route.reference, demo_route.truth())


DIFFERENCE_METHODS = sorted(m for m, cls in METHODS.items() if "differences" in cls.rows)  # fabmap: its own tests


@pytest.mark.parametrize("method", DIFFERENCE_METHODS)
def test_streaming_equals_batch_in_map_mode(demo_route: demo.DemoRoute, method: str, tmp_path: Path) -> None:
    cache = Cache(tmp_path / "cache")
    query = demo_route.queries[0]
    training = _training(demo_route) if method == "trained" else None
    run = api.localize(query, reference=demo_route.reference, method=method, training=training,
                       out=tmp_path / "batch.csv", cache=cache)
    loc = Localizer(demo_route.reference, method=method, training=training, cache=cache)
    streamed = _stream(loc, sorted(query.iterdir()))
    _assert_same(_batch_rows(run.path), streamed)
    assert loc.frames == len(streamed)


def test_a_map_frame_left_out_keeps_its_place_streamed_batch_and_restored(demo_route: demo.DemoRoute,
                                                                          tmp_path: Path) -> None:
    # catgraph places the map's nodes at their frames' positions in the folder's full order, the
    # unreadable frame counted (counted by the frames kept, the track ran a node ahead after it)
    cache, reference = Cache(tmp_path / "cache"), tmp_path / "reference"
    shutil.copytree(demo_route.reference, reference)
    n_map = len(list(reference.iterdir()))
    sorted(reference.iterdir())[3].write_bytes(b"")  # the fourth frame cannot be read
    query = demo_route.queries[0]
    frames = sorted(query.iterdir())
    run = api.localize(query, reference=reference, method="catgraph", out=tmp_path / "batch.csv", cache=cache)
    first = Localizer(reference, method="catgraph", cache=cache)
    assert first.method.save_state()["nodes"].tolist() == [p for p in range(n_map) if p != 3]
    streamed = _stream(first, frames[:50])
    first.save(tmp_path / "state.npz")
    rest = _stream(Localizer.load(tmp_path / "state.npz", cache=cache), frames[50:])
    _assert_same(_batch_rows(run.path), pd.concat([streamed, rest], ignore_index=True))


@pytest.mark.parametrize("method", ["catgraph", "online"])
def test_query_frames_left_out_are_stepped_across_streamed_batch_and_restored(demo_route: demo.DemoRoute,
                                                                             method: str, tmp_path: Path) -> None:
    # a batch run steps across the query's unreadable frames (their places counted); a Localizer
    # told of them (skip) decides the same, a state saved between the skip and the next frame too
    cache, query = Cache(tmp_path / "cache"), tmp_path / "query"
    shutil.copytree(demo_route.queries[0], query)
    frames = sorted(query.iterdir())
    for k in (3, 20, 21):
        frames[k].write_bytes(b"")
    run = api.localize(query, reference=demo_route.reference, method=method, out=tmp_path / "batch.csv", cache=cache)
    assert [Path(path).name for path, _ in run.skipped] == [frames[k].name for k in (3, 20, 21)]

    def streamed(loc: Localizer, paths: list[Path], told: bool = True) -> pd.DataFrame:
        rows = []
        for path in paths:
            try:
                rows.append(_stream(loc, [path]))
            except FrameError:
                if told:
                    loc.skip()
        return pd.concat(rows, ignore_index=True)

    first = Localizer(demo_route.reference, method=method, cache=cache)
    head = streamed(first, frames[:21])  # ends on a skip: the state holds the frame passed
    first.save(tmp_path / "state.npz")
    rest = streamed(Localizer.load(tmp_path / "state.npz", cache=cache), frames[21:])
    batch = _batch_rows(run.path)
    _assert_same(batch, pd.concat([head, rest], ignore_index=True))
    untold = streamed(Localizer(demo_route.reference, method=method, cache=cache), frames, told=False)
    assert batch["confidence"].tolist() != untold["confidence"].tolist()


def _looped_descriptors(seed: int = 3) -> tuple[np.ndarray, list[str]]:
    """A route of 60 places driven twice and half a third time, revisits alike: float32 rows of
    whole numbers (sums exact in any order, so batch blocks and single rows agree bit for bit)."""
    rng = np.random.default_rng(seed)
    places = rng.integers(0, 256, (60, 64), dtype=np.uint8)
    order = np.r_[np.arange(60), np.arange(60), np.arange(30)]
    noise = rng.integers(-12, 13, (order.size, 64))
    rows = np.clip(places[order].astype(int) + noise, 0, 255).astype(np.float32)
    return rows, [f"f{i:04d}" for i in range(order.size)]


_SEQUENCE_PARAMS = {"online": {"init": 40}, "threshold": {"normaliser": 255.0},
                    "catgraph": {"frontier": 10, "seed": 2}}  # laps of 60 frames: a frontier of 10 lets them meet


@pytest.mark.parametrize("method, exclude_recent", [("online", None), ("threshold", None), ("catgraph", None),
                                                     ("online", 1)])  # a recent window narrower than the same place's
def test_streaming_equals_batch_in_sequence_mode(method: str, exclude_recent: int | None, tmp_path: Path) -> None:
    rows, names = _looped_descriptors()
    np.save(tmp_path / "route.npy", rows)
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    cache = Cache(tmp_path / "cache")
    params = _SEQUENCE_PARAMS[method]
    run = api.localize(tmp_path / "route.npy", metric="l1", query_names_file=tmp_path / "names.txt",
                       method=method, method_params=params, out=tmp_path / "batch.csv", cache=cache,
                       exclude_recent=exclude_recent)
    loc = Localizer(None, descriptor="external", method=method, cache=cache, exclude_recent=exclude_recent,
                    descriptor_params={"metric": "l1", "length": 64}, **params)
    decisions = [loc.observe(row, name=name) for row, name in zip(rows, names)]
    streamed = pd.DataFrame({"frame": [d.frame for d in decisions], "match": [d.match_name for d in decisions],
                             "difference": [f"{d.difference:.9g}" for d in decisions],
                             "confidence": [f"{d.confidence:.9g}" for d in decisions],
                             "stage": [d.stage for d in decisions]}).replace("nan", "")
    _assert_same(_batch_rows(run.path), streamed)
    # the loop is closed: second-lap frames match first-lap frames of the same place
    second_lap = [d for d in decisions[70:120] if d.match >= 0]
    assert sum(int(d.match_name[1:]) == int(d.frame[1:]) - 60 for d in second_lap) >= 0.8 * len(second_lap)


_CONTINUE = """
import json, sys
from collections.abc import Callable
from pathlib import Path
from wiloc.localization.localizer import Localizer
loc = Localizer.load(sys.argv[1])
out = [loc.observe(Path(p)) for p in sys.argv[2:]]
print(json.dumps([[d.frame, d.match_name, repr(d.confidence), repr(d.new_place), d.stage] for d in out]))
"""


@pytest.mark.parametrize("method", ["online", "catgraph"])
def test_save_load_in_a_new_process_continues_identically(demo_route: demo.DemoRoute, method: str,
                                                          tmp_path: Path, cache_dir: Path) -> None:
    frames = sorted(demo_route.queries[0].iterdir())
    whole = Localizer(demo_route.reference, method=method, seed=5) if method == "catgraph" else \
        Localizer(demo_route.reference, method=method)
    expected = [whole.observe(f) for f in frames]
    first = Localizer(demo_route.reference, method=method, **({"seed": 5} if method == "catgraph" else {}))
    for f in frames[:100]:
        first.observe(f)
    first.save(tmp_path / "state.npz")
    result = subprocess.run([sys.executable, "-c", _CONTINUE, str(tmp_path / "state.npz"),
                             *map(str, frames[100:])], capture_output=True, text=True, check=True)
    continued = json.loads(result.stdout)
    assert len(continued) == len(frames) - 100 > 0
    for got, want in zip(continued, expected[100:]):
        assert got == [want.frame, want.match_name, repr(want.confidence), repr(want.new_place), want.stage]


@pytest.mark.parametrize("method, cut", [("online", 80), ("catgraph", 15), ("catgraph", 80)])
def test_sequence_mode_state_round_trips(method: str, cut: int, tmp_path: Path) -> None:
    """Saved and loaded mid-run (catgraph at 15: before its map has 2 frames), the localizer goes on as before."""
    rows, names = _looped_descriptors(seed=4)
    params = {"init": 30} if method == "online" else _SEQUENCE_PARAMS[method]
    make = lambda: Localizer(None, descriptor="external", method=method, cache=Cache(tmp_path / "c"),
                             descriptor_params={"metric": "l1", "length": 64}, **params)
    whole = make()
    expected = [whole.observe(r, name=n) for r, n in zip(rows, names)]
    part = make()
    for r, n in zip(rows[:cut], names[:cut]):
        part.observe(r, name=n)
    part.save(tmp_path / "s.npz")
    again = Localizer.load(tmp_path / "s.npz", cache=Cache(tmp_path / "c"))
    assert again.frames == cut
    continued = [again.observe(r, name=n) for r, n in zip(rows[cut:], names[cut:])]
    assert list(map(repr, continued)) == list(map(repr, expected[cut:]))  # repr: NaN (no decision yet) equals NaN


def test_sequence_mode_with_odometry_streams_as_batch_and_round_trips(tmp_path: Path) -> None:
    """catgraph in sequence mode with the traversal's odometry (a CSV for the batch run, a step
    per observed frame for the localizer) decides the same either way, and a state saved before
    its map has 2 frames or mid-run goes on as before."""
    rows, names = _looped_descriptors(seed=4)
    np.save(tmp_path / "route.npy", rows)
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    steps = np.where(np.arange(len(names)) % 7 == 3, 0.5, 1.25)
    steps[0] = 0.0
    (tmp_path / "odometry.csv").write_text("name,distance\n" + "".join(f"{n},{float(s)!r}\n" for n, s in zip(names, steps)))
    params = _SEQUENCE_PARAMS["catgraph"]
    run = api.localize(tmp_path / "route.npy", metric="l1", query_names_file=tmp_path / "names.txt",
                       method="catgraph", method_params=params, odometry=tmp_path / "odometry.csv",
                       out=tmp_path / "batch.csv", cache=Cache(tmp_path / "c"))
    make = lambda: Localizer(None, descriptor="external", method="catgraph", cache=Cache(tmp_path / "c"),
                             descriptor_params={"metric": "l1", "length": 64}, **params)
    whole = make()
    expected = [whole.observe(r, name=n, odometry=float(s)) for r, n, s in zip(rows, names, steps)]
    batch = pd.read_csv(run.path, comment="#", dtype=str, keep_default_na=False)
    assert list(batch["match"]) == [d.match_name or "" for d in expected]
    assert list(batch["confidence"]) == [f"{d.confidence:.9g}".replace("nan", "") for d in expected]
    without = make()
    assert [without.observe(r, name=n).match_name for r, n in zip(rows, names)] != [d.match_name for d in expected]
    for cut in (15, 80):
        part = make()
        for r, n, s in zip(rows[:cut], names[:cut], steps[:cut]):
            part.observe(r, name=n, odometry=float(s))
        part.save(tmp_path / "s.npz")
        again = Localizer.load(tmp_path / "s.npz", cache=Cache(tmp_path / "c"))
        continued = [again.observe(r, name=n, odometry=float(s)) for r, n, s in zip(rows[cut:], names[cut:], steps[cut:])]
        assert list(map(repr, continued)) == list(map(repr, expected[cut:]))


def test_observe_takes_images_files_and_descriptors(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    loc = Localizer(demo_route.reference, method="threshold")
    path = sorted(demo_route.queries[0].iterdir())[10]
    by_file = loc.observe(path)
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    by_array = loc.observe(gray, name="gray")
    by_bgr = loc.observe(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), name="bgr")
    by_descriptor = loc.observe(loc.describe(path), name="descriptor")
    assert by_file.frame == path.name and by_array.frame == "gray"
    assert by_file.match == by_descriptor.match and by_file.confidence == by_descriptor.confidence
    assert by_array.match == by_bgr.match and abs(by_array.match - by_file.match) <= 1
    with pytest.raises(WilocError, match="descriptor of 5 values; this map's have"):
        loc.observe(np.zeros(5, np.uint8))
    assert wiloc.Localizer is Localizer


def test_a_descriptor_of_another_length_in_sequence_mode_names_the_runs_frames(tmp_path: Path) -> None:
    rows, _ = _looped_descriptors()
    loc = Localizer(None, descriptor="external", method="online", init=30, cache=Cache(tmp_path / "c"),
                    descriptor_params={"metric": "l1", "length": 64})
    loc.observe(rows[0])
    with pytest.raises(WilocError, match="descriptor of 5 values; this run's earlier frames' have 64"):
        loc.observe(np.zeros(5, np.float32))


def test_bad_setup_names_the_parameter(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    with pytest.raises(UsageError) as err:
        Localizer(None, method="seqslam")
    assert err.value.parameter == "map"  # the Localizer's name of it (the library's run functions: reference)
    with pytest.raises(ParameterError) as err:
        Localizer(demo_route.reference, method="online", bin=50)
    assert err.value.parameter == "bin" and "not a parameter of method 'online'" in err.value.problem
    with pytest.raises(ParameterError) as err:
        Localizer(demo_route.reference, method="nope")
    assert err.value.parameter == "method"
    with pytest.raises(UsageError) as err:
        Localizer(demo_route.reference, method="online", map_odometry=demo_route.positions / "reference.csv")
    assert err.value.parameter == "map_odometry"
    with pytest.raises(ParameterError, match="normaliser"):
        Localizer(None, descriptor="gist", method="threshold")
    with pytest.raises(ParameterError, match="applies to a run with the query's odometry only") as err:
        Localizer(demo_route.reference, method="catgraph", odometry_scale=0.1)  # no map odometry: none is read
    assert err.value.parameter == "odometry_scale"
    for map_odometry in (demo_route.positions / "reference.csv", None):  # odometry may come with each frame
        Localizer(demo_route.reference if map_odometry else None, method="catgraph", map_odometry=map_odometry,
                  odometry_scale=0.1)


def test_a_changed_map_is_refused_on_load(demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    import shutil
    map_copy = tmp_path / "map"
    shutil.copytree(demo_route.reference, map_copy)
    loc = Localizer(map_copy, method="threshold")
    loc.observe(min(demo_route.queries[0].iterdir()))
    loc.save(tmp_path / "s.npz")
    victim = sorted(map_copy.iterdir())[3]
    cv2.imwrite(str(victim), 255 - cv2.imread(str(victim)))
    with pytest.raises(WilocError, match="the map changed"):
        Localizer.load(tmp_path / "s.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a state")
    with pytest.raises(WilocError, match="not a saved localizer state"):
        Localizer.load(tmp_path / "junk.npz")


def _rewritten(path: Path, change: Callable[[dict[str, np.ndarray]], None]) -> None:
    """The saved state at ``path`` with its members changed by ``change``, written back as an .npz."""
    with np.load(path) as data:
        members = {key: data[key] for key in data.files}
    change(members)
    np.savez(path, **members)


@pytest.mark.parametrize("edit", ["particles", "meta", "digest gone"])
def test_a_state_changed_after_saving_is_refused_on_load(demo_route: demo.DemoRoute, tmp_path: Path,
                                                         cache_dir: Path, edit: str) -> None:
    """A state edited by hand (a particle array cut short, a parameter changed) or damaged is
    refused as one error naming the file, not continued into numpy's errors at the next frame."""
    loc = Localizer(demo_route.reference, method="catgraph")
    loc.observe(min(demo_route.queries[0].iterdir()))
    loc.save(tmp_path / "s.npz")

    def change(members: dict[str, np.ndarray]) -> None:
        if edit == "particles":
            members["method_state.pos"] = members["method_state.pos"][:10]
        elif edit == "meta":
            members["meta"] = np.array(str(members["meta"]).replace('"particles": 2000', '"particles": 20'))
        else:
            del members["meta_digest"]

    _rewritten(tmp_path / "s.npz", change)
    with pytest.raises(WilocError, match="the state was changed after it was saved") as err:
        Localizer.load(tmp_path / "s.npz")
    assert err.value.where == str(tmp_path / "s.npz")


def test_saving_never_replaces_a_file_of_another_kind(demo_route: demo.DemoRoute, tmp_path: Path,
                                                      cache_dir: Path) -> None:
    """A state or results saved over a frame, or a table of one's own, is refused and the file
    kept; results are not written while a followed run holds their file, nor to a folder's name."""
    from wiloc.evaluation.results_lock import results_lock

    loc = Localizer(demo_route.reference, method="threshold")
    frame = min(demo_route.queries[0].iterdir())
    loc.observe(frame)
    victim = tmp_path / "frame.png"
    victim.write_bytes(frame.read_bytes())
    with pytest.raises(WilocError, match="no saved localizer state, and saving would replace it"):
        loc.save(victim)
    with pytest.raises(WilocError, match="no wiloc results file"):
        loc.results().save(victim)
    assert victim.read_bytes() == frame.read_bytes()
    loc.save(tmp_path / "s.npz")
    loc.save(tmp_path / "s.npz")  # its own state is replaced
    with results_lock(tmp_path / "run.csv"), pytest.raises(CacheBusyError, match="in use by another wiloc run"):
        loc.results().save(tmp_path / "run.csv")
    assert not (tmp_path / "run.csv").exists()
    with pytest.raises(ParameterError, match="names a folder"):
        loc.results().save(f"{tmp_path}/runs/")
    assert loc.results().save(tmp_path / "run.csv").read_text().startswith("# wiloc-results")


@pytest.mark.parametrize("as_paths", [False, True])
def test_a_saved_or_pickled_trained_localizer_keeps_its_training_pair(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                       cache_dir: Path, as_paths: bool) -> None:
    """The results of a trained localizer loaded or unpickled record its training pair as the
    original's do (they said none: a header without train_query and train_map), its ground-truth
    files given as text or as paths (a Path ended the save in json's TypeError)."""
    frames = sorted(demo_route.queries[0].iterdir())
    training = _training(demo_route)
    if as_paths:
        truth = training.truth
        training = api.Training(training.query, training.reference, api.TruthSource(
            kind=truth.kind, path=Path(truth.path), ref_path=Path(truth.ref_path), radius=truth.radius))
    loc = Localizer(demo_route.reference, method="trained", training=training)
    loc.observe(frames[0])
    loc.save(tmp_path / "state.npz")
    for copy in (Localizer.load(tmp_path / "state.npz"), pickle.loads(pickle.dumps(loc))):
        copy.observe(frames[1])
        assert copy.results().header.train_query == str(training.query.resolve())
    loc.observe(frames[1])
    assert copy.results().header == loc.results().header


def test_loading_a_missing_file_or_a_folder_says_so(tmp_path: Path) -> None:
    """A state file that is not there is named as missing, a folder as a folder: not as a file
    of the wrong kind with the system's error number."""
    for given, problem in ((tmp_path / "gone.npz", "file does not exist"), (tmp_path, "a folder, not a saved")):
        with pytest.raises(WilocError) as err:
            Localizer.load(given)
        assert err.value.where == str(given) and err.value.problem.startswith(problem), str(err.value)
        assert "Errno" not in str(err.value)


@pytest.mark.realdata
@pytest.mark.parametrize("method", DIFFERENCE_METHODS)
def test_gardens_point_streamed_frame_by_frame_equals_batch(data_root: Path, method: str, tmp_path: Path,
                                                             real_data_cache: Path, cache_dir: Path) -> None:
    gp = data_root / "gardens-point-walking"
    cache = Cache(real_data_cache)
    training = api.Training(gp / "night_right", gp / "day_right", api.TruthSource(tolerance=2)) \
        if method == "trained" else None
    run = api.localize(gp / "day_left", reference=gp / "day_right", method=method, training=training,
                       out=tmp_path / "batch.csv", cache=cache)
    loc = Localizer(gp / "day_right", method=method, training=training, cache=cache)
    _assert_same(_batch_rows(run.path), _stream(loc, sorted((gp / "day_left").glob("*.jpg"))))


# ------------------------------------------------------------- what the API is given, checked in one place

TAKES = "give an image file's path, an image array or a descriptor row"


@pytest.mark.parametrize("frame, what", [(None, "frame is None"), (5, "frame is of type int, not an array of numbers"),
                                         ({}, "frame is of type dict, not an array of numbers"),
                                         ([[0, 1], [2]], "frame is of type list, not an array of numbers")])
def test_observe_says_what_it_got_that_is_no_frame(frame: object, what: str, demo_route: demo.DemoRoute,
                                                   cache_dir: Path) -> None:
    """``observe(None)`` said ``an image must be gray ... got shape ()``: it names what it got and
    what it takes (a ragged nested list too, which numpy cannot make one array of)."""
    loc = Localizer(demo_route.reference, method="threshold")
    with pytest.raises(WilocError) as err:
        loc.observe(frame)
    assert str(err.value) == f"observe: {what}; {TAKES}"
    assert loc.frames == 0


def test_a_float_image_outside_0_1_says_what_it_holds(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """A float image of 8-bit values (``cv2.imread(...).astype(np.float32)``) is told to be one,
    with what to give; NaN is named as NaN, other values by their range; none is decided."""
    loc = Localizer(demo_route.reference, method="threshold")
    image = cv2.imread(str(sorted(demo_route.queries[0].iterdir())[10]))
    low, high = int(image.min()), int(image.max())
    nan = (image / 255.0).astype(np.float32)
    nan[0, 0, 0] = np.nan
    for given, said in ((image.astype(np.float32), f"values in [{low}, {high}] found: an 8-bit image's values, "
                                                   "give it as uint8 or divided by 255"),
                        (nan, "NaN found"), (image / 255.0 - 0.5, f"values in [{low / 255 - 0.5:g}, {high / 255 - 0.5:g}] found)")):
        with pytest.raises(WilocError) as err:
            loc.observe(given)
        assert said in str(err.value) and str(err.value).startswith("observe: a float")
    assert loc.frames == 0


def test_observe_takes_a_nested_list_of_8_bit_values(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """A nested list of ints (as JSON gives) or tuples are read as the 8-bit image they spell, as an
    integer array of another type whose values lie in [0, 255]; values outside are refused, never
    wrapped or scaled."""
    loc = Localizer(demo_route.reference, method="threshold")
    gray = cv2.imread(str(sorted(demo_route.queries[0].iterdir())[10]), cv2.IMREAD_GRAYSCALE)
    expected = loc.describe(gray)
    for given in (gray.tolist(), tuple(map(tuple, gray.tolist())), gray.astype(np.int32),
                  cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR).tolist()):
        assert np.array_equal(loc.describe(given), expected)
    assert loc.observe(gray.tolist(), name="listed").frame == "listed"
    for value in (256, -1):
        listed = gray.tolist()
        listed[3][4] = value
        low, high = min(map(min, listed)), max(map(max, listed))
        with pytest.raises(WilocError, match=re.escape(f"observe: an image of int64 values in [{low}, {high}]; "
                                                       "integers other than uint8 and uint16 "
                                                       "are read as 8-bit values in [0, 255]")):
            loc.observe(listed)
    assert loc.frames == 1


def test_evaluate_scores_one_run_and_compare_several(demo_route: demo.DemoRoute, tmp_path: Path,
                                                     cache_dir: Path) -> None:
    """``api.evaluate(["x.csv"], ...)`` was a bare TypeError: it scores one run and says how to
    score several; ``api.compare`` takes one run alone as ``[run]`` (not the characters of its
    name), any iterable of runs once (a generator was used up by the check and compared nothing),
    and refuses none at all."""
    truth = demo_route.truth()
    path = api.localize(demo_route.queries[0], reference=demo_route.reference, method="threshold",
                        out=tmp_path / "run.csv").path
    for wrong, problem in ([[path], "one run is scored at a time, got a list of 1: score each "
                                    "([api.evaluate(run, truth) for run in runs]) or compare them (api.compare)"],
                           [None, "a results file's path, a LocalizeRun or Results, got NoneType"]):
        with pytest.raises(ParameterError) as err:
            api.evaluate(wrong, truth)
        assert err.value.parameter == "run" and err.value.problem == problem
    assert api.evaluate(str(path), truth).summary.as_dict() == api.evaluate(path, truth).summary.as_dict()
    listed = api.compare([path], truth).table1
    for runs in (path, str(path), (p for p in [path])):
        assert api.compare(runs, truth).table1.equals(listed)
    for wrong, problem in ([[], "no runs given"],
                           [None, "one run or several: results files' paths, LocalizeRun or Results, got NoneType"],
                           [[path, None], "a results file's path, a LocalizeRun or Results, got NoneType"]):
        with pytest.raises(ParameterError) as err:
            api.compare(wrong, truth)
        assert err.value.parameter == "runs" and err.value.problem == problem


def test_a_map_that_is_no_traversal_names_the_map_parameter(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """A list of folders or an array of descriptors as ``map`` was a bare TypeError: one map is one
    traversal, and descriptors in memory are given as an ``Entry`` (``entry_from_array``)."""
    for wrong, got in ([[demo_route.reference, demo_route.queries[0]], "got list"],
                       [np.zeros((5, 1152), np.uint8), "got ndarray"]):
        with pytest.raises(ParameterError) as err:
            Localizer(wrong, method="online")
        assert err.value.parameter == "map" and got in err.value.problem and "entry_from_array" in err.value.problem
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor
    rows = np.random.default_rng(0).integers(0, 256, (30, 1152)).astype(np.uint8)
    loc = Localizer(entry_from_array(rows, [f"m{i}" for i in range(30)], get_descriptor("sad")), method="online")
    assert loc.observe(rows[5]).match_name == "m5"


def test_observe_takes_a_new_text_name_for_each_frame(demo_route: demo.DemoRoute, tmp_path: Path,
                                                       cache_dir: Path) -> None:
    """Names are written into results, which hold one row per name (a file naming a frame twice
    is refused when read): a name given that is not text, empty, not UTF-8 (os.fsdecode's name of
    a file whose name holds other bytes) or an earlier frame's is refused
    before anything is decided, after a load too; a file observed again under its own name (a
    camera writing latest.jpg each time) gets the frame's index after its stem."""
    loc = Localizer(demo_route.reference, method="threshold")
    path = min(demo_route.queries[0].iterdir())
    for name, problem in ([5, "name must be text (str), got int 5"], ["", "name is empty"],
                          ["bad\udcff", "name 'bad\\xff' is not valid UTF-8 (results files hold names as UTF-8 text)"]):
        with pytest.raises(WilocError) as err:
            loc.observe(path, name=name)
        assert str(err.value) == f"observe: {problem}"
    assert loc.observe(path).frame == path.name
    assert loc.observe(path, name="again").frame == "again"
    loc.save(tmp_path / "s.npz")
    for again in (Localizer.load(tmp_path / "s.npz"), loc):
        for frame, name in ((path, path.name), (np.zeros(1152, np.uint8), "again")):
            with pytest.raises(WilocError, match=re.escape(f"observe: name '{name}' is an earlier frame's")):
                again.observe(frame, name=name)
        assert again.frames == 2 and again.names == [path.name, "again"]
    assert loc.observe(np.zeros(1152, np.uint8)).frame == "000002"
    assert loc.observe(path).frame == f"{path.stem}-000003{path.suffix}"


def test_several_descriptor_rows_at_once_are_told_as_rows_not_a_narrow_image(demo_route: demo.DemoRoute,
                                                                              tmp_path: Path, cache_dir: Path) -> None:
    """observe(np.stack([row, row])) said 'image of 1152 x 2 pixels: one side is over 256 times the
    other'; against a descriptor matrix file, that the map takes no images."""
    loc = Localizer(demo_route.reference, method="threshold")
    row = loc.describe(min(demo_route.queries[0].iterdir()))
    rows = np.random.default_rng(0).random((30, 16)).astype(np.float32)
    np.save(tmp_path / "map.npy", rows)
    imported = Localizer(tmp_path / "map.npy", metric="l1", method="threshold")
    for localizer, given, length in ((loc, np.stack([row, row]), 1152), (imported, rows[:3], 16)):
        with pytest.raises(WilocError) as err:
            localizer.observe(given)
        k = len(given)
        assert str(err.value) == (f"observe: an array of {k} x {length} looks like {k} descriptor rows; observe "
                                  f"takes one frame at a time: a row of {length} values (or 1 x {length})")
        assert localizer.observe(given[:1]).frame == "000000"
    assert loc.observe(np.zeros((30, 1152), np.uint8)).frame == "000001"  # an image 1152 pixels wide, as before


def test_a_default_name_an_earlier_frame_was_given_gets_a_free_one(demo_route: demo.DemoRoute,
                                                                     cache_dir: Path) -> None:
    """An array frame's index, 000001, given earlier as a name: the frame was refused, where a file
    observed again gets a free name (latest-000012.jpg); that one taken too, a count follows."""
    loc = Localizer(demo_route.reference, method="threshold")
    path = min(demo_route.queries[0].iterdir())
    row = np.zeros(1152, np.uint8)
    loc.observe(row, name="000001")
    assert loc.observe(row).frame == "000001-2"
    loc.observe(path)
    loc.observe(row, name=f"{path.stem}-000004{path.suffix}")
    assert loc.observe(path).frame == f"{path.stem}-000004-2{path.suffix}"
    assert loc.names == ["000001", "000001-2", path.name, f"{path.stem}-000004{path.suffix}",
                         f"{path.stem}-000004-2{path.suffix}"]


@pytest.mark.parametrize("bad, problem", [(float("nan"), "finite and >= 0"), (-1.0, "finite and >= 0"),
                                          ("1.0", "a number, got str"), (True, "a number, got bool")])
def test_a_refused_odometry_leaves_the_run_as_it_was(demo_route: demo.DemoRoute, cache_dir: Path, bad: object,
                                                     problem: str) -> None:
    """A robot that retries a frame after its odometry was refused (a NaN from its wheel encoders)
    gets the decisions of a run that never saw the refused call."""
    def localizer() -> Localizer:
        return Localizer(demo_route.reference, method="catgraph", seed=0,
                         map_odometry=demo_route.positions / "reference.csv")
    frames = sorted(demo_route.queries[0].iterdir())[:40]
    clean, retried = localizer(), localizer()
    expected = [clean.observe(frame, odometry=1.0) for frame in frames]
    got = []
    for k, frame in enumerate(frames):
        if k == 20:
            with pytest.raises(WilocError, match=problem) as err:
                retried.observe(frame, odometry=bad)
            assert err.value.parameter == "odometry"
        got.append(retried.observe(frame, odometry=1.0))
    assert [(d.match, d.confidence, d.new_place) for d in got] == [(d.match, d.confidence, d.new_place)
                                                                  for d in expected]



def test_with_the_maps_odometry_the_first_frames_is_not_read_and_later_ones_are_needed(
        demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """On a map with odometry a streaming run decides as the batch run with both odometry CSVs,
    whether its first frame comes with an odometry (unread: a distance from no frame) or with
    none; a later frame without odometry is refused, naming it, and the run goes on as if that
    call had not been made."""
    from wiloc.localization.odometry import read_odometry

    query, positions = demo_route.queries[0], demo_route.positions
    frames = sorted(query.iterdir())[:60]
    travelled = read_odometry(positions / f"{query.name}.csv").steps([f.name for f in frames])  # metres between
    batch = api.localize(query, reference=demo_route.reference, method="catgraph", method_params={"seed": 0},
                         odometry=positions / f"{query.name}.csv", map_odometry=positions / "reference.csv")
    for first in (None, 0.0, 5.0):
        loc = Localizer(demo_route.reference, method="catgraph", seed=0, map_odometry=positions / "reference.csv")
        got = []
        for k, (frame, step) in enumerate(zip(frames, travelled)):
            if k == 30:
                with pytest.raises(WilocError, match="query frame 30: with the map's odometry, odometry comes with "
                                                     "every frame after the first") as err:
                    loc.observe(frame)
                assert err.value.parameter == "odometry"
            got.append(loc.observe(frame, odometry=first if k == 0 else float(step)))
        np.testing.assert_array_equal([d.match for d in got], batch.decisions.match[:60])
        np.testing.assert_array_equal([d.confidence for d in got], batch.decisions.confidence[:60])


def _matrix_map(tmp_path: Path) -> tuple[np.ndarray, Path, Path]:
    """A map of imported descriptors: a .npy matrix of 40 rows and its names file."""
    rows = np.random.default_rng(7).random((40, 32)).astype(np.float32)
    np.save(tmp_path / "map.npy", rows)
    (tmp_path / "names.txt").write_text("".join(f"place{i:02d}.jpg\n" for i in range(40)))
    return rows, tmp_path / "map.npy", tmp_path / "names.txt"


def test_a_map_with_a_names_file_is_loaded_with_it(tmp_path: Path, cache_dir: Path) -> None:
    """The state recorded the map but not its names file: a .npy map loaded with its frames
    numbered instead of named, and was refused as changed since it was saved."""
    rows, matrix, names = _matrix_map(tmp_path)
    loc = Localizer(matrix, metric="l1", map_names=names, method="online", exclude_recent=2)
    loc.observe(rows[3] + 0.01)
    loc.save(tmp_path / "state.npz")
    again = Localizer.load(tmp_path / "state.npz")
    assert again.map_names == loc.map_names and again.observe(rows[4]).match_name == "place04.jpg"


@pytest.mark.parametrize("in_memory", [False, True])
def test_a_pickled_or_copied_localizer_continues_on_its_own(in_memory: bool, tmp_path: Path,
                                                             cache_dir: Path) -> None:
    """pickle (multiprocessing, joblib, a notebook's store) was an AttributeError about a local
    lambda: a localizer pickles as it saves, and a copy (copy.copy too) continues with the
    decisions of the original, which its steps leave alone."""
    import copy
    import pickle

    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    rows, matrix, names = _matrix_map(tmp_path)
    spec = get_descriptor("external", metric="l1", length=32)
    map_ = entry_from_array(rows, names.read_text().split(), spec) if in_memory else matrix
    loc = Localizer(map_, metric="l1", map_names=None if in_memory else names, method="catgraph", particles=200,
                    seed=3)
    query = rows[5:25] + np.random.default_rng(8).normal(0, 0.02, (20, 32)).astype(np.float32)
    for row in query[:8]:
        loc.observe(row)
    copies = [pickle.loads(pickle.dumps(loc)), copy.copy(loc), copy.deepcopy(loc)]
    expected = [repr(loc.observe(row)) for row in query[8:]]
    for other in copies:
        assert other.frames == 8 and [repr(other.observe(row)) for row in query[8:]] == expected


def test_observe_takes_one_descriptor_as_a_batch_of_one(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """A 1 x D array (a network's output for one image, rows[k:k + 1]) of the map's length was taken
    for an image one pixel high and refused for its aspect: it is the descriptor."""
    frame = sorted(demo_route.queries[0].iterdir())[3]
    as_row, as_batch = (Localizer(demo_route.reference, method="threshold") for _ in range(2))
    descriptor = as_row.describe(frame)
    assert repr(as_batch.observe(descriptor[None, :])) == repr(as_row.observe(descriptor))


@pytest.mark.parametrize("frame, problem", [
    ("a\0b.jpg", "the frame's path holds a NUL character; no file is named so"),
    (b"\xff\xd8\xff\xe0\x00\x10JFIF\x00", "frame is the bytes of an encoded image, not a file's path: give its "
                                          "file, or the image decoded (cv2.imdecode)"),
    ("x" * 300 + ".jpg", "cannot read file (File name too long)"),
    (bytes([200]) * 300, "frame is 300 bytes that no file's path can be (no file can have this name (a part of 300 "
                         "bytes; file systems take at most 255)): image data, such as a ROS Image's data? give the "
                         "image as an array (numpy.frombuffer(data, numpy.uint8).reshape(height, width, channels))"),
    (bytes([200, 0]) * 150, "frame is 300 bytes that no file's path can be (they hold a NUL byte): image data, such "
                            "as a ROS Image's data? give the image as an array (numpy.frombuffer(data, "
                            "numpy.uint8).reshape(height, width, channels))")])
def test_observe_refuses_what_no_file_is_named_in_one_line(frame: object, problem: str, demo_route: demo.DemoRoute,
                                                           cache_dir: Path) -> None:
    """A path holding NUL, an encoded image's bytes (a ROS CompressedImage's data) and a name too
    long for the file system were a ValueError (embedded null byte) or an OSError."""
    loc = Localizer(demo_route.reference, method="threshold")
    for call in (loc.observe, loc.read):  # raw pixel bytes ended in an OSError (File name too long)
        with pytest.raises(FrameError) as err:
            call(frame)
        assert err.value.problem == problem and loc.frames == 0


def test_errors_pickle_with_their_fields() -> None:
    """A WilocError raised in a worker process (describe's, a multiprocessing pool's) is pickled to
    the process that re-raises it: unpickling called __init__ with the message alone, a TypeError."""
    import pickle

    from wiloc.errors import CacheBusyError

    for error in (WilocError("day_left/x.jpg", "cannot read"), FrameError("x.jpg", "truncated JPEG"),
                  ParameterError("particles", "must be >= 1"), CacheBusyError("cache", "in use")):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error) and str(again) == str(error)
        assert (again.where, again.problem, again.parameter, again.exit_code) == \
               (error.where, error.problem, error.parameter, error.exit_code)


def test_the_package_lists_the_names_it_loads_on_first_use() -> None:
    """``dir(wiloc)`` (a notebook's completion of ``wiloc.``) showed none of the verbs nor
    ``Localizer``, which load on first use; each listed name is there."""
    assert set(wiloc.__all__) <= set(dir(wiloc))
    assert all(getattr(wiloc, name) is not None for name in wiloc.__all__)


def test_localize_takes_one_query_and_one_reference(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """``api.localize([q1, q2], ...)``, as the command line takes several queries, was a bare
    TypeError from pathlib: the query and the reference are one traversal each, named in the error."""
    queries = list(demo_route.queries[:2])
    for query, reference, parameter, got in ([queries, demo_route.reference, "query", "got list: localize each"],
                                             [queries[0], [demo_route.reference], "reference", "got list"],
                                             [None, demo_route.reference, "query", "got NoneType"]):
        with pytest.raises(ParameterError) as err:
            api.localize(query, reference=reference, method="threshold")
        assert err.value.parameter == parameter and err.value.problem.startswith("one traversal (a folder")
        assert got in err.value.problem


def test_a_map_in_memory_is_checked_as_an_observed_row_is() -> None:
    """entry_from_array cast the rows into the descriptor's dtype: 300 became 44 in a sad map,
    1e40 infinite in a float32 one, and NaN rows were kept; each is refused naming the source."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    names = [f"m{i}" for i in range(6)]
    sad, floats = get_descriptor("sad"), get_descriptor("external", metric="l1", length=8)
    nan_row = np.ones((6, 8))
    nan_row[2] = np.nan
    for rows, spec, problem in ([np.full((6, 1152), 300), sad, "a descriptor of int64 values; this map's rows are "
                                                               "uint8 (integers in [0, 255])"],
                                [np.full((6, 8), 1e40), floats, "the descriptor holds values beyond the range of "
                                                                 "this map's float32 rows"],
                                [nan_row, floats, "the descriptor holds NaN or infinite values"]):
        with pytest.raises(WilocError) as err:
            entry_from_array(rows, names, spec, source="walk.npy")
        assert str(err.value) == f"walk.npy: {problem}"
    kept = entry_from_array(np.full((6, 1152), 255, np.int64)[:, ::1], names, sad)
    assert kept.data.dtype == np.uint8 and kept.data.flags.c_contiguous and int(kept.data.max()) == 255


def test_a_map_in_memory_names_each_row_once_in_text() -> None:
    """entry_from_array took a name twice (matches to either row then named the same frame) and
    names that are no text (a range of indices: a TypeError in the digest); each is refused naming
    the source, as an imported matrix's names are."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    rows, spec = np.ones((4, 8), np.float32), get_descriptor("external", metric="l1", length=8)
    for names, problem in ([["a.jpg", "b.jpg", "a.jpg", "c.jpg"], "rows 1 and 3: duplicate frame name 'a.jpg'"],
                           [list(range(4)), "row 1: frame name 0; each row needs a non-empty text name"],
                           [["a.jpg", "", "b.jpg", "c.jpg"], "row 2: frame name ''; each row needs a non-empty text name"]):
        with pytest.raises(WilocError) as err:
            entry_from_array(rows, names, spec, source="walk.npy")
        assert str(err.value).startswith(f"walk.npy: {problem}")
    assert entry_from_array(rows, np.array(["a", "b", "c", "d"]), spec).names == ["a", "b", "c", "d"]


def test_the_cache_is_given_as_a_cache_or_its_folder(demo_route: demo.DemoRoute, tmp_path: Path) -> None:
    """``cache="~/wiloc-cache"``, as ``--cache DIR`` takes it, was an AttributeError ('str' object
    has no attribute 'lock') once describing began: a folder's path is that cache's folder."""
    [report] = api.describe(demo_route.reference, cache=str(tmp_path / "by-text"))
    assert [info.folder for info in Cache(tmp_path / "by-text").list_entries()] == [report.folder]
    loc = Localizer(demo_route.reference, method="threshold", cache=tmp_path / "by-text")
    assert loc.describer.cache.root == (tmp_path / "by-text").resolve()
    with pytest.raises(ParameterError) as err:
        api.describe(demo_route.reference, cache=5)
    assert err.value.parameter == "cache" and err.value.problem == "a Cache or a cache folder's path, got int"


@pytest.mark.parametrize("method", ["threshold", "catgraph"])
def test_exclude_recent_against_a_map_is_refused_where_it_does_nothing(demo_route: demo.DemoRoute, method: str,
                                                                        tmp_path: Path, cache_dir: Path) -> None:
    """Against a map only the methods learning from the map's differences to itself read
    exclude_recent: given to another, the API refuses it, as the CLI refuses --exclude-recent,
    before any work (nothing is written); left out, the run goes on with the default."""
    query, out = demo_route.queries[0], tmp_path / "run.csv"
    calls = (lambda **kw: Localizer(demo_route.reference, method=method, **kw),
             lambda **kw: api.localize(query, reference=demo_route.reference, method=method, out=out, **kw),
             lambda **kw: api.follow_folder(query, reference=demo_route.reference, method=method, out=out, **kw))
    for call in calls:
        with pytest.raises(ParameterError) as err:
            call(exclude_recent=3)
        assert err.value.parameter == "exclude_recent" and f"for method '{method}'" in err.value.problem
        assert "online" in err.value.problem and not out.exists()
    assert Localizer(demo_route.reference, method=method).exclude_recent == 10
    assert Localizer(demo_route.reference, method="online", exclude_recent=3).exclude_recent == 3
    sequence = Localizer(None, descriptor="external", descriptor_params={"metric": "l1", "length": 4},
                         method=method, exclude_recent=3, **({"normaliser": 1.0} if method == "threshold" else {}))
    assert sequence.exclude_recent == 3


def test_training_and_jobs_of_another_type_are_named(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    """A training pair given as a tuple was an AttributeError ('tuple' object has no attribute
    'query'), and jobs='2' (read from a config file) a TypeError comparing it with 1."""
    pair = (demo_route.queries[1], demo_route.reference, demo_route.truth())
    for run in (lambda: Localizer(demo_route.reference, method="trained", training=pair),
                lambda: api.localize(demo_route.queries[0], reference=demo_route.reference, method="trained",
                                     training=pair)):
        with pytest.raises(ParameterError) as err:
            run()
        assert err.value.parameter == "training" and err.value.problem.endswith("got tuple")
    for jobs in ("2", 2.0):
        with pytest.raises(ParameterError) as err:
            api.describe(demo_route.reference, jobs=jobs)
        assert err.value.parameter == "jobs" and err.value.problem == f"must be an integer, got {jobs!r}"


_COMPILED = """
import json, sys
from wiloc.localization.localizer import Localizer
from wiloc.methods.catgraph import filter_kernels, rank_kernels
kernels = [filter_kernels.weigh, rank_kernels.rank_log_ratio]
before = [len(k.signatures) for k in kernels]
loc = Localizer(sys.argv[1], method="catgraph", seed=5)
print(json.dumps([before, [len(k.signatures) for k in kernels]]))
"""


def test_the_compiled_kernels_are_ready_when_the_localizer_starts(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                   cache_dir: Path) -> None:
    """A new localizer builds (or loads) its method's compiled kernels as it starts, so that the
    first frame a robot gives it is decided at the usual pace (on a machine that had not built
    them, catgraph's first two frames took 7 s of CPU); its decisions are those of a localizer
    that did not (the batch run's: test_streaming_equals_batch_in_map_mode)."""
    result = subprocess.run([sys.executable, "-c", _COMPILED, str(demo_route.reference)], capture_output=True,
                            text=True, check=True)
    before, after = json.loads(result.stdout)
    assert before == [0, 0] and min(after) >= 1, result.stdout


_COMPILED_IN_SEQUENCE_MODE = """
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from wiloc.localization.localizer import Localizer

def compiled():
    return {f"{name}.{attr}": len(kernel.signatures) for name, module in list(sys.modules.items())
            if name.startswith("wiloc") for attr, kernel in vars(module).items() if isinstance(kernel, CPUDispatcher)}

rng = np.random.default_rng(3)
places = rng.integers(0, 256, (60, 64))
rows = np.clip(places[np.r_[np.arange(60), np.arange(60)]] + rng.integers(-12, 13, (120, 64)), 0, 255)
loc = Localizer(None, descriptor="external", descriptor_params={"metric": "l1", "length": 64}, method=sys.argv[1],
                cache=sys.argv[2], **json.loads(sys.argv[4]))
if sys.argv[3] == "loaded":
    loc.save(sys.argv[2] + "/state.npz")
    loc = Localizer.load(sys.argv[2] + "/state.npz", cache=sys.argv[2])
ready = compiled()
stages = [loc.observe(row.astype(np.float32)).stage for row in rows]
print(json.dumps([ready, compiled(), stages]))
"""


@pytest.mark.parametrize("method, how", [("catgraph", "new"), ("online", "new"), ("catgraph", "loaded")])
def test_the_compiled_kernels_are_ready_in_sequence_mode(method: str, how: str, tmp_path: Path, cache_dir: Path) -> None:
    """In sequence mode too the kernels are built as the localizer starts or is loaded, not when
    its filter starts mid-run (frame 72 with catgraph's defaults, 5 s of CPU on a machine that
    had not built them): no frame of the run compiles or loads one. Its decisions are those of
    a localizer that did not (test_streaming_equals_batch_in_sequence_mode)."""
    params = {"frontier": 10} if method == "catgraph" else {}  # online: init ends at frame 110
    result = subprocess.run([sys.executable, "-c", _COMPILED_IN_SEQUENCE_MODE, method, str(tmp_path), how,
                             json.dumps(params)], capture_output=True, text=True, check=True)
    ready, after, stages = json.loads(result.stdout)
    assert {"track", "update"} & set(stages), stages  # the filter (online: its update stage) ran
    assert ready and after == ready, (ready, after)


def test_a_map_held_in_memory_gives_its_descriptor_and_refuses_another() -> None:
    """A Localizer over an in-memory map took the default descriptor, sad: its results header
    recorded sad for a gist map, and an image observed ended in numpy's ValueError about rows
    of 1152 and 512 values."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    spec = get_descriptor("gist")
    rows = np.random.default_rng(0).random((30, spec.length)).astype(np.float32)
    map_ = entry_from_array(rows, [f"m{i}" for i in range(30)], spec)
    loc = Localizer(map_, method="online")
    loc.observe(rows[4])
    assert loc.observe(np.random.default_rng(1).integers(0, 256, (48, 64), dtype=np.uint8)).match >= 0
    assert (loc.results().header.descriptor, loc.describer.spec.length) == ("gist", spec.length)
    with pytest.raises(ParameterError, match="the map held in memory was described with 'gist', not 'sad'") as refused:
        Localizer(map_, descriptor="sad", method="online")
    assert refused.value.parameter == "descriptor"
    sad = get_descriptor("sad")
    thumbnails = entry_from_array(np.zeros((30, sad.length), np.uint8), [f"m{i}" for i in range(30)], sad)
    assert Localizer(thumbnails, descriptor_params={"patch": 8}, method="online").describer.spec == sad
    with pytest.raises(ParameterError, match="the map held in memory was described with") as refused:
        Localizer(thumbnails, descriptor_params={"patch": 4}, method="online")
    assert refused.value.parameter == "descriptor_params"
    external = get_descriptor("external", metric="l1", length=8)
    small = entry_from_array(rows[:, :8], [f"m{i}" for i in range(30)], external)
    assert Localizer(small, descriptor="external", metric="l1", method="online").describer.spec.metric == "l1"


def test_a_localizer_over_a_cached_map_takes_its_descriptor_parameters(demo_route: demo.DemoRoute,
                                                                        tmp_path: Path) -> None:
    """A Localizer over the entry api.describe gives (its parameters hold the cache's
    code_version besides the descriptor's) ended in 'code_version: not a parameter of descriptor
    'sad'', given descriptor parameters or not."""
    from wiloc.descriptors.registry import get_descriptor

    cache = Cache(tmp_path / "cache")
    [report] = api.describe([demo_route.reference], "sad", descriptor_params={"patch": 4}, cache=cache)
    loc = Localizer(report.entry, method="threshold", cache=cache)
    assert loc.describer.spec == get_descriptor("sad", patch=4)
    first = min(demo_route.reference.iterdir())
    assert loc.observe(first).match_name == first.name
    assert Localizer(report.entry, descriptor_params={"patch": 4}, method="threshold").describer.spec.params["patch"] == 4
    with pytest.raises(ParameterError, match="the map held in memory was described with") as refused:
        Localizer(report.entry, descriptor_params={"patch": 8}, method="threshold")
    assert refused.value.parameter == "descriptor_params"


@pytest.mark.parametrize("descriptor", ["sad", "brisk-gist"])
def test_a_run_records_the_same_descriptor_parameters_however_it_is_made(descriptor: str, demo_route: demo.DemoRoute,
                                                                          tmp_path: Path) -> None:
    """wiloc localize recorded sad's {"crop": "none"}, the same run through api.localize or a
    Localizer over the map's folder {}, and a Localizer over the map's cached entry ended in
    'code_version: not a parameter of descriptor': each records every parameter, defaults resolved."""
    from typer.testing import CliRunner

    from wiloc.cli import app
    from wiloc.descriptors.registry import get_descriptor
    from wiloc.evaluation.results import read_results

    query, reference, cache = demo_route.queries[0], demo_route.reference, Cache(tmp_path / "cache")
    cli = CliRunner().invoke(app, ["localize", str(query), "--map", str(reference), "--descriptor", descriptor,
                                   "--method", "threshold", "--cache", str(cache.root), "--out", str(tmp_path / "cli.csv")])
    assert cli.exit_code == 0, cli.output
    recorded = [read_results(tmp_path / "cli.csv").header.descriptor_params,
                api.localize(query, reference=reference, descriptor=descriptor, method="threshold",
                             cache=cache).results.header.descriptor_params]
    [report] = api.describe([reference], descriptor, cache=cache)
    for map_ in (reference, report.entry):
        loc = Localizer(map_, descriptor=descriptor, method="threshold", cache=cache)
        loc.observe(min(query.iterdir()))
        recorded.append(loc.results().header.descriptor_params)
    assert recorded == [dict(get_descriptor(descriptor).params)] * 4


def test_a_localizer_over_an_imported_map_from_the_cache_compares_its_rows(tmp_path: Path) -> None:
    """The entry api.import_descriptors gives holds the file's digest and reader in its
    parameters, not external's storage: a Localizer over it ended in 'file_digest: not a
    parameter of descriptor 'external''. It takes the entry's metric, length and dtype."""
    rows = np.random.default_rng(0).random((20, 16)).astype(np.float32)
    np.save(tmp_path / "m.npy", rows)
    report = api.import_descriptors(tmp_path / "m.npy", cache=Cache(tmp_path / "cache"), metric="l1")
    loc = Localizer(report.entry, descriptor="external", metric="l1", method="threshold")
    assert loc.observe(rows[7]).match == 7
    assert loc.results().header.descriptor_params == {"metric": "l1", "length": 16, "dtype": "float32"}


def test_a_map_of_imported_rows_in_memory_refuses_an_image_in_one_line() -> None:
    """Rows held in memory as ``external`` descriptors are compared, never computed: an image given
    to such a map ended in a TypeError traceback where a map file of them is refused in one line."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    rows = np.random.default_rng(0).random((20, 16)).astype(np.float32)
    entry = entry_from_array(rows, [f"f{i}" for i in range(20)],
                             get_descriptor("external", metric="l1", length=16, dtype="float32"))
    loc = Localizer(entry, method="threshold")
    assert loc.observe(rows[3]).match == 3
    with pytest.raises(WilocError, match="a map of imported descriptors takes descriptors, not images"):
        loc.observe(np.zeros((40, 60), np.uint8))
    assert loc.frames == 1


def test_a_folder_streamed_in_api_frames_order_decides_as_the_batch_run(tmp_path: Path, cache_dir: Path) -> None:
    """``api.frames`` lists a folder as a batch run reads it (img2 before img10, which ``sorted``
    puts after img10), so a localizer given its frames one by one makes the batch run's decisions."""
    scenes = places(12, seed=3)
    ref = write_traversal(tmp_path / "ref", scenes, 1.0, seed=1)
    query = write_traversal(tmp_path / "query", scenes, 0.8, seed=2)
    (query / ".hidden.png").write_bytes(b"")
    (query / "notes.txt").write_text("not a frame")
    listed = api.frames(query)
    assert [p.name for p in listed] == [f"img{i}" + ".png" for i in range(12)]
    assert [p.name for p in sorted(query.glob("img*.png"))] != [p.name for p in listed]
    batch = api.localize(query, reference=ref, method="threshold", out=tmp_path / "batch.csv").results
    loc = Localizer(ref, method="threshold")
    streamed = [loc.observe(path).match_name for path in listed]
    assert list(batch.frames["frame"]) == [p.name for p in listed] and list(batch.frames["match"]) == streamed


def _saved(demo_route: demo.DemoRoute, path: Path, **setup: object) -> Localizer:
    """A localizer over the demo map that observed a query frame, saved to ``path``."""
    loc = Localizer(setup.pop("map", demo_route.reference), **setup)
    loc.observe(min(demo_route.queries[0].iterdir()), odometry=0.0 if "map_odometry" in setup else None)
    loc.save(path)
    return loc


def test_load_takes_the_map_it_was_saved_with(demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    """load(map=5) ended in a TypeError; a copy of the saved map's folder elsewhere (a map moved to
    the robot) was refused as a changed map: it is taken, as its frames and descriptors are the
    same, and continues as the original would. Another map is refused, naming the saved one."""
    first, second = sorted(demo_route.queries[0].iterdir())[:2]
    _saved(demo_route, tmp_path / "s.npz", method="catgraph")
    shutil.copytree(demo_route.reference, tmp_path / "copy")
    for given, got in ((5, "got int"), ([1, 2], "got list")):
        with pytest.raises(ParameterError) as err:
            Localizer.load(tmp_path / "s.npz", map=given)
        assert err.value.parameter == "map" and got in err.value.problem
    saved_with = re.escape(str(demo_route.reference.resolve()))
    with pytest.raises(WilocError, match=f"not the one it was saved with: {saved_with}"):
        Localizer.load(tmp_path / "s.npz", map=demo_route.queries[0])
    moved, original = (Localizer.load(tmp_path / "s.npz", map=m) for m in (tmp_path / "copy", demo_route.reference))
    assert moved.frames == original.frames == 1
    assert repr(moved.observe(second)) == repr(original.observe(second)) and first != second
    assert moved.results().header.map == str((tmp_path / "copy").resolve())


def test_a_rewritten_map_odometry_is_refused_on_load(demo_route: demo.DemoRoute, tmp_path: Path,
                                                     cache_dir: Path) -> None:
    """The state keeps a digest of the map's odometry CSV: one rewritten since is refused as a
    changed map is (the loaded run would decide from the old content and its results name the
    new); the same content written again is no change, and a state saved before the digest was
    kept is loaded as it was."""
    from wiloc.localization.state_file import DIGEST, state_digest

    csv = tmp_path / "odometry.csv"
    shutil.copy(demo_route.positions / "reference.csv", csv)
    original = csv.read_bytes()
    _saved(demo_route, tmp_path / "s.npz", method="catgraph", map_odometry=csv)
    csv.write_text(csv.read_text().replace(",0.00\n", ",0.50\n"))  # the route bent sideways
    with pytest.raises(WilocError, match="the map's odometry changed since .*s.npz was saved") as err:
        Localizer.load(tmp_path / "s.npz")
    assert err.value.where == str(csv.resolve())

    def older(members: dict[str, np.ndarray]) -> None:
        meta = json.loads(str(members["meta"]))
        del meta["map_odometry_digest"]
        members["meta"] = np.array(json.dumps(meta))
        members[DIGEST] = np.array(state_digest(str(members["meta"]), {k: v for k, v in members.items()
                                                                   if k not in ("meta", DIGEST)}))

    _rewritten(tmp_path / "s.npz", older)
    assert Localizer.load(tmp_path / "s.npz").frames == 1
    csv.write_bytes(original)
    _saved(demo_route, tmp_path / "t.npz", method="catgraph", map_odometry=csv)
    csv.write_bytes(original)
    assert Localizer.load(tmp_path / "t.npz").frames == 1


def test_a_localizer_shows_the_settings_that_differ_from_the_defaults(demo_route: demo.DemoRoute,
                                                                      cache_dir: Path) -> None:
    """Two localizers that decide otherwise printed the same: the descriptor's parameters,
    exclude_recent and the map's odometry were left out."""
    csv = demo_route.positions / "reference.csv"
    plain = repr(Localizer(demo_route.reference, method="online"))
    shown = repr(Localizer(demo_route.reference, method="online", descriptor_params={"crop": "top-half", "patch": 8},
                           exclude_recent=3))
    assert "descriptor_params" not in plain and "exclude_recent" not in plain
    assert "descriptor_params={'crop': 'top-half'}, exclude_recent=3" in shown  # patch 8 is the default
    assert f"map_odometry={str(csv)!r}" in repr(Localizer(demo_route.reference, method="catgraph", map_odometry=csv))


@pytest.mark.parametrize("query, problem", [("missing", "folder does not exist"),
                                            ("frame", "an image file is not a traversal")])
def test_results_refuse_a_query_that_is_no_traversal(query: str, problem: str, demo_route: demo.DemoRoute,
                                                     tmp_path: Path, cache_dir: Path) -> None:
    """results(query=) wrote a missing folder, or an image file, into the header, which a batch
    run refuses as its query."""
    frame = min(demo_route.queries[0].iterdir())
    given = tmp_path / "missing" if query == "missing" else frame
    loc = Localizer(demo_route.reference, method="threshold")
    loc.observe(frame)
    with pytest.raises(WilocError, match=problem) as err:
        loc.results(query=given)
    assert err.value.where == str(given)
    assert loc.results(query=demo_route.queries[0]).header.query == str(demo_route.queries[0])
    bag, emptied = tmp_path / "ros2bag", tmp_path / "emptied"  # a ROS 2 bag's folder; one a live source emptied
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    emptied.mkdir()
    for folder in (bag, emptied):
        assert loc.results(query=folder).header.query == str(folder)


def test_bytes_that_name_no_file_are_said_in_one_line(demo_route: demo.DemoRoute, tmp_path: Path,
                                                       cache_dir: Path) -> None:
    """A raw frame's bytes without a NUL (a bright gray image) were taken as a file's path: the
    error printed thousands of its bytes as text, control characters and all, over many lines."""
    loc = Localizer(demo_route.reference, method="threshold")
    frame = bytes(range(1, 256)) * 8  # 2040 bytes, a few '/' among them: no part of it too long for a name
    with pytest.raises(FrameError) as err:
        loc.observe(frame)
    message = str(err.value)
    assert "\n" not in message and "\r" not in message and len(message) < 400, message
    assert "frame is 2040 bytes that name no file (b'\\x01\\x02" in message and "give the image as an array" in message
    named = tmp_path / "frame.jpg"
    shutil.copy(min(demo_route.queries[0].iterdir()), named)
    loc.observe(os.fsencode(named))  # bytes naming a file are its path
    assert loc.frames == 1


def test_observe_says_what_a_path_that_is_no_frame_is(demo_route: demo.DemoRoute, tmp_path: Path,
                                                      cache_dir: Path) -> None:
    """A broken link's read said "No such file or directory", a loop's "Too many levels of symbolic
    links", where describing says what they are; "." and "/" said "name is empty"; a list of paths
    was taken for a descriptor of 1 value."""
    (tmp_path / "broken.jpg").symlink_to(tmp_path / "gone.jpg")
    (tmp_path / "a.jpg").symlink_to(tmp_path / "b.jpg")
    (tmp_path / "b.jpg").symlink_to(tmp_path / "a.jpg")
    loc = Localizer(demo_route.reference, method="threshold")
    for frame, problem in ((tmp_path / "broken.jpg", "broken symbolic link"), (tmp_path / "a.jpg", "symbolic link loop"),
                           (".", "not a regular file"), ("/", "not a regular file")):
        with pytest.raises(FrameError) as err:
            loc.observe(frame)
        assert err.value.problem == problem, frame
    with pytest.raises(WilocError, match="frame is of type list, not an array of numbers"):
        loc.observe([str(min(demo_route.queries[0].iterdir()))])
    assert loc.frames == 0


@pytest.mark.parametrize("parameter", ["map", "map_odometry", "map_names"])
@pytest.mark.parametrize("path, problem", [("", "the path is empty"),
                                           ("a\0b", "the path holds a NUL character; no file is named so")])
def test_a_path_no_file_can_have_is_refused_naming_its_parameter(parameter: str, path: str, problem: str,
                                                                 tmp_path: Path, demo_route: demo.DemoRoute,
                                                                 cache_dir: Path) -> None:
    """A NUL in map_odometry or map_names was a bare ValueError (embedded null byte), one in map
    was shown as a space; an empty map was the current folder."""
    np.save(tmp_path / "rows.npy", np.random.default_rng(0).random((20, 8)).astype(np.float32))
    setup: dict[str, object] = {"map": demo_route.reference, "method": "catgraph", parameter: path}
    if parameter == "map_names":  # a names file goes with a descriptor matrix file
        setup.update(map=tmp_path / "rows.npy", metric="l1")
    with pytest.raises(ParameterError) as err:
        Localizer(**setup)
    assert (err.value.parameter, err.value.problem) == (parameter, problem)


def test_results_refuse_a_query_a_batch_run_refuses(demo_route: demo.DemoRoute, tmp_path: Path,
                                                    cache_dir: Path) -> None:
    """results(query=) recorded a FIFO, an empty path (the current folder) and a descriptor matrix
    file for frames described from images, each of which a batch run refuses."""
    loc = Localizer(demo_route.reference, method="threshold")
    loc.observe(min(demo_route.queries[0].iterdir()))
    os.mkfifo(tmp_path / "pipe")
    np.save(tmp_path / "rows.npy", np.zeros((3, 4), dtype=np.float32))
    for query, problem in ((tmp_path / "pipe", "not a folder, video, ROS bag or descriptor matrix file"),
                           ("", "the path is empty"),
                           (tmp_path / "rows.npy", "a descriptor matrix file, but the frames were described from "
                                                   "images")):
        with pytest.raises(WilocError) as err:
            loc.results(query=query)
        assert err.value.problem.startswith(problem), query

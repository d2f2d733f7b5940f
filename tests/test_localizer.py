"""The streaming Localizer: frame by frame it decides exactly what batch ``localize`` decides, in map
and sequence mode, and a saved run continues identically in another process."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

import wiloc
from wiloc import api, demo
from wiloc.cache.store import Cache
from wiloc.errors import ParameterError, UsageError, WilocError
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


@pytest.mark.parametrize("method", ["online", "threshold", "catgraph"])
def test_streaming_equals_batch_in_sequence_mode(method: str, tmp_path: Path) -> None:
    rows, names = _looped_descriptors()
    np.save(tmp_path / "route.npy", rows)
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    cache = Cache(tmp_path / "cache")
    params = _SEQUENCE_PARAMS[method]
    run = api.localize(tmp_path / "route.npy", metric="l1", query_names_file=tmp_path / "names.txt",
                       method=method, method_params=params, out=tmp_path / "batch.csv", cache=cache)
    loc = Localizer(None, descriptor="external", method=method, cache=cache,
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
    make = lambda: Localizer(None, descriptor="external", method=method, cache=Cache(tmp_path / "c"),  # noqa: E731
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
    with pytest.raises(WilocError, match="descriptor of 5 values"):
        loc.observe(np.zeros(5, np.uint8))
    assert wiloc.Localizer is Localizer


def test_bad_setup_names_the_parameter(demo_route: demo.DemoRoute, cache_dir: Path) -> None:
    with pytest.raises(UsageError) as err:
        Localizer(None, method="seqslam")
    assert err.value.parameter == "reference"
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


def test_a_changed_map_is_refused_on_load(demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path) -> None:
    import shutil
    map_copy = tmp_path / "map"
    shutil.copytree(demo_route.reference, map_copy)
    loc = Localizer(map_copy, method="threshold")
    loc.observe(sorted(demo_route.queries[0].iterdir())[0])
    loc.save(tmp_path / "s.npz")
    victim = sorted(map_copy.iterdir())[3]
    cv2.imwrite(str(victim), 255 - cv2.imread(str(victim)))
    with pytest.raises(WilocError, match="the map changed"):
        Localizer.load(tmp_path / "s.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a state")
    with pytest.raises(WilocError, match="not a saved localizer state"):
        Localizer.load(tmp_path / "junk.npz")


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

"""Tests of reading odometry CSVs into per-frame arc length."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from wiloc import api, demo
from wiloc.errors import WilocError
from wiloc.localization.odometry import read_odometry, steps


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "odo.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_distance_form_with_header(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "name,distance\na.png,10\nb.png,2.5\nc.png,7.5\n"))
    assert odo.names == ("a.png", "b.png", "c.png")
    np.testing.assert_allclose(odo.arclength(), [0.0, 2.5, 10.0])


def test_distance_of_a_left_out_frame_still_counts(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "a,0\nb,2\nc,3\nd,1\n"))
    np.testing.assert_allclose(odo.arclength(["a", "c", "d"]), [0.0, 5.0, 6.0])


def test_xy_form_without_header_sums_step_lengths(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "a,0,0\nb,3,4\nc,3,10\n"))
    np.testing.assert_allclose(odo.arclength(), [0.0, 5.0, 11.0])


def test_arclength_follows_requested_frame_order(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "name,x,y\nc,3,10\na,0,0\nb,3,4\nextra,100,100\n"))
    np.testing.assert_allclose(odo.arclength(["a", "b", "c"]), [0.0, 5.0, 11.0])


def test_steps_are_differences_starting_at_zero() -> None:
    np.testing.assert_allclose(steps(np.array([2.0, 3.0, 7.0])), [0.0, 1.0, 4.0])


@pytest.mark.parametrize("text, problem", [
    ("", "no odometry rows"),
    ("name,distance\n", "no odometry rows"),
    ("a,1,2,3\n", "4 columns"),
    ("a,1\nb,1,2\n", "line 2: expected 2 columns"),
    ("a,1\nb,x\n", "line 2: not a number"),
    ("a,1\nb,nan\n", "line 2: non-finite"),
    ("a,1\n,2\n", "line 2: empty frame name"),
    ("a,1\na,2\n", "'a' appears more than once"),
])
def test_bad_files_raise(tmp_path: Path, text: str, problem: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(WilocError, match=problem) as err:
        read_odometry(path)
    assert err.value.where == str(path)


def test_negative_distance_raises(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "a,5\nb,-3\n"))
    with pytest.raises(WilocError, match="negative distance at frame 'b'"):
        odo.arclength()


@pytest.mark.parametrize("text", ["a,1e308\nb,1e308\nc,1e308\n", "a,0,0\nb,1e308,0\nc,-1e308,0\n"])
def test_a_distance_no_float_holds_names_the_frame_and_warns_nothing(tmp_path: Path, text: str) -> None:
    """Every value finite, their running total (or a step between two positions) not: one error
    naming the file and the frame, no numpy warning."""
    odo = read_odometry(_write(tmp_path, text))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(WilocError, match="the distance travelled up to frame 'c' is more than a float can hold") as err:
            odo.arclength(["a", "b", "c"])
    assert err.value.where == odo.path


def test_missing_frame_raises(tmp_path: Path) -> None:
    """A frame missing from a file whose other names match is named alone; a file none of whose
    names matches also says how its names look against the frames'."""
    odo = read_odometry(_write(tmp_path, "a,0\nb,1\n"))
    with pytest.raises(WilocError, match=r"^[^:]*: no odometry for 1 frame\(s\), first 'z'$"):
        odo.arclength(["a", "z"])
    with pytest.raises(WilocError, match=r"first 'y' \(names such as 'a'; the frames are named such as 'y'\)$"):
        odo.arclength(["y", "z"])


def test_unreadable_file_raises(tmp_path: Path) -> None:
    """A missing file or a folder is said so once, in a line naming its path once."""
    with pytest.raises(WilocError, match=r"absent\.csv: file does not exist$") as err:
        read_odometry(tmp_path / "absent.csv")
    assert str(err.value).count("absent.csv") == 1
    with pytest.raises(WilocError, match=r": a folder, not an odometry CSV file$"):
        read_odometry(tmp_path)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(WilocError, match="cannot read"):
        read_odometry(binary)


@pytest.mark.parametrize("text", [
    "timestamp,name,distance\n0.0,a.png,0\n0.1,b.png,2\n0.2,c.png,3\n",
    "name,x,y,z\na.png,0,0,5\nb.png,0,2,7\nc.png,3,2,1\n",
    "frame,heading,y,x\na.png,90,0,0\nb.png,90,2,0\nc.png,0,2,3\n",
])
def test_a_header_picks_its_columns_by_name(tmp_path: Path, text: str) -> None:
    """A log with a timestamp first or a z after x,y was refused ('not a number in a.png,0',
    'got 4 columns'): the header names the columns, so they are taken by name."""
    odo = read_odometry(_write(tmp_path, text))
    assert odo.names == ("a.png", "b.png", "c.png")
    np.testing.assert_allclose(odo.arclength(), [0.0, 2.0, 5.0])


def test_a_row_shorter_than_its_header_is_named(tmp_path: Path) -> None:
    with pytest.raises(WilocError, match="line 3: expected 3 columns, as the header names, got 2"):
        read_odometry(_write(tmp_path, "timestamp,name,distance\n0.0,a.png,0\n0.1,b.png\n"))


def test_names_that_match_no_frame_say_why(tmp_path: Path) -> None:
    odo = read_odometry(_write(tmp_path, "name,distance\n0000,0\n0001,1\n"))
    with pytest.raises(WilocError, match=r"no odometry for 2 frame\(s\), first '0000.jpg' \(names such as '0000' "
                                         r"differ from the frames' in their suffix, such as '0000.jpg'\)"):
        odo.arclength(["0000.jpg", "0001.jpg"])


def test_another_separator_is_named(tmp_path: Path) -> None:
    with pytest.raises(WilocError, match="got 1 columns; columns must be separated by commas"):
        read_odometry(_write(tmp_path, "name;distance\na.png;0\nb.png;1\n"))


def test_gps_positions_give_metres_along_the_earth(tmp_path: Path) -> None:
    """A name,lat,lon log was read as x,y: its arc length came out in degrees (1e-5 'metres' a
    step), and the filter took the robot for standing still."""
    from wiloc.given import EARTH_RADIUS_M

    north = np.degrees(np.array([0.0, 10.0, 25.0]) / EARTH_RADIUS_M)  # 10 m, then 15 m due north
    rows = "".join(f"{name},{float(51.0 + d)!r},-1.0\n" for name, d in zip("abc", north))
    for header in ("name,lat,lon\n", "image,Latitude,Longitude\n"):
        np.testing.assert_allclose(read_odometry(_write(tmp_path, header + rows)).arclength(), [0.0, 10.0, 25.0],
                                   rtol=1e-9)
    with pytest.raises(WilocError, match=r"lat must lie in \[-90, 90\]"):
        read_odometry(_write(tmp_path, "name,lat,lon\na,95,0\nb,96,0\n"))


@pytest.mark.parametrize(("values", "doubted"), [(np.arange(30.0), True),  # distances from the start
                                                  (1.0 + 0.1 * np.sin(np.arange(30.0)), False),  # steps
                                                  (np.linspace(0.5, 3.0, 30), False),  # steps, speeding up
                                                  (np.arange(10.0), False)])  # too few rows to tell
def test_distances_that_only_grow_tenfold_are_doubted_as_from_the_start(tmp_path: Path, values: np.ndarray,
                                                                        doubted: bool) -> None:
    """A name,distance file of distances from the start would be summed again into a route that
    grows quadratically: said in one line naming the file, not refused (a vehicle may speed up)."""
    path = _write(tmp_path, "name,distance\n" + "".join(f"f{i},{v}\n" for i, v in enumerate(values)))
    doubt = read_odometry(path).doubt()
    assert (doubt is not None) == doubted
    if doubted:
        assert doubt.startswith(f"odometry {path}: its distances only grow (0 to 29)")
    positions = _write(tmp_path, "name,x,y\n" + "".join(f"f{i},{v},0\n" for i, v in enumerate(values)))
    assert read_odometry(positions).doubt() is None


def test_a_run_with_distances_from_the_start_warns_of_them(demo_route: demo.DemoRoute, tmp_path: Path,
                                                          cache_dir: Path) -> None:
    query = demo_route.queries[0]
    names = [p.name for p in api.frames(query)]
    cumulative = _write(tmp_path, "".join(f"{name},{i}\n" for i, name in enumerate(names)))
    run = api.localize(query, reference=demo_route.reference, method="catgraph", odometry=cumulative,
                       map_odometry=demo_route.positions / "reference.csv", out=tmp_path / "run.csv")
    assert [w for w in run.warnings if w.startswith(f"odometry {cumulative}")] != []


def test_steps_are_the_files_own_distances_summed_over_rows_left_out(tmp_path: Path) -> None:
    """A batch run differenced the cumulative sum again: its steps differed from the file's
    distances in the last bits (589 of 599 on a random log), and catgraph's draws with them."""
    values = np.random.default_rng(1).uniform(0.3, 2.7, 300).round(7)
    odo = read_odometry(_write(tmp_path, "".join(f"f{i},{float(v)!r}\n" for i, v in enumerate(values))))
    names = [f"f{i}" for i in range(300)]
    np.testing.assert_array_equal(odo.steps(names), np.r_[0.0, values[1:]])
    assert not np.array_equal(steps(odo.arclength(names)), np.r_[0.0, values[1:]])  # what a run gave before
    np.testing.assert_array_equal(odo.steps(["f0", "f2", "f3"]), [0.0, values[1] + values[2], values[3]])
    xy = read_odometry(_write(tmp_path, "name,x,y\nc,3,10\na,0,0\nb,3,4\n"))
    np.testing.assert_array_equal(xy.steps(["a", "b", "c"]), [0.0, 5.0, 6.0])


def test_distance_rows_out_of_the_frames_order_are_named(tmp_path: Path) -> None:
    """A log sorted as text (img10 before img2) was read as negative steps: "query frame 10: the
    step must be finite and >= 0, got -187.0", naming neither the file nor the cause."""
    path = _write(tmp_path, "".join(f"img{i},1\n" for i in sorted(range(12), key=str)))
    names = [f"img{i}" for i in range(12)]
    for read in (read_odometry(path).steps, read_odometry(path).arclength):
        with pytest.raises(WilocError, match=r"its rows are not in the frames' order: 'img10' comes before 'img9'") as err:
            read(names)
        assert err.value.where == str(path)


def test_a_batch_run_with_odometry_decides_as_the_localizer_given_the_files_distances(
        demo_route: demo.DemoRoute, tmp_path: Path, cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """catgraph in sequence mode with a name,distance log of fractional distances: the batch run
    gave the filter the arc length differenced again, where Localizer.observe(odometry=d) gives the
    file's d, so the two decided other matches (88 of 600 on Nordland). Both now step the filter
    with the file's own numbers and write the same rows."""
    import csv

    from wiloc.localization.localizer import Localizer
    from wiloc.methods.catgraph.filter import CatGraph

    query = demo_route.queries[0]
    frames = list(api.frames(query))
    distances = np.random.default_rng(2).uniform(0.3, 2.7, len(frames)).round(7)
    log = _write(tmp_path, "".join(f"{p.name},{float(d)!r}\n" for p, d in zip(frames, distances)))
    given: list[float | None] = []
    step = CatGraph.step

    def recorded(self: CatGraph, row: np.ndarray, odometry: float | None = None, ahead: object = None) -> object:
        given.append(odometry)
        return step(self, row, odometry, ahead)

    monkeypatch.setattr(CatGraph, "step", recorded)
    batch = api.localize(query, method="catgraph", odometry=log, out=tmp_path / "batch.csv")
    stepped, given[:] = given[-len(frames):], []
    assert stepped == [0.0, *distances[1:].tolist()]
    loc = Localizer(None, descriptor="sad", method="catgraph")
    for i, (path, distance) in enumerate(zip(frames, distances)):
        loc.observe(path, odometry=None if i == 0 else float(distance))
    loc.results(query=query).save(tmp_path / "live.csv")

    def rows(path: Path) -> list[dict[str, str]]:
        return list(csv.DictReader(line for line in path.read_text().splitlines() if not line.startswith("#")))

    assert batch.path is not None and rows(batch.path) == rows(tmp_path / "live.csv")

"""benchmarks/bench_pace.py: the variants' frame indices and ground truth, and that a variant run
on re-sampled descriptor rows decides as ``wiloc localize`` does on folders holding those frames."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import benchmark_module
from wiloc.descriptors.registry import get_descriptor


@pytest.fixture(scope="module")
def bench():
    with benchmark_module("bench_pace") as module:
        yield module


@pytest.fixture
def shared_cache(real_data_cache: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The session's real-data cache as ``WILOC_CACHE``, which the benchmark reads its traversals
    through: Gardens Point's descriptors and differences are described once a session, not once a test."""
    monkeypatch.setenv("WILOC_CACHE", str(real_data_cache))
    return real_data_cache


def by_name(bench, n: int) -> dict:
    return {v.name: v for v in bench.variants(n)}


def test_every_variant_is_built_in_order_and_within_the_route(bench) -> None:
    made = bench.variants(200)
    assert [v.name for v in made] == list(bench.VARIANTS)
    for v in made:
        assert v.query_frames.min() >= 0 and v.query_frames.max() < 200
        assert np.all(np.diff(v.map_frames) > 0) and v.map_frames[0] == 0
        assert v.truth.shape == v.query_frames.shape
        assert v.truth.min() >= 0 and v.truth.max() < v.map_frames.size
        # the true node is the kept map frame nearest the query's original frame
        gap = np.abs(v.map_frames[v.truth] - v.query_frames)
        nearest = np.abs(v.map_frames[None, :] - v.query_frames[:, None]).min(axis=1)
        np.testing.assert_array_equal(gap, nearest)
    assert [v.name for v in bench.variants(50, ["jump", "same"])] == ["jump", "same"]
    with pytest.raises(ValueError, match="unknown variant"):
        bench.variants(50, ["sideways"])


def test_same_reversed_and_query_paces(bench) -> None:
    n = 30
    v = by_name(bench, n)
    np.testing.assert_array_equal(v["same"].query_frames, np.arange(n))
    np.testing.assert_array_equal(v["same"].truth, np.arange(n))
    np.testing.assert_array_equal(v["reversed"].query_frames, n - 1 - np.arange(n))
    np.testing.assert_array_equal(v["reversed"].truth, n - 1 - np.arange(n))  # frame k -> node n-1-k
    np.testing.assert_array_equal(v["pace-2"].query_frames, np.arange(0, n, 2))
    np.testing.assert_array_equal(v["pace-3"].truth, np.arange(0, n, 3))
    for name in ("same", "reversed", "pace-2", "pace-3", "stop", "u-turn", "jump"):
        np.testing.assert_array_equal(v[name].map_frames, np.arange(n))


def test_thinned_maps_put_each_query_frame_on_its_nearest_node(bench) -> None:
    v = by_name(bench, 10)
    half = v["pace-1/2"]
    np.testing.assert_array_equal(half.map_frames, [0, 2, 4, 6, 8])
    np.testing.assert_array_equal(half.query_frames, np.arange(10))
    np.testing.assert_array_equal(half.truth, [0, 0, 1, 1, 2, 2, 3, 3, 4, 4])  # ties go to the earlier node
    third = v["pace-1/3"]
    np.testing.assert_array_equal(third.map_frames, [0, 3, 6, 9])
    np.testing.assert_array_equal(third.truth, [0, 0, 1, 1, 1, 2, 2, 2, 3, 3])


def test_stop_u_turn_and_jump_on_the_issue_route_of_200_frames(bench) -> None:
    v = by_name(bench, 200)
    stop = v["stop"].query_frames
    assert stop.size == 219 and np.count_nonzero(stop == 60) == 20
    np.testing.assert_array_equal(np.unique(stop), np.arange(200))
    np.testing.assert_array_equal(v["u-turn"].query_frames, np.r_[np.arange(120), np.arange(119, 39, -1)])
    np.testing.assert_array_equal(v["u-turn"].truth, v["u-turn"].query_frames)
    np.testing.assert_array_equal(v["jump"].query_frames, np.r_[0:80, 150:200, 80:150])
    longer = by_name(bench, 1000)["stop"].query_frames  # a stop of 10-20 frames every 200 frames
    held = [np.count_nonzero(longer == at) for at in (60, 260, 460, 660, 860)]
    assert held[0] == 20 and all(10 <= h <= 20 for h in held)


def test_drift_moves_between_half_and_twice_the_thinned_maps_pace(bench) -> None:
    drift = by_name(bench, 400)["drift"]
    np.testing.assert_array_equal(drift.map_frames, np.arange(0, 400, 2))
    steps = np.diff(drift.query_frames)
    assert steps.min() == 1 and steps.max() == 4  # 0.5 to 2 map nodes per frame
    assert drift.query_frames[0] == 0 and drift.query_frames[-1] >= 396
    np.testing.assert_array_equal(drift.query_frames, by_name(bench, 400)["drift"].query_frames)


def test_truth_is_the_true_node_plus_minus_two(bench) -> None:
    v = by_name(bench, 20)["reversed"]
    known = bench.truth(v)
    dense = known.matrix.toarray()
    assert dense.shape == (20, 20) and known.has_match().all() and not known.sequence
    np.testing.assert_array_equal(np.flatnonzero(dense[0]), [17, 18, 19])  # frame 0 is node 19
    np.testing.assert_array_equal(np.flatnonzero(dense[10]), [7, 8, 9, 10, 11])


def test_off_map_variants_are_built_only_when_named(bench) -> None:
    assert not set(bench.OFF_MAP_VARIANTS) & {v.name for v in bench.variants(200)}
    start, leave = bench.variants(200, ["start-off", "leave"])
    np.testing.assert_array_equal(start.map_frames, np.arange(50, 200))
    np.testing.assert_array_equal(start.query_frames, np.arange(200))
    assert (start.truth[:48] == bench.NO_NODE).all()
    assert start.truth[48] == 0 and start.truth[50] == 0 and start.truth[199] == 149
    np.testing.assert_array_equal(leave.map_frames, np.r_[0:60, 100:200])
    assert leave.truth[59] == 59 and leave.truth[61] == 59 and leave.truth[98] == 60 and leave.truth[100] == 60
    assert (leave.truth[62:98] == bench.NO_NODE).all()


def test_off_map_frames_match_nothing_and_no_frame_matches_across_the_gap(bench) -> None:
    start, leave = bench.variants(200, ["start-off", "leave"])
    has = bench.truth(start).has_match()
    assert not has[:48].any() and has[48:].all()
    dense = bench.truth(leave).matrix.toarray()
    assert not dense[62:98].any()
    np.testing.assert_array_equal(np.flatnonzero(dense[59]), [57, 58, 59])  # nodes 60, 61 are places 100, 101
    np.testing.assert_array_equal(np.flatnonzero(dense[100]), [60, 61, 62])


def synthetic(bench, n: int):
    """A traversal of ``n`` random sad rows, its query the same rows with noise: frame i is place i."""
    rng = np.random.default_rng(0)
    places = rng.integers(0, 256, (n, 1152), dtype=np.uint8)
    query = np.clip(places.astype(int) + rng.integers(-10, 11, places.shape), 0, 255).astype(np.uint8)
    sad = get_descriptor("sad")
    return bench.Traversal(name="synthetic", map_folder=Path("map"), query_folder=Path("query"), descriptor="sad",
                           map_data=places, query_data=query, metric=sad.metric, scale=sad.scale,
                           natural_max=sad.natural_max)


def test_a_run_scores_with_wilocs_measures(bench) -> None:
    n = 60
    trav = synthetic(bench, n)
    variant = by_name(bench, n)["reversed"]
    row = bench.run_variant(trav, variant, "threshold")
    assert row["r1"] == 1.0 and row["frames"] == n and row["map_nodes"] == n
    assert {"ap", "ece", "precision@0.9", "accepted@0.9", "new_place", "new_place_ece", "seconds"} <= set(row)


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["catgraph", "online"])  # online learns from the map's own differences too
def test_a_thinned_map_decides_as_localize_on_a_folder_of_those_frames(bench, data_root: Path, shared_cache: Path,
                                                                      tmp_path: Path, method: str) -> None:
    from wiloc import api

    walk = data_root / "gardens-point-walking"
    trav = bench.load_traversal("day_left/sad", data_root)
    variant = by_name(bench, trav.length)["pace-1/2"]
    thinned = tmp_path / "day_right"
    thinned.mkdir()
    frames = sorted(p.name for p in (walk / "day_right").glob("*.jpg"))
    for i in variant.map_frames:
        shutil.copyfile(walk / "day_right" / frames[i], thinned / frames[i])
    run = api.localize(walk / "day_left", reference=thinned, descriptor="sad", method=method)
    ours = bench.decide(trav, variant, method)
    np.testing.assert_array_equal(ours.match, run.decisions.match)
    np.testing.assert_array_equal(ours.confidence, run.decisions.confidence)


@pytest.mark.realdata
def test_the_command_runs_the_chosen_runs_with_method_parameters(bench, data_root: Path, shared_cache: Path,
                                                                 tmp_path: Path, capsys) -> None:
    out = tmp_path / "rows.json"
    rows = bench.main([str(data_root), "--traversals", "day_left/sad", "--variants", "same,pace-2",
                       "--methods", "catgraph", "--param", "catgraph.particles=500",
                       "--param", "catgraph.sequence_speeds=1", "--json", str(out)])
    assert [(r["variant"], r["method"]) for r in rows] == [("same", "catgraph"), ("pace-2", "catgraph")]
    assert rows[0]["params"] == {"particles": 500, "sequence_speeds": (1.0,), "seed": 0}
    assert rows[0]["r1"] > 0.9 and rows[1]["frames"] == 100
    assert len(json.loads(out.read_text())) == 2
    with pytest.raises(SystemExit):
        bench.main([str(data_root), "--methods", "catgraph", "--param", "catgraph.particles=0"])


@pytest.mark.realdata
def test_held_out_traversals_swap_the_map_and_the_query(bench, data_root: Path, shared_cache: Path) -> None:
    """``--traversals held-out`` runs the five swapped pairs, each map the other's query."""
    rows = bench.main([str(data_root), "--traversals", "held-out,day_left/sad", "--variants", "same",
                       "--methods", "catgraph", "--param", "catgraph.particles=300", "--frames", "60"])
    assert [r["traversal"] for r in rows] == [*bench.HELD_OUT, "day_left/sad"]
    assert [r["map"] for r in rows] == ["day_left"] * 4 + ["winter", "day_right"]
    swapped = bench.load_traversal("day_right-on-day_left/sad", data_root)
    plain = bench.load_traversal("day_left/sad", data_root)
    np.testing.assert_array_equal(swapped.map_data, plain.query_data)
    np.testing.assert_array_equal(swapped.query_data, plain.map_data)
    with pytest.raises(SystemExit):
        bench.main([str(data_root), "--traversals", "held-out/sad"])


def test_seeds_are_listed_once_each_and_runs_merge_into_their_means(bench) -> None:
    assert bench.seed_list("0-2,5, 7-8") == [0, 1, 2, 5, 7, 8]
    for bad in ("", "2-x", "0-2,1", "-1"):
        with pytest.raises(ValueError, match="--seeds"):
            bench.seed_list(bad)
    run = {"traversal": "t", "variant": "same", "method": "catgraph", "ap": 0.5, "ece": 0.1, "new_place": None,
           "new_place_ece": None,
           "seconds": 1.0}
    rows = [{**run, "r1": 0.9, "precision@0.9": 1.0, "accepted@0.9": 10, "params": {"seed": 0}},
            {**run, "r1": 0.6, "precision@0.9": None, "accepted@0.9": 0, "params": {"seed": 1}},
            {**run, "variant": "pace-2", "r1": 0.3, "precision@0.9": 0.5, "accepted@0.9": 3, "params": {"seed": 0}}]
    same, fast = bench.over_seeds(rows)
    assert (same["variant"], same["seeds"], fast["seeds"]) == ("same", [0, 1], [0])
    assert same["r1"] == pytest.approx(0.75) and (same["r1_low"], same["r1_high"]) == (0.6, 0.9)
    assert same["precision@0.9"] == 1.0 and same["accepted@0.9"] == 5  # precision over runs that accepted any
    assert np.isnan(same["new_place"]) and fast["r1"] == 0.3


@pytest.mark.realdata
def test_the_command_runs_each_seed_and_prints_their_means(bench, data_root: Path, shared_cache: Path,
                                                           tmp_path: Path, capsys) -> None:
    out = tmp_path / "rows.json"
    rows = bench.main([str(data_root), "--traversals", "day_left/sad", "--variants", "pace-2",
                       "--methods", "catgraph", "--param", "catgraph.particles=300", "--seeds", "0-1",
                       "--json", str(out)])
    assert [r["params"]["seed"] for r in rows] == [0, 1] and len(json.loads(out.read_text())) == 2
    mean = bench.over_seeds(rows)[0]
    assert mean["r1"] == pytest.approx((rows[0]["r1"] + rows[1]["r1"]) / 2)
    printed = capsys.readouterr().out
    assert f"{mean['r1']:.3f} ({min(r['r1'] for r in rows):.3f}-" in printed and "seeds 0-1 (means" in printed
    for wrong in (["--seeds", "1-x"], ["--param", "catgraph.seed=3"], ["--seed", "1", "--seeds", "2-3"]):
        with pytest.raises(SystemExit):
            bench.main([str(data_root), "--methods", "catgraph", *wrong])


def test_odometry_steps_measure_how_far_not_which_way_with_the_noise_asked_for(bench) -> None:
    n = 200
    variants = by_name(bench, n)
    reversed_steps = bench.odometry_steps(variants["reversed"], 0.0)
    np.testing.assert_array_equal(reversed_steps, np.r_[0.0, np.ones(n - 1)])
    stop = variants["stop"]
    steps = bench.odometry_steps(stop, 0.0)
    repeated = np.r_[False, np.diff(stop.query_frames) == 0]
    assert repeated.sum() >= 19 and np.all(steps[repeated] == 0) and np.all(steps[~repeated][1:] == 1)
    np.testing.assert_array_equal(bench.odometry_steps(variants["pace-3"], 0.0)[1:], 3.0)
    np.testing.assert_allclose(bench.odometry_steps(variants["pace-3"], 0.0, factor=1.1)[1:], 3.3)
    noisy = bench.odometry_steps(variants["pace-3"], 0.5)
    np.testing.assert_array_equal(noisy, bench.odometry_steps(variants["pace-3"], 0.5))  # one draw for every run
    assert noisy.min() >= 0.0 and 0.3 < np.std(noisy[1:] / 3.0) < 0.7 and not np.all(noisy[1:] == 3.0)


def test_odometry_goes_to_the_methods_that_take_it(bench) -> None:
    """catgraph runs with the query's steps and the map's positions (as with odometry CSVs);
    threshold, which takes none, runs as without."""
    n = 60
    trav = synthetic(bench, n)
    variant = by_name(bench, n)["pace-2"]
    with_odometry = bench.run_variant(trav, variant, "catgraph", odometry=0.0)
    without = bench.run_variant(trav, variant, "catgraph")
    assert (with_odometry["odometry"], without["odometry"]) == (0.0, None)
    assert bench.decide(trav, variant, "catgraph", odometry=0.0).params["odometry"] is True
    assert bench.decide(trav, variant, "catgraph").params["odometry"] is False
    assert bench.run_variant(trav, variant, "threshold", odometry=0.0)["odometry"] is None


def test_the_acceptance_counts_the_ratios_bars_and_rows_above_seqslam(bench) -> None:
    def run(method: str, traversal: str, variant: str, r1: float, ece: float = 0.01, precision: float | None = 1.0,
            accepted: int = 5) -> dict:
        return {"method": method, "traversal": traversal, "variant": variant, "r1": r1, "ece": ece,
                "precision@0.9": precision, "accepted@0.9": accepted}

    rows = [run("catgraph", "day_left/sad", "same", 1.0), run("catgraph", "day_left/sad", "pace-2", 0.94),
            run("catgraph", "night_right/sad", "same", 0.8, ece=0.2), run("catgraph", "night_right/sad", "pace-2", 0.72),
            run("catgraph", "night_right/sad", "jump", 0.71, precision=0.5),
            run("catgraph", "night_right/sad", "drift", 0.1, precision=None, accepted=0),
            run("seqslam", "day_left/sad", "same", 0.5), run("seqslam", "night_right/sad", "drift", 0.2)]
    catgraph, seqslam = bench.acceptance(rows)
    # day_left needs 0.95 of its same pace (0.94 falls short); night_right 0.9 (0.72 holds, 0.71 not)
    assert (catgraph["ratio_held"], catgraph["ratio_runs"]) == (1, 4)
    assert catgraph["ratio_failed"] == ["day_left/sad pace-2 0.940", "night_right/sad jump 0.710",
                                        "night_right/sad drift 0.100"]
    assert (catgraph["ece_held"], catgraph["precision_held"], catgraph["runs"]) == (5, 5, 6)
    assert (catgraph["above_seqslam"], catgraph["versus_seqslam"]) == (1, 2)
    assert catgraph["mean_r1"] == pytest.approx((1.0 + 0.94 + 0.8 + 0.72 + 0.71 + 0.1) / 6)
    assert seqslam["versus_seqslam"] == 0 and seqslam["ratio_runs"] == 0  # its drift has no same-pace run


@pytest.mark.parametrize(("args", "code", "line"), [
    (["--frames", "0"], 2, "error: --frames must be at least 10, got 0"),
    (["--frames", "-3"], 2, "error: --frames must be at least 10, got -3"),
    (["--methods", "catgrap"], 2, "error: --methods: unknown method 'catgrap' (choose from "),
    (["--methods", "catgraph,bogus"], 2, "error: --methods: unknown method 'bogus' (choose from "),
    (["--json", "{tmp}/missing/rows.json"], 2,
     "error: --json {tmp}/missing/rows.json: folder {tmp}/missing does not exist"),
    (["--json", "{tmp}/file/rows.json"], 2, "error: --json {tmp}/file/rows.json: {tmp}/file is not a folder"),
    (["--json", "{tmp}"], 2, "error: --json {tmp}: is a folder"),
    ([], 1, "{tmp}/no-data/gardens-point-walking/day_right: folder does not exist"),
])
def test_bad_options_and_missing_data_are_one_line(bench, args: list[str], code: int, line: str, tmp_path: Path,
                                                   cache_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").touch()
    with pytest.raises(SystemExit) as ended:
        bench.main([str(tmp_path / "no-data"), "--traversals", "day_left/sad", "--variants", "same",
                    "--methods", "threshold", *(arg.format(tmp=tmp_path) for arg in args)])
    out, err = capsys.readouterr()
    assert ended.value.code == code and line.format(tmp=tmp_path) in err.strip().splitlines()[-1]
    assert "Traceback" not in err and "runs in" not in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # nothing described or written

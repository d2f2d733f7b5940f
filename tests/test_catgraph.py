"""Tests of the whole-image CAT-Graph particle filter on synthetic traversals with known truth."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from wiloc.cache.store import Cache
from wiloc.decisions import Decisions
from wiloc.errors import ParameterError, WilocError
from wiloc.localization.array_run import run_on_rows
from wiloc.methods import base
from wiloc.methods.catgraph.filter import CatGraph
from wiloc.methods.catgraph.paces import odometry_factors
from wiloc.methods.catgraph.trajectory import (contrast_normalise, even_shifted_reads, posterior_ranking, read_runs,
                                               shifted_reads)

from helpers import loop_rows

N_REF = 300
TOL = 2


def _rows(truth: np.ndarray, n_ref: int, rng: np.random.Generator, noise: float = 0.08,
          depth: float = 0.65, width: float = 1.5) -> np.ndarray:
    """Differences to every node: a dip of ``depth`` (sd ``width`` nodes) around the true
    position, ~1 elsewhere.

    ``truth`` holds the true (continuous) node position per frame, NaN for an unmapped place.
    """
    j = np.arange(n_ref, dtype=np.float64)
    offset = np.where(np.isnan(truth), np.inf, truth)[:, None] - j[None, :]
    dip = depth * np.exp(-0.5 * (offset / width) ** 2)
    return 1.0 + noise * rng.standard_normal((truth.size, n_ref)) - dip


def _ref_self(rng: np.random.Generator) -> np.ndarray:
    return _rows(np.arange(N_REF, dtype=np.float64), N_REF, rng)


def localize_catgraph(rows, ref, n: int, *, ref_arclength=None, query_steps=None, exclude_recent: int = 10,
                      progress=None, **params) -> Decisions:
    """A catgraph run on arrays, with every parameter at its default unless given."""
    return run_on_rows(CatGraph(**params), rows, n, map_self=ref, exclude_recent=exclude_recent,
                       arclength=ref_arclength, odometry=query_steps, progress=progress)


def _hits(match: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.abs(match - np.round(truth)) <= TOL


@pytest.mark.parametrize("speed", [0.5, 1.5, 2.0])
def test_tracks_query_at_other_speed_than_map_with_odometry(speed: float) -> None:
    rng = np.random.default_rng(1)
    truth = 10.0 + speed * np.arange(int(270 / speed))  # the query covers `speed` nodes per frame
    dec = localize_catgraph(iter(_rows(truth, N_REF, rng)), _ref_self(rng), truth.size,
                            ref_arclength=np.arange(float(N_REF)), query_steps=np.r_[0.0, np.diff(truth)])
    assert _hits(dec.match[20:], truth[20:]).mean() >= 0.9


@pytest.mark.parametrize("speed", [1 / 3, 0.5, 2 / 3, 1.5, 2.0, -1.0, -1.5])
def test_without_odometry_re_seeded_particles_carry_the_pace_of_their_sequence(speed: float) -> None:
    # Re-seeded particles move at the pace whose sequence trajectory scored best at their node, so
    # the default follows a query at another pace than the map's, or driving the route the other
    # way; with a sequence score of the map's pace alone every particle moves at that pace and
    # the track is lost.
    rng = np.random.default_rng(1)
    start = 10.0 if speed > 0 else N_REF - 10.0
    truth = start + speed * np.arange(int(270 / abs(speed)))
    rows, ref = _rows(truth, N_REF, rng), _ref_self(rng)
    assert _hits(localize_catgraph(iter(rows), ref, truth.size).match[20:], truth[20:]).mean() >= 0.9
    one_pace = localize_catgraph(iter(rows), ref, truth.size, sequence_speeds=(1.0,))
    assert _hits(one_pace.match[20:], truth[20:]).mean() < 0.5


@pytest.mark.parametrize("speed", [1 / 3, 3.0, -1.0, -0.5])
def test_with_odometry_a_pace_is_a_direction_and_the_odometry_says_how_far(speed: float) -> None:
    # Odometry measures how far the query went, not which way (the route driven backwards
    # travels a positive distance): every particle's pace becomes +-1 at the first frame with
    # odometry (times its factor near 1, odometry_scale), and the query is followed at a third or
    # three times the map's node spacing a frame, or backwards.
    rng = np.random.default_rng(1)
    start = 10.0 if speed > 0 else N_REF - 10.0
    truth = start + speed * np.arange(int(270 / abs(speed)))
    rows, ref, steps = _rows(truth, N_REF, rng), _ref_self(rng), np.r_[0.0, np.abs(np.diff(truth))]
    for scale in (0.0, 0.05):
        method = CatGraph(odometry_scale=scale, odometry_scale_wide=0.0)
        dec = run_on_rows(method, iter(rows), truth.size, map_self=ref, arclength=np.arange(float(N_REF)),
                          odometry=steps)
        assert _hits(dec.match[20:], truth[20:]).mean() >= 0.9 and dec.params["odometry"] is True
        factors = np.abs(method._speed)
        assert np.all(factors == 1.0) if scale == 0 else (np.all(np.abs(np.log(factors)) < 6 * scale)
                                                          and np.any(factors != 1.0))


@pytest.mark.parametrize("factor, wide", [(0.85, 0.0), (1.2, 0.0), (0.7, 0.3), (1.35, 0.3)])
def test_with_odometry_a_scale_the_query_and_the_map_disagree_by_is_learned(factor: float, wide: float) -> None:
    # The query's odometry reads short or long against the map's, on weak evidence: with paces of
    # exactly +-1 the cloud runs ahead or falls behind; each particle's own factor
    # (odometry_scale) lets the ones that fit take over, and where the two disagree by a third,
    # the tenth of the factors drawn wider (odometry_scale_wide) do.
    rng = np.random.default_rng(5)
    truth = 10.0 + np.arange(280.0)
    rows, ref, steps = _rows(truth, N_REF, rng, depth=0.15), _ref_self(rng), factor * np.r_[0.0, np.ones(279)]
    hits = {(scale, spread): _hits(localize_catgraph(iter(rows), ref, truth.size, ref_arclength=np.arange(float(N_REF)),
                                                     query_steps=steps, odometry_scale=scale,
                                                     odometry_scale_wide=spread).match[40:], truth[40:]).mean()
            for scale, spread in ((0.0, 0.0), (0.05, 0.0), (0.05, wide))}
    assert hits[0.05, wide] >= 0.9 and hits[0.05, wide] > hits[0.0, 0.0]
    if wide:
        assert hits[0.05, 0.0] < 0.5


def test_odometry_factors_a_tenth_drawn_wider() -> None:
    rng = np.random.default_rng(0)
    assert np.all(odometry_factors(0.0, 0.0, rng, 100) == 1.0)
    narrow = np.abs(np.log(odometry_factors(0.05, 0.0, rng, 10_000)))
    assert narrow.max() < 0.3 and narrow.min() > 0
    both = np.abs(np.log(odometry_factors(0.05, 0.3, rng, 10_000)))
    assert 0.02 < (both > 0.3).mean() < 0.045  # a tenth from sd 0.3, of which a third lie beyond 0.3


def test_with_odometry_a_restored_state_keeps_the_paces_as_directions() -> None:
    rng = np.random.default_rng(4)
    truth = 10.0 + 0.5 * np.arange(200)
    rows, ref, steps = _rows(truth, N_REF, rng), _ref_self(rng), np.r_[0.0, np.diff(truth)]
    whole = CatGraph(seed=3)
    expected = run_on_rows(whole, iter(rows), truth.size, map_self=ref, arclength=np.arange(float(N_REF)),
                           odometry=steps)
    first = CatGraph(seed=3)
    run_on_rows(first, iter(rows[:30]), 30, map_self=ref, arclength=np.arange(float(N_REF)), odometry=steps[:30])
    resumed = CatGraph(seed=3)
    resumed.restore(first.context, copy.deepcopy(first.state()))
    later = [resumed.step(row, odometry=float(step)) for row, step in zip(rows[30:], steps[30:])]
    assert [d.match for d in later] == expected.match[30:].tolist()
    assert [d.confidence for d in later] == expected.confidence[30:].tolist()


def test_finds_track_where_a_map_stretch_resembles_every_frame() -> None:
    # Nodes 100-159 look 0.25 closer to every query frame (a tunnel, snow): single frames match
    # there (true node best for 10 % of frames), so particles re-seeded at single-frame matches
    # would go there; the contrast-normalised sequence score finds the track.
    rng = np.random.default_rng(11)
    truth = np.arange(20.0, 100.0)
    alike = np.where((np.arange(N_REF) >= 100) & (np.arange(N_REF) < 160), -0.25, 0.0)
    rows = _rows(truth, N_REF, rng, depth=0.3) + alike
    assert _hits(rows.argmin(axis=1), truth).mean() < 0.2
    dec = localize_catgraph(iter(rows), _ref_self(rng), truth.size)
    assert _hits(dec.match[40:], truth[40:]).mean() >= 0.9


def test_relocalises_after_a_jump_along_the_map() -> None:
    # The query jumps 80 nodes ahead (kidnapped): the jump prior (0.001 per frame) makes the
    # filter wait for a settled sequence score before it believes the jump.
    rng = np.random.default_rng(11)
    truth = np.r_[np.arange(20.0, 100.0), np.arange(180.0, 300.0)]
    dec = localize_catgraph(iter(_rows(truth, N_REF, rng, depth=0.3)), _ref_self(rng), truth.size)
    hits = _hits(dec.match, truth)
    assert hits[40:80].mean() >= 0.9 and hits[150:].mean() >= 0.9


def test_contrast_normalise_removes_what_a_stretch_shares() -> None:
    row = np.ones(60)
    row[30:] -= 0.5  # a stretch closer to everything
    row[10] -= 0.3  # the true place, a dip outside it
    z = contrast_normalise(row, 5)
    assert row.argmin() != 10 and z.argmin() == 10
    assert z.shape == row.shape and np.all(np.isfinite(z))
    np.testing.assert_array_equal(contrast_normalise(np.full(20, 0.7), 3), 0.0)


def test_tracks_with_odometry_steps() -> None:
    rng = np.random.default_rng(2)
    arc = np.cumsum(rng.uniform(0.5, 1.5, N_REF))  # uneven node spacing in metres
    truth_m = np.linspace(arc[5], arc[-5], 150)
    truth = np.interp(truth_m, arc, np.arange(N_REF, dtype=np.float64))
    steps = np.r_[0.0, np.diff(truth_m)]
    dec = localize_catgraph(iter(_rows(truth, N_REF, rng)), _ref_self(rng), truth.size,
                            ref_arclength=arc, query_steps=steps)
    assert _hits(dec.match[20:], truth[20:]).mean() >= 0.9


def test_detour_raises_new_place_and_relocalizes() -> None:
    rng = np.random.default_rng(3)
    truth = np.arange(20.0, 220.0)
    detour = slice(80, 110)  # 30 frames through places absent from the map
    truth[detour] = np.nan
    truth[110:] += 60.0  # rejoins the map further along
    dec = localize_catgraph(iter(_rows(truth, N_REF, rng)), _ref_self(rng), truth.size)
    p_new = dec.columns["new_place"]
    assert p_new[detour].mean() > 0.3 and p_new[detour].mean() > 20 * p_new[30:80].mean()
    assert _hits(dec.match[30:80], truth[30:80]).mean() >= 0.9
    relocalize = 10
    assert _hits(dec.match[110 + relocalize:], truth[110 + relocalize:]).mean() >= 0.9
    # confidence drops while the filter is lost
    assert np.median(dec.confidence[detour]) < np.median(dec.confidence[30:80])


def test_map_frames_left_out_keep_their_place_in_the_nodes_count() -> None:
    # A map folder whose every 20th frame could not be read: the kept frames' rows, and their
    # positions in the map's full order. Counted by the frames kept, the track runs one node
    # ahead after each gap, while the query moves one frame of the full order a frame (a route
    # whose neighbouring frames look alike over several nodes, as real ones do).
    rng = np.random.default_rng(3)
    kept = np.delete(np.arange(N_REF), np.arange(15, N_REF, 20))
    truth = np.arange(N_REF, dtype=np.float64)  # the query retraces the full route, frame by frame
    rows = _rows(truth, N_REF, rng, width=8.0)[:, kept]
    ref = _rows(truth, N_REF, rng, width=8.0)[np.ix_(kept, kept)]
    steps = ref[np.arange(kept.size - 1), np.arange(1, kept.size)]

    def hits(positions: np.ndarray | None) -> float:
        method = CatGraph()
        method.start(base.MapContext(sequence=False, exclude_recent=10, n_map=kept.size, frame_positions=positions,
                                     neighbours=lambda: steps))
        match = method.run(iter(rows), truth.size).match
        return float((np.abs(kept[match] - truth) <= TOL).mean())

    assert hits(kept.astype(np.float64)) >= 0.95
    assert hits(None) < 0.9


def test_query_frames_left_out_are_stepped_across() -> None:
    # A query folder whose every 10th frame could not be read: the kept frames' rows, and the
    # frames passed before each. Stepped one frame a row, the track falls a node behind at each
    # gap; stepped across the frames passed (Method.skip, run's passed), it keeps the place.
    rng = np.random.default_rng(3)
    truth = np.arange(N_REF, dtype=np.float64)
    kept = np.delete(np.arange(N_REF), np.arange(5, N_REF, 10))
    rows = _rows(truth, N_REF, rng, width=8.0)[kept]
    ref = _ref_self(rng)
    passed = np.diff(kept, prepend=-1) - 1

    def hits(given: np.ndarray | None) -> float:
        method = CatGraph()
        method.start(base.MapContext(sequence=False, exclude_recent=10, n_map=N_REF,
                                     neighbours=lambda: ref[np.arange(N_REF - 1), np.arange(1, N_REF)]))
        match = method.run(iter(rows), kept.size, passed=given).match
        assert method.passed == 0
        return float((np.abs(match - truth[kept]) <= TOL).mean())

    assert hits(passed) >= 0.95
    assert hits(None) < 0.9


def test_frames_passed_are_kept_in_a_state_and_checked() -> None:
    method = CatGraph()
    method.start(base.MapContext(sequence=False, exclude_recent=10, n_map=N_REF,
                                 neighbours=lambda: np.ones(N_REF - 1)))
    method.skip(2)
    assert method.elapsed == 3
    state = method.state()
    restored = CatGraph()
    restored.restore(method.context, state)
    assert restored.passed == 2
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ParameterError, match="frames"):
            method.skip(bad)


def test_a_query_driving_on_past_the_end_of_the_map_is_off_it() -> None:
    # The map's last 100 places, then 30 frames on past its end (ground the map does not hold). A
    # particle carried past an end is re-seeded and its weight goes to the unexplained hypothesis:
    # nothing there is claimed. Held at the end (before), particles stood on the last nodes and
    # matches beyond the end reached confidence 0.72 (P(new place) 0.87 on average).
    rng = np.random.default_rng(0)
    truth = np.r_[np.arange(200.0, 300.0), np.full(30, np.nan)]
    dec = localize_catgraph(iter(_rows(truth, N_REF, rng)), _ref_self(rng), truth.size)
    beyond = slice(105, 130)
    assert _hits(dec.match[20:100], truth[20:100]).mean() >= 0.9
    assert dec.confidence[beyond].max() < 0.2
    assert dec.columns["new_place"][beyond].mean() > 0.9


def test_weight_carried_past_the_ends_moves_from_the_track_to_the_unexplained() -> None:
    from wiloc.methods.catgraph.observation import Transition
    prior = Transition(track=0.7, jump=0.1, unexplained=0.2)
    moved = prior.beyond(0.25)
    assert moved.track == pytest.approx(0.525) and moved.unexplained == pytest.approx(0.375)
    assert moved.jump == 0.1 and moved.track + moved.jump + moved.unexplained == pytest.approx(1.0)
    assert prior.beyond(0.0) == prior


def test_an_image_repeated_exactly_is_evidence_once() -> None:
    # A camera standing still on one place: 16 frames. Nearly repeated images (each with its own
    # noise) are evidence each time, and the track becomes sure; the same image repeated exactly
    # holds nothing the first did not, so nothing is learned from it and nothing grows surer.
    rng = np.random.default_rng(5)
    truth = np.r_[np.full(16, 100.0), np.arange(101.0, 200.0)]
    nearly, ref = _rows(truth, N_REF, rng), _ref_self(rng)
    exactly = nearly.copy()
    exactly[1:16] = exactly[0]
    standing = localize_catgraph(iter(nearly), ref, truth.size)
    frozen = localize_catgraph(iter(exactly), ref, truth.size)
    assert standing.confidence[15] >= 0.9 and standing.columns["new_place"][15] < standing.columns["new_place"][0]
    np.testing.assert_array_equal(frozen.columns["new_place"][:16], frozen.columns["new_place"][0])
    assert frozen.confidence[:16].max() < 0.6
    assert _hits(frozen.match[40:], truth[40:]).mean() >= 0.9


def test_a_stop_on_one_repeated_image_is_followed_whichever_it_was() -> None:
    # An image repeated for 20 frames: the query stood still (a stop), or moved on while its
    # camera repeated the image (a frozen video). Either way the track is right 10 frames after it.
    rng = np.random.default_rng(6)
    ref = _ref_self(rng)
    moving = np.arange(20.0, 220.0)
    stop = np.r_[np.arange(20.0, 80.0), np.full(20, 80.0), np.arange(81.0, 201.0)]
    for truth in (stop, moving):
        rows = _rows(truth, N_REF, rng)
        rows[61:80] = rows[60]
        after = slice(90, None)
        assert _hits(localize_catgraph(iter(rows), ref, truth.size).match[after], truth[after]).mean() >= 0.9


def test_while_an_image_repeats_the_group_moving_on_is_unsure_of_its_pace_so_the_stop_is_decided() -> None:
    # A stop on one repeated image: half of the particles stand, half move on. At one exact pace
    # the two groups are equally narrow and the read-out takes either, by the draw; moving on at a
    # pace known only roughly, the moving group spreads and the standing one holds the decision.
    rng = np.random.default_rng(9)
    ref = _ref_self(rng)
    stop = np.r_[np.arange(20.0, 80.0), np.full(20, 80.0), np.arange(81.0, 201.0)]
    rows = _rows(stop, N_REF, rng)
    rows[61:80] = rows[60]

    def worst(spread: float) -> float:
        return min(float(_hits(localize_catgraph(iter(rows), ref, stop.size, repeat_pace_spread=spread,
                                                 seed=seed).match[60:80], stop[60:80]).mean()) for seed in range(6))

    assert worst(0.1) >= 0.75
    assert worst(0.0) < 0.5
    whole = localize_catgraph(iter(rows), ref, stop.size)  # restored mid-stop, it moves on as it would have
    first = CatGraph()
    run_on_rows(first, iter(rows[:70]), 70, map_self=ref)
    resumed = CatGraph()
    resumed.restore(first.context, copy.deepcopy(first.state()))
    assert [resumed.step(row).match for row in rows[70:]] == whole.match[70:].tolist()


def test_with_odometry_a_repeated_image_moves_as_the_odometry_says() -> None:
    # A camera frozen for 20 frames while the query drives on: the odometry says it moved, so
    # every particle moves with it and the decisions follow the query through the frozen stretch,
    # however likely standing still is without odometry.
    rng = np.random.default_rng(7)
    truth = np.arange(20.0, 220.0)
    rows = _rows(truth, N_REF, rng)
    rows[61:80] = rows[60]
    dec = localize_catgraph(iter(rows), _ref_self(rng), truth.size, ref_arclength=np.arange(float(N_REF)),
                            query_steps=np.r_[0.0, np.diff(truth)], repeat_standing=0.9)
    assert _hits(dec.match[61:80], truth[61:80]).mean() >= 0.9


def test_same_seed_same_decisions_other_seed_differs() -> None:
    rng = np.random.default_rng(4)
    truth = np.arange(100.0)
    rows, ref = _rows(truth, N_REF, rng), _ref_self(rng)
    a = localize_catgraph(iter(rows), ref, truth.size, seed=7)
    b = localize_catgraph(iter(rows), ref, truth.size, seed=7)
    c = localize_catgraph(iter(rows), ref, truth.size, seed=8)
    for x, y in [(a.match, b.match), (a.confidence, b.confidence),
                 (a.columns["new_place"], b.columns["new_place"])]:
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a.confidence, c.confidence)


def test_output_shape_model_and_params() -> None:
    rng = np.random.default_rng(5)
    truth = np.arange(40.0)
    rows = _rows(truth, N_REF, rng)
    calls: list[tuple[int, int]] = []
    dec = localize_catgraph(iter(rows), _ref_self(rng), truth.size, particles=300,
                            progress=lambda done, total: calls.append((done, total)))
    assert len(dec) == truth.size and set(dec.stage) == {"track"}
    assert dec.decided.all()
    np.testing.assert_array_equal(dec.difference, rows[np.arange(truth.size), dec.match])
    assert np.all((dec.confidence >= 0) & (dec.confidence <= 1))
    assert dec.model is None  # no histogram model: the observation model is the rank likelihood
    assert dec.params["particles"] == 300 and dec.params["method"] == "catgraph"
    assert 0.02 <= dec.params["learned_a"] < 1.0 and 0 < dec.params["departure_share"] <= 1
    assert calls[-1] == (truth.size, truth.size) and len(calls) == truth.size
    learned = (dec.params["learned_a"], dec.params["departure_share"])  # the table's 9 digits, not a CPU's last bits
    assert [float(f"{value:.9g}") for value in learned] == list(learned)


@pytest.mark.parametrize("kwargs, where", [
    ({"particles": 0}, "particles"),
    ({"particles": 1.5}, "particles"),
    ({"leave": 1.0}, "leave"),
    ({"stretch_close": 0.6}, "stretch_close"),
    ({"departure_prior": (0.0, 1.0)}, "departure_prior"),
    ({"sequence_rate": 0.0}, "sequence_rate"),
    ({"sequence_speeds": ()}, "sequence_speeds"),
    ({"sequence_speeds": (1.0, 0.0)}, "sequence_speeds"),
    ({"sequence_speeds": (0.25, -0.25), "rank_pace_min": 0.5}, "rank_pace_min"),
    ({"speed_range": (2.0, 1.0)}, "speed_range"),
    ({"contrast_window": 0}, "contrast_window"),
    ({"seed": -1}, "seed"),
    ({"bin": 50}, "bin"),
    ({"ref_arclength": np.arange(N_REF - 1.0)}, "map_odometry"),
    ({"ref_arclength": np.r_[np.arange(N_REF - 1.0), 0.0]}, "map_odometry"),
    ({"ref_arclength": np.zeros(N_REF)}, "map_odometry"),
    ({"query_steps": np.ones(10)}, "odometry"),
    ({"ref_arclength": np.arange(float(N_REF)), "query_steps": -np.ones(10)}, "odometry"),
])
def test_bad_parameters_raise_naming_the_parameter(kwargs: dict, where: str) -> None:
    rng = np.random.default_rng(8)
    rows = _rows(np.arange(10.0), N_REF, rng)
    with pytest.raises(WilocError) as err:
        localize_catgraph(iter(rows), _ref_self(rng), 10, **kwargs)
    assert err.value.parameter == where and err.value.where == where


def test_row_count_must_match_n_frames() -> None:
    rng = np.random.default_rng(9)
    rows = _rows(np.arange(10.0), N_REF, rng)
    with pytest.raises(WilocError, match="expected n_frames=11"):
        localize_catgraph(iter(rows), _ref_self(rng), 11)
    with pytest.raises(WilocError, match="more difference rows"):
        localize_catgraph(iter(rows), _ref_self(rng), 9)


def test_messages_name_parameters_not_flags() -> None:
    rng = np.random.default_rng(8)
    rows = _rows(np.arange(10.0), N_REF, rng)
    with pytest.raises(WilocError, match=r"^odometry: a query odometry needs the map's too \(map_odometry\)"):
        localize_catgraph(iter(rows), _ref_self(rng), 10, query_steps=np.ones(10))
    with pytest.raises(WilocError, match=r"^particles: must lie in \[1, 1000000\], got 0"):
        localize_catgraph(iter(rows), _ref_self(rng), 10, particles=0)


def test_one_frame_map_says_so() -> None:
    with pytest.raises(WilocError, match="the map needs at least 2 frames, got 1"):
        localize_catgraph(iter(np.ones((3, 1))), np.zeros((1, 1)), 3)


@pytest.mark.parametrize("node", [0, 2])
def test_mode_on_a_map_shorter_than_the_mode_window(node: int) -> None:
    # 3 nodes < 2 * mode_window + 1 = 5: np.convolve(..., "same") returned 5 masses, shifted by
    # one node, and every node's window holds all the weight, so the mass alone cannot decide.
    rng = np.random.default_rng(12)
    rows = 1.0 + 0.02 * rng.standard_normal((30, 3))
    rows[:, node] -= 0.6
    ref = np.array([[0.0, 1.0, 1.1], [1.0, 0.0, 0.9], [1.1, 0.9, 0.0]])
    dec = localize_catgraph(iter(rows), ref, rows.shape[0], exclude_recent=0, particles=200,
                            ref_arclength=np.arange(3.0), query_steps=np.zeros(rows.shape[0]))  # standing still
    assert np.all(dec.match[10:] == node)
    np.testing.assert_array_equal(dec.difference, rows[np.arange(rows.shape[0]), dec.match])


@pytest.mark.parametrize("even", [True, False])
def test_sequence_score_step_is_the_numpy_expression_value_for_value(even: bool) -> None:
    from wiloc.methods.catgraph.filter_kernels import advance
    from wiloc.methods.catgraph.trajectory import read_runs, shifted_reads

    rng = np.random.default_rng(3)
    nodes = np.arange(700.0) if even else np.cumsum(rng.random(700) * (rng.random(700) < 0.9))
    speeds = np.array([0.5, 1.0, -1.0, 1.5, 2.0, -2.0])  # forward and backward paces, interleaved
    score, contrast = rng.normal(size=(speeds.size, 700)), rng.normal(size=700)
    at, a = shifted_reads(nodes, speeds * 0.8)
    prev = score.ravel()
    want = (1.0 - 0.1) * ((1.0 - a) * prev[at] + a * prev[at + 1]).reshape(score.shape) + 0.1 * contrast
    out, lowest = np.empty_like(score), np.empty((2, 700))
    advance(score, at, a, read_runs(at, a, 700), contrast, 0.1, (speeds < 0).astype(np.intp), out, lowest)
    assert np.array_equal(out, want)
    assert np.array_equal(lowest[0], want[speeds > 0].min(axis=0))
    assert np.array_equal(lowest[1], want[speeds < 0].min(axis=0))


@pytest.mark.parametrize(("n_nodes", "half"), [(500, 2), (500, 0), (3, 2), (40, 5)])
def test_posterior_mode_sums_only_nodes_near_particles_and_reads_out_as_a_pass_over_every_node(
        n_nodes: int, half: int) -> None:
    from wiloc.methods.catgraph.filter_kernels import posterior_mode

    rng = np.random.default_rng(n_nodes + half)
    marks = np.zeros(n_nodes, dtype=np.int64)
    for frame in range(1, 40):
        particles = 300
        j = np.minimum(rng.integers(0, n_nodes - 1, particles) // (1 + frame % 3 * 40), n_nodes - 2)
        frac = np.round(rng.random(particles), 1)  # some exactly at 0.5
        w = rng.integers(1, 4, particles).astype(np.float64)  # ties between nodes' weights and masses
        w /= w.sum()
        own = np.empty(n_nodes)
        mode, mass = posterior_mode(j, frac, w, half, 1e-12, own, marks, frame)
        want_own = np.bincount(j + (frac >= 0.5), w, minlength=n_nodes)
        want_mass = np.convolve(want_own, np.ones(2 * half + 1))[half:half + n_nodes] if n_nodes > 2 * half else \
            np.array([want_own[max(i - half, 0):i + half + 1][::-1].sum() for i in range(n_nodes)])
        near = np.flatnonzero(want_mass >= want_mass.max() - 1e-12)
        assert np.array_equal(own, want_own)
        assert mode == near[np.argmax(want_own[near])] and mass == want_mass[mode]


@pytest.mark.parametrize("renormalise", [True, False])
def test_weighing_is_the_numpy_expression_up_to_the_order_of_sums(renormalise: bool) -> None:
    from scipy.special import logsumexp

    from wiloc.methods.catgraph.filter_kernels import weigh
    from wiloc.methods.catgraph.observation import RankLikelihood

    rng = np.random.default_rng(8)
    row = np.round(rng.random(900) * 60).astype(np.float32).astype(np.float64)  # ties, float32 values
    model = RankLikelihood(0.4, 10.0, 0.02)
    model.use_row(row)
    j = rng.integers(0, 899, 500)
    frac = np.where(rng.random(500) < 0.3, 0.0, rng.random(500))
    omega = np.where(rng.random(500) < 0.1, rng.random(500), 1.0)  # some near duplicates
    log_ratio = model.at(j, frac, omega)
    t = model.t((1.0 - frac) * row[j] + frac * row[j + 1])
    assert np.array_equal(model._t, t)  # the interpolated ranks, digit for digit
    want = model.log_ratio(t, omega)
    # ln a: the kernel's log is the C library's, numpy's may be its own SIMD loop (numpy 1.24 on an
    # AVX-512 CPU differs in the last bit on a few values), so the ratios agree to rounding
    np.testing.assert_allclose(log_ratio, want, rtol=1e-15, atol=1e-15)
    total = np.sum(np.exp(model.log_ratio(model.t(row), np.ones(900))))
    assert model.mean(np.ones(900)) == pytest.approx(np.log(total) - np.log(900), rel=1e-12)

    log_w = np.log(rng.dirichlet(np.ones(500)))
    kept = rng.random(500) > 0.05
    prior = log_w - logsumexp(log_w[kept]) if renormalise else log_w
    expected = np.where(kept, np.log(0.9) + prior + log_ratio, np.log(0.01))
    log_map = logsumexp(expected)
    out, w = np.empty(500), np.empty(500)
    got_map, squares = weigh(log_w, kept, renormalise, log_ratio, np.log(0.9), np.log(0.01), out, w)
    assert got_map == pytest.approx(log_map, rel=1e-13)
    np.testing.assert_allclose(out, expected - log_map, rtol=1e-12)
    np.testing.assert_allclose(w, np.exp(expected - log_map), rtol=1e-12)
    assert w.sum() == pytest.approx(1.0) and squares == pytest.approx(np.sum(w * w), rel=1e-12)


def test_smallest_takes_ties_in_index_order_or_drawn_by_the_generator() -> None:
    from wiloc.methods.catgraph.trajectory import smallest

    rng = np.random.default_rng(4)
    values = rng.integers(0, 5, 300).astype(np.float64)  # many ties
    for k in (1, 7, 60, 299, 300, 400):
        want = np.sort(np.argsort(values, kind="stable")[:k])
        assert np.array_equal(np.sort(smallest(values, k)), want)
        drawn = smallest(values, k, np.random.default_rng(5))  # ties drawn: the same values, other indices
        assert drawn.size == min(k, values.size) == np.unique(drawn).size
        assert np.array_equal(np.sort(values[drawn]), np.sort(values[want]))
        assert np.array_equal(drawn, smallest(values, k, np.random.default_rng(5)))


def test_the_posterior_ranks_the_mode_first_then_the_nodes_of_most_weight() -> None:
    own = np.array([0.0, 0.1, 0.3, 0.1, 0.0, 0.25, 0.25])
    assert posterior_ranking(own, 5).tolist() == [5, 2, 6, 1, 3]  # equal weights in order of position
    assert posterior_ranking(own, 5, k=3).tolist() == [5, 2, 6]
    assert posterior_ranking(np.zeros(4), 2).tolist() == [2]  # nodes without weight are no candidates


def test_sequence_mode_calls_a_first_pass_new_and_follows_its_revisit() -> None:
    """Without a map the traversal so far is the map (frames before the recent window and the
    frontier): on a generated loop the first pass is new (P(new place) high, nothing claimed) and
    the revisit is followed and claimed once it has run a few frames."""
    rng = np.random.default_rng(11)
    places, recent = 150, 10
    rows, route = loop_rows(rng, places, recent, memory=0.9)
    n = route.size
    out = run_on_rows(CatGraph(), rows, n, sequence=True, exclude_recent=recent)
    started = recent + CatGraph.Params().frontier + 2  # the map's first 2 nodes
    assert np.all(out.stage[:started] == "none") and np.all(out.match[:started] == -1)
    assert np.all(out.stage[started:] == "track")
    first, revisit = np.arange(started, places), np.arange(places + 5, n)
    right = np.abs(route[np.maximum(out.match, 0)] - route) <= TOL
    assert np.mean(out.columns["new_place"][first]) > 0.9 and np.mean(out.confidence[first]) < 0.1
    assert np.mean(right[revisit]) > 0.95
    assert np.mean(out.columns["new_place"][revisit]) < 0.1 and np.mean(out.confidence[revisit]) > 0.8
    assert out.match[started:].max() < n - recent - CatGraph.Params().frontier  # never a frame of the frontier


def test_sequence_mode_refuses_a_traversal_too_short_mixed_odometry_and_the_maps() -> None:
    method = CatGraph(frontier=20)
    assert "at least 33" in method.query_problem(32, True, 10)
    assert method.query_problem(33, True, 10) is None and method.query_problem(5, False, 10) is None
    method.start(base.MapContext(sequence=True, exclude_recent=10))
    method.step(np.ones(40), odometry=None)
    method.step(np.ones(40), odometry=1.0)  # the second frame says: odometry with every frame
    with pytest.raises(WilocError, match="query frame 2: in sequence mode odometry comes with every frame") as err:
        method.step(np.ones(40))
    assert err.value.parameter == "odometry" and method.frames == 2
    method.step(np.ones(40), odometry=0.5)  # refused, the frame can be given again
    with pytest.raises(WilocError, match="takes no map odometry in sequence mode") as err:  # the map's positions
        CatGraph().start(base.MapContext(sequence=True, exclude_recent=10, arclength=np.arange(50.0)))
    assert err.value.parameter == "map_odometry"


def test_sequence_mode_with_odometry_follows_a_revisit_at_twice_the_pace() -> None:
    """With odometry the map's nodes sit where the traversal's frames were taken and a particle's
    pace is its direction: a revisit at twice the first pass's pace is followed from the steps the
    odometry gives. A traversal standing still at its start has no map to move along until it
    moves: the filter starts once the map spans a distance."""
    rng = np.random.default_rng(11)
    places, recent, frontier = 150, 10, CatGraph.Params().frontier
    rows, route = loop_rows(rng, places, recent, memory=0.9, revisit_pace=2)
    n = route.size
    steps = np.r_[0.0, np.abs(np.diff(route))].astype(np.float64)
    steps[places] = 1.0  # from the first pass's end back to its start: a stand-in distance
    steps[1:5] = 0.0  # standing still at the start
    out = run_on_rows(CatGraph(), rows, n, sequence=True, exclude_recent=recent, odometry=steps)
    started = recent + frontier + 2 + 4  # 2 nodes, and the 4 frames standing still at one position
    assert np.all(out.stage[:started] == "none") and np.all(out.stage[started:] == "track")
    right = np.abs(route[np.maximum(out.match, 0)] - route) <= TOL
    revisit = np.arange(places + 5, n)
    assert np.mean(right[revisit]) > 0.9 and np.mean(out.columns["new_place"][revisit]) < 0.1
    assert np.mean(out.columns["new_place"][started:places]) > 0.9
    steps[places + 1:] = 1.0  # odometry saying the revisit keeps the first pass's pace: it is trusted, and misleads
    misled = run_on_rows(CatGraph(), rows, n, sequence=True, exclude_recent=recent, odometry=steps)
    assert np.mean((np.abs(route[np.maximum(misled.match, 0)] - route) <= TOL)[revisit]) < 0.5


@pytest.mark.parametrize("n", [2, 3, 17, 1000])
def test_sequence_modes_reads_are_those_of_the_general_lookup_on_its_nodes(n: int) -> None:
    # sequence mode's map is the nodes 0..n-1, one more per frame: its compiled lookup and runs
    # must be what shifted_reads finds on those nodes and the numpy definition of the runs
    paces = np.asarray(CatGraph.Params().sequence_speeds)
    at, a = shifted_reads(np.arange(n, dtype=np.float64), paces)
    step = np.arange(at.size)
    new = (step % n == 0) | np.r_[True, (at[1:] != at[:-1] + 1) | (a[1:] != a[:-1])]
    first = np.flatnonzero(new)
    end = np.append(first[1:], at.size)
    for shortest in (1, 3, 16):
        runs = np.column_stack((first, end))[end - first >= shortest]
        even_at, even_a, even_runs = even_shifted_reads(n, paces, shortest)
        np.testing.assert_array_equal(even_at, at)
        np.testing.assert_array_equal(even_a, a)
        np.testing.assert_array_equal(even_runs, runs)
        np.testing.assert_array_equal(read_runs(at, a, n, shortest), runs)


@pytest.mark.realdata
@pytest.mark.parametrize("descriptor", ["sad", "gist"])
def test_sequence_mode_closes_the_gardens_point_loop_with_probabilities(data_root, real_data_cache, descriptor: str) -> None:
    """GP day_right then day_left as one traversal (benchmarks/bench_loops.py, loop dr+dl),
    without a map: the revisit is followed, every frame claimed at 0.99 is right, first visits
    are called new places, and the confidence is calibrated (ECE 0.025 and 0.040 measured)."""
    from helpers import benchmark_module

    with benchmark_module("bench_loops") as bench:
        row = bench.run_loop(bench.load_loop("dr+dl", descriptor, data_root, Cache(real_data_cache)), "catgraph")
    assert row["r1"] >= 0.9 and row["r100"] >= 0.7
    assert row["precision@0.99"] >= 0.99 and row["accepted@0.99"] >= 100
    assert row["new_first"] >= 0.85 and row["new_revisit"] <= 0.1 and row["ece"] <= 0.05
    if descriptor == "sad":
        assert row["new_first"] >= 0.95


@pytest.mark.realdata
def test_a_first_pass_through_look_alike_country_is_new_ground(data_root, real_data_cache, tmp_path) -> None:
    """Nordland summer 0-999 then winter 0-999 as one traversal with gist (loop s+w): the first
    pass is mostly forest and track that resemble earlier frames by chance. Read against each
    node's chance resemblance, its frames are called new places (mean P(new place) 0.83, against
    0.40 with every node alike; 0.52 on a simulated AVX2 CPU, where gist's last digits differ) and
    the confidence is near calibrated (ECE 0.075 / 0.079, against 0.240 / 0.191). The loop reads
    each season's first 1000 frames only: those alone are described (gist describes each frame by
    itself), not the 3576 of each folder."""
    from helpers import benchmark_module, first_frames

    dataset = "nordland-summer-winter-64x32"
    for season in ("summer", "winter"):
        first_frames(data_root / dataset / season, tmp_path / dataset / season, 1000)
    with benchmark_module("bench_loops") as bench:
        loop = bench.load_loop("s+w", "gist", tmp_path, Cache(real_data_cache))
        row, alike = bench.run_loop(loop, "catgraph"), bench.run_loop(loop, "catgraph", {"hub_weight": 0})
    assert row["new_first"] >= 0.75 and row["ece"] <= 0.1
    assert alike["new_first"] <= row["new_first"] - 0.2 and alike["ece"] >= row["ece"] + 0.08  # what it changes


@pytest.mark.parametrize("name", ["repeat_pace_spread", "odometry_scale", "odometry_scale_wide"])
def test_a_spread_of_a_pace_or_factor_is_at_most_one(name: str) -> None:
    # A spread of 1000 was taken and the run ended in numpy's errors (exp overflowing to inf, the
    # weights NaN; a factor of 0 a ZeroDivisionError): a spread of the log of 1 already draws factors
    # from a third to three times within one sd. At 1 a run with a stop and odometry decides every frame.
    with pytest.raises(ParameterError) as err:
        CatGraph(**{name: 1.5})
    assert err.value.parameter == name
    rng = np.random.default_rng(3)
    truth = np.r_[np.arange(20.0, 60.0), np.full(10, 60.0), np.arange(61.0, 120.0)]
    rows, ref = _rows(truth, N_REF, rng), _ref_self(rng)
    rows[41:50] = rows[40]
    spread = {"repeat_pace_spread": 1.0, "odometry_scale": 1.0, "odometry_scale_wide": 1.0}
    for steps in (None, np.r_[0.0, np.abs(np.diff(truth))]):
        dec = localize_catgraph(iter(rows), ref, truth.size, ref_arclength=None if steps is None else
                                np.arange(float(N_REF)), query_steps=steps,
                                **{k: v for k, v in spread.items() if steps is not None or k == "repeat_pace_spread"})
        assert (dec.match >= 0).all() and np.isfinite(dec.confidence).all()

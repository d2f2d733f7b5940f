"""SeqSLAM as a method: its contrast enhancement, its trajectory search over velocities (forward,
faster, backwards), causal decisions, resumed state, declared parameters, and its recall on real
data."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from wiloc.decisions import Decisions
from wiloc.errors import ParameterError, UsageError, WilocError
from wiloc.localization.array_run import run_on_rows
from wiloc.methods.base import MapContext
from wiloc.methods.seqslam import SeqSLAM, _add_shifted, enhance, lowest_enhanced, trajectory_offsets
from wiloc.rows import ArrayRows

N_MAP = 120


def _rows(truth: np.ndarray, rng: np.random.Generator, noise: float = 0.15) -> np.ndarray:
    """Difference rows of query frames at map positions ``truth``: a narrow valley at the true
    place under noise strong enough that a frame's own best match is often wrong."""
    offset = truth[:, None] - np.arange(N_MAP)[None, :]
    return 1.0 + noise * rng.standard_normal((truth.size, N_MAP)) - 0.3 * np.exp(-0.5 * (offset / 1.5) ** 2)


def _context() -> MapContext:
    return MapContext(sequence=False, exclude_recent=5, n_map=N_MAP)


def _run(rows: np.ndarray | list[np.ndarray], **params: object) -> Decisions:
    """A batch run over ``rows`` (one array, or a list of 2-D blocks of consecutive rows)."""
    method = SeqSLAM(**params)
    method.start(_context())
    return method.run(iter(rows), sum(len(block) for block in rows) if isinstance(rows, list) else len(rows))


def _followed(match: np.ndarray, truth: np.ndarray, first: int = 10) -> float:
    """The share of frames from ``first`` on whose match is within 2 map frames of the truth."""
    return float(np.mean(np.abs(match[first:] - np.round(truth[first:])) <= 2))


def test_enhancement_matches_a_hand_computed_row() -> None:
    """Half window 1: each value against itself and its neighbours (two at the ends), sample std."""
    row = np.array([[1.0, 2.0, 3.0, 4.0, 10.0]])
    expected = [-0.5 / np.sqrt(0.5), 0.0, 0.0, (4 - 17 / 3) / np.sqrt(43 / 3), 3.0 / np.sqrt(18.0)]
    np.testing.assert_allclose(enhance(row, 1)[0], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(enhance(np.full((2, 6), 5.0), 2), np.zeros((2, 6)))  # flat: 0, not NaN


def test_the_lowest_enhanced_value_is_the_shift_that_makes_scores_non_negative() -> None:
    row = np.array([[1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0]])
    assert enhance(row, 3)[0, 3] == pytest.approx(lowest_enhanced(7, 3))
    assert lowest_enhanced(7, 3) == pytest.approx(-6 / np.sqrt(7))
    rng = np.random.default_rng(0)
    assert enhance(rng.random((50, 200)), 5).min() >= lowest_enhanced(200, 5)


def test_offsets_take_the_nearest_frame_and_count_equal_trajectories_once() -> None:
    offsets = trajectory_offsets(np.array([0.8, 0.9, 1.0, 1.1, 1.2]), 3)
    np.testing.assert_array_equal(offsets, [[0, 1, 2]])  # 0.8 x 2 = 1.6 and 1.2 x 2 = 2.4: frame 2 for all
    np.testing.assert_array_equal(trajectory_offsets(np.array([-1.0, 2.0]), 3), [[0, -1, -2], [0, 2, 4]])


@pytest.mark.parametrize("shift, expected", [(0, [1, 2, 3, 4]), (2, [1, 1, 1, 2]), (-1, [2, 3, 4, 4]),
                                             (10, [1, 1, 1, 1]), (-10, [4, 4, 4, 4])])
def test_a_trajectory_leaving_the_map_stays_at_its_end(shift: int, expected: list[float]) -> None:
    out = np.full(4, 10.0)
    _add_shifted(out, np.array([1.0, 2.0, 3.0, 4.0]), shift)
    np.testing.assert_array_equal(out, 10.0 + np.array(expected))


def test_follows_a_query_at_the_maps_pace_where_single_frames_fail() -> None:
    rng = np.random.default_rng(1)
    truth = np.arange(10.0, 100.0)
    rows = _rows(truth, rng)
    single = _followed(rows.argmin(axis=1), truth)
    decided = _run(rows)
    assert single < 0.8
    assert _followed(decided.match, truth) >= 0.95
    assert np.all((decided.confidence >= 0) & (decided.confidence <= 1))


def test_follows_a_query_at_twice_the_pace_when_the_velocities_cover_it() -> None:
    rng = np.random.default_rng(2)
    truth = 5.0 + 2.0 * np.arange(55)
    rows = _rows(truth, rng)
    assert _followed(_run(rows, v_min=1.8, v_max=2.2).match, truth) >= 0.95
    assert _followed(_run(rows).match, truth) < 0.8  # the defaults (0.8-1.2) do not reach 2x


def test_follows_a_query_driven_backwards_with_negative_velocities() -> None:
    rng = np.random.default_rng(3)
    truth = 110.0 - np.arange(90)
    rows = _rows(truth, rng)
    assert _followed(_run(rows, v_min=-1.2, v_max=-0.8).match, truth) >= 0.95
    assert _followed(_run(rows).match, truth) < 0.8


def test_a_decision_never_changes_when_later_frames_arrive() -> None:
    rng = np.random.default_rng(4)
    rows = _rows(np.arange(10.0, 70.0), rng)
    whole = _run(rows)
    for k in (1, 5, 23):
        part = _run(rows[:k])
        np.testing.assert_array_equal(part.match, whole.match[:k])
        np.testing.assert_array_equal(part.confidence, whole.confidence[:k])


def test_stepping_equals_a_batch_run_over_blocks_of_rows() -> None:
    rng = np.random.default_rng(5)
    rows = _rows(np.arange(20.0, 90.0), rng).astype(np.float32)
    batch = _run([rows[:30], rows[30:]], v_min=0.5, v_max=1.5)  # 2-D blocks, as the kernels give them
    stepper = SeqSLAM(v_min=0.5, v_max=1.5)
    stepper.start(_context())
    steps = [stepper.step(row) for row in rows]
    np.testing.assert_array_equal(batch.match, [d.match for d in steps])
    np.testing.assert_array_equal(batch.confidence, [d.confidence for d in steps])
    np.testing.assert_array_equal(batch.columns["score"], [d.extra["score"] for d in steps])


@pytest.mark.parametrize("stop", [4, 10, 27])  # before the ring of ds rows is full, just full, wrapped
def test_restored_state_gives_identical_later_decisions(stop: int) -> None:
    rng = np.random.default_rng(6)
    rows = _rows(np.arange(10.0, 60.0), rng)
    whole = SeqSLAM()
    whole.start(_context())
    expected = [whole.step(row) for row in rows]
    first = SeqSLAM()
    first.start(_context())
    for row in rows[:stop]:
        first.step(row)
    resumed = SeqSLAM()
    resumed.restore(_context(), copy.deepcopy(first.state()))
    assert [resumed.step(row) for row in rows[stop:]] == expected[stop:]
    other = SeqSLAM(ds=5)
    with pytest.raises(WilocError, match="another map or ds"):
        other.restore(_context(), first.state())


@pytest.mark.parametrize("values, parameter", [
    ({"v_min": 1.5, "v_max": 1.0}, "v_max"),
    ({"v_step": 0.0}, "v_step"),
    ({"v_min": -10.0, "v_max": 10.0, "v_step": 0.001}, "v_step"),  # 20,001 velocities
    ({"ds": 0}, "ds"),
    ({"enhance_window": 1}, "enhance_window"),
    ({"unique_window": -2}, "unique_window"),
])
def test_invalid_parameters_name_the_parameter(values: dict, parameter: str) -> None:
    with pytest.raises(ParameterError) as err:
        SeqSLAM(**values)
    assert err.value.parameter == parameter


def test_velocities_run_from_v_min_to_v_max_included() -> None:
    np.testing.assert_allclose(SeqSLAM().params.velocities(), [0.8, 0.9, 1.0, 1.1, 1.2])
    np.testing.assert_allclose(SeqSLAM(v_min=-1.0, v_max=1.0, v_step=0.5).params.velocities(),
                               [-1.0, -0.5, 0.0, 0.5, 1.0])


def test_needs_a_map_and_one_finite_value_per_map_frame() -> None:
    with pytest.raises(UsageError, match="needs a map"):
        SeqSLAM().check_inputs(sequence=True, training=False)
    with pytest.raises(WilocError, match="needs a map"):
        SeqSLAM().start(MapContext(sequence=True, exclude_recent=5))
    method = SeqSLAM()
    method.start(_context())
    with pytest.raises(WilocError, match="expected 120 finite values"):
        method.step(np.full(N_MAP, np.inf))
    with pytest.raises(WilocError, match="expected 120 finite values"):
        method.step(np.ones(N_MAP - 1))


def test_a_map_within_the_uniqueness_window_gives_confidence_zero() -> None:
    """Six map frames, all within +-5 of any match: nothing to tell the best from."""
    rows = np.random.default_rng(7).random((5, 6))
    method = SeqSLAM()
    method.start(MapContext(sequence=False, exclude_recent=5, n_map=6))
    decisions = [method.step(row) for row in rows]
    assert all(d.confidence == 0.0 and 0 <= d.match < 6 for d in decisions)


def test_run_on_rows_records_the_velocities_searched() -> None:
    rows = _rows(np.arange(10.0, 30.0), np.random.default_rng(8))
    decided = run_on_rows(SeqSLAM(v_min=0.5, v_max=1.0, v_step=0.25), iter(rows), len(rows),
                          map_self=ArrayRows(np.ones((N_MAP, N_MAP))))
    assert decided.params["velocities"] == [0.5, 0.75, 1.0]
    assert decided.params["method"] == "seqslam" and decided.params["ds"] == 10


@pytest.mark.realdata
@pytest.mark.parametrize("dataset, query, reference, least", [
    ("gardens-point-walking", "day_left", "day_right", 0.33),
    ("nordland-summer-winter-64x32", "winter", "summer", 0.65),
])
def test_recall_at_1_on_real_data(data_root: Path, real_data_cache: Path, cache_dir: Path, dataset: str, query: str,
                                  reference: str, least: float) -> None:
    """SeqSLAM's defaults with ``sad``, tolerance +-2 aligned frames. Measured R@1: Gardens Point
    day_left 0.375 (single frames, ``threshold``: 0.420: the +-5-frame contrast enhancement is
    narrower than this walk's valleys), Nordland winter 0.707 (single frames: 0.115)."""
    from wiloc import api
    from wiloc.cache.store import Cache

    root = data_root / dataset
    run = api.localize(root / query, reference=root / reference, descriptor="sad", method="seqslam",
                       cache=Cache(real_data_cache))
    summary = api.evaluate(run, api.TruthSource(tolerance=2)).summary.as_dict()
    assert summary["recall_at_1"] >= least

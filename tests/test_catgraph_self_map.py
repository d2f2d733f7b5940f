"""Sequence mode's map of the traversal itself (``wiloc.methods.catgraph.self_map``): where each
frame was taken, and which frames nearly repeat the one before, bounded from the rows alone."""
from __future__ import annotations

import numpy as np
import pytest

from wiloc.errors import WilocError
from wiloc.methods.catgraph.observation import novelty_weights
from wiloc.methods.catgraph.self_map import SelfMap, StepBounds, Trail


def _route_with_stops(rng: np.random.Generator) -> np.ndarray:
    """Descriptors of a route of 120 frames that stands still twice (frames repeated with a
    camera's noise) and starts on 8 identical black frames."""
    looks = np.cumsum(rng.normal(0.0, 1.0, (100, 32)), axis=0)
    order = np.r_[np.zeros(8, dtype=int), np.arange(40), np.full(12, 40), np.arange(41, 70), np.full(10, 70),
                  np.arange(71, 92)]
    frames = looks[order] + rng.normal(0.0, 0.05, (order.size, 32))
    frames[:8] = 0.0
    return frames


def _rows(frames: np.ndarray, recent: int) -> list[np.ndarray]:
    """Sequence-mode rows: frame k's L1 differences to the frames before k - ``recent``."""
    d = np.abs(frames[:, None, :] - frames[None, :, :]).mean(axis=2)
    return [d[k, :max(0, k - recent)] for k in range(len(frames))]


def test_the_rows_bound_each_step_from_below_and_mark_the_frames_that_repeat() -> None:
    frames = _route_with_stops(np.random.default_rng(3))
    steps = np.abs(np.diff(frames, axis=0)).mean(axis=1)  # d(j, j + 1), which no row holds
    bounds = StepBounds()
    for row in _rows(frames, recent=10):
        bounds.add(row)
    bound = bounds.state()
    n = len(frames) - 12  # the pairs some row compares with a third frame
    assert bound.size >= n and np.all(bound[:n] <= steps[:n] + 1e-12)  # the triangle inequality
    assert np.all(bound[:7] == 0.0)  # the black frames: the same in every row
    damped, wanted = bounds.weights(n, 0.25), novelty_weights(steps[:n - 1], 0.25)
    assert np.mean((damped < 1.0) == (wanted < 1.0)) >= 0.95  # the same near-duplicates as the steps mark
    assert damped[1:7].max() == 0.0 and damped[20:40].min() == 1.0 and damped[50:57].max() < 0.5


def test_a_row_value_that_is_not_finite_bounds_nothing() -> None:
    bounds = StepBounds()
    bounds.add(np.array([1.0, 2.0, 4.0]))
    bounds.add(np.array([1.0, np.nan, 1.0, 5.0, np.inf, np.inf]))
    np.testing.assert_array_equal(bounds.state(), [1.0, 2.0, 4.0, 0.0, 0.0])
    assert bounds.weights(6, 0.25).shape == (6,)  # frames no row has bounded yet count as repeats
    again = StepBounds(bounds.state())
    np.testing.assert_array_equal(again.state(), bounds.state())


def test_the_trail_places_frames_by_their_odometry_or_index() -> None:
    by_index = Trail()
    for k in range(5):
        by_index.add(k, None)
    assert by_index.odometry is False and by_index.nodes(4).tolist() == [0.0, 1.0, 2.0, 3.0]
    assert by_index.positions().size == 0
    walked = SelfMap()
    for k, step in enumerate([7.0, 0.0, 0.0, 2.5, 1.0]):  # the first frame's odometry is not read
        walked.add(k, step, np.zeros(0), 0, bounds=False)
    trail = walked.trail
    assert trail.nodes(5).tolist() == [0.0, 0.0, 0.0, 2.5, 3.5]
    assert not trail.spans(3) and trail.spans(4)  # standing still at the start: no map to move along
    with pytest.raises(ValueError):
        trail.nodes(5)[0] = 1.0  # read-only
    with pytest.raises(WilocError, match="query frame 5: in sequence mode odometry comes with every frame"):
        trail.add(5, None)
    continued = SelfMap(walked.state(), frames=5)
    assert continued.trail.nodes(5).tolist() == trail.nodes(5).tolist() and continued.trail.odometry
    with pytest.raises(WilocError, match="query frame 5: expected 3 finite values"):
        continued.add(5, 0.5, np.array([1.0, np.nan, 2.0, 3.0]), 3, bounds=True)
    assert continued.trail.positions().size == 5 and continued.bounds.state().size == 0  # refused: nothing added
    continued.add(5, 0.5, np.array([1.0, 2.0, 2.0, np.nan]), 3, bounds=True)
    assert continued.trail.nodes(6)[-1] == 4.0

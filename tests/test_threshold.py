"""The threshold baseline: same hypothesis as the online model, confidence 1 - m / normaliser."""
from __future__ import annotations

import numpy as np
import pytest

from wiloc.errors import WilocError
from wiloc.methods.threshold import localize_threshold


def _rows(rng: np.random.Generator, n: int = 30, m: int = 12) -> np.ndarray:
    rows = rng.uniform(0.1, 2.0, (n, m))
    rows[3] = np.inf
    rows[5, :6] = np.inf
    return rows


def test_confidence_order_is_reverse_of_difference() -> None:
    rows = _rows(np.random.default_rng(1))
    out = localize_threshold(list(rows), len(rows))
    d = out.decided
    assert not d[3] and out.match[3] == -1 and np.isnan(out.confidence[3])
    assert out.match[5] == 6 + np.argmin(rows[5, 6:])
    assert np.array_equal(np.argsort(out.confidence[d]), np.argsort(-out.difference[d]))


def test_default_normaliser_is_largest_decided_difference() -> None:
    rows = _rows(np.random.default_rng(2))
    out = localize_threshold(list(rows), len(rows))
    m = out.difference[out.decided]
    assert out.params["normaliser"] == pytest.approx(m.max())
    assert out.confidence[out.decided].min() == pytest.approx(0.0)
    assert np.all(out.confidence[out.decided] <= 1.0)


def test_given_normaliser_is_used() -> None:
    rows = _rows(np.random.default_rng(3))
    out = localize_threshold(iter(rows), len(rows), normaliser=4.0)
    d = out.decided
    assert np.allclose(out.confidence[d], 1.0 - np.min(rows[d], axis=1) / 4.0)
    assert out.params["normaliser"] == 4.0 and out.params["normaliser_given"]
    # a constant from elsewhere (e.g. the map) can be exceeded: no clipping, order is kept
    out = localize_threshold(iter(rows), len(rows), normaliser=0.3)
    assert out.confidence[d].min() < 0
    assert np.array_equal(np.argsort(out.confidence[d]), np.argsort(-out.difference[d]))


@pytest.mark.parametrize("bad", [0.0, -1.0, np.inf, np.nan])
def test_bad_normaliser_is_a_user_error(bad: float) -> None:
    with pytest.raises(WilocError):
        localize_threshold([np.ones(3)], 1, normaliser=bad)


def test_row_count_must_match() -> None:
    with pytest.raises(WilocError):
        localize_threshold([np.ones(3)] * 2, 3)

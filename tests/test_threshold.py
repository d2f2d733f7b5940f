"""The threshold baseline: same hypothesis as the online model, confidence 1 - m / normaliser."""
from __future__ import annotations

import numpy as np
import pytest

from wiloc.errors import ParameterError, WilocError
from wiloc.localization.array_run import run_on_rows
from wiloc.methods.threshold import Threshold


def _rows(rng: np.random.Generator, n: int = 30, m: int = 12) -> np.ndarray:
    rows = rng.uniform(0.1, 2.0, (n, m))
    rows[3] = np.inf
    rows[5, :6] = np.inf
    return rows


def test_confidence_order_is_reverse_of_difference() -> None:
    rows = _rows(np.random.default_rng(1))
    out = run_on_rows(Threshold(), list(rows), len(rows), natural_max=2.0)
    d = out.decided
    assert not d[3] and out.match[3] == -1 and np.isnan(out.confidence[3])
    assert out.match[5] == 6 + np.argmin(rows[5, 6:])
    assert np.array_equal(np.argsort(out.confidence[d]), np.argsort(-out.difference[d]))
    assert np.allclose(out.confidence[d], 1.0 - out.difference[d] / 2.0)


def test_default_normaliser_is_the_maps_largest_difference_without_a_natural_maximum() -> None:
    rng = np.random.default_rng(2)
    rows = _rows(rng)
    ref = rng.uniform(0.0, 3.0, (12, 12))
    ref[4, 7] = np.inf  # not a difference: ignored
    out = run_on_rows(Threshold(), list(rows), len(rows), map_self=ref)
    finite = ref[np.isfinite(ref)]
    assert out.params["normaliser_used"] == pytest.approx(finite.max())
    with_max = run_on_rows(Threshold(), list(rows), len(rows), map_self=ref, natural_max=10.0)
    assert with_max.params["normaliser_used"] == 10.0


def test_given_normaliser_is_used() -> None:
    rows = _rows(np.random.default_rng(3))
    out = run_on_rows(Threshold(normaliser=4.0), iter(rows), len(rows), natural_max=2.0)
    d = out.decided
    assert np.allclose(out.confidence[d], 1.0 - np.min(rows[d], axis=1) / 4.0)
    assert out.params["normaliser"] == 4.0 and out.params["normaliser_used"] == 4.0
    # a constant from elsewhere (e.g. the map) can be exceeded: no clipping, order is kept
    out = run_on_rows(Threshold(normaliser=0.3), iter(rows), len(rows))
    assert out.confidence[d].min() < 0
    assert np.array_equal(np.argsort(out.confidence[d]), np.argsort(-out.difference[d]))


@pytest.mark.parametrize("bad", [0.0, -1.0, np.inf, np.nan, "1"])
def test_bad_normaliser_is_a_user_error(bad: float) -> None:
    with pytest.raises(ParameterError) as err:
        Threshold(normaliser=bad)
    assert err.value.parameter == "normaliser"


def test_without_any_scale_the_normaliser_must_be_given() -> None:
    with pytest.raises(ParameterError, match="normaliser"):
        run_on_rows(Threshold(), [np.ones(3)], 1, sequence=True)


def test_row_count_must_match() -> None:
    with pytest.raises(WilocError):
        run_on_rows(Threshold(), [np.ones(3)] * 2, 3, natural_max=1.0)

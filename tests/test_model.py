"""The histogram model: smoothing, clamping, Bayes' rule."""
from __future__ import annotations

import numpy as np
import pytest

from wiloc.model import HistogramModel


def test_empty_bins_never_give_nan() -> None:
    model = HistogramModel.from_range(0.0, 1.0, bins=10, smoothing=0.5)
    model.add_same([0.05, 0.05])
    model.add_different([0.95])
    post = model.posterior(np.linspace(0.0, 1.0, 21))
    assert np.all(np.isfinite(post))
    # an empty bin falls back to the ratio of the smoothed totals, not 0/0
    empty = model.posterior(0.5)
    prior = model.prior_same()
    same = 0.5 / (2 + 0.5 * 10) * prior
    diff = 0.5 / (1 + 0.5 * 10) * (1 - prior)
    assert empty == pytest.approx(same / (same + diff))


def test_completely_empty_model_is_uninformative() -> None:
    model = HistogramModel.from_range(0.0, 1.0, bins=4, smoothing=0.0)
    assert model.posterior(0.3) == pytest.approx(0.5)


def test_values_outside_range_clamp_into_edge_bins() -> None:
    model = HistogramModel.from_range(0.0, 1.0, bins=5)
    assert model.bin_of([-3.0, 0.0, 0.99, 1.0, 7.0]).tolist() == [0, 0, 4, 4, 4]
    model.add_same([-1.0, 12.0])
    assert model.b[0] == 1 and model.b[-1] == 1 and model.b.sum() == 2


def test_posterior_in_unit_interval_and_follows_counts() -> None:
    rng = np.random.default_rng(0)
    model = HistogramModel.from_range(0.0, 2.0, bins=20, smoothing=0.1)
    model.add_same(rng.gamma(4.0, 0.1, 500))
    model.add_different(rng.normal(1.3, 0.2, 500))
    post = model.posterior(np.linspace(-1.0, 3.0, 101))
    assert np.all((post >= 0) & (post <= 1))
    assert model.posterior(0.35) > 0.9 and model.posterior(1.4) < 0.1


def test_configured_prior_overrides_sample_share() -> None:
    model = HistogramModel.from_range(0.0, 1.0, bins=2, smoothing=0.0, prior=0.5)
    model.add_same([0.2])
    model.add_different([0.2, 0.2, 0.2, 0.8])
    assert model.prior_same() == 0.5
    # P(d|L) = 1, P(d|~L) = 3/4 in the low bin
    assert model.posterior(0.2) == pytest.approx(1 / (1 + 0.75))


def test_round_trip_through_dict() -> None:
    model = HistogramModel.from_range(0.0, 1.0, bins=3, smoothing=0.2, prior=0.3)
    model.add_same([0.1])
    model.add_different([0.9])
    again = HistogramModel.from_dict(model.to_dict())
    assert np.array_equal(again.b, model.b) and np.array_equal(again.c, model.c)
    assert again.posterior(0.1) == model.posterior(0.1)


@pytest.mark.parametrize("bins", [0, -3])
def test_bin_count_below_one_is_refused(bins: int) -> None:
    with pytest.raises(ValueError, match="bins must be >= 1"):
        HistogramModel.from_range(0.0, 1.0, bins=bins)


def test_repr_is_one_short_line_of_bins_range_and_counts() -> None:
    """A model (``decisions.model``) printed its edges and both count arrays whole, over 100 lines."""
    model = HistogramModel.from_range(0.0, 2.5, bins=100, smoothing=0.5)
    model.add_same([0.1, 0.2, 0.3])
    model.add_different([1.5, 2.0])
    shown = repr(model)
    assert "\n" not in shown and len(shown) < 200, shown
    assert shown.startswith("HistogramModel(") and "bins=100" in shown and "range=(0, 2.5)" in shown
    assert "same=3" in shown and "different=2" in shown and "smoothing=0.5" in shown and "prior=None" in shown
    assert str(model.b.tolist()) not in shown

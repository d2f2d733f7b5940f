"""Calibration measures: ECE, Brier score, reliability bins and precision/recall at fixed cuts."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wiloc.evaluation.groundtruth import Truth
from wiloc.evaluation.metrics import correct_matches, decided_confidence
from wiloc.evaluation.reliability import (NEW_PLACE_KEYS, brier_score, counts_at_cuts, expected_calibration_error,
                                          reliability_bins, summarize_calibration, summarize_new_place, wilson_interval)

NAN = float("nan")


# --- hand-made cases -------------------------------------------------------------------------

def test_ece_and_brier_by_hand() -> None:
    confidence = [0.05, 0.15, 0.15, 0.95, 0.95]
    correct = [False, False, True, True, True]
    # bin 0: 1 frame, gap 0.05; bin 1: 2 frames, mean 0.15, half correct, gap 0.35; bin 9: gap 0.05
    assert expected_calibration_error(confidence, correct) == pytest.approx((0.05 + 2 * 0.35 + 2 * 0.05) / 5)
    assert brier_score(confidence, correct) == pytest.approx((0.05**2 + 0.15**2 + 0.85**2 + 2 * 0.05**2) / 5)


def test_undecided_frames_are_left_out_of_every_measure_but_recall() -> None:
    base = summarize_calibration([0.05, 0.95], [False, True], n_positive=2, cuts=[0.5])
    with_nan = summarize_calibration([0.05, NAN, 0.95, NAN], [False, True, True, False], n_positive=4,
                                     cuts=[0.5])
    assert with_nan.ece == pytest.approx(base.ece) == pytest.approx(0.05)
    assert with_nan.brier == pytest.approx(base.brier)
    assert with_nan.bins.count.sum() == 2
    assert with_nan.mean_confidence == pytest.approx(0.5) and with_nan.share_correct == 0.5
    assert with_nan.cuts.accepted.tolist() == [1]
    assert with_nan.cuts.recall.tolist() == [0.25]  # the undecided true match still counts in recall


def test_bins_edges_belong_to_the_upper_bin_and_one_to_the_last() -> None:
    bins = reliability_bins([0.0, 0.1, 0.3, 0.7, 0.9999, 1.0], [True] * 6)
    assert bins.edges.tolist() == pytest.approx([k / 10 for k in range(11)])
    assert bins.count.tolist() == [1, 1, 0, 1, 0, 0, 0, 1, 0, 2]


def test_empty_bins_are_nan_and_do_not_count() -> None:
    bins = reliability_bins([0.42, 0.44, 0.86], [True, False, True])
    assert bins.count.tolist() == [0, 0, 0, 0, 2, 0, 0, 0, 1, 0]
    empty = bins.count == 0
    assert np.isnan(bins.mean_confidence[empty]).all() and np.isnan(bins.share_correct[empty]).all()
    assert bins.mean_confidence[4] == pytest.approx(0.43) and bins.share_correct[4] == 0.5
    assert bins.ece == pytest.approx((2 * 0.07 + 0.14) / 3)


def test_confidences_outside_unit_interval_are_clipped_into_the_edge_bins() -> None:
    # The threshold baseline gives 1 - d / d_max, below 0 beyond d_max.
    confidence = [-0.4, 1.3, 0.55]
    correct = [False, True, True]
    bins = reliability_bins(confidence, correct)
    assert bins.count[0] == 1 and bins.count[9] == 1
    assert bins.mean_confidence[0] == 0.0 and bins.mean_confidence[9] == 1.0
    assert bins.ece == pytest.approx(0.45 / 3)  # only the 0.55 frame is off, by 0.45
    assert brier_score(confidence, correct) == pytest.approx(0.45**2 / 3)
    # Cuts compare the confidences as written: -0.4 is not >= 0, 1.3 is >= 1.
    cuts = counts_at_cuts(confidence, correct, n_positive=2, cuts=[0.0, 1.0])
    assert cuts.accepted.tolist() == [2, 1]


def test_cuts_count_ties_new_places_and_nothing_accepted() -> None:
    # Frame 1 has no true match (a new place): accepted, it is wrong. Frame 5 is undecided.
    confidence = [0.99, 0.9, 0.9, 0.5, 0.2, NAN]
    correct = [True, False, True, True, False, True]
    cuts = counts_at_cuts(confidence, correct, n_positive=5, cuts=[0.5, 0.9, 0.99, 1.0])
    assert cuts.accepted.tolist() == [4, 3, 1, 0]  # both 0.9 frames are accepted at 0.9
    assert cuts.true_positives.tolist() == [3, 2, 1, 0]
    assert cuts.precision[:3].tolist() == pytest.approx([3 / 4, 2 / 3, 1.0])
    assert np.isnan(cuts.precision[3])
    assert cuts.recall.tolist() == pytest.approx([3 / 5, 2 / 5, 1 / 5, 0.0])


def test_accepted_frame_without_true_match_is_wrong_through_the_truth() -> None:
    # Query c has no true match; its confident match is wrong. Query d has no match at all, so its
    # confidence is ignored (undecided).
    truth = Truth(np.array([[1, 0], [0, 1], [0, 0], [1, 0]], dtype=bool), ["a", "b", "c", "d"], ["r0", "r1"])
    match = np.array([0, 0, 1, -1])
    confidence = decided_confidence(match, [0.95, 0.3, 0.97, 0.99])
    assert np.isnan(confidence[3])
    correct = correct_matches(match, truth)
    assert correct.tolist() == [True, False, False, False]
    calibration = summarize_calibration(confidence, correct, int(truth.has_match().sum()), cuts=[0.9])
    assert calibration.cuts.accepted.tolist() == [2]
    assert calibration.cuts.precision.tolist() == [0.5]
    assert calibration.cuts.recall.tolist() == pytest.approx([1 / 3])
    assert calibration.share_correct == pytest.approx(1 / 3)


def test_new_place_is_scored_against_the_frames_without_a_true_match() -> None:
    p_new = [0.9, 0.1, NAN, 0.6, 0.2]
    has_match = [False, True, False, True, True]  # frame 2, without a true match, says nothing
    calibration = summarize_new_place(p_new, has_match, cuts=(0.5,))
    assert calibration is not None
    assert calibration.mean_confidence == pytest.approx(0.45) and calibration.share_correct == 0.25
    assert calibration.brier == pytest.approx((0.01 + 0.01 + 0.36 + 0.04) / 4)
    assert calibration.ece == pytest.approx((0.1 + 0.1 + 0.6 + 0.2) / 4)
    # accepted at 0.5: frames 0 (new) and 3 (not); recall counts both frames without a match
    assert calibration.cuts.accepted.tolist() == [2] and calibration.cuts.precision.tolist() == [0.5]
    assert calibration.cuts.recall.tolist() == [0.5]
    assert set(calibration.row(NEW_PLACE_KEYS)) == {NEW_PLACE_KEYS + key for key in calibration.row()}
    assert summarize_new_place([NAN, NAN], [True, False]) is None


def test_nothing_decided_gives_nan_not_an_error() -> None:
    calibration = summarize_calibration([NAN, NAN], [True, False], n_positive=2)
    assert np.isnan([calibration.ece, calibration.brier, calibration.mean_confidence,
                     calibration.share_correct]).all()
    assert calibration.cuts.accepted.tolist() == [0, 0, 0]
    assert np.isnan(calibration.cuts.precision).all() and calibration.cuts.recall.tolist() == [0, 0, 0]


def test_cuts_outside_unit_interval_are_refused() -> None:
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        counts_at_cuts([0.5], [True], 1, cuts=[0.5, 1.5])
    with pytest.raises(ValueError):
        counts_at_cuts([0.5], [True], 1, cuts=[NAN])


def test_row_and_dict_views_agree() -> None:
    calibration = summarize_calibration([0.05, 0.95, 0.92], [False, True, False], n_positive=3,
                                        cuts=[0.5, 0.99])
    row = calibration.row()
    assert list(row) == ["ece", "brier", "mean_confidence", "share_correct", "precision@0.5", "recall@0.5",
                         "accepted@0.5", "precision@0.99", "recall@0.99", "accepted@0.99"]
    assert row["precision@0.5"] == 0.5 and row["accepted@0.5"] == 2 and np.isnan(row["precision@0.99"])
    data = calibration.as_dict()
    assert data["cuts"][0] == {"cut": 0.5, "precision": 0.5, "recall": pytest.approx(1 / 3), "accepted": 2}
    assert [b["count"] for b in data["reliability"]] == [1, 0, 0, 0, 0, 0, 0, 0, 0, 2]
    assert data["reliability"][9]["low"] == 0.9 and data["reliability"][9]["high"] == 1.0
    assert data["ece"] == row["ece"] == pytest.approx(calibration.bins.ece)


# --- properties --------------------------------------------------------------------------------

@st.composite
def calibrated_groups(draw: st.DrawFn) -> tuple[list[float], list[bool]]:
    """Groups of frames sharing one confidence c = k / n with exactly k of n correct."""
    confidence: list[float] = []
    correct: list[bool] = []
    for n, k in draw(st.lists(st.integers(1, 40).flatmap(lambda n: st.tuples(st.just(n), st.integers(0, n))),
                              min_size=1, max_size=12)):
        confidence += [k / n] * n
        correct += [True] * k + [False] * (n - k)
    return confidence, correct


@settings(max_examples=60, deadline=None)
@given(calibrated_groups())
def test_exactly_calibrated_sample_has_zero_ece(sample: tuple[list[float], list[bool]]) -> None:
    confidence, correct = sample
    assert expected_calibration_error(confidence, correct) == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(calibrated_groups(), st.floats(-0.3, 0.3))
def test_constant_offset_gives_ece_equal_to_the_offset(sample: tuple[list[float], list[bool]],
                                                      offset: float) -> None:
    confidence, correct = (np.asarray(a) for a in sample)
    shifted = confidence + offset
    keep = (shifted >= 0.0) & (shifted <= 1.0)  # no clipping, so every frame is off by the offset
    if not keep.any():
        return
    assert expected_calibration_error(shifted[keep], correct[keep]) == pytest.approx(abs(offset), abs=1e-9)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_sampled_calibrated_confidences_have_small_ece(seed: int) -> None:
    rng = np.random.default_rng(seed)
    confidence = rng.random(20_000)
    correct = rng.random(20_000) < confidence
    assert expected_calibration_error(confidence, correct) < 0.03
    # A sample twice as sure as it should be is clearly miscalibrated.
    assert expected_calibration_error(np.minimum(2 * confidence, 1.0), correct) > 0.15


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.5, 1.5), st.booleans()), min_size=1, max_size=60))
def test_ece_bounds_the_overall_gap_and_brier_stays_in_unit_interval(frames: list[tuple[float, bool]]) -> None:
    confidence, correct = (np.asarray(a) for a in zip(*frames))
    calibration = summarize_calibration(confidence, correct, n_positive=len(frames))
    # Binning can only hide gaps, never invent them: ECE >= |mean confidence - share correct|.
    assert calibration.ece >= abs(calibration.mean_confidence - calibration.share_correct) - 1e-12
    assert 0.0 <= calibration.brier <= 1.0 and 0.0 <= calibration.ece <= 1.0
    assert calibration.bins.count.sum() == len(frames)


def test_wilson_interval_matches_scipy_and_stays_in_the_unit_interval() -> None:
    from scipy.stats import binomtest

    successes, counts = np.array([0, 3, 10, 7, 0]), np.array([10, 10, 10, 1000, 0])
    low, high = wilson_interval(successes, counts)
    for k, n, lo, hi in zip(successes[:4], counts[:4], low, high):
        expected = binomtest(int(k), int(n)).proportion_ci(method="wilson")
        assert (lo, hi) == pytest.approx((expected.low, expected.high), abs=1e-9)
    assert low[0] == pytest.approx(0.0) and high[0] > 0.1  # not empty at a share of 0
    assert high[2] == pytest.approx(1.0) and low[2] < 0.9  # nor at 1
    assert np.isnan(low[4]) and np.isnan(high[4])  # an empty bin has none

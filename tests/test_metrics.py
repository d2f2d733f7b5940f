"""Exact precision-recall counting, summary metrics and the Table II global threshold."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wiloc.evaluation.groundtruth import Truth
from wiloc.evaluation.metrics import (average_precision, global_threshold, max_f1, pr_curve,
                                      precision_at_thresholds, recall_at_1, recall_at_precision, summarize)

NAN = float("nan")


# --- hand-made counting cases ----------------------------------------------------------------

def test_wrong_accepted_match_is_false_positive_and_lowers_recall() -> None:
    # Three frames, all with a true match; the middle one's best match is wrong.
    curve = pr_curve([0.9, 0.8, 0.7], [True, False, True], n_positive=3)
    assert curve.tp.tolist() == [1, 1, 2]
    assert curve.fp.tolist() == [0, 1, 1]
    assert curve.precision[-1] == pytest.approx(2 / 3)
    assert curve.recall[-1] == pytest.approx(2 / 3)  # the wrong match is not a recalled frame
    assert recall_at_precision(curve, 1.0) == (pytest.approx(1 / 3), 0.9)


def test_accepted_frame_without_true_match_is_false_positive() -> None:
    # Frame 1 has no true match (a new place), so its match cannot be correct.
    truth = Truth(np.array([[1, 0], [0, 0], [0, 1]], dtype=bool), ["a", "b", "c"], ["r0", "r1"])
    summary = summarize(np.array([0, 1, 1]), np.array([0.9, 0.95, 0.5]), truth)
    assert summary.with_true_match == 2
    assert summary.curve.fp.tolist() == [1, 1, 1]
    assert summary.recall_at_100 == 0.0
    assert summary.curve.recall[-1] == 1.0
    assert summary.recall_at_1 == 1.0


def test_ties_form_one_step() -> None:
    curve = pr_curve([0.5, 0.5, 0.5, 0.2], [True, False, True, True], n_positive=4)
    assert curve.thresholds.tolist() == [0.5, 0.2]
    assert curve.tp.tolist() == [2, 3]
    assert curve.fp.tolist() == [1, 1]
    # The correct tied frames cannot be taken without the wrong one.
    assert recall_at_precision(curve, 1.0)[0] == 0.0


def test_recall_at_full_precision_is_zero_when_most_confident_is_wrong() -> None:
    curve = pr_curve([0.99, 0.9, 0.8, 0.7], [False, True, True, True], n_positive=4)
    recall, threshold = recall_at_precision(curve, 1.0)
    assert recall == 0.0 and np.isnan(threshold)
    assert recall_at_precision(curve, 0.75) == (0.75, 0.7)


def test_undecided_frames_are_never_accepted_but_count_for_recall() -> None:
    curve = pr_curve([NAN, 0.8, NAN], [True, True, False], n_positive=3)
    assert curve.thresholds.tolist() == [0.8]
    assert curve.recall.tolist() == [pytest.approx(1 / 3)]


def test_average_precision_and_max_f1_by_hand() -> None:
    curve = pr_curve([0.9, 0.8, 0.7, 0.6], [True, False, True, False], n_positive=2)
    # Steps: recall 1/2 at precision 1, then recall 1 at precision 2/3.
    assert average_precision(curve) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    f1, threshold = max_f1(curve)
    assert f1 == pytest.approx(2 * (2 / 3) / (1 + 2 / 3)) and threshold == 0.7


def test_summarize_counts_and_keys() -> None:
    names = [f"f{i}" for i in range(4)]
    truth = Truth(np.eye(4, dtype=bool), names, names)
    summary = summarize(np.array([0, 2, -1, 3]), np.array([0.8, 0.9, NAN, 0.1]), truth)
    d = summary.as_dict()
    assert set(d) == {"frames", "decided", "with_true_match", "recall_at_100", "recall_at_99",
                      "recall_at_90", "auc", "max_f1", "max_f1_threshold", "recall_at_1"}
    assert (d["frames"], d["decided"], d["with_true_match"]) == (4, 3, 4)
    assert d["recall_at_100"] == 0.0  # the most confident (0.9) is wrong
    assert d["recall_at_1"] == 0.5
    with pytest.raises(ValueError):
        summarize(np.array([0, 1]), np.array([0.5, 0.5]), truth)


def test_global_threshold_on_two_traversals() -> None:
    a = ([0.9, 0.7, 0.5, 0.3], [True, True, False, True], 4)
    b = ([0.8, 0.6, 0.4], [True, False, True], 3)
    # 100 %: A fails from 0.5 down, B from 0.6 down -> the lowest keeping both is 0.7.
    threshold, recalls = global_threshold([a, b], 1.0)
    assert threshold == 0.7
    assert recalls == [pytest.approx(2 / 4), pytest.approx(1 / 3)]
    # 66 %: at 0.3, A has 3/4 and B 2/3 -> both keep it.
    threshold, recalls = global_threshold([a, b], 0.66)
    assert threshold == 0.3
    assert recalls == [pytest.approx(3 / 4), pytest.approx(2 / 3)]


def test_global_threshold_without_any_keeping_threshold() -> None:
    # The first traversal's only decision is wrong: every threshold that B keeps (0.8) accepts it.
    b = ([0.8, 0.6, 0.4], [True, False, True], 3)
    threshold, recalls = global_threshold([([0.9], [False], 1), b], 1.0)
    assert np.isnan(threshold) and recalls == [0.0, 0.0]


def test_precision_at_thresholds_is_nan_when_nothing_accepted() -> None:
    got = precision_at_thresholds([0.9, 0.5, NAN], [True, False, True], [1.0, 0.9, 0.5, 0.0])
    assert np.isnan(got[0])
    assert got[1:].tolist() == [1.0, 0.5, 0.5]


def test_recall_at_1_ignores_confidence() -> None:
    assert recall_at_1([True, False, True, True], [True, True, False, True]) == pytest.approx(2 / 3)
    assert recall_at_1([False], [False]) == 0.0


# --- properties on random inputs -------------------------------------------------------------

@st.composite
def runs(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, int]:
    """Random confidences (coarse, so ties happen; some NaN), correctness and positive counts."""
    n = draw(st.integers(1, 40))
    levels = draw(st.integers(1, 6))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    conf = rng.integers(0, levels, n) / levels
    conf[rng.random(n) < 0.15] = np.nan
    has_match = rng.random(n) < 0.8
    correct = has_match & (rng.random(n) < 0.6)
    return conf, correct, int(has_match.sum())


@settings(max_examples=60, deadline=None)
@given(runs())
def test_curve_is_bounded_and_recall_grows(run: tuple[np.ndarray, np.ndarray, int]) -> None:
    curve = pr_curve(*run)
    assert np.all((curve.precision >= 0) & (curve.precision <= 1))
    assert np.all((curve.recall >= 0) & (curve.recall <= 1))
    assert np.all(np.diff(curve.thresholds) < 0)
    assert np.all(np.diff(curve.recall) >= 0)  # loosening the threshold never loses recall
    assert 0.0 <= average_precision(curve) <= 1.0
    assert 0.0 <= max_f1(curve)[0] <= 1.0


@settings(max_examples=60, deadline=None)
@given(runs())
def test_exact_curve_matches_brute_force_count(run: tuple[np.ndarray, np.ndarray, int]) -> None:
    conf, correct, n_positive = run
    curve = pr_curve(conf, correct, n_positive)
    distinct = np.unique(conf[~np.isnan(conf)])
    assert sorted(curve.thresholds.tolist()) == distinct.tolist()
    for tau, p, r in zip(curve.thresholds, curve.precision, curve.recall):
        accepted = [i for i in range(conf.size) if not np.isnan(conf[i]) and conf[i] >= tau]
        tp = sum(bool(correct[i]) for i in accepted)
        assert p == pytest.approx(tp / len(accepted))
        assert r == pytest.approx(tp / n_positive if n_positive else 0.0)
    np.testing.assert_allclose(precision_at_thresholds(conf, correct, curve.thresholds),
                               curve.precision)


@settings(max_examples=40, deadline=None)
@given(runs(), st.sampled_from([1.0, 0.99, 0.9, 0.5]))
def test_global_threshold_on_one_traversal_is_recall_at_precision(
        run: tuple[np.ndarray, np.ndarray, int], target: float) -> None:
    threshold, (recall,) = global_threshold([run], target)
    expected = recall_at_precision(pr_curve(*run), target)[0]
    assert recall == pytest.approx(expected)
    if not np.isnan(threshold):
        assert precision_at_thresholds(run[0], run[1], [threshold])[0] >= target


@settings(max_examples=40, deadline=None)
@given(st.lists(runs(), min_size=2, max_size=3), st.sampled_from([1.0, 0.9, 0.7]))
def test_global_threshold_keeps_precision_everywhere_and_is_lowest(
        inputs: list[tuple[np.ndarray, np.ndarray, int]], target: float) -> None:
    threshold, recalls = global_threshold(inputs, target)
    candidates = np.unique(np.concatenate([c[~np.isnan(c)] for c, _, _ in inputs]))

    def keeps(tau: float) -> bool:
        return all(np.isnan(p) or p >= target
                   for c, ok, _ in inputs for p in precision_at_thresholds(c, ok, [tau]))

    if np.isnan(threshold):
        assert not any(keeps(t) for t in candidates)
        return
    assert keeps(threshold)
    assert not any(keeps(t) for t in candidates[candidates < threshold])
    for (c, ok, n), r in zip(inputs, recalls):
        tp = int(np.sum(ok & (c >= threshold)))  # NaN >= threshold is False
        assert r == pytest.approx(tp / n if n else 0.0)


def test_precision_target_in_percent_is_met_exactly() -> None:
    # 999 of 1000 is 99.9 %, but 999 / 1000 >= 99.9 / 100 is False in floating point.
    conf = np.r_[np.full(999, 0.8), 0.8, np.full(500, 0.3)]
    ok = np.r_[np.ones(999, bool), False, np.zeros(500, bool)]
    target = 99.9 / 100
    assert recall_at_precision(pr_curve(conf, ok, 1000), target) == (pytest.approx(0.999), 0.8)
    threshold, recalls = global_threshold([(conf, ok, 1000)], target)
    assert threshold == 0.8 and recalls == [pytest.approx(0.999)]
    # the slack is relative and tiny: 100 % still rejects one error in a million
    big = np.r_[np.ones(999_999, bool), False]
    recall, threshold = recall_at_precision(pr_curve(np.ones(big.size), big, big.size), 1.0)
    assert recall == 0.0 and np.isnan(threshold)


def test_max_f1_has_no_threshold_when_every_f1_is_zero() -> None:
    curve = pr_curve([0.994, 0.5, 0.2], [False, False, False], 3)
    f1, threshold = max_f1(curve)
    assert f1 == 0.0 and np.isnan(threshold)

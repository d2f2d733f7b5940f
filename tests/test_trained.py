"""The trained model: histograms from labelled pairs, decisions with P(L | m)."""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse
from scipy import stats

from wiloc.errors import WilocError
from wiloc.localization.array_run import run_on_rows
from wiloc.methods.base import TrainingRows
from wiloc.methods.trained import Trained, TrainedParams, train_model


def _labelled(rng: np.random.Generator, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows over m candidates: the true match of row k is candidate k % m (gamma), others normal."""
    labels = np.zeros((n, m), dtype=bool)
    labels[np.arange(n), np.arange(n) % m] = True
    rows = stats.norm(0.7, 0.1).rvs(size=(n, m), random_state=rng)
    rows[labels] = stats.gamma(4.0, scale=0.08).rvs(size=n, random_state=rng)
    return rows, labels


def test_all_pairs_posterior_matches_truth() -> None:
    rng = np.random.default_rng(11)
    rows, labels = _labelled(rng, 3000, 4)
    model = train_model(list(rows), scipy.sparse.csr_matrix(labels), TrainedParams(bins=25, pairs="all"))
    assert model.b.sum() == labels.sum() and model.c.sum() == (~labels).sum()
    fb = np.diff(stats.gamma(4.0, scale=0.08).cdf(model.edges))
    fc = np.diff(stats.norm(0.7, 0.1).cdf(model.edges))
    prior = model.prior_same()
    assert prior == pytest.approx(0.25)
    truth = prior * fb / (prior * fb + (1 - prior) * fc)
    counts = model.b + model.c
    bulk = counts >= 0.01 * counts.sum()
    centres = 0.5 * (model.edges[1:] + model.edges[:-1])
    err = np.abs(model.posterior(centres) - truth)[bulk]
    assert bulk.sum() >= 10 and err.max() < 0.1


def test_minima_pairs_label_each_best_match() -> None:
    rng = np.random.default_rng(12)
    rows, labels = _labelled(rng, 400, 6)
    rows[::7] = np.inf
    model = train_model(iter(rows), labels, TrainedParams(bins=10))
    decided = np.isfinite(rows).any(axis=1)
    right = labels[np.arange(400), np.argmin(rows, axis=1)] & decided
    assert model.b.sum() == right.sum()
    assert model.c.sum() == decided.sum() - right.sum()


def test_localize_trained_uses_the_posterior_of_the_minimum() -> None:
    rng = np.random.default_rng(13)
    rows, labels = _labelled(rng, 300, 5)
    model = train_model(list(rows), labels, TrainedParams(bins=20))
    test_rows, _ = _labelled(rng, 50, 5)
    test_rows[4] = np.inf
    out = run_on_rows(Trained(bins=20), list(test_rows), 50, training=TrainingRows(list(rows), labels))
    assert out.match[4] == -1 and np.isnan(out.confidence[4])
    ok = out.decided
    assert np.array_equal(out.match[ok], np.argmin(test_rows[ok], axis=1))
    assert np.allclose(out.confidence[ok], model.posterior(test_rows[ok].min(axis=1)))
    for learned, trained in [(out.model.b, model.b), (out.model.c, model.c), (out.model.edges, model.edges)]:
        np.testing.assert_array_equal(learned, trained)
    assert out.params["bins"] == 20 and out.params["method"] == "trained"


def test_training_needs_both_classes_and_matching_shapes() -> None:
    rows = np.ones((3, 4))
    with pytest.raises(WilocError):
        train_model(list(rows), np.zeros((3, 4), dtype=bool))
    with pytest.raises(WilocError):
        train_model(list(rows), np.eye(3, 5, dtype=bool))
    with pytest.raises(WilocError):
        TrainedParams(pairs="some")  # type: ignore[arg-type]


@pytest.mark.parametrize(("option", "value"), [
    ("bins", 0), ("smoothing", 0.0), ("smoothing", -1.0), ("prior", 1.5)])
def test_bad_option_names_the_parameter(option: str, value: float) -> None:
    with pytest.raises(WilocError) as err:
        Trained(**{option: value})
    assert err.value.parameter == option and err.value.problem.startswith("must ")


def test_p_new_place_is_one_minus_the_confidence_and_the_docs_say_so() -> None:
    """trained models no new place: its P(new place) is 1 - P(L | m), which a wrong match in the
    map raises as a frame off the map does. The docs that list it among the runs saying
    P(new place) must say what it is, not present it as a model of new places."""
    from pathlib import Path

    rng = np.random.default_rng(17)
    rows, labels = _labelled(rng, 200, 5)
    test_rows, _ = _labelled(rng, 30, 5)
    out = run_on_rows(Trained(bins=20), list(test_rows), 30, training=TrainingRows(list(rows), labels))
    np.testing.assert_allclose(out.columns["new_place"], 1.0 - out.confidence)
    docs = Path(__file__).resolve().parents[1] / "docs"
    for name in ("evaluation.md", "guide.md", "formats.md", "algorithm.md"):
        text = " ".join(docs.joinpath(name).read_text().split())
        assert re.search(r"`trained`('s)?[^.]*?(P\(new place\)|new_place)?[^.]*? 1 - (its |`)?confidence"
                         r"|`new_place` is 1 - P\(L \| m\)", text), name


@pytest.mark.parametrize(("label", "wider"), [(True, "smaller"), (False, "larger")])
def test_one_sided_training_truth_names_the_training_options(label: bool, wider: str) -> None:
    """Labels all true (--train-tolerance 200 on 200 frames) were refused as "train: ...", neither
    an option nor a file: the problem is the training truth, --train-gt and its tolerance or radius."""
    from wiloc.cli.params import flag

    rows = np.random.default_rng(3).random((6, 4))
    with pytest.raises(WilocError) as err:
        train_model(list(rows), np.full((6, 4), label))
    assert flag(err.value.parameter) == "--train-gt"
    assert err.value.problem.startswith("training needs both true and false matches")
    assert f"with a {wider} tolerance or radius" in err.value.problem
    with pytest.raises(WilocError) as err:
        train_model(list(rows), np.eye(6, 5, dtype=bool))
    assert err.value.parameter == "training" and err.value.where == "training"

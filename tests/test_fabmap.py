"""FAB-MAP 1.0 (wiloc/fabmap): Chow-Liu tree, detector and place models, likelihood, new place."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from wiloc.errors import ParameterError
from wiloc.bow.fabmap import (
                              NEW_PLACE_METHODS,
                              ChowLiuTree,
                              Detector,
                              FabMap,
                              FabMapParams,
                              mutual_information,
                              )
from wiloc.parameters import declared


def _tree_samples(rng: np.random.Generator, parent: np.ndarray, p_root: float,
                  p_on: np.ndarray, p_off: np.ndarray, n: int) -> np.ndarray:
    """n draws of a tree-structured binary distribution; parent[q] < q, node 0 the root."""
    z = np.zeros((n, len(parent)), bool)
    z[:, 0] = rng.random(n) < p_root
    for q in range(1, len(parent)):
        z[:, q] = rng.random(n) < np.where(z[:, parent[q]], p_on[q], p_off[q])
    return z


def _edges(parent: np.ndarray) -> set[frozenset[int]]:
    return {frozenset((q, int(p))) for q, p in enumerate(parent) if p >= 0}


# ----------------------------------------------------------------------------- Chow-Liu tree

def test_chow_liu_recovers_a_known_tree() -> None:
    rng = np.random.default_rng(3)
    k = 12
    parent = np.r_[-1, [rng.integers(0, q) for q in range(1, k)]]
    p_on, p_off = rng.uniform(0.75, 0.9, k), rng.uniform(0.05, 0.2, k)
    z = _tree_samples(rng, parent, 0.5, p_on, p_off, 5000)
    tree = ChowLiuTree.fit(z)
    assert _edges(tree.parent) == _edges(parent)
    assert (tree.parent < 0).sum() == 1 and tree.parent[tree.root] == -1
    assert tree.root == int(np.argmax(z.sum(axis=0)))  # the most frequent word
    # Where the fit orients an edge as the generator did, it recovers the conditionals.
    same = [q for q in range(1, k) if tree.parent[q] == parent[q]]
    assert same
    assert np.allclose(tree.conditional[same, 1], p_on[same], atol=0.05)
    assert np.allclose(tree.conditional[same, 0], p_off[same], atol=0.05)


def test_mutual_information_matches_a_direct_count() -> None:
    rng = np.random.default_rng(0)
    a = rng.random(400) < 0.3
    b = np.where(rng.random(400) < 0.8, a, ~a)
    c = rng.random(400) < 0.5
    info = mutual_information(np.column_stack([a, b, c, a]))
    joint = np.array([[np.mean((a == x) & (b == y)) for y in (0, 1)] for x in (0, 1)])
    pa, pb = joint.sum(1), joint.sum(0)
    direct = sum(joint[x, y] * np.log(joint[x, y] / (pa[x] * pb[y]))
                 for x in (0, 1) for y in (0, 1) if joint[x, y] > 0)
    assert info[0, 1] == pytest.approx(direct, rel=1e-12) and info[1, 0] == info[0, 1]
    entropy = -(pa * np.log(pa)).sum()
    assert info[0, 3] == pytest.approx(entropy, rel=1e-12)  # a word with its copy
    assert info[0, 2] < 0.01 and np.all(np.diag(info) == 0)


def test_smoothing_keeps_probabilities_inside_0_1_and_falls_back_to_the_marginal() -> None:
    z = np.zeros((10, 3), bool)
    z[:, 0] = True  # always on: the root; word 1 never seen; word 2 copies word 0
    z[:, 2] = True
    tree = ChowLiuTree.fit(z, smoothing=1.0)
    assert tree.root == 0
    assert tree.marginal == pytest.approx([11 / 12, 1 / 12, 11 / 12])
    assert np.all((tree.conditional > 0) & (tree.conditional < 1))
    # The parent state "off" never occurs: that conditional is the word's own marginal.
    assert tree.conditional[2, 0] == pytest.approx(tree.marginal[2])
    assert tree.conditional[2, 1] == pytest.approx((10 + 2 * 11 / 12) / 12)
    assert tree.conditional[0] == pytest.approx([11 / 12, 11 / 12])  # the root: its marginal


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "1"])
def test_tree_smoothing_is_checked(bad: object) -> None:
    with pytest.raises(ParameterError) as info:
        ChowLiuTree.fit(np.eye(4, dtype=bool), smoothing=bad)  # type: ignore[arg-type]
    assert info.value.parameter == "smoothing"


# ----------------------------------------------------------------------------- brute force

def _brute_appearance(tree: ChowLiuTree, detector: Detector, observations: np.ndarray) -> np.ndarray:
    """p(e_q = 1 | L) by Bayes' rule over e_q in {0, 1}, one observation at a time."""
    p_one = detector.detection()  # p(z=1 | e=0), p(z=1 | e=1)
    out = np.empty(tree.n_words)
    for q in range(tree.n_words):
        weight = np.array([1 - tree.marginal[q], tree.marginal[q]])
        for z in observations:
            weight = weight * np.where(z[q], p_one, 1 - p_one)
        out[q] = weight[1] / weight.sum()
    return out


def _brute_likelihood(tree: ChowLiuTree, detector: Detector, appearance: np.ndarray,
                      z: np.ndarray) -> float:
    """p(Z | L) as the sum over all 2^K hidden states e of prod_q p(z_q | e_q, z_p) p(e_q | L),
    p(z_q | e_q, z_p) proportional to p(z_q | e_q) p(z_q | z_p) / p(z_q) (the root: p(z | e))."""
    p_one = detector.detection()

    def p_word(q: int, e: int) -> float:
        def f(s: int) -> float:
            d = p_one[e] if s else 1 - p_one[e]
            if tree.parent[q] < 0:
                return d
            c = tree.conditional[q, int(z[tree.parent[q]])]
            m = tree.marginal[q]
            return d * (c if s else 1 - c) / (m if s else 1 - m)
        return f(int(z[q])) / (f(0) + f(1))

    total = 0.0
    for e in itertools.product((0, 1), repeat=tree.n_words):
        term = 1.0
        for q, eq in enumerate(e):
            term *= p_word(q, eq) * (appearance[q] if eq else 1 - appearance[q])
        total += term
    return total


@pytest.fixture
def tiny() -> tuple[ChowLiuTree, np.ndarray]:
    """A 5-word tree fitted on random training data, and that data."""
    rng = np.random.default_rng(7)
    parent = np.array([-1, 0, 0, 1, 1])
    train = _tree_samples(rng, parent, 0.4, np.full(5, 0.7), np.full(5, 0.2), 60)
    return ChowLiuTree.fit(train), train


@pytest.mark.parametrize("detector", [(0.0, 0.61), (0.05, 0.3)])
def test_likelihood_equals_the_sum_over_hidden_states(tiny: tuple, detector: tuple) -> None:
    tree, train = tiny
    params = FabMapParams(false_positive=detector[0], false_negative=detector[1])
    fabmap = FabMap(tree, params, training=train)
    rng = np.random.default_rng(1)
    visits = [rng.random((m, 5)) < 0.5 for m in (1, 1, 3, 2)]
    for observations in visits:
        fabmap.add_place(observations)
    for place, observations in enumerate(visits):
        assert fabmap.appearance(place) == pytest.approx(
            _brute_appearance(tree, fabmap.detector, observations), rel=1e-12)
    for z in (rng.random((6, 5)) < 0.5):
        expected = [np.log(_brute_likelihood(tree, fabmap.detector, fabmap.appearance(j), z))
                    for j in range(len(visits))]
        assert fabmap.log_likelihoods(z) == pytest.approx(expected, rel=1e-10)
        # Sampled new place: the mean over place models of the training images, each seen once.
        sampled = np.mean([_brute_likelihood(tree, fabmap.detector,
                                             _brute_appearance(tree, fabmap.detector, s[None]), z)
                           for s in fabmap.new_place_samples.astype(bool)])
        assert fabmap.new_place_log_likelihood(z) == pytest.approx(np.log(sampled), rel=1e-10)
        rows, new = fabmap.frame_log_likelihoods(z)
        assert np.array_equal(rows, fabmap.log_likelihoods(z))
        assert new == fabmap.new_place_log_likelihood(z)
        mean_field = FabMap(tree, FabMapParams(*detector, new_place="mean-field"))
        average = _brute_likelihood(tree, fabmap.detector, tree.marginal, z)
        assert mean_field.new_place_log_likelihood(z) == pytest.approx(np.log(average), rel=1e-10)


def test_likelihood_is_a_distribution_over_all_observations(tiny: tuple) -> None:
    tree, train = tiny
    fabmap = FabMap(tree, training=train)
    fabmap.add_place(train[0])
    fabmap.add_place(train[1:4])
    every = np.array(list(itertools.product((0, 1), repeat=5)), bool)
    total = np.exp([fabmap.log_likelihoods(z) for z in every]).sum(axis=0)
    assert total == pytest.approx([1.0, 1.0], rel=1e-12)
    assert np.exp([fabmap.new_place_log_likelihood(z) for z in every]).sum() == pytest.approx(1.0)


def test_updating_a_place_equals_adding_it_with_all_observations(tiny: tuple) -> None:
    tree, train = tiny
    a, b = FabMap(tree, training=train), FabMap(tree, training=train)
    a.add_place(train[:3])
    b.add_place(train[0])
    b.update_place(0, train[1:3])
    assert np.array_equal(a.appearance(0), b.appearance(0))
    assert a.log_likelihoods(train[5]) == pytest.approx(b.log_likelihoods(train[5]))
    with pytest.raises(IndexError):
        b.update_place(1, train[0])


def test_zero_false_positive_makes_a_seen_word_certain() -> None:
    detector = Detector(0.0, 0.61)
    assert detector.appearance(1, 1, 0.01) == 1.0
    assert detector.appearance(2, 0, 0.2) == pytest.approx(0.2 * 0.61**2 / (0.2 * 0.61**2 + 0.8))
    assert detector.appearance(3, 1, 0.2) == 1.0


# ----------------------------------------------------------------------------- posterior

def test_the_fabmap_method_decides_by_the_model_s_posterior(tiny: tuple) -> None:
    from wiloc.methods.fabmap import FabMapMethod

    tree, train = tiny
    method = FabMapMethod(new_place_prior=0.6, posterior_smoothing=0.9, window=0)
    fabmap = FabMap(tree, method.params, training=train)
    for z in train[:6]:
        fabmap.add_place(z)
    for z in train[10:14]:
        places, new = fabmap.posterior(z)
        rows, new_row = fabmap.frame_log_likelihoods(z)
        decision = method.decide(rows - new_row, None)
        assert decision.match == int(np.argmax(places))
        assert (decision.confidence, decision.new_place) == pytest.approx((places.max(), new), rel=1e-12)


def test_posterior_is_normalised_over_places_and_new_place(tiny: tuple) -> None:
    tree, train = tiny
    params = FabMapParams(posterior_smoothing=1.0, new_place_prior=0.5)
    fabmap = FabMap(tree, params, training=train)
    for z in train[:4]:
        fabmap.add_place(z)
    z = train[2]
    places, new = fabmap.posterior(z)
    assert places.sum() + new == pytest.approx(1.0)
    log = np.append(np.log(0.5 / 4) + fabmap.log_likelihoods(z),
                    np.log(0.5) + fabmap.new_place_log_likelihood(z))
    expected = np.exp(log - np.logaddexp.reduce(log))
    assert np.append(places, new) == pytest.approx(expected, rel=1e-10)
    # A place with prior 0 gets nothing; the others share its mass by their likelihoods.
    places, new = fabmap.posterior(z, prior=[1.0, 1.0, 0.0, 1.0])
    assert places[2] == 0.0 and places.sum() + new == pytest.approx(1.0)


def test_posterior_smoothing_and_empty_map(tiny: tuple) -> None:
    tree, train = tiny
    fabmap = FabMap(tree, training=train)  # sigma = 0.99
    places, new = fabmap.posterior(train[0])
    assert places.shape == (0,) and new == pytest.approx(1.0)
    fabmap.add_place(train[0])
    fabmap.add_place(train[1])
    places, new = fabmap.posterior(train[0], prior=[0.0, 1.0])
    assert places[0] == pytest.approx(0.01 / 3)  # (1 - sigma) / (places + 1)
    with pytest.raises(ValueError, match="prior"):
        fabmap.posterior(train[0], prior=[1.0])


def test_new_place_probability_rises_on_a_detour() -> None:
    """A generated world: places whose scene elements follow a tree-structured distribution, seen
    through a noisy detector. The map is one visit of a 40-place route; the query revisits it,
    then takes a 20-place detour the map never saw."""
    rng = np.random.default_rng(1)
    k = 100
    parent = np.r_[-1, [rng.integers(0, q) for q in range(1, k)]]
    p_on, p_off = rng.uniform(0.5, 0.8, k), rng.uniform(0.1, 0.2, k)

    def places(n: int) -> np.ndarray:
        return _tree_samples(rng, parent, 0.3, p_on, p_off, n)

    def observe(elements: np.ndarray) -> np.ndarray:  # 20 % missed, 1 % spurious
        return np.where(elements, rng.random(elements.shape) > 0.2, rng.random(elements.shape) < 0.01)

    train = observe(places(300))
    route, detour = places(40), places(20)
    tree = ChowLiuTree.fit(train)
    queries = observe(np.vstack([route, detour]))
    for method in ("sampled", "mean-field"):
        fabmap = FabMap(tree, FabMapParams(new_place=method), training=train)
        for z in observe(route):
            fabmap.add_place(z)
        results = [fabmap.posterior(z) for z in queries]
        new = np.array([p_new for _, p_new in results])
        best = np.array([np.argmax(p) for p, _ in results])
        assert np.mean(best[:40] == np.arange(40)) >= 0.9
        assert new[40:].mean() > 10 * new[:40].mean()
        assert np.median(new[40:]) > np.max(np.sort(new[:40])[:-2])  # all but 2 revisits below
        if method == "sampled":
            assert new[:40].mean() < 0.1 and new[40:].mean() > 0.7


# ----------------------------------------------------------------------------- parameters

@pytest.mark.parametrize(("name", "value"), [
    ("false_positive", -0.1), ("false_positive", 0.5), ("false_negative", 0.0),
    ("false_negative", 1.0), ("new_place", "exact"), ("samples", 0), ("samples", 2.5),
    ("new_place_prior", 1.0), ("posterior_smoothing", 0.0), ("posterior_smoothing", 1.5),
    ("seed", -1), ("false_negative", float("nan")), ("new_place_prior", True),
])
def test_every_parameter_is_checked_and_named(name: str, value: object) -> None:
    with pytest.raises(ParameterError) as info:
        FabMapParams(**{name: value})
    assert info.value.parameter == name


def test_every_parameter_is_declared_with_help_and_range() -> None:
    for d in declared(FabMapParams):
        assert d.help and (d.choices or d.kind == "int" or d.range_text), d.name
    assert declared(FabMapParams)[2].choices == NEW_PLACE_METHODS


def test_defaults_are_the_published_ones() -> None:
    p = FabMapParams()
    assert (p.false_positive, 1 - p.false_negative) == (0.0, pytest.approx(0.39))
    assert (p.new_place, p.samples, p.new_place_prior, p.posterior_smoothing) == \
        ("sampled", 3000, 0.9, 0.99)


def test_sampling_needs_training_and_is_capped_and_seeded(tiny: tuple) -> None:
    tree, train = tiny
    with pytest.raises(ParameterError) as info:
        FabMap(tree)
    assert info.value.parameter == "new_place"
    assert len(FabMap(tree, training=train).new_place_samples) == len(train)  # fewer than 3000
    a = FabMap(tree, FabMapParams(samples=10, seed=1), training=train).new_place_samples
    b = FabMap(tree, FabMapParams(samples=10, seed=1), training=train).new_place_samples
    c = FabMap(tree, FabMapParams(samples=10, seed=2), training=train).new_place_samples
    assert len(a) == 10 and np.array_equal(a, b) and not np.array_equal(a, c)


def test_observations_are_checked(tiny: tuple) -> None:
    tree, train = tiny
    fabmap = FabMap(tree, training=train)
    with pytest.raises(ValueError, match="K = 5"):
        fabmap.add_place(np.ones(4, bool))
    with pytest.raises(ValueError, match="bool or 0/1"):
        fabmap.add_place(np.full(5, 2))
    with pytest.raises(ValueError, match="one observation"):
        fabmap.log_likelihoods(train[:2])

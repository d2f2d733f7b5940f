"""The online model: the Appendix logic on hand-made rows, causality, and unsupervised convergence."""
from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy import stats

from wiloc.cache.store import Cache
from wiloc.decisions import Decisions
from wiloc.errors import WilocError
from wiloc.localization.array_run import run_on_rows
from wiloc.methods.online import Online, near_miss

from helpers import loop_rows

INF = np.inf


def localize_online(rows: list[np.ndarray], n: int, *, sequence: bool, init_rows: list[np.ndarray] | None = None,
                    progress=None, **params) -> Decisions:
    """An online run on arrays; ``init_rows``: the map against itself, inf on the diagonal."""
    return run_on_rows(Online(**params), rows, n, sequence=sequence, exclude_recent=0, progress=progress,
                       map_self=None if init_rows is None else np.array(init_rows))


def _seq(values: list[list[float]], n: int) -> list[np.ndarray]:
    """Sequence-mode rows: row k lists the differences to frames 0..len-1, the rest not candidates."""
    rows = []
    for vals in values:
        row = np.full(n, INF)
        row[: len(vals)] = vals
        rows.append(row)
    return rows


def test_initialisation_adds_only_to_c() -> None:
    rows = _seq([[], [0.5], [0.7, 0.3], [0.9, 0.6, 0.4]], 4)
    calls: list[tuple[int, int]] = []
    out = localize_online(rows, 4, sequence=True, init=3, bins=10,
                          progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (4, 4) and len(calls) == 4
    assert out.stage.tolist() == ["none", "init", "init", "init"]
    assert not out.decided.any()
    assert out.model is not None and out.model.b.sum() == 0
    assert out.model.c.sum() == 3
    assert np.array_equal(out.model.c, np.bincount(out.model.bin_of([0.5, 0.3, 0.4]), minlength=10))
    # the bin range is fixed from the minima seen, starting at 0
    assert out.model.edges[0] == 0.0 and out.model.edges[-1] == pytest.approx(0.5)


def test_update_adds_minimum_to_b_and_near_miss_to_c() -> None:
    rows = _seq([[], [0.8], [0.9, 0.7], [0.2, 0.6, 0.9]], 4)
    out = localize_online(rows, 4, sequence=True, init=2, bins=8, same_place_window=0)
    assert out.stage.tolist() == ["none", "init", "init", "update"]
    assert out.match[3] == 0 and out.difference[3] == 0.2
    assert out.columns["m_r"][3] == 0.6
    model = out.model
    assert np.array_equal(model.b, np.bincount(model.bin_of([0.2]), minlength=8))
    assert np.array_equal(model.c, np.bincount(model.bin_of([0.8, 0.7, 0.6]), minlength=8))


def test_candidate_whose_match_is_in_m_is_skipped() -> None:
    match = np.array([-1, -1, -1, 0, -1, -1, -1])
    row = np.array([0.1, INF, 0.5, 0.2, 0.3, INF, INF])
    # z = 0; frame 3 was matched to 0, so it is the same place; frame 4 is not
    assert near_miss(row, 0, match, window=0) == 0.3
    assert near_miss(row, 0, np.full(7, -1), window=0) == 0.2


def test_candidate_that_is_the_match_of_min_m_is_skipped() -> None:
    match = np.array([-1, -1, -1, -1, -1, 1, -1, -1])
    row = np.array([INF, 0.2, 0.3, INF, INF, 0.1, INF, INF])
    # z = 5 was matched to 1, so frame 1 is the same place; frame 2 is not
    assert near_miss(row, 5, match, window=0) == 0.3
    assert near_miss(row, 5, np.full(8, -1), window=0) == 0.2


def test_chain_of_links_grows_m() -> None:
    # visits 0, 3, 6 of one place: match(6) = 3, match(3) = 0; z = 6 -> 3 -> 0 all excluded
    match = np.array([-1, -1, -1, 0, -1, -1, 3, -1, -1])
    row = np.array([0.15, 0.9, 0.8, 0.12, INF, INF, 0.1, INF, INF])
    assert near_miss(row, 6, match, window=0) == 0.8


def test_frames_within_window_of_z_are_skipped() -> None:
    row = np.array([0.9, 0.3, 0.25, 0.1, 0.2, 0.35, 0.5])
    assert near_miss(row, 3, None, window=0) == 0.2
    assert near_miss(row, 3, None, window=2) == 0.5
    assert np.isnan(near_miss(row, 3, None, window=6))


def test_frames_within_window_of_z_join_m() -> None:
    n = 200
    row = np.full(n, INF)
    row[[50, 120, 130, 140]] = [0.1, 0.2, 0.3, 0.4]
    match = np.full(n, -1)
    match[120] = 51
    # 51 lies within +-2 of z = 50, so frame 120, matched to 51, is the same place as z
    assert near_miss(row, 50, match, window=2) == 0.3
    # min(M) is 48, the window's first frame: the frame it was matched to is the same place too
    match[48] = 130
    assert near_miss(row, 50, match, window=2) == 0.4


def test_match_links_are_recorded_by_the_run() -> None:
    n = 5
    rows = _seq([[], [0.9], [0.3, 0.8], [0.95, 0.9, 0.85], [0.25, 0.6, 0.2, 0.7]], n)
    out = localize_online(rows, n, sequence=True, init=1, bins=10, same_place_window=0)
    assert out.match[2] == 0
    # frame 4: z = 2; frame 0 is excluded because match(2) = 0; frame 1 (0.6) is the near miss
    assert out.match[4] == 2 and out.columns["m_r"][4] == 0.6


def test_confidence_is_causal_and_the_frame_updates_the_histograms_after() -> None:
    rng = np.random.default_rng(5)
    n = 40
    rows = [np.where(np.arange(n) < k - 2, rng.uniform(0.0, 1.0, n), INF) for k in range(n)]
    for k in (20, 33):
        before = localize_online(rows[:k], k, sequence=True, init=10, bins=10).model
        frozen = copy.deepcopy(before)
        after = localize_online(rows[: k + 1], k + 1, sequence=True, init=10, bins=10)
        later = localize_online(rows[: k + 6], k + 6, sequence=True, init=10, bins=10)
        np.testing.assert_array_equal(later.confidence[: k + 1], after.confidence)  # later frames change nothing
        np.testing.assert_array_equal(later.columns["new_place"][: k + 1], after.columns["new_place"])
        assert after.model.b.sum() == frozen.b.sum() + 1


def test_appendix_confidence_is_p_l_given_m_from_the_histograms_before_the_frame() -> None:
    """``confidence="appendix"``: the paper's P(L | m) (SPEC.md section 4), computed before the
    frame's m and m_r join the histograms, and P(new place) 1 - P(L | m); the decisions and the
    histograms are those of the default run."""
    from wiloc.model import HistogramModel

    rows, _ = loop_rows(np.random.default_rng(2), places=40, recent=5)
    n = len(rows)
    filtered = localize_online(rows, n, sequence=True, init=20, bins=12)
    out = localize_online(rows, n, sequence=True, init=20, bins=12, confidence="appendix")
    np.testing.assert_array_equal(out.match, filtered.match)
    np.testing.assert_array_equal(out.model.b, filtered.model.b)
    assert not np.allclose(out.confidence[out.decided], filtered.confidence[out.decided])
    init = [float(np.min(rows[k])) for k in range(n) if out.stage[k] == "init"]
    model = HistogramModel.from_values(np.array(init), 12, smoothing=0.1)
    model.add_different(np.array(init))
    for k in np.flatnonzero(out.decided):
        assert out.confidence[k] == pytest.approx(float(model.posterior(out.difference[k])), abs=1e-12)
        model.add_same(np.array([out.difference[k]]))
        if np.isfinite(out.columns["m_r"][k]):
            model.add_different(np.array([out.columns["m_r"][k]]))
    np.testing.assert_allclose(out.columns["new_place"][out.decided], 1.0 - out.confidence[out.decided])


def test_map_mode_initialises_from_reference_rows() -> None:
    ref = [np.array([INF, 0.6, 0.8]), np.array([0.6, INF, 0.7]), np.array([0.8, 0.7, INF])]
    queries = [np.array([0.1, 0.5, 0.9]), np.array([0.4, 0.2, 0.3])]
    out = localize_online(queries, 2, sequence=False, init_rows=ref, bins=5, same_place_window=0)
    assert out.stage.tolist() == ["update", "update"]
    assert out.match.tolist() == [0, 1]
    assert out.columns["m_r"].tolist() == [0.5, 0.3]
    assert out.model.b.sum() == 2 and out.model.c.sum() == 5
    with pytest.raises(WilocError):
        localize_online(queries, 2, sequence=False)
    with pytest.raises(WilocError):
        localize_online(queries, 3, sequence=False, init_rows=ref)
    with pytest.raises(WilocError):
        localize_online(queries, 2, sequence=True, init=0)


def test_default_prior_is_the_share_of_b_and_a_fixed_prior_is_kept() -> None:
    ref = [np.array([INF, 0.6, 0.8]), np.array([0.6, INF, 0.7]), np.array([0.8, 0.7, INF])]
    queries = [np.array([0.1, 0.5, 0.9]), np.array([0.4, 0.2, 0.3])]
    share = localize_online(queries, 2, sequence=False, init_rows=ref, bins=5)
    # b: the 2 decided minima; c: the 3 initial minima (no m_r: every map frame is within +-W of z)
    assert share.params["prior"] is None and share.model.prior_same() == pytest.approx(2 / 5)
    fixed = localize_online(queries, 2, sequence=False, init_rows=ref, bins=5, prior=0.5)
    assert fixed.model.prior_same() == 0.5
    # in sequence mode the confidence is the filter's along the traversal: before its map (frames
    # older than the recent window and the frontier) has 2 frames, nothing is a revisit
    rows = _seq([[], [0.8], [0.9, 0.7], [0.2, 0.6, 0.9]], 4)
    first = localize_online(rows, 4, sequence=True, init=2, bins=8)
    assert first.stage[3] == "update" and first.confidence[3] == 0.0 and first.columns["new_place"][3] == 1.0


def test_map_mode_confidence_is_the_map_filters_probability_of_the_best_match() -> None:
    rng = np.random.default_rng(3)
    n = 60
    ref = 1.0 + 0.05 * rng.standard_normal((n, n)) - 0.5 * np.exp(-0.5 * (np.subtract.outer(np.arange(n), np.arange(n)) / 1.5) ** 2)
    truth = np.arange(5, 55)
    queries = list(ref[truth] + 0.05 * rng.standard_normal((truth.size, n)))
    out = localize_online(queries, truth.size, sequence=False, init_rows=list(ref))
    assert np.all(out.match == np.argmin(np.array(queries), axis=1))  # the single-frame decision
    assert np.mean(out.confidence[10:]) > 0.9  # the track is certain once found
    assert np.all((out.confidence >= 0) & (out.confidence <= 1)) and np.all(np.isfinite(out.columns["m_r"]))


@pytest.mark.parametrize(("option", "value"), [
    ("init", 0), ("bins", 0), ("same_place_window", -1), ("smoothing", 0.0),
    ("smoothing", -0.5), ("smoothing", np.nan), ("prior", 1.0), ("prior", 0.0)])
def test_bad_option_names_the_parameter(option: str, value: float) -> None:
    rows = _seq([[], [0.5], [0.7, 0.3]], 3)
    with pytest.raises(WilocError) as err:
        localize_online(rows, 3, sequence=True, **{option: value})
    assert err.value.parameter == option and err.value.exit_code == 2
    assert err.value.problem.startswith("must ")


def _bin_posterior(edges: np.ndarray, same: stats.rv_continuous, diff: stats.rv_continuous,
                   prior: float) -> np.ndarray:
    """The posterior a histogram with these edges converges to under the known densities."""
    fb = np.diff(same.cdf(edges))
    fc = np.diff(diff.cdf(edges))
    return prior * fb / (prior * fb + (1 - prior) * fc)


@pytest.mark.parametrize("window", [0, 2])
def test_online_posterior_converges_to_truth_without_labels(window: int) -> None:
    """A route of P places driven L times; row k compares frame k with frames before k - R.

    Each earlier visit of the place is a little further from frame k the older it is (the latest
    visit looks most alike), so the runs' own match links form the chain the recursive test
    follows; no labels reach the model. With a same-place window (the default's 2) the chain
    must still start at z's own link.
    """
    rng = np.random.default_rng(7)
    places, laps, recent = 80, 12, 5
    same = stats.gamma(4.0, scale=0.05)             # same place: mean 0.2
    near = stats.norm(0.6, 0.08)                    # smallest difference to another place
    n = places * laps
    rows = []
    for k in range(n):
        row = np.full(n, INF)
        cand = np.arange(max(0, k - recent))
        if cand.size:
            visits = cand[cand % places == k % places]
            others = cand[cand % places != k % places]
            nm = max(near.rvs(random_state=rng), 0.01)
            row[others] = nm + rng.exponential(0.3, others.size)
            row[rng.choice(others)] = nm
            if visits.size:
                # the latest visit gets the same-place value, older visits are close behind it
                age = np.arange(visits.size)[::-1]
                row[visits] = same.rvs(random_state=rng) + 0.04 * age + rng.uniform(0, 0.02) * (age > 0)
        rows.append(row)
    out = localize_online(rows, n, sequence=True, init=places - recent - 1, bins=20,
                          same_place_window=window)
    model = out.model
    truth = _bin_posterior(model.edges, same, near, model.prior_same())
    centres = 0.5 * (model.edges[1:] + model.edges[:-1])
    # the bulk: bins that hold at least 1 % of the pooled samples
    counts = model.b + model.c
    bulk = counts >= 0.01 * counts.sum()
    assert bulk.sum() >= 8
    err = np.abs(model.posterior(centres) - truth)[bulk]
    assert err.max() < 0.2 and err.mean() < 0.05
    # the repaired recursive test keeps earlier visits out of c
    assert np.mean(out.columns["m_r"][out.decided] < 0.35) < 0.02


def test_candidates_come_in_the_order_of_a_stable_sort_of_the_row() -> None:
    from wiloc.methods.online import _increasing
    rng = np.random.default_rng(1)
    for _ in range(300):
        n = int(rng.integers(0, 400))
        row = np.round(rng.random(n) * rng.integers(1, 20)) / 7  # many ties
        row[rng.random(n) < 0.2] = INF
        finite = np.flatnonzero(np.isfinite(row))
        expected = finite[np.argsort(row[finite], kind="stable")].tolist()
        assert list(_increasing(row, first=int(rng.integers(1, 10)))) == expected


def test_a_first_pass_is_new_and_its_revisit_is_recognised() -> None:
    """Sequence mode on a generated loop: the first pass holds no revisit, so it must not be
    claimed (confidence low, P(new place) high); along the revisit the best match is right and
    the filter run alongside must say so once the revisit has run a few frames. The looks are
    alike over a few places only (an AR(1) walk): looks that drift without bound are taken for a
    revisit of the frames just before the frontier (docs/catgraph.md, "Sequence mode")."""
    rng = np.random.default_rng(11)
    places, recent = 150, 10
    rows, route = loop_rows(rng, places, recent, memory=0.9)
    n = route.size
    out = run_on_rows(Online(), rows, n, sequence=True, exclude_recent=recent)
    decided = out.decided
    first = decided & (np.arange(n) < places)
    revisit = np.arange(n) >= places + 5
    right = np.abs(route[np.maximum(out.match, 0)] - route) <= 2
    assert first.sum() >= 30 and np.mean(right[revisit]) > 0.9  # the generator makes the revisit easy
    assert np.mean(out.confidence[first]) < 0.1 and np.mean(out.columns["new_place"][first]) > 0.9
    assert np.mean(out.confidence[revisit]) > 0.8 and np.mean(out.columns["new_place"][revisit]) < 0.1


def test_sequence_mode_restores_to_identical_decisions() -> None:
    rng = np.random.default_rng(2)
    rows, route = loop_rows(rng, 80, 10, memory=0.9)
    n = route.size
    whole = run_on_rows(Online(), rows, n, sequence=True, exclude_recent=10)
    first = Online()
    run_on_rows(first, rows[:120], 120, sequence=True, exclude_recent=10)
    state = copy.deepcopy(first.state())
    resumed = Online()
    resumed.restore(first.context, state)
    rest = resumed.run(iter(np.array(rows[120:])[None]), n - 120)
    np.testing.assert_array_equal(rest.confidence, whole.confidence[120:])
    np.testing.assert_array_equal(rest.columns["new_place"], whole.columns["new_place"][120:])


@pytest.mark.realdata
def test_loop_closure_on_gardens_point_claims_no_first_visit(data_root, real_data_cache) -> None:
    """GP day_right then day_left as one traversal (benchmarks/bench_loops.py, loop dr+dl): no
    frame at confidence >= 0.99 is wrong, first visits are called new places, and the confidence
    is calibrated (ECE 0.048 measured; P(L | m) gave 0.203, the revisit chain 0.069)."""
    from helpers import benchmark_module

    with benchmark_module("bench_loops") as bench:
        row = bench.run_loop(bench.load_loop("dr+dl", "sad", data_root, Cache(real_data_cache)), "online")
    assert row["accepted@0.99"] >= 20 and row["precision@0.99"] >= 0.99
    assert row["new_first"] >= 0.95 and row["ece"] <= 0.06

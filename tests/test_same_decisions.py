"""The filter's compiled per-frame passes decide as the numpy code before them did.

``data/filter_decisions_1343bc2_stratified.npz`` holds the decisions of ``catgraph`` and ``online``
(default parameters, seed 0) on Gardens Point (day_left and night_right against day_right, ``sad``
and ``gist``) and Nordland (winter against summer, ``sad``), as the numpy filter of commit 1343bc2
computes them with the particles' stratified start of today (that one line changed in it), on a
cache that today's code described (the filter's decisions move with the ``gist`` descriptors'
last digits). Sums now taken in another order change the last digits of a confidence; the
matches must be the same and the confidences within 1e-9.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from wiloc import api
from wiloc.cache import Cache

REFERENCE = Path(__file__).parent / "data" / "filter_decisions_1343bc2_stratified.npz"
CASES = [("day_left", "sad"), ("night_right", "sad"), ("day_left", "gist"), ("night_right", "gist"),
         ("nordland", "sad")]


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Cache:
    return Cache(tmp_path_factory.mktemp("cache"))


@pytest.mark.realdata
@pytest.mark.parametrize("method", ["catgraph", "online"])
@pytest.mark.parametrize(("query", "descriptor"), CASES)
def test_decisions_are_those_of_the_numpy_filter(data_root: Path, cache: Cache, query: str, descriptor: str,
                                                 method: str) -> None:
    if query == "nordland":
        root = data_root / "nordland-summer-winter-64x32"
        folder, reference = root / "winter", root / "summer"
    else:
        root = data_root / "gardens-point-walking"
        folder, reference = root / query, root / "day_right"
    run = api.localize(folder, reference=reference, descriptor=descriptor, method=method, cache=cache, jobs=1)
    decisions = run.decisions
    with np.load(REFERENCE) as stored:
        key = f"{query}-{descriptor}-{method}"
        np.testing.assert_array_equal(decisions.match, stored[f"{key}/match"])
        np.testing.assert_allclose(decisions.confidence, stored[f"{key}/confidence"], rtol=0, atol=1e-9)
        if method == "catgraph":
            np.testing.assert_allclose(decisions.columns["new_place"], stored[f"{key}/new_place"], rtol=0, atol=1e-9)

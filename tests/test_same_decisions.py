"""Every method decides the same on the real data whichever way this machine computes it.

The last digits of float sums, FFTs and BLAS products depend on the CPU (its SIMD width, the BLAS
kernels picked for it), so decisions are never compared with numbers stored from another machine.
They are compared with what this machine computes another way: a ``Localizer`` fed the descriptors
frame by frame, saved halfway and continued by a new object loaded from the saved state, against
batch ``localize`` (difference rows in blocks, ``jobs=2``) where the differences are integer sums
(``sad``), and against the same ``Localizer`` run straight through where they are float products
(``gist``: BLAS sums one row and a block of rows in different orders, so batch and streamed
differences, hence some of CAT-Graph's matches, differ in their last digits). Cases: Gardens Point
night_right against day_right (``sad``), day_left and night_right against day_right (``gist``),
Nordland winter against summer (``sad``); Gardens Point day_left with ``sad`` is in
test_localizer.py (streamed) and test_follow.py (followed, killed and resumed).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.decisions import Decision, Decisions
from wiloc.description.distances import DifferencesTo
from wiloc.description.traversals import Describer
from wiloc.localization.localizer import Localizer
from wiloc.methods.registry import METHODS

CASES = [("night_right", "sad"), ("day_left", "gist"), ("night_right", "gist"), ("nordland", "sad")]
DIFFERENCE_METHODS = sorted(m for m, cls in METHODS.items() if "differences" in cls.rows)  # fabmap: its own tests

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def cache(real_data_cache: Path) -> Cache:
    return Cache(real_data_cache)


def _folders(data_root: Path, query: str) -> tuple[Path, Path, Path]:
    """(query, reference, the other query: what ``trained`` learns from) of a case."""
    if query == "nordland":
        root = data_root / "nordland-summer-winter-64x32"
        return root / "winter", root / "summer", root / "winter"
    root = data_root / "gardens-point-walking"
    other = {"day_left": "night_right", "night_right": "day_left"}[query]
    return root / query, root / "day_right", root / other


def _observe(localizer: Localizer, frames: np.ndarray) -> list[Decision]:
    return [localizer.observe(row) for row in frames]


def _as_decisions(decisions: list[Decision]) -> Decisions:
    return Decisions(match=[d.match for d in decisions], difference=[d.difference for d in decisions],
                     confidence=[d.confidence for d in decisions], stage=[d.stage for d in decisions],
                     columns={"new_place": np.array([d.new_place for d in decisions])})


def _assert_same(expected: Decisions, got: Decisions) -> None:
    for field in ("match", "stage", "difference", "confidence"):
        np.testing.assert_array_equal(getattr(expected, field), getattr(got, field), err_msg=field)
    if "new_place" in expected.columns:
        np.testing.assert_array_equal(expected.columns["new_place"], got.columns["new_place"], err_msg="new_place")


@pytest.mark.parametrize("method", DIFFERENCE_METHODS)
@pytest.mark.parametrize(("query", "descriptor"), CASES)
def test_streamed_and_resumed_decides_as_batch(data_root: Path, cache: Cache, query: str, descriptor: str,
                                               method: str, tmp_path: Path) -> None:
    folder, reference, other = _folders(data_root, query)
    training = api.Training(other, reference, api.TruthSource(tolerance=2)) if method == "trained" else None

    def localizer() -> Localizer:
        return Localizer(reference, descriptor=descriptor, method=method, training=training, cache=cache, jobs=1)

    entry = Describer(descriptor, {}, cache).entry(folder)
    frames, half = entry.data, len(entry.data) // 2
    first = localizer()
    decisions = _observe(first, frames[:half])
    resumed = _as_decisions(decisions + _observe(Localizer.load(first.save(tmp_path / "state.npz"), cache=cache),
                                                 frames[half:]))
    if DifferencesTo(entry.data[:1], entry.metric).exact:
        expected = api.localize(folder, reference=reference, descriptor=descriptor, method=method,
                                training=training, cache=cache, jobs=2).decisions
    else:
        expected = _as_decisions(_observe(localizer(), frames))
    _assert_same(expected, resumed)

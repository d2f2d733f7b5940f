"""The cache keys what it holds by the versions of the libraries that computed it: two environments
with different OpenCV (or onnxruntime) versions sharing one cache never serve each other's rows or
local features; an imported matrix, which no library computed, is keyed by its file alone; and
what a user sees of an entry's parameters is still the descriptor's own."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc import Localizer, api
from wiloc.cache.features import FeatureStore
from wiloc.cache.store import Cache
from wiloc.description.describing import describe_folder
from wiloc.description.matrix_import import import_matrix
from wiloc.description.traversals import entry_params
from wiloc.description.vocabulary_build import build_vocabulary
from wiloc.descriptors import base
from wiloc.descriptors.registry import DESCRIPTOR_NAMES, get_descriptor

from helpers import write_images
from test_vocabulary import SMALL, _folder


def _installed(monkeypatch: pytest.MonkeyPatch, **versions: str) -> None:
    """From now on the version lookup reports ``versions`` (by library name) for those libraries,
    as another environment sharing the cache would; this process still computes with its own."""
    real = base.library_version
    monkeypatch.setattr(base, "library_version", lambda name: versions.get(name) or real(name))


@pytest.mark.parametrize("descriptor", DESCRIPTOR_NAMES)
def test_another_opencv_describes_afresh_and_the_same_one_reuses(descriptor: str, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "route"
    write_images(folder, 3)
    cache = Cache(tmp_path / "cache")
    first = describe_folder(folder, get_descriptor(descriptor), cache, jobs=1)
    same = describe_folder(folder, get_descriptor(descriptor), cache, jobs=1)
    assert (first.computed, same.computed, same.entry.key) == (3, 0, first.entry.key)
    _installed(monkeypatch, opencv="0.0.1")
    other = describe_folder(folder, get_descriptor(descriptor), cache, jobs=1)
    assert other.computed == 3 and other.entry.key != first.entry.key
    assert np.array_equal(other.entry.data, first.entry.data)  # the same OpenCV computed both, in truth
    assert sorted(i.params["libraries"]["opencv"] for i in cache.list_entries()) == sorted(["0.0.1", cv2.__version__])


def test_local_features_of_another_opencv_are_kept_in_another_folder(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    store = FeatureStore(Cache(tmp_path / "cache"), SMALL.feature_setting())
    extracted: list[int] = []

    def extract() -> np.ndarray:
        extracted.append(1)
        return np.full((2, 128), 7, np.float32)

    store.features("d1", extract)
    store.features("d1", extract)
    folder = store.folder
    assert extracted == [1]
    _installed(monkeypatch, opencv="0.0.1")
    assert store.folder != folder and store.read("d1") is None
    np.testing.assert_array_equal(store.features("d1", extract), np.full((2, 128), 7, np.float32))
    assert extracted == [1, 1] and sorted(p.name for p in folder.parent.iterdir()) == sorted([folder.name,
                                                                                              store.folder.name])


def test_bow_under_another_opencv_extracts_the_local_features_again(tmp_path: Path, cache_dir: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The vocabulary's training kept its images' features; describing them with ``bow`` in the
    same environment extracts none, under another OpenCV version every one again, into a folder of
    its own."""
    import wiloc.description.frame_describing as framing

    cache = Cache(cache_dir)
    train = _folder(tmp_path / "train", range(6))
    spec = get_descriptor("bow", file=build_vocabulary([train], cache, SMALL).path)
    extracted: list[int] = []
    real = framing.extract_features
    monkeypatch.setattr(framing, "extract_features", lambda *args, **kw: extracted.append(1) or real(*args, **kw))
    first = describe_folder(train, spec, cache, jobs=1)
    assert first.computed == 6 and extracted == []
    _installed(monkeypatch, opencv="0.0.1")
    other = describe_folder(train, spec, cache, jobs=1)
    assert other.computed == 6 and len(extracted) == 6 and other.entry.key != first.entry.key
    assert np.array_equal(other.entry.data, first.entry.data)
    assert [len(list(folder.iterdir())) for folder in (cache_dir / "features").iterdir()] == [6, 6]


def test_an_imported_matrix_is_keyed_by_its_file_not_by_opencv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No library of this environment computed an imported matrix's rows: another OpenCV version
    reuses its entry, while it describes a folder afresh."""
    np.save(tmp_path / "rows.npy", np.random.default_rng(0).random((4, 8)).astype(np.float32))
    folder = tmp_path / "route"
    write_images(folder, 2)
    cache = Cache(tmp_path / "cache")
    imported = import_matrix(tmp_path / "rows.npy", cache, None, "cosine")
    described = describe_folder(folder, get_descriptor("sad"), cache, jobs=1)
    _installed(monkeypatch, opencv="0.0.1")
    again = import_matrix(tmp_path / "rows.npy", cache, None, "cosine")
    assert (again.computed, again.entry.key) == (0, imported.entry.key)
    assert describe_folder(folder, get_descriptor("sad"), cache, jobs=1).entry.key != described.entry.key


def test_what_a_user_sees_of_an_entrys_parameters_is_the_descriptors_own(tmp_path: Path) -> None:
    """An entry's key holds the OpenCV version; its parameters as a run takes and records them
    (``entry_params``, a results file's descriptor_params) do not."""
    folder = tmp_path / "route"
    write_images(folder, 3)
    cache = Cache(tmp_path / "cache")
    [report] = api.describe([folder], "sad", descriptor_params={"patch": 4}, cache=cache)
    own = dict(get_descriptor("sad", patch=4).params)
    assert report.entry.params["libraries"] == {"opencv": cv2.__version__}
    assert entry_params(report.entry) == own
    loc = Localizer(report.entry, method="threshold", cache=cache)
    loc.observe(folder / "img0.jpg")
    assert loc.results().header.descriptor_params == own


def test_an_onnx_entry_is_keyed_by_onnxruntime_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A network's rows depend on the runtime that ran it: another onnxruntime version describes afresh."""
    pytest.importorskip("onnxruntime")
    from test_onnx import conv_model

    conv_model(tmp_path / "m.onnx")
    folder = tmp_path / "route"
    write_images(folder, 2)
    cache = Cache(tmp_path / "cache")
    spec = get_descriptor("onnx", model=tmp_path / "m.onnx")
    assert set(spec.cache_params["libraries"]) == {"opencv", "onnxruntime"}
    first = describe_folder(folder, spec, cache, jobs=1)
    assert describe_folder(folder, spec, cache, jobs=1).computed == 0
    _installed(monkeypatch, onnxruntime="0.0.1")
    other = describe_folder(folder, spec, cache, jobs=1)
    assert other.computed == 2 and other.entry.key != first.entry.key
    assert np.array_equal(other.entry.data, first.entry.data)

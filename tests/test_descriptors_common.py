"""Checks every registered descriptor must pass (as tests/test_methods_common.py does for methods),
on small generated images, plus an example descriptor added the documented way
(docs/descriptors.md, "Adding a descriptor"): one class and one registry line."""
from __future__ import annotations

import json
import pickle
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from typer.testing import CliRunner

from wiloc import api
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.cli.params import OWN_FORMS, descriptor_options, flag
from wiloc.descriptors import registry
from wiloc.descriptors.base import METRICS, Descriptor, DescriptorSpec
from wiloc.errors import WilocError
from wiloc.evaluation.results import read_results
from wiloc.localization.localizer import Localizer
from wiloc.parameters import Parameters, declared, param


def _scene(seed: int, h: int = 96, w: int = 128) -> NDArray[np.uint8]:
    """A blurred noise image with a few filled rectangles: texture, corners and blobs."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (0, 0), 2)
    for _ in range(6):
        x, y = int(rng.integers(0, w - 24)), int(rng.integers(0, h - 24))
        cv2.rectangle(image, (x, y), (x + int(rng.integers(6, 24)), y + int(rng.integers(6, 24))),
                      int(rng.integers(0, 256)), -1)
    return image


def _folder(path: Path, seeds: range) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        gray = _scene(seed)
        cv2.imwrite(str(path / f"img{seed:03d}.png"), cv2.merge([gray, np.roll(gray, 7, axis=1), 255 - gray]))
    return path


# --- parameters of the descriptors that need a file: one maker each ------------------------------

def _bow(tmp: Path) -> dict[str, Any]:
    from wiloc.bow.vocabulary_params import VocabularyParams
    from wiloc.description.vocabulary_build import build_vocabulary

    small = VocabularyParams(words=16, max_features=60, max_side=320, iterations=10)
    report = build_vocabulary([_folder(tmp / "training", range(100, 104))], Cache(tmp / "vocabulary"), small)
    return {"file": str(report.path)}


def _onnx(tmp: Path) -> dict[str, Any]:
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper

    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
             helper.make_node("Flatten", ["pooled"], ["vector"])]
    graph = helper.make_graph(nodes, "mean colour", [helper.make_tensor_value_info("image", TensorProto.FLOAT,
                                                                                  ["N", 3, 16, 16])],
                              [helper.make_tensor_value_info("vector", TensorProto.FLOAT, ["N", 3])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(tmp / "mean.onnx"))
    return {"model": str(tmp / "mean.onnx")}


#: Descriptors whose parameters name a file: how a test makes one. Every other registered
#: descriptor is made with its defaults; ``external`` is imported, never computed.
NEEDS_FILE: dict[str, Callable[[Path], dict[str, Any]]] = {"bow": _bow, "onnx": _onnx}
IMPORTED = ("external",)
COMPUTED = [name for name in registry.DESCRIPTORS if name not in IMPORTED]


@pytest.fixture(params=COMPUTED)
def made(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[type[Descriptor], dict]:
    """A registered computed descriptor's class and the parameters a test gives it."""
    cls = registry.DESCRIPTORS[request.param]
    if cls.depends:
        assert request.param in NEEDS_FILE, f"'{request.param}' depends on {cls.depends}: add a maker"
        return cls, NEEDS_FILE[request.param](tmp_path_factory.mktemp(request.param))
    return cls, {}


def _read(path: Path, colour: bool) -> NDArray[np.uint8]:
    return cv2.imread(str(path), cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE)


# --- common checks -------------------------------------------------------------------------------

def test_the_class_declares_what_the_pipeline_asks(made: tuple[type[Descriptor], dict]) -> None:
    cls, given = made
    assert cls.name in registry.DESCRIPTORS and registry.descriptor_class(cls.name) is cls
    assert issubclass(cls.Params, Parameters)
    for d in declared(cls.Params):
        assert d.help.strip(), f"{cls.name}.{d.name} has no help"
    spec = registry.get_descriptor(cls.name, **given)
    assert spec.name == cls.name and spec.metric in METRICS and (cls.metric in (None, spec.metric))
    assert spec.colour == cls.colour and spec.length > 0 and spec.scale > 0
    assert spec.metric != "hamming" or spec.dtype == np.uint8  # packed bits


@pytest.mark.parametrize("name", [*COMPUTED, *IMPORTED])
def test_an_unknown_parameter_is_named_as_a_method_names_it(name: str) -> None:
    """``descriptor_params={"patchh": 8}`` was a ParameterError naming ``descriptor`` (the same
    for every wrong name); like a method's, it names the parameter and lists the valid ones."""
    from wiloc import api
    from wiloc.errors import ParameterError

    with pytest.raises(ParameterError) as err:
        api.describe([], name, descriptor_params={"no_such_parameter": 1})
    assert err.value.parameter == "no_such_parameter"
    assert err.value.problem.startswith(f"not a parameter of descriptor '{name}' (valid: ")


def test_shape_dtype_and_determinism(made: tuple[type[Descriptor], dict]) -> None:
    cls, given = made
    spec = registry.get_descriptor(cls.name, **given)
    images = [cv2.merge([_scene(s), _scene(s + 50), _scene(s + 90)]) if spec.colour else _scene(s) for s in range(3)]
    rows = spec.compute_batch(images)
    assert rows.shape == (3, spec.length) and rows.dtype == spec.dtype
    again = np.stack([spec.compute(image) for image in images])
    np.testing.assert_array_equal(rows, again)
    assert not np.array_equal(rows[0], rows[1])  # different images, different descriptors
    if rows.dtype.kind == "f":
        assert np.all(np.isfinite(rows))


def test_an_image_that_is_not_what_the_descriptor_takes_is_named(made: tuple[type[Descriptor], dict]) -> None:
    """``compute`` ran on whatever it was given: a colour image was Python's unpacking error, an
    empty one a ZeroDivisionError or an OpenCV assertion, a float image in [0, 1] other values."""
    cls, given = made
    spec = registry.get_descriptor(cls.name, **given)
    image = cv2.merge([_scene(0)] * 3) if spec.colour else _scene(0)
    other = image[:, :, 0] if spec.colour else cv2.merge([image] * 3)
    for wrong in (image / 255.0, other, image[:0]):
        with pytest.raises(WilocError) as err:
            spec.compute(wrong)
        assert err.value.where == f"descriptor '{spec.name}'" and f"got {wrong.dtype} values of shape" in err.value.problem
        with pytest.raises(WilocError):
            spec.compute_batch([image, wrong])


def test_the_cache_key_holds_every_parameter_and_is_stable(made: tuple[type[Descriptor], dict]) -> None:
    cls, given = made
    spec = registry.get_descriptor(cls.name, **given)
    assert spec.key == json.dumps({"name": cls.name, "params": dict(spec.params)}, sort_keys=True)
    assert {d.name for d in declared(cls.Params)} == set(spec.params)  # defaults filled in
    assert registry.get_descriptor(cls.name, **spec.params).key == spec.key  # complete parameters are a fixed point
    assert pickle.loads(pickle.dumps(spec)).key == spec.key  # as worker processes receive it


def test_built_in_cache_keys_are_those_of_earlier_releases() -> None:
    """The cache keys of the built-in descriptors at their defaults: changing one would make every
    cache entry of earlier runs unreachable."""
    assert registry.get_descriptor("sad").key == \
        '{"name": "sad", "params": {"crop": "none", "patch": 8, "storage": "uint8"}}'
    assert registry.get_descriptor("gist").key == '{"name": "gist", "params": {}}'
    assert registry.get_descriptor("brisk-gist").key == '{"name": "brisk-gist", "params": {"keypoint_size": 48.0}}'
    assert registry.get_descriptor("brisk-gist", keypoint_size=40).key == \
        '{"name": "brisk-gist", "params": {"keypoint_size": 40.0}}'  # an int for a float is stored as the float


def test_describing_resumes_from_the_cache(made: tuple[type[Descriptor], dict], tmp_path: Path) -> None:
    """Frames added to a folder are computed; the others reused; the rows equal a fresh run's."""
    cls, given = made
    folder = _folder(tmp_path / "route", range(4))
    [first] = api.describe([folder], cls.name, descriptor_params=given, cache=Cache(tmp_path / "cache"), jobs=1)
    assert (first.computed, first.reused) == (4, 0)
    _folder(folder, range(4, 6))
    [resumed] = api.describe([folder], cls.name, descriptor_params=given, cache=Cache(tmp_path / "cache"), jobs=1)
    assert (resumed.computed, resumed.reused, resumed.frames) == (2, 4, 6)
    [fresh] = api.describe([folder], cls.name, descriptor_params=given, cache=Cache(tmp_path / "fresh"), jobs=1)
    assert resumed.entry.names == fresh.entry.names
    np.testing.assert_array_equal(resumed.entry.data, fresh.entry.data)
    spec = registry.get_descriptor(cls.name, **given)
    np.testing.assert_array_equal(fresh.entry.data[5], spec.compute(_read(folder / "img005.png", spec.colour)))


def test_every_settable_parameter_has_a_command_line_flag() -> None:
    for name, cls in registry.DESCRIPTORS.items():
        for d in cls.options():
            option = descriptor_options().get(d.name)
            assert d.name in OWN_FORMS or (option is not None and name in option.by_owner), (name, d.name)
    assert [flag(n) for n in ("crop", "patch", "storage", "keypoint_size")] == \
        ["--crop", "--patch", "--storage", "--keypoint-size"]


# --- the example: one class (here inline) and one registry line ----------------------------------

@dataclass(frozen=True)
class StripesParams(Parameters):
    owner = "stripes"
    stripes: int = param(6, "Horizontal stripes whose mean gray levels form the descriptor.", low=1, high=64)


class Stripes(Descriptor):
    """The mean gray level of each of ``stripes`` horizontal stripes, compared by l1."""

    name = "stripes"
    Params = StripesParams
    metric = "l1"

    @classmethod
    def spec(cls, params: dict[str, Any]) -> DescriptorSpec:
        return cls._spec(params, dtype=np.dtype(np.float32), length=params["stripes"],
                         scale=1.0 / params["stripes"], min_size=None, natural_max=255.0)

    @classmethod
    def compute(cls, image: NDArray[np.uint8], params: Mapping[str, Any]) -> NDArray:
        return cv2.resize(image, (1, params["stripes"]), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()


@pytest.fixture
def with_stripes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.DESCRIPTORS, "stripes", Stripes)  # the one registry line


def test_an_example_descriptor_from_python(with_stripes: None, tmp_path: Path) -> None:
    ref = _folder(tmp_path / "ref", range(12))
    query = tmp_path / "query"
    shutil.copytree(ref, query)
    cache = Cache(tmp_path / "cache")
    [report] = api.describe([ref], "stripes", descriptor_params={"stripes": 4}, cache=cache, jobs=1)
    assert report.shape == (12, 4) and report.descriptor == "stripes"
    run = api.localize(query, reference=ref, descriptor="stripes", descriptor_params={"stripes": 4},
                       method="threshold", cache=cache, jobs=1, out=tmp_path / "out.csv")
    assert list(run.results.frames["match"]) == [p.name for p in sorted(ref.iterdir())]  # the same images
    header = read_results(tmp_path / "out.csv").header
    assert (header.descriptor, header.descriptor_params) == ("stripes", {"stripes": 4})
    localizer = Localizer(ref, descriptor="stripes", descriptor_params={"stripes": 4}, method="threshold",
                          cache=cache, jobs=1)
    assert localizer.observe(query / "img007.png").match_name == "img007.png"


def test_an_example_descriptor_from_the_command_line(with_stripes: None, tmp_path: Path) -> None:
    ref = _folder(tmp_path / "ref", range(12))
    query = tmp_path / "query"
    shutil.copytree(ref, query)
    runner = CliRunner()
    env = {"WILOC_CACHE": str(tmp_path / "cache"), "COLUMNS": "200"}
    described = runner.invoke(app, ["describe", str(ref), "--descriptor", "stripes", "--jobs", "1", "--json"], env=env)
    assert described.exit_code == 0, described.output
    [row] = json.loads(described.stdout)["results"]
    assert (row["descriptor"], row["shape"], row["computed"]) == ("stripes", [12, 6], 12)
    out = tmp_path / "out.csv"
    ran = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--descriptor", "stripes",
                              "--method", "threshold", "--jobs", "1", "-o", str(out)], env=env)
    assert ran.exit_code == 0, ran.output
    assert list(read_results(out).frames["match"]) == [p.name for p in sorted(ref.iterdir())]
    refused = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--descriptor", "stripes",
                                  "--crop", "top-half", "-o", str(out)], env=env)
    assert refused.exit_code == 2 and "--crop: applies to --descriptor sad only" in refused.stderr


def test_new_flags_set_their_parameters(tmp_path: Path) -> None:
    """--patch, --storage and --keypoint-size reach the descriptor: a different cache entry, a
    different stored form."""
    ref = _folder(tmp_path / "ref", range(3))
    runner = CliRunner()
    env = {"WILOC_CACHE": str(tmp_path / "cache")}
    for args in (["--patch", "4", "--storage", "float32"], ["--descriptor", "brisk-gist", "--keypoint-size", "24"]):
        result = runner.invoke(app, ["describe", str(ref), "--jobs", "1", *args], env=env)
        assert result.exit_code == 0, result.output
    params = sorted(json.dumps(info.params, sort_keys=True) for info in Cache(tmp_path / "cache").list_entries())
    libraries = {"libraries": {"opencv": cv2.__version__}}  # the key holds the version of OpenCV too
    assert params == [json.dumps({"code_version": 1, "crop": "none", **libraries, "patch": 4, "storage": "float32"},
                                 sort_keys=True),
                      json.dumps({"code_version": 1, "keypoint_size": 24.0, **libraries}, sort_keys=True)]
    bad = runner.invoke(app, ["describe", str(ref), "--patch", "5"], env=env)
    assert bad.exit_code == 2 and bad.stderr.startswith("error: --patch: must divide")
    wrong = runner.invoke(app, ["describe", str(ref), "--descriptor", "gist", "--keypoint-size", "24"], env=env)
    assert wrong.exit_code == 2 and "--keypoint-size: applies to --descriptor brisk-gist only" in wrong.stderr

"""The ``onnx`` descriptor: small networks built here with the onnx package's helpers, run through
``wiloc describe``, ``localize`` and ``Localizer``, checked against the same arithmetic in numpy."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper

from wiloc import Localizer
from wiloc.cache.store import Cache
from wiloc.cli import app
from wiloc.description.describing import describe_bag, describe_folder, describe_video
from wiloc.descriptors.registry import get_descriptor

runner = CliRunner()
SIDE = 32  # the test network's input: 3 x 32 x 32
MEAN, STD = (0.5, 0.4, 0.3), (0.2, 0.25, 0.3)


def conv_model(path: Path, *, seed: int = 0, metadata: dict[str, str] | None = None,
               input_shape: list | None = None, output_shape: list | None = None, flatten: bool = True) -> dict:
    """A 3x3 convolution (8 filters), ReLU, global average pool and flatten: N x 3 x 32 x 32 in,
    N x 8 out; its weights, for the numpy reference."""
    rng = np.random.default_rng(seed)
    weights = rng.normal(size=(8, 3, 3, 3)).astype(np.float32)
    bias = rng.normal(size=8).astype(np.float32)
    nodes = [helper.make_node("Conv", ["image", "W", "B"], ["conv"], pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["conv"], ["relu"]),
             helper.make_node("GlobalAveragePool", ["relu"], ["pooled" if flatten else "vector"])]
    if flatten:
        nodes.append(helper.make_node("Flatten", ["pooled"], ["vector"]))
    _save(path, nodes, [numpy_helper.from_array(weights, "W"), numpy_helper.from_array(bias, "B")],
          input_shape or ["N", 3, SIDE, SIDE], output_shape or ["N", 8], metadata)
    return {"weights": weights, "bias": bias}


def _save(path: Path, nodes: list, initializers: list, input_shape: list, output_shape: list,
          metadata: dict[str, str] | None) -> None:
    graph = helper.make_graph(nodes, "test", [helper.make_tensor_value_info("image", TensorProto.FLOAT, input_shape)],
                              [helper.make_tensor_value_info("vector", TensorProto.FLOAT, output_shape)], initializers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8  # readable by every onnxruntime since 1.16
    helper.set_model_props(model, metadata if metadata is not None else
                           {"wiloc.mean": ",".join(map(str, MEAN)), "wiloc.std": ",".join(map(str, STD)),
                            "wiloc.colour": "rgb"})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def reference(images: list[np.ndarray], weights: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """The conv model's descriptors in numpy: RGB / 255, (x - mean) / std, 3x3 convolution with
    zero padding, ReLU, mean over the image, L2-normalised."""
    rows = []
    for bgr in images:
        x = (bgr[:, :, ::-1].astype(np.float64) / 255 - np.array(MEAN)) / np.array(STD)
        padded = np.pad(x, ((1, 1), (1, 1), (0, 0)))
        windows = np.lib.stride_tricks.sliding_window_view(padded, (3, 3), axis=(0, 1))  # H x W x C x 3 x 3
        conv = np.einsum("hwcij,fcij->hwf", windows, weights.astype(np.float64)) + bias
        row = np.maximum(conv, 0).mean(axis=(0, 1))
        rows.append(row / np.linalg.norm(row))
    return np.array(rows)


def colour_images(folder: Path, count: int, seed: int = 0, side: int = SIDE) -> list[np.ndarray]:
    """``count`` random colour PNGs of side x side pixels, as written."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    images = []
    for i in range(count):
        image = rng.integers(0, 256, (side, side, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / f"frame{i:03d}.png"), image)
        images.append(image)
    return images


def _ok(result) -> object:
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_describe_matches_numpy_reference(tmp_path: Path, cache_dir: Path) -> None:
    model = tmp_path / "m.onnx"
    weights = conv_model(model)
    images = colour_images(tmp_path / "route", 40)
    [report] = _ok(runner.invoke(app, ["describe", str(tmp_path / "route"), "--descriptor", "onnx",
                                       "--model", str(model), "--json"]))["results"]
    assert report["descriptor"] == "onnx" and report["computed"] == 40 and report["shape"] == [40, 8]
    spec = get_descriptor("onnx", model=model)
    assert spec.metric == "cosine" and spec.length == 8
    assert spec.params["mean"] == list(MEAN) and spec.params["input_size"] == [SIDE, SIDE]
    stored = describe_folder(tmp_path / "route", spec, Cache(cache_dir))
    assert stored.computed == 0 and stored.reused == 40  # the command's entry, read back
    np.testing.assert_allclose(stored.entry.data, reference(images, **weights), atol=1e-5)
    # the same frames one at a time, as the Localizer describes them
    loc = Localizer(tmp_path / "route", descriptor="onnx", descriptor_params={"model": str(model)},
                    method="threshold", cache=Cache(cache_dir))
    np.testing.assert_allclose(loc.describe(tmp_path / "route" / "frame007.png"), stored.entry.data[7], atol=1e-6)
    np.testing.assert_allclose(loc.describe(images[7]), stored.entry.data[7], atol=1e-6)
    assert loc.observe(images[7]).match_name == "frame007.png"


def test_new_weights_in_an_external_data_file_are_a_new_descriptor(tmp_path: Path, cache_dir: Path) -> None:
    """torch's exporter keeps the weights in model.onnx.data beside the graph: retrained weights
    leave model.onnx's bytes as they were, and must not reuse the old weights' descriptors."""
    images = colour_images(tmp_path / "route", 4)
    model, graphs = tmp_path / "m.onnx", set()
    for seed in (0, 1):
        weights = conv_model(model, seed=seed)
        (tmp_path / "m.onnx.data").unlink(missing_ok=True)
        onnx.save_model(onnx.load(str(model)), str(model), save_as_external_data=True, all_tensors_to_one_file=True,
                        location="m.onnx.data", size_threshold=0)
        graphs.add(model.read_bytes())
        [report] = _ok(runner.invoke(app, ["describe", str(tmp_path / "route"), "--descriptor", "onnx",
                                           "--model", str(model), "--json"]))["results"]
        assert report["computed"] == 4 and report["reused"] == 0
        stored = describe_folder(tmp_path / "route", get_descriptor("onnx", model=model), Cache(cache_dir))
        np.testing.assert_allclose(stored.entry.data, reference(images, **weights), atol=1e-5)
    assert len(graphs) == 1  # the same graph file both times: only the weights beside it changed


def test_a_half_precision_model_takes_its_batch_as_float16(tmp_path: Path, cache_dir: Path) -> None:
    """A model exported with model.half() declares a float16 input: it gets the same batch in
    float16 and gives the float model's descriptors within float16's precision."""
    images = colour_images(tmp_path / "route", 6)
    weights = conv_model(tmp_path / "float.onnx")
    model = onnx.load(str(tmp_path / "float.onnx"))
    model.graph.input[0].type.tensor_type.elem_type = TensorProto.FLOAT16
    model.graph.node.insert(0, helper.make_node("Cast", ["image"], ["image32"], to=TensorProto.FLOAT))
    model.graph.node[1].input[0] = "image32"
    onnx.checker.check_model(model)
    onnx.save(model, str(tmp_path / "half.onnx"))
    rows = {}
    for name in ("float", "half"):
        [report] = _ok(runner.invoke(app, ["describe", str(tmp_path / "route"), "--descriptor", "onnx",
                                           "--model", str(tmp_path / f"{name}.onnx"), "--json"]))["results"]
        assert report["computed"] == 6
        rows[name] = describe_folder(tmp_path / "route", get_descriptor("onnx", model=tmp_path / f"{name}.onnx"),
                                     Cache(cache_dir)).entry.data
    np.testing.assert_allclose(rows["half"], reference(images, **weights), atol=5e-3)
    assert not np.array_equal(rows["half"], rows["float"])  # the input was rounded to float16


def test_options_override_metadata_and_change_the_cache_key(tmp_path: Path, cache_dir: Path) -> None:
    model = tmp_path / "m.onnx"
    weights = conv_model(model, metadata={})  # no metadata: defaults, input size from the model
    images = colour_images(tmp_path / "route", 4)
    plain = get_descriptor("onnx", model=model)
    assert plain.params["mean"] == [0.0] * 3 and plain.params["colour"] == "rgb" and plain.params["normalise"]
    given = get_descriptor("onnx", model=model, mean="0.5,0.4,0.3", std=list(STD), colour="rgb")
    assert given.key != plain.key
    row = describe_folder(tmp_path / "route", given, Cache(cache_dir), jobs=1).entry.data
    np.testing.assert_allclose(row, reference(images, **weights), atol=1e-5)
    bgr = get_descriptor("onnx", model=model, colour="bgr", normalise="false")
    assert bgr.key != plain.key and not bgr.params["normalise"]
    # a changed model file is another descriptor: its digest is in the key
    conv_model(model, seed=1, metadata={})
    assert get_descriptor("onnx", model=model).key != plain.key


def test_resize_and_crop(tmp_path: Path) -> None:
    """Larger images are resized (area) to the input, or scaled to cover it and cut at the centre."""
    model = tmp_path / "m.onnx"
    weights = conv_model(model)
    wide = np.random.default_rng(3).integers(0, 256, (64, 128, 3), dtype=np.uint8)
    stretch = get_descriptor("onnx", model=model)
    expected = reference([cv2.resize(wide, (SIDE, SIDE), interpolation=cv2.INTER_AREA)], **weights)[0]
    np.testing.assert_allclose(stretch.compute(wide), expected, atol=1e-5)
    crop = get_descriptor("onnx", model=model, resize="crop")
    centre = cv2.resize(wide, (64, SIDE), interpolation=cv2.INTER_AREA)[:, 16:48]
    np.testing.assert_allclose(crop.compute(wide), reference([centre], **weights)[0], atol=1e-5)


def test_fixed_batch_model_and_dynamic_output_length(tmp_path: Path) -> None:
    """A model exported without a dynamic batch axis (N = 1) is run one image at a time; an
    output whose width is not fixed is measured by running the model."""
    model = tmp_path / "m.onnx"
    weights = conv_model(model, input_shape=[1, 3, SIDE, SIDE], output_shape=[1, "D"])
    images = colour_images(tmp_path / "route", 5)
    spec = get_descriptor("onnx", model=model)
    assert spec.length == 8
    np.testing.assert_allclose(spec.compute_batch(images), reference(images, **weights), atol=1e-5)


def test_video_frames_are_described_in_colour(tmp_path: Path) -> None:
    """A video's frames go to the network in colour, as OpenCV decodes them."""
    model = tmp_path / "m.onnx"
    conv_model(model)
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (SIDE, SIDE))
    for image in colour_images(tmp_path / "frames", 6):
        writer.write(image)
    writer.release()
    capture = cv2.VideoCapture(str(video))
    decoded = [frame for ok, frame in iter(capture.read, (False, None)) if ok]
    capture.release()
    spec = get_descriptor("onnx", model=model)
    report = describe_video(video, spec, Cache(tmp_path / "cache"))
    assert report.entry.names == [f"{i:06d}" for i in range(6)]
    np.testing.assert_allclose(report.entry.data, spec.compute_batch(decoded), atol=1e-6)


_KILLED_RUN = """
import sys, time
from pathlib import Path
import wiloc.description.describing
import wiloc.description.frame_describing
from wiloc.cache.store import Cache
from wiloc.descriptors.registry import DescriptorSpec, get_descriptor
wiloc.description.frame_describing.COLOUR_BATCH = 2
batch = DescriptorSpec.compute_batch
def slow(self, images, threads=0):
    time.sleep(0.2)
    return batch(self, images, threads)
DescriptorSpec.compute_batch = slow
wiloc.description.describing.describe_folder(Path(sys.argv[1]), get_descriptor("onnx", model=sys.argv[3]), Cache(Path(sys.argv[2])))
"""


def test_bag_images_are_described_in_colour_as_the_folder_s(tmp_path: Path, cache_dir: Path) -> None:
    pytest.importorskip("rosbags")
    from test_rosbags import BagWriter, stamps
    model = tmp_path / "m.onnx"
    conv_model(model)
    images = colour_images(tmp_path / "route", 5)
    writer = BagWriter(tmp_path / "run.bag", "ros1")
    for stamp, image in zip(stamps(5), images):
        writer.image("/raw", stamp, image[:, :, ::-1], "rgb8")
        writer.compressed("/png", stamp, cv2.imencode(".png", image)[1].tobytes(), "png")
    writer.close()
    spec = get_descriptor("onnx", model=model)
    folder = describe_folder(tmp_path / "route", spec, Cache(cache_dir)).entry.data
    for topic in ("/raw", "/png"):
        [report] = _ok(runner.invoke(app, ["describe", str(tmp_path / "run.bag"), "--topic", topic, "--descriptor",
                                           "onnx", "--model", str(model), "--json"]))["results"]
        assert report["computed"] == 5 and report["failed"] == 0
        bag = describe_bag(tmp_path / "run.bag", spec, Cache(cache_dir), topic=topic)
        np.testing.assert_array_equal(bag.entry.data, folder)


def test_killed_describe_resumes(tmp_path: Path) -> None:
    """A run killed (SIGKILL) after some frames keeps them; the next run computes only the rest,
    and the entry equals a run that was never interrupted."""
    from helpers import interrupt_after_six_frames

    model = tmp_path / "m.onnx"
    conv_model(model)
    folder, count = tmp_path / "route", 30
    colour_images(folder, count)
    cache = Cache(tmp_path / "cache")
    run = interrupt_after_six_frames([_KILLED_RUN, str(folder), str(cache.root), str(model)], cache, signal.SIGKILL)
    assert run.returncode == -signal.SIGKILL
    [info] = cache.list_entries()
    assert not info.complete and 6 <= info.frames < count
    spec = get_descriptor("onnx", model=model)
    resumed = describe_folder(folder, spec, cache)
    assert (resumed.computed, resumed.reused) == (count - info.frames, info.frames)
    clean = describe_folder(folder, spec, Cache(tmp_path / "clean"))
    assert resumed.entry.names == clean.entry.names
    np.testing.assert_allclose(resumed.entry.data, clean.entry.data, atol=1e-6)


def _route(folder: Path, scenes: list[np.ndarray], shift: int, seed: int) -> Path:
    """A traversal of colour frames of the given scenes, each shifted sideways and noisier."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    for i, scene in enumerate(scenes):
        image = np.roll(scene, shift, axis=1) + rng.normal(0, 6, scene.shape)
        cv2.imwrite(str(folder / f"img{i}.png"), np.clip(image, 0, 255).astype(np.uint8))
    return folder


def test_localize_catgraph_end_to_end(tmp_path: Path, cache_dir: Path) -> None:
    rng = np.random.default_rng(0)
    scenes = [cv2.resize(rng.uniform(0, 255, (6, 8, 3)).astype(np.float32), (96, 64), interpolation=cv2.INTER_CUBIC)
              for _ in range(40)]
    ref, query = _route(tmp_path / "ref", scenes, 0, 1), _route(tmp_path / "query", scenes, 3, 2)
    model = tmp_path / "m.onnx"
    conv_model(model, metadata={"wiloc.input_size": "96x64"}, input_shape=["N", 3, "H", "W"])
    out = tmp_path / "run.csv"
    [row] = _ok(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--descriptor", "onnx",
                                    "--model", str(model), "--method", "catgraph", "--out", str(out), "--json"]))["runs"]
    assert row["frames"] == 40 and row["method"] == "catgraph" and row["descriptor"] == "onnx"
    metrics = _ok(runner.invoke(app, ["evaluate", str(out), "--json"]))["runs"][0]
    assert metrics["frames"] == 40 and metrics["recall_at_1"] > 0.5


@pytest.mark.realdata
def test_gardens_point_catgraph_with_an_onnx_descriptor(tmp_path: Path, cache_dir: Path, data_root: Path) -> None:
    """A network that is nothing but a zero-mean gray thumbnail (a correlation descriptor, as
    the classic tiny-image baseline), on day_left against day_right: it runs end to end and
    recalls well above chance (chance R@1 with +-2 frames: 5 / 200)."""
    model = tmp_path / "thumb.onnx"
    thumbnail_model(model)
    root = data_root / "gardens-point-walking"
    out = tmp_path / "gp.csv"
    [row] = _ok(runner.invoke(app, ["localize", str(root / "day_left"), "--map", str(root / "day_right"),
                                    "--descriptor", "onnx", "--model", str(model), "--method", "catgraph",
                                    "--out", str(out), "--json"]))["runs"]
    assert row["frames"] == 200
    metrics = _ok(runner.invoke(app, ["evaluate", str(out), "--gt", "aligned", "--tolerance", "2", "--json"]))
    assert metrics["runs"][0]["recall_at_1"] > 0.25


def thumbnail_model(path: Path) -> None:
    """N x 3 x 32 x 64 -> N x 2048: channel mean (gray), minus the image's mean, flattened."""
    nodes = [helper.make_node("ReduceMean", ["image"], ["gray"], axes=[1], keepdims=1),
             helper.make_node("ReduceMean", ["gray"], ["level"], axes=[1, 2, 3], keepdims=1),
             helper.make_node("Sub", ["gray", "level"], ["centred"]),
             helper.make_node("Flatten", ["centred"], ["vector"])]
    _save(path, nodes, [], ["N", 3, 32, 64], ["N", 2048], {"wiloc.colour": "bgr"})


# ----------------------------------------------------------------------------------------- bad inputs

def _error(args: list[str]) -> tuple[int, str]:
    result = runner.invoke(app, args)
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return result.exit_code, lines[0]


@pytest.fixture
def one_frame(tmp_path: Path, cache_dir: Path) -> Path:
    colour_images(tmp_path / "route", 1)
    return tmp_path / "route"


def test_missing_model_file(one_frame: Path, tmp_path: Path) -> None:
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(tmp_path / "no.onnx")])
    assert code == 1 and line == f"error: {tmp_path / 'no.onnx'}: model file does not exist"


def test_model_missing_for_onnx(one_frame: Path) -> None:
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx"])
    assert code == 2 and "--model" in line


def test_model_for_another_descriptor(one_frame: Path, tmp_path: Path) -> None:
    code, line = _error(["describe", str(one_frame), "--model", str(tmp_path / "m.onnx")])
    assert code == 2 and line == "error: --model: applies to --descriptor onnx only"


def test_not_an_onnx_file(one_frame: Path, tmp_path: Path) -> None:
    bad = tmp_path / "m.onnx"
    bad.write_text("this is not a network\n")
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(bad)])
    assert code == 1 and line.startswith(f"error: {bad}: not an ONNX model onnxruntime can run")


def test_wrong_input_rank(one_frame: Path, tmp_path: Path) -> None:
    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("Identity", ["image"], ["vector"])]
    _save(model, nodes, [], ["N", 3 * SIDE * SIDE], ["N", 3 * SIDE * SIDE], {})
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model)])
    assert code == 1
    assert line == (f"error: {model}: input 'image' has rank 2 (N x 3072); need a 4-D image batch (N x 3 x H x W)")


def test_output_not_a_vector(one_frame: Path, tmp_path: Path) -> None:
    model = tmp_path / "m.onnx"
    conv_model(model, output_shape=["N", 8, 1, 1], flatten=False)
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model)])
    assert code == 1
    assert line == f"error: {model}: output 'vector' has shape N x 8 x 1 x 1; need one vector per image (N x D)"


@pytest.mark.parametrize("output", ["no values", "nan"])
def test_a_model_giving_no_values_or_nan_is_one_line_naming_it(output: str, one_frame: Path, tmp_path: Path) -> None:
    """A vector of 0 values ended in a ZeroDivisionError traceback (its scale is 1 / D); NaN rows
    in a line naming the descriptor, not the model, after numpy's warning of the division."""
    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]), helper.make_node("Flatten", ["pooled"], ["flat"])]
    if output == "no values":
        nodes.append(helper.make_node("Slice", ["flat", "zero", "zero", "one"], ["vector"]))
        constants = [numpy_helper.from_array(np.array([0], np.int64), "zero"),
                     numpy_helper.from_array(np.array([1], np.int64), "one")]
    else:  # the logarithm of a negative number
        nodes += [helper.make_node("Abs", ["flat"], ["size"]), helper.make_node("Add", ["size", "one"], ["above"]),
                  helper.make_node("Neg", ["above"], ["below"]), helper.make_node("Log", ["below"], ["vector"])]
        constants = [numpy_helper.from_array(np.array(1.0, np.float32), "one")]
    _save(model, nodes, constants, ["N", 3, SIDE, SIDE], ["N", None], {})
    result = runner.invoke(app, ["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model)])
    assert result.exit_code == 1 and result.stderr.strip().splitlines() == [
        f"error: {model}: " + ("the model gave an output of shape (1, 0) for 1 images; need one vector per image "
                               "(N x D, D at least 1)" if output == "no values" else
                               "the model gave NaN or infinite values for 1 of 1 images")], result.output


def test_bad_preprocessing_values(one_frame: Path, tmp_path: Path) -> None:
    model = tmp_path / "m.onnx"
    conv_model(model, metadata={"wiloc.std": "0,1,1"})
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model)])
    assert code == 2 and "metadata wiloc.std must be 3 positive numbers" in line
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", "std=1", "--preprocess", "colour=hsv"])
    assert code == 2 and line == "error: --preprocess: onnx colour must be one of rgb, bgr; got 'hsv'"
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", "gamma=2"])
    assert code == 2 and line.startswith("error: --preprocess: 'gamma=2': give KEY=VALUE")
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", "std=1", "--preprocess", "input_size=64x64"])
    assert code == 2 and line.startswith("error: --preprocess: ")
    assert "does not fit the model's fixed input of 32x32" in line
    conv_model(tmp_path / "good.onnx")
    for bad in ("std=0", "input_size=abc", "colour=xyz"):
        code, line = _error(["localize", str(one_frame), "--descriptor", "onnx", "--model",
                             str(tmp_path / "good.onnx"), "--preprocess", bad])
        assert code == 2 and line.startswith(f"error: --preprocess: onnx {bad.partition('=')[0]} must be"), line


def test_onnxruntime_missing(one_frame: Path, tmp_path: Path) -> None:
    """Without onnxruntime, the descriptor says how to install it (a fresh interpreter in which
    importing onnxruntime fails)."""
    model = tmp_path / "m.onnx"
    conv_model(model)
    code = ("import sys; sys.modules['onnxruntime'] = None\n"
            "from wiloc.__main__ import main; sys.exit(main())")
    result = subprocess.run([sys.executable, "-c", code, "describe", str(one_frame), "--descriptor", "onnx",
                             "--model", str(model)], capture_output=True, text=True, check=False)
    assert result.returncode == 1
    assert result.stderr.strip() == 'error: onnx: needs onnxruntime, an optional dependency: pip install "wiloc[onnx]"'


@pytest.mark.parametrize("size", ["100000x100000", "4097x32", "32x4097", "5000"])
def test_an_input_size_beyond_any_network_s_is_refused_at_once(size: str, one_frame: Path, tmp_path: Path) -> None:
    """A network of dynamic H and W is run once on a blank image of input_size to learn its D: a
    huge one was numpy's _ArrayMemoryError traceback (100000x100000), or the process killed for
    its memory (20000x20000). Sides above 4096 are refused before any is allocated."""
    model = tmp_path / "m.onnx"
    conv_model(model, input_shape=["N", 3, "H", "W"])
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", f"input_size={size}"])
    assert code == 2 and line.startswith("error: --preprocess: onnx input_size ") and "4096" in line, line


@pytest.mark.filterwarnings("error::RuntimeWarning")  # numpy's overflow warnings fail it
@pytest.mark.parametrize("bad, key", [("std=1e-40", "std"), ("std=1e39", "std"), ("std=1e-46", "std"),
                                      ("mean=1e39", "mean"), ("mean=-1e39", "mean"), ("mean=1e38", "mean and std")])
def test_preprocessing_beyond_float32_is_refused_without_numpy_warnings(bad: str, key: str, one_frame: Path,
                                                                        tmp_path: Path) -> None:
    """The samples are float32: a mean or std beyond its range, or a std so small that (x - mean) /
    std overflows, printed numpy's overflow warnings and then blamed the model for NaN values (a std
    of 1e39 turned every input into 0, silently). Each is refused up front, naming the key."""
    model = tmp_path / "m.onnx"
    conv_model(model)
    result = runner.invoke(app, ["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                                 "--preprocess", bad])
    lines = result.stderr.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.stderr
    assert lines[0].startswith(f"error: --preprocess: onnx {key} "), lines[0]


@pytest.mark.parametrize("normalise", ["true", "false"])
def test_a_model_giving_an_all_zero_vector_is_one_line_naming_it(normalise: str, one_frame: Path,
                                                                 tmp_path: Path) -> None:
    """Under cosine a zero vector's difference is undefined (it was 1 to every frame, each query
    decided as the map's first frame); normalising leaves it zero. Refused as imported zero rows
    are, not stored."""
    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
             helper.make_node("Flatten", ["pooled"], ["flat"]), helper.make_node("Sub", ["flat", "flat"], ["vector"])]
    _save(model, nodes, [], ["N", 3, SIDE, SIDE], ["N", 3], {})
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", f"normalise={normalise}"])
    assert code == 1
    assert line == f"error: {model}: the model gave an all-zero vector for 1 of 1 images (cosine difference undefined)"


def test_blank_padding_and_probe_images_may_give_zero_vectors(tmp_path: Path, cache_dir: Path) -> None:
    """Only the frames' own vectors are checked: the blank images a fixed batch is padded with,
    and the one a model of unknown vector length is first run on, may give zeros."""
    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
             helper.make_node("Flatten", ["pooled"], ["vector"])]
    _save(model, nodes, [], [4, 3, SIDE, SIDE], [4, None], {})  # blank inputs (mean 0) pool to zeros
    colour_images(tmp_path / "route", 3)
    [report] = _ok(runner.invoke(app, ["describe", str(tmp_path / "route"), "--descriptor", "onnx",
                                       "--model", str(model), "--json"]))["results"]
    assert report["computed"] == 3 and report["shape"] == [3, 3]


@pytest.mark.parametrize("probe", [False, True])
def test_a_model_failing_while_running_is_wiloc_s_one_line_only(probe: bool, one_frame: Path, tmp_path: Path) -> None:
    """onnxruntime logged its own escape-coded line on stderr (sequential_executor.cc ...
    ExecuteKernel) before wiloc's error, for a batch's run and for the run that learns the vector
    length (``probe``). Its log goes to the process's stderr, not Python's: a subprocess."""
    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
             helper.make_node("Reshape", ["pooled", "shape"], ["vector"])]  # fails unless N is 2
    _save(model, nodes, [numpy_helper.from_array(np.array([2, 3], np.int64), "shape")], ["N", 3, SIDE, SIDE],
          ["N", None if probe else 3], {})
    result = subprocess.run([sys.executable, "-m", "wiloc", "describe", str(one_frame), "--descriptor", "onnx",
                             "--model", str(model)], capture_output=True, text=True, check=False)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 1 and len(lines) == 1, result.stderr
    assert lines[0].startswith(f"error: {model}: the model failed on a batch of 1 ("), lines[0]


def test_a_repeated_preprocess_key_is_a_usage_error(one_frame: Path, tmp_path: Path) -> None:
    """The last of a key's values was kept without a word."""
    model = tmp_path / "m.onnx"
    conv_model(model)
    code, line = _error(["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model),
                         "--preprocess", "mean=0.1,0.1,0.1", "--preprocess", "std=1", "--preprocess", " mean=0.2"])
    assert code == 2
    assert line == "error: --preprocess: mean given twice ('mean=0.1,0.1,0.1', ' mean=0.2'); give each key once"


def test_zero_vectors_cached_before_they_were_refused_are_described_afresh(one_frame: Path, tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows cached by code version 1, which stored a model's zero vectors, were reused without
    the check: the descriptor's version is raised so that they are computed again (and refused)."""
    from wiloc.descriptors.learned import Onnx

    model = tmp_path / "m.onnx"
    nodes = [helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
             helper.make_node("Flatten", ["pooled"], ["flat"]), helper.make_node("Sub", ["flat", "flat"], ["vector"])]
    _save(model, nodes, [], ["N", 3, SIDE, SIDE], ["N", 3], {})
    args = ["describe", str(one_frame), "--descriptor", "onnx", "--model", str(model)]
    with monkeypatch.context() as before:  # version 1, which kept zero rows
        before.setattr(Onnx, "version", 1)
        before.setattr(Onnx, "compute_batch", classmethod(lambda cls, images, params, threads:
                                                          np.zeros((len(images), 3), np.float32)))
        assert runner.invoke(app, args).exit_code == 0
    code, line = _error(args)
    assert code == 1
    assert line.endswith("the model gave an all-zero vector for 1 of 1 images (cosine difference undefined)")

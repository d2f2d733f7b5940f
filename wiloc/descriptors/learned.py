"""The ``onnx`` descriptor: any image-to-vector network exported to ONNX, run with onnxruntime.

The network takes a batch of colour images, N x 3 x H x W float32, and gives one vector per
image, N x D. How an image becomes its input is read from the model's metadata
(``metadata_props``, keys ``wiloc.input_size``, ``wiloc.resize``, ``wiloc.mean``, ``wiloc.std``,
``wiloc.colour``, ``wiloc.normalise``) or given as parameters of the same names, which win:

1. the decoded BGR image in the network's colour order (``colour``: ``rgb`` or ``bgr``);
2. resized to ``input_size`` (w, h): ``stretch`` to it, or ``crop``: scaled so it covers it,
   then its centre cut out (area interpolation shrinking, bilinear enlarging);
3. samples / 255, minus ``mean``, divided by ``std`` (per channel, in the network's order);
4. the network's output rows, L2-normalised when ``normalise``; an all-zero row, whose cosine
   difference is undefined, normalised or not, is refused.

onnxruntime is an optional dependency (``pip install "wiloc[onnx]"``), imported only here, only
when an ``onnx`` descriptor is made; OpenCV where it is used (the command line reads the
declarations). docs/descriptors.md, "Learned descriptors (ONNX)".
"""
from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors.base import Descriptor, DescriptorSpec, check_names, scale_and_max
from wiloc.errors import WilocError
from wiloc.parameters import Parameters, declared, param

#: The model metadata keys read (``wiloc.`` + a parameter name), in the order the docs list them.
PREFIX = "wiloc."
KEYS = ("input_size", "resize", "mean", "std", "colour", "normalise")
RESIZES = ("stretch", "crop")
COLOURS = ("rgb", "bgr")
DEFAULTS: dict[str, Any] = {"resize": "stretch", "mean": [0.0, 0.0, 0.0], "std": [1.0, 1.0, 1.0],
                            "colour": "rgb", "normalise": True}
INSTALL = 'needs onnxruntime, an optional dependency: pip install "wiloc[onnx]"'
#: Images per inference run when the model's batch axis is dynamic: large enough that the
#: runtime's threads share out each run, small enough that a batch's inputs stay a few MB.
BATCH = 16
#: The largest input side taken (``input_size``): far above any place-recognition network's input
#: (224 to about 1024 a side), while a blank 4096 x 4096 image, which a network of dynamic H and W is
#: run on to learn its vector length, is 192 MiB of float32 before the network's own activations.
MAX_SIDE = 4096
#: The float32 range the preprocessing values and the inputs they give must stay within (its largest
#: value, its smallest normal one), as Python floats: a mean or std beyond it, or a std so small that
#: (x - mean) / std overflows, gave infinite inputs (a std of 1e39 silently zero ones).
FLOAT32_MAX, FLOAT32_TINY = float(np.finfo(np.float32).max), float(np.finfo(np.float32).tiny)
#: Input sample types taken, and the array type each is given as: a half-precision export
#: (``model.half()``) takes its batch as float16.
INPUT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16}


@dataclass(frozen=True)
class Network:
    """What a model file says about itself: its digest, its input, its vector length (None:
    known only by running it), and its ``wiloc.*`` metadata (``wiloc.`` removed)."""

    path: str
    digest: str
    input_size: tuple[int, int] | None  # (w, h) when the input's spatial axes are fixed
    length: int | None
    metadata: dict[str, str]


def _runtime() -> Any:
    try:
        import onnxruntime
    except ImportError:
        raise WilocError("onnx", INSTALL) from None
    return onnxruntime


def _model_bytes(path: Path) -> bytes:
    if not path.exists():
        raise WilocError(path, "model file does not exist")
    if not path.is_file():
        raise WilocError(path, "not a file (give an .onnx model file)")
    return path.read_bytes()


def _digest(path: Path) -> str:
    """The blake2b digest of the model file's bytes and, when its weights are kept in files
    beside it (external data: torch's exporter writes ``model.onnx.data``), of those files'
    names and bytes too: new weights under the same graph make a new descriptor."""
    data = _model_bytes(path)
    digest = hashlib.blake2b(data, digest_size=16)
    for name in external_files(data):
        digest.update(b"\0" + name.encode())
        weights = path.parent / name
        if weights.is_file():  # missing: onnxruntime refuses the model, naming it
            with weights.open("rb") as handle:
                while chunk := handle.read(1 << 24):
                    digest.update(chunk)
    return digest.hexdigest()


def external_files(model: bytes) -> list[str]:
    """The files an ONNX model's tensors keep their data in, read from its protobuf bytes without
    the onnx package: each tensor's ``external_data`` entry ``location`` (field 1, the key, then
    field 2, the value: ``0a 08 'location' 12 <length> <name>``)."""
    names = set()
    for found in re.finditer(rb"\x0a\x08location\x12", model):
        length, shift, at = 0, 0, found.end()
        while at < len(model):  # the value's length, a varint
            length |= (model[at] & 0x7F) << shift
            shift, at = shift + 7, at + 1
            if model[at - 1] < 0x80:
                break
        names.add(model[at:at + length].decode("utf-8", "replace"))
    return sorted(names)


@lru_cache(maxsize=4)
def _session(path: str, digest: str, threads: int) -> Any:
    """An inference session of the model at ``path`` whose bytes have ``digest``, on ``threads``
    intra-op threads (0: onnxruntime's default, every physical core). Kept for the next batch
    of the same model: making one parses and optimises the graph."""
    ort = _runtime()
    if _digest(Path(path)) != digest:
        raise WilocError(path, "the model file changed while in use; run again")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    # fatal only: wiloc reports problems itself, as one line; at 3 (errors) a kernel failing while
    # running also printed onnxruntime's own escape-coded log line on stderr before it
    options.log_severity_level = 4
    try:
        # from the path, not the bytes: a large model's weights may be in files beside it
        return ort.InferenceSession(path, sess_options=options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own classes, one per kind of refusal
        raise WilocError(path, f"not an ONNX model onnxruntime can run ({_said(exc, path)})") from None


def _said(exc: Exception, path: str) -> str:
    """The first line of an onnxruntime error, without its code prefix and the model's path
    (the error line names the file already)."""
    text = str(exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    first = re.sub(r"^\[ONNXRuntimeError\] : \d+ : ", "", first)
    return first.replace(f"Load model from {path} failed:", "").strip()


def open_network(model: str | Path) -> Network:
    """Check the model file and read what it says about itself; WilocError naming the file for a
    file that is missing, not ONNX, without one 4-D image input, or without a vector output."""
    path = Path(model).expanduser().resolve()
    digest = _digest(path)
    session = _session(str(path), digest, 0)
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if len(inputs) != 1:
        raise WilocError(path, f"the model has {len(inputs)} inputs; need one image batch input (N x 3 x H x W)")
    shape = inputs[0].shape
    if len(shape) != 4:
        raise WilocError(path, f"input '{inputs[0].name}' has rank {len(shape)} ({_shape(shape)}); "
                               "need a 4-D image batch (N x 3 x H x W)")
    if isinstance(shape[1], int) and shape[1] != 3:
        raise WilocError(path, f"input '{inputs[0].name}' has {shape[1]} channels ({_shape(shape)}); "
                               "need 3 colour channels (N x 3 x H x W)")
    if inputs[0].type not in INPUT_TYPES:
        raise WilocError(path, f"input '{inputs[0].name}' is a {inputs[0].type}; need {' or '.join(INPUT_TYPES)}")
    out = outputs[0].shape
    if len(out) != 2:
        raise WilocError(path, f"output '{outputs[0].name}' has shape {_shape(out)}; need one vector per "
                               "image (N x D)")
    meta = session.get_modelmeta().custom_metadata_map
    fixed = all(isinstance(side, int) and side > 0 for side in shape[2:])
    return Network(
        path=str(path), digest=digest,
        input_size=(shape[3], shape[2]) if fixed else None,
        length=out[1] if isinstance(out[1], int) and out[1] > 0 else None,
        metadata={key[len(PREFIX):]: value for key, value in meta.items() if key.startswith(PREFIX)})


def _shape(shape: Sequence[Any]) -> str:
    return " x ".join(str(side) if isinstance(side, int) else str(side or "?") for side in shape) or "scalar"


def preprocessing(network: Network, given: Mapping[str, Any]) -> dict[str, Any]:
    """Every preprocessing parameter, JSON-ready: each given one (a value or the text the
    metadata would hold), else the model's metadata, else the default (``input_size``: the
    input's fixed size). ValueError naming the parameter (and where it came from) when one
    cannot work."""
    unknown = sorted(set(network.metadata) - set(KEYS))
    if unknown:
        raise ValueError(f"{network.path}: unknown metadata key(s) {', '.join(PREFIX + k for k in unknown)}; "
                         f"valid: {', '.join(PREFIX + k for k in KEYS)}")
    params: dict[str, Any] = {}
    for key in KEYS:
        if given.get(key) is not None:
            value, source = given[key], f"onnx {key}"
        elif key in network.metadata:
            value, source = network.metadata[key], f"{network.path}: metadata {PREFIX}{key}"
        elif key == "input_size":
            if network.input_size is None:
                raise ValueError(f"{network.path}: the input's height and width are not fixed; give input_size "
                                 f"(WxH) or the metadata {PREFIX}input_size")
            value, source = list(network.input_size), "the model's input"
        else:
            value, source = DEFAULTS[key], key
        params[key] = _parse(key, value, source)
    extreme = max(max(abs(mean), abs(1 - mean)) / std for mean, std in zip(params["mean"], params["std"]))
    if extreme > FLOAT32_MAX:
        raise ValueError(f"onnx mean and std give inputs beyond float32's range ((samples / 255 - mean) / std up to "
                         f"{extreme:.2g}); got mean {params['mean']}, std {params['std']}")
    if network.input_size is not None and tuple(params["input_size"]) != network.input_size:
        w, h = network.input_size
        raise ValueError(f"{network.path}: input_size {_size_text(params['input_size'])} does not fit the "
                         f"model's fixed input of {w}x{h}")
    return params


def _size_text(size: Sequence[int]) -> str:
    return f"{size[0]}x{size[1]}"


def _parse(key: str, value: Any, source: str) -> Any:
    """One parameter from a value or its text form ('224x224', '0.485,0.456,0.406', 'rgb', 'true')."""
    if key == "input_size":
        parts = value.lower().replace("x", ",").split(",") if isinstance(value, str) else value
        parts = [parts] if isinstance(parts, int) else list(parts)
        try:
            size = [int(p) for p in parts]
        except (TypeError, ValueError):
            size = []
        size = size * 2 if len(size) == 1 else size
        if len(size) != 2 or min(size) < 1 or any(isinstance(p, float) and not float(p).is_integer() for p in parts):
            raise ValueError(f"{source} must be a size WxH (224x224) or one side (224); got {value!r}")
        if max(size) > MAX_SIDE:
            raise ValueError(f"{source} must be at most {MAX_SIDE} pixels a side, far above any network's input; "
                             f"got {_size_text(size)}")
        return size
    if key in ("mean", "std"):
        parts = value.split(",") if isinstance(value, str) else value
        try:
            numbers = [float(p) for p in ([parts] if isinstance(parts, (int, float)) else parts)]
        except (TypeError, ValueError):
            numbers = []
        numbers = numbers * 3 if len(numbers) == 1 else numbers
        low = FLOAT32_TINY if key == "std" else -FLOAT32_MAX  # a std below float32's normal ones overflows
        if len(numbers) != 3 or not all(low <= n <= FLOAT32_MAX for n in numbers):  # NaN too
            what = "positive numbers" if key == "std" else "numbers"
            raise ValueError(f"{source} must be 3 {what} (one per channel) or one for all, each from {low:.2g} to "
                             f"{FLOAT32_MAX:.2g} (float32's range); got {value!r}")
        return numbers
    if key == "normalise":
        text = str(value).strip().lower()
        if text not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"{source} must be true or false; got {value!r}")
        return text in ("true", "1", "yes")
    choices = RESIZES if key == "resize" else COLOURS
    text = str(value).strip().lower()
    if text not in choices:
        raise ValueError(f"{source} must be one of {', '.join(choices)}; got {value!r}")
    return text


def vector_length(network: Network, params: Mapping[str, Any]) -> int:
    """D, the length of the network's vectors: its output's fixed width, else found by running
    one blank image."""
    if network.length is not None:
        return network.length
    w, h = params["input_size"]
    return int(_run(network.path, network.digest, np.zeros((1, 3, h, w), np.float32), 1).shape[1])


def preprocess(image: NDArray[np.uint8], input_size: Sequence[int], resize: str, mean: Sequence[float],
               std: Sequence[float], colour: str) -> NDArray[np.float32]:
    """One 8-bit BGR image (H x W x 3) as the network's input, 3 x h x w float32."""
    import cv2

    w, h = input_size
    if colour == "rgb":
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if resize == "crop":
        factor = max(w / image.shape[1], h / image.shape[0])
        covering = (max(w, round(image.shape[1] * factor)), max(h, round(image.shape[0] * factor)))
        image = _resized(image, covering)
        top, left = (image.shape[0] - h) // 2, (image.shape[1] - w) // 2
        image = image[top:top + h, left:left + w]
    else:
        image = _resized(image, (w, h))
    x = image.astype(np.float32) / np.float32(255.0)
    x = (x - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def _resized(image: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.uint8]:
    """``image`` at ``size`` (w, h): area interpolation shrinking, bilinear enlarging, as it is."""
    import cv2

    if (image.shape[1], image.shape[0]) == size:
        return image
    shrinking = size[0] * size[1] < image.shape[0] * image.shape[1]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)


def _run(path: str, digest: str, batch: NDArray[np.float32], threads: int) -> NDArray[np.float32]:
    """The network's output for an input batch, checked to be one vector per image."""
    session = _session(path, digest, threads)
    [given] = session.get_inputs()
    try:
        out = session.run(None, {given.name: batch.astype(INPUT_TYPES[given.type], copy=False)})[0]
    except Exception as exc:  # onnxruntime's own error classes
        raise WilocError(path, f"the model failed on a batch of {batch.shape[0]} ({_said(exc, path)})") from None
    out = np.asarray(out)
    if out.ndim != 2 or out.shape[0] != batch.shape[0] or out.shape[1] == 0:
        raise WilocError(path, f"the model gave an output of shape {out.shape} for {batch.shape[0]} images; "
                               "need one vector per image (N x D, D at least 1)")
    bad = int((~np.isfinite(out).all(axis=1)).sum()) if out.dtype.kind == "f" else 0
    if bad:  # named here, the model's: as the rows of a descriptor they would name no file
        raise WilocError(path, f"the model gave NaN or infinite values for {bad} of {batch.shape[0]} images")
    return out.astype(np.float32, copy=False)


def compute_onnx(images: Sequence[NDArray[np.uint8]], *, model: str, model_digest: str,
                 input_size: Sequence[int], resize: str, mean: Sequence[float], std: Sequence[float],
                 colour: str, normalise: bool, threads: int = 0) -> NDArray[np.float32]:
    """The descriptors of 8-bit BGR images, one row each: preprocessed, run in batches (of
    :data:`BATCH`, or of the model's fixed batch size, the last one padded with blank images)
    on ``threads`` intra-op threads (0: onnxruntime's default), then L2-normalised when
    ``normalise``; WilocError naming the model when it gives an image an all-zero vector."""
    fixed = _session(model, model_digest, threads).get_inputs()[0].shape[0]
    padded = isinstance(fixed, int) and fixed > 0
    size = fixed if padded else BATCH
    inputs = [preprocess(image, input_size, resize, mean, std, colour) for image in images]
    rows = []
    for start in range(0, len(inputs), size):
        chunk = inputs[start:start + size]
        padding = [np.zeros_like(chunk[0])] * (size - len(chunk)) if padded else []
        rows.append(_run(model, model_digest, np.stack(chunk + padding), threads)[:len(chunk)])
    out = np.concatenate(rows) if rows else np.zeros((0, 0), np.float32)
    zero = int((~np.any(out != 0, axis=1)).sum())
    if zero:  # its cosine difference to anything is undefined (was 1): refused, as imported zero rows are
        raise WilocError(model, f"the model gave an all-zero vector for {zero} of {len(out)} images "
                                "(cosine difference undefined)")
    if normalise and out.size:
        norms = np.linalg.norm(out.astype(np.float64), axis=1, keepdims=True)
        out = (out / np.where(norms > 0, norms, 1.0)).astype(np.float32)
    return out


@dataclass(frozen=True)
class OnnxParams(Parameters):
    """The ``onnx`` descriptor's parameters: the model, and how an image becomes its input (each
    read from the model's metadata where not given)."""

    owner = "onnx"
    model: str = param(None, "The network, an .onnx file.")
    model_digest: str | None = param(None, "The model file's content digest; default: read from the file "
                                           "(given, it must match).")
    input_size: tuple[float, float] | None = param(None, "Input width and height; default: the model's metadata, "
                                                         "else its fixed input size.", low=1)
    resize: Literal["stretch", "crop"] | None = param(None, "stretch to the input size, or crop: cover it and cut "
                                                            "out the centre; default: the model's metadata, else stretch.")
    mean: tuple[float, float, float] | None = param(None, "Per channel, subtracted from samples / 255; default: the "
                                                          "model's metadata, else 0.")
    std: tuple[float, float, float] | None = param(None, "Per channel, dividing the samples after the mean; "
                                                         "default: the model's metadata, else 1.", low=0, low_open=True)
    colour: Literal["rgb", "bgr"] | None = param(None, "The network's channel order; default: the model's metadata, "
                                                       "else rgb.")
    normalise: bool | None = param(None, "L2-normalise the output vectors; default: the model's metadata, else true.")


class Onnx(Descriptor):
    """A network's vectors of colour images, compared by the cosine distance."""

    name = "onnx"
    Params = OnnxParams
    metric = "cosine"
    depends = "its model"
    version = 2  # 2: an all-zero row is refused (version 1 cached them, and reused they went unchecked)
    colour = True
    derived = ("model_digest",)
    libraries = ("opencv", "onnxruntime")  # OpenCV decodes and resizes, onnxruntime runs the network

    @classmethod
    def make(cls, given: Mapping[str, Any]) -> DescriptorSpec:
        """``model`` required; preprocessing parameters as text or values (``preprocessing``);
        ``model_digest`` read from the file (given, it must match)."""
        check_names(cls.name, given, [d.name for d in declared(cls.Params)])
        if not isinstance(given.get("model"), (str, Path)):
            raise ValueError(f"onnx needs model=<an .onnx model file>; got {given.get('model')!r}")
        network = open_network(given["model"])
        if given.get("model_digest") not in (None, network.digest):
            raise ValueError(f"onnx model_digest {given['model_digest']!r} does not match {network.path} "
                             f"(its content changed: {network.digest})")
        params = {"model": network.path, "model_digest": network.digest, **preprocessing(network, given)}
        cls.Params(**{k: tuple(v) if isinstance(v, list) else v for k, v in params.items()})
        length = vector_length(network, params)
        scale, natural_max = scale_and_max("cosine", length)
        return cls._spec(params, dtype=np.dtype(np.float32), length=length, scale=scale, min_size=None,
                         natural_max=natural_max)

    @classmethod
    def compute_batch(cls, images: Sequence[NDArray[np.uint8]], params: Mapping[str, Any],
                      threads: int) -> NDArray:
        return compute_onnx(images, threads=threads, **params)

"""Descriptor registry: name -> ``DescriptorSpec`` (how to compute, store and compare it).

A spec holds only data (name, parameters, storage facts); ``compute`` looks the kernel up by
name, so a spec pickles cheaply into worker processes. ``params`` always holds every parameter
(defaults filled in), so equal descriptors give equal cache keys.

Besides the built-in descriptors, installed packages may register their own under the entry-point
group ``wiloc.descriptors`` (:class:`DescriptorPlugin`); they are loaded on first use of a name
that is not built in, or when the descriptors are listed.
"""
from __future__ import annotations

import functools
import json
from importlib.metadata import entry_points
from pathlib import Path
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from wiloc.descriptors import bow, brisk_gist, gist, learned, sad
from wiloc.features import decode_size
from wiloc.vocabulary import read_vocabulary_header

DESCRIPTOR_NAMES = ("sad", "gist", "brisk-gist")
METRICS = ("l1", "sqeuclidean", "hamming", "cosine")
PLUGIN_GROUP = "wiloc.descriptors"
BUILT_IN = "built-in"

# Smallest decode (w, h) per descriptor that keeps its result: the resize target times a factor
# measured on Gardens Point (docs/descriptors.md, "Reduced decode").
SAD_DECODE_FACTOR = 6
GIST_DECODE_FACTOR = 1
BRISK_DECODE_FACTOR = 1

_COMPUTE: dict[str, Callable[..., NDArray]] = {
    "sad": sad.compute_sad,
    "gist": gist.compute_gist,
    "brisk-gist": brisk_gist.compute_brisk_gist,
    "bow": bow.compute_bow,
}
#: Kernels that describe several colour images at once (``compute_batch``).
_COMPUTE_BATCH: dict[str, Callable[..., NDArray]] = {
    "onnx": learned.compute_onnx,
}


@dataclass(frozen=True)
class DescriptorSpec:
    """Everything the pipeline needs to know about one descriptor with fixed parameters."""

    name: str
    params: Mapping[str, Any]
    metric: str
    dtype: np.dtype
    length: int
    scale: float
    min_size: tuple[int, int] | None
    natural_max: float | None
    colour: bool = False  # computed from 8-bit BGR images (H x W x 3), in batches: ``compute_batch``

    @property
    def key(self) -> str:
        """Canonical JSON of name and parameters: the descriptor part of a cache key."""
        return json.dumps({"name": self.name, "params": dict(self.params)}, sort_keys=True)

    def compute(self, image: NDArray[np.uint8]) -> NDArray:
        """Descriptor of one 8-bit image, flat, ``(length,)`` of ``dtype``: grayscale (H x W), or
        BGR (H x W x 3) for a ``colour`` descriptor."""
        if self.colour:
            return self.compute_batch([image])[0]
        if self.name in _COMPUTE:
            return _COMPUTE[self.name](image, **self.params)
        plugin = _plugins().found.get(self.name)
        if plugin is None:
            raise TypeError(f"'{self.name}' descriptors are imported, not computed")
        return plugin.descriptor.compute(image, **{k: self.params[k] for k in plugin.descriptor.params})

    def compute_batch(self, images: Sequence[NDArray[np.uint8]], threads: int = 0) -> NDArray:
        """Descriptors of several images, one row each: a ``colour`` descriptor's network runs
        them in batches on ``threads`` threads (0: its runtime's default); the others are
        computed one by one."""
        if self.name in _COMPUTE_BATCH:
            return _COMPUTE_BATCH[self.name](images, threads=threads, **self.params)
        return np.stack([self.compute(image) for image in images])


def _choose(value: Any, choices: tuple, what: str) -> Any:
    if value not in choices:
        raise ValueError(f"{what} must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return value


def _check_params(
    name: str, given: Mapping[str, Any], defaults: Mapping[str, Any]
) -> dict[str, Any]:
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        valid = ", ".join(defaults) or "none"
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for '{name}'; valid: {valid}")
    return {**defaults, **given}


def _sad(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("sad", params, {"crop": "none", "patch": 8, "storage": "uint8"})
    _choose(p["crop"], sad.CROPS, "sad crop")
    _choose(p["patch"], sad.PATCHES, "sad patch")
    _choose(p["storage"], sad.STORAGES, "sad storage")
    rows = 2 if p["crop"] == "top-half" else 1
    f = SAD_DECODE_FACTOR
    return DescriptorSpec(
        name="sad",
        params=p,
        metric="l1",
        dtype=np.dtype(np.float32 if p["storage"] == "float32" else np.uint8),
        length=sad.LENGTH,
        scale=sad.scale(p["storage"]),
        min_size=(sad.WIDTH * f, sad.HEIGHT * rows * f),
        natural_max=sad.natural_max(p["storage"]),
    )


def _gist(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("gist", params, {})
    side = gist.IMAGE_SIZE * GIST_DECODE_FACTOR
    return DescriptorSpec(
        name="gist",
        params=p,
        metric="sqeuclidean",
        dtype=np.dtype(np.float32),
        length=gist.LENGTH,
        scale=1.0,
        min_size=(side, side),
        natural_max=None,
    )


def _brisk_gist(params: Mapping[str, Any]) -> DescriptorSpec:
    p = _check_params("brisk-gist", params, {"keypoint_size": 48.0})
    size = p["keypoint_size"]
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not 4 <= size <= 96:
        raise ValueError(f"brisk-gist keypoint_size must be a number in [4, 96]; got {size!r}")
    p["keypoint_size"] = float(size)
    side = brisk_gist.IMAGE_SIZE * BRISK_DECODE_FACTOR
    return DescriptorSpec(
        name="brisk-gist",
        params=p,
        metric="hamming",
        dtype=np.dtype(np.uint8),
        length=brisk_gist.LENGTH,
        scale=1.0,
        min_size=(side, side),
        natural_max=float(brisk_gist.LENGTH * 8),
    )


def _bow(params: Mapping[str, Any]) -> DescriptorSpec:
    """Word presence over a vocabulary: ``file`` (a vocabulary .h5) required; ``vocabulary``, its
    key, is read from the file (given, it must match)."""
    p = _check_params("bow", params, {"file": None, "vocabulary": None})
    if not isinstance(p["file"], (str, Path)):
        raise ValueError(f"bow needs file=<vocabulary .h5 file>; got {p['file']!r}")
    file = Path(p["file"]).expanduser().resolve()
    key, vocabulary, n_words = read_vocabulary_header(file)
    if p["vocabulary"] not in (None, key):
        raise ValueError(f"bow vocabulary {p['vocabulary']!r} does not match {file} (key {key})")
    return DescriptorSpec(
        name="bow",
        params={"file": str(file), "vocabulary": key},
        metric="hamming",
        dtype=np.dtype(np.uint8),
        length=(n_words + 7) // 8,
        scale=1.0,
        min_size=decode_size(vocabulary.max_side),
        natural_max=float(n_words),
    )


def _external(params: Mapping[str, Any]) -> DescriptorSpec:
    """A user's matrix: ``metric`` and ``length`` required; ``dtype`` uint8 for hamming."""
    p = _check_params("external", params, {"metric": None, "length": None, "dtype": "float32"})
    metric, length, dtype = _storage("external", p["metric"], p["length"], p["dtype"])
    p["dtype"] = dtype.name
    scale, natural_max = _scale_and_max(metric, length)
    return DescriptorSpec(
        name="external",
        params=p,
        metric=metric,
        dtype=dtype,
        length=length,
        scale=scale,
        min_size=None,
        natural_max=natural_max,
    )


def _scale_and_max(metric: str, length: int) -> tuple[float, float | None]:
    """Scale and natural maximum of a descriptor of `length` values compared by `metric`, where
    nothing else is known of it (an imported matrix, a network's vectors, a plugin's)."""
    scales = {"l1": 1.0 / length, "sqeuclidean": 1.0, "hamming": 1.0, "cosine": 1.0}
    maxima = {"l1": None, "sqeuclidean": None, "hamming": 8.0 * length, "cosine": 2.0}
    return scales[metric], maxima[metric]


def _storage(what: str, metric: Any, length: Any, dtype: Any) -> tuple[str, int, np.dtype]:
    """A descriptor's metric, length and dtype, checked: a metric of METRICS, a positive length,
    packed bits (uint8) for hamming and floats for the others."""
    metric = _choose(metric, METRICS, f"{what} metric")
    if isinstance(length, bool) or not isinstance(length, int) or length < 1:
        raise ValueError(f"{what} length must be a positive integer; got {length!r}")
    dtype = np.dtype(dtype)
    if (metric == "hamming") != (dtype == np.uint8):
        raise ValueError("hamming descriptors are packed bits (uint8); other metrics need floats")
    return metric, length, dtype


def _onnx(params: Mapping[str, Any]) -> DescriptorSpec:
    """A network exported to ONNX (``wiloc.descriptors.learned``): ``model`` (an .onnx file)
    required; the preprocessing parameters from the model's metadata where not given;
    ``model_digest``, the file's content digest, is read from the file (given, it must match)."""
    p = _check_params("onnx", params, {"model": None, "model_digest": None, **{k: None for k in learned.KEYS}})
    if not isinstance(p["model"], (str, Path)):
        raise ValueError(f"onnx needs model=<an .onnx model file>; got {p['model']!r}")
    network = learned.open_network(p["model"])
    if p["model_digest"] not in (None, network.digest):
        raise ValueError(f"onnx model_digest {p['model_digest']!r} does not match {network.path} "
                         f"(its content changed: {network.digest})")
    preprocessing = learned.preprocessing(network, p)
    length = learned.vector_length(network, preprocessing)
    scale, natural_max = _scale_and_max("cosine", length)
    return DescriptorSpec(
        name="onnx",
        params={"model": network.path, "model_digest": network.digest, **preprocessing},
        metric="cosine",
        dtype=np.dtype(np.float32),
        length=length,
        scale=scale,
        min_size=None,
        natural_max=natural_max,
        colour=True,
    )


_BUILDERS: dict[str, Callable[[Mapping[str, Any]], DescriptorSpec]] = {
    "sad": _sad,
    "gist": _gist,
    "brisk-gist": _brisk_gist,
    "bow": _bow,
    "external": _external,
    "onnx": _onnx,
}


def get_descriptor(name: str, **params: Any) -> DescriptorSpec:
    """The spec of a named descriptor with the given parameters (defaults for the rest).

    ``external`` describes an imported matrix: ``get_descriptor("external", metric="cosine",
    length=D, dtype="float32")``; ``bow`` a vocabulary's word presence:
    ``get_descriptor("bow", file=VOCABULARY_H5)``; ``onnx`` a network's vectors:
    ``get_descriptor("onnx", model=MODEL_ONNX)``. Other names are looked up among the
    installed plugins (:class:`DescriptorPlugin`).
    """
    if name in _BUILDERS:
        return _BUILDERS[name](params)
    plugins = _plugins()
    if name not in plugins.found:
        choices = ", ".join([*DESCRIPTOR_NAMES, "bow", "onnx", *plugins.found])
        failed = next((f"; {problem}" for problem in plugins.problems if f"'{name}'" in problem), "")
        raise ValueError(f"unknown descriptor {name!r}; choose one of {choices}{failed}")
    return _plugin_spec(name, plugins.found[name], params)


# -------------------------------------------------------------------------------------------- plugins

@dataclass(frozen=True)
class DescriptorPlugin:
    """A descriptor that an installed package registers: the value of an entry point in the group
    ``wiloc.descriptors`` (the entry point's name is the descriptor's name). In its pyproject.toml::

        [project.entry-points."wiloc.descriptors"]
        tiny = "tiny_descriptor:TINY"     # TINY = DescriptorPlugin(compute=..., metric="l1", length=64)

    ``compute(gray, **params)`` gives the descriptor of one 8-bit grayscale image (H x W) as a flat
    ``(length,)`` array of ``dtype`` (packed bits, uint8, for ``hamming``); ``params`` are its
    parameters and their defaults (JSON values). It runs in worker processes, so it must be a
    module-level function. The cache keys its results by name, parameters and the package's
    version, so a new release of the package computes afresh.
    """

    compute: Callable[..., NDArray]
    metric: str
    length: int
    dtype: str = "float32"
    params: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class _Loaded:
    """A plugin that loaded: where it came from (``distribution version``) and what it registers."""

    origin: str
    descriptor: DescriptorPlugin


@dataclass(frozen=True)
class _Plugins:
    found: dict[str, _Loaded]
    problems: tuple[str, ...]  # one line per plugin that could not be loaded, naming it


@functools.cache
def _plugins() -> _Plugins:
    """The installed descriptor plugins, loaded once per process; a plugin that fails to load, or
    registers something that cannot work, is left out with one line saying why."""
    found: dict[str, _Loaded] = {}
    problems: list[str] = []
    for point in entry_points(group=PLUGIN_GROUP):
        origin = f"{point.dist.name} {point.dist.version}" if point.dist is not None else point.value
        where = f"descriptor plugin '{point.name}' ({origin})"
        if point.name in _BUILDERS or point.name in found:
            taken = found[point.name].origin if point.name in found else "a built-in descriptor"
            problems.append(f"{where}: the name is taken by {taken}; left out")
            continue
        try:
            plugin = point.load()
            if not isinstance(plugin, DescriptorPlugin):
                raise TypeError(f"{point.value} is a {type(plugin).__name__}, not a wiloc DescriptorPlugin")
            if not callable(plugin.compute):
                raise TypeError("its compute is not callable")
            _storage(point.name, plugin.metric, plugin.length, plugin.dtype)
            json.dumps(dict(plugin.params))
            if "plugin" in plugin.params:
                raise ValueError("'plugin' is wiloc's parameter (the package's version); name yours otherwise")
        except Exception as exc:  # anything a third-party import or declaration may raise
            said = str(exc).strip().splitlines()
            problems.append(f"{where} failed to load: {type(exc).__name__}{': ' + said[0] if said else ''}")
            continue
        found[point.name] = _Loaded(origin, plugin)
    return _Plugins(found, tuple(problems))


def plugin_problems() -> tuple[str, ...]:
    """One line per installed descriptor plugin that could not be loaded, naming it and why."""
    return _plugins().problems


def _plugin_spec(name: str, loaded: _Loaded, params: Mapping[str, Any]) -> DescriptorSpec:
    plugin = loaded.descriptor
    metric, length, dtype = _storage(name, plugin.metric, plugin.length, plugin.dtype)
    p = _check_params(name, params, {**plugin.params, "plugin": loaded.origin})
    if p["plugin"] != loaded.origin:
        raise ValueError(f"{name}: described by {p['plugin']}, but {loaded.origin} is installed")
    scale, natural_max = _scale_and_max(metric, length)
    return DescriptorSpec(name=name, params=p, metric=metric, dtype=dtype, length=length, scale=scale,
                          min_size=None, natural_max=natural_max)


@dataclass(frozen=True)
class DescriptorInfo:
    """One descriptor as ``describe --list-descriptors`` shows it: where it comes from
    (``built-in``, or a plugin's ``distribution version``), its metric and its length where
    they do not depend on its parameters (else None, and ``depends`` says on what)."""

    name: str
    source: str
    metric: str | None
    length: int | None
    depends: str = ""


def available_descriptors() -> list[DescriptorInfo]:
    """Every descriptor wiloc can compute or import: the built-in ones, then the plugins."""
    infos = []
    for name in DESCRIPTOR_NAMES:
        spec = get_descriptor(name)
        infos.append(DescriptorInfo(name, BUILT_IN, spec.metric, spec.length))
    infos += [DescriptorInfo("bow", BUILT_IN, "hamming", None, "its vocabulary"),
              DescriptorInfo("onnx", BUILT_IN, "cosine", None, "its model"),
              DescriptorInfo("external", BUILT_IN, None, None, "the imported matrix")]
    for name, loaded in _plugins().found.items():
        infos.append(DescriptorInfo(name, loaded.origin, loaded.descriptor.metric, loaded.descriptor.length))
    return infos
